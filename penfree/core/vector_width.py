"""512-bit vectors for chosen kernels, on CPUs that have them.

LLVM compiles Numba's kernels for the host CPU, but on the Intel cores with AVX-512
(Skylake-server and later) it *prefers* 256-bit vectors: a loop of float64 sums over
float32 positions then runs 4 vertices wide, and the fit's passes are bound by that
arithmetic, not by memory. Numba sets no vector width per function, and its
process-wide setting (``NUMBA_CPU_FEATURES``) would change every Numba user's code.

`wide` marks one dispatcher. While it compiles, the LLVM functions of its own code and
of its ``prange`` bodies (Numba's parfor gufuncs, compiled inside it) get the function
attribute ``"prefer-vector-width"="512"``. Numba's own overloads compiled on the way,
and the other kernels, keep the default (only the ``prange`` bodies of a kernel that a
marked one calls, if it were compiled on the way, would be wide too: the fit's kernels
call none). The compiled code is cached as any other kernel's.

- The arithmetic is the same. Under the fit's ``reassoc`` flag a sum is split over more
  lanes, so its last bits depend on the width, as they already depend on the CPU;
  both builds of a kernel are wide, so serial and parallel still agree bit for bit.
- Without AVX-512 the attribute changes nothing.
- Not every loop gains: the float64 map with its summaries ran 1.1-1.2x slower wide,
  so only the passes measured faster are marked (`penfree.core.fit.kernels`).
- If Numba lacks the hook this uses (``CPUContext.post_lowering``), kernels compile at
  the default width, and nothing else changes.
"""

from __future__ import annotations

import threading

#: The LLVM function attribute (a string attribute: llvmlite's `add` takes enum ones only).
ATTRIBUTE = '"prefer-vector-width"="512"'

#: The name prefix of the functions Numba compiles for the bodies of ``prange`` loops.
_GUFUNC_PREFIX = "__numba_parfor_gufunc"

#: Per thread, the names of the wide dispatchers compiling (Numba compiles in the caller).
_compiling = threading.local()


def _marked(library_name: str) -> bool:
    stack = getattr(_compiling, "names", None)
    return bool(stack) and (library_name == stack[-1] or library_name.startswith(_GUFUNC_PREFIX))


def _with_attribute(post_lowering):
    def hooked(self, mod, library):
        if _marked(library.name):
            for fn in mod.functions:
                if not fn.is_declaration:
                    set.add(fn.attributes, ATTRIBUTE)
        return post_lowering(self, mod, library)

    hooked.penfree_wide = True
    return hooked


def _install() -> bool:
    """Put the hook in front of Numba's CPU ``post_lowering`` (once); False without one."""
    try:
        from numba.core.cpu import CPUContext
    except ImportError:  # pragma: no cover - another Numba layout
        return False
    hook = getattr(CPUContext, "post_lowering", None)
    if hook is None:  # pragma: no cover
        return False
    if not getattr(hook, "penfree_wide", False):
        CPUContext.post_lowering = _with_attribute(hook)
    return True


def wide(dispatcher):
    """Compile `dispatcher` (an ``njit`` dispatcher) with 512-bit vectors preferred.

    Returns the same dispatcher, whose `compile` now marks its code while it runs.
    A specialisation loaded from Numba's cache is not compiled again.
    """
    if not hasattr(dispatcher, "py_func") or not _install():  # NUMBA_DISABLE_JIT: a plain function
        return dispatcher
    compile_ = dispatcher.compile
    name = dispatcher.py_func.__qualname__

    def compile(sig):
        stack = _compiling.__dict__.setdefault("names", [])
        stack.append(name)
        try:
            return compile_(sig)
        finally:
            stack.pop()

    compile.wide = True
    dispatcher.compile = compile
    return dispatcher
