"""Serial or parallel: one rule, by the size of the work, for every dual-build kernel.

A Numba parallel region costs tens of microseconds on an idle machine, and on a
loaded one it waits for every worker thread to be scheduled: with another process
holding one of two cores, a 0.1 ms region took 3-5 ms (issue 13). Kernels whose
loops write only their own slots (or reduce over fixed chunks) are therefore
compiled twice from one source, and `parallel_kernel` runs the parallel build
only when the work is large enough to pay for a region even when a thread is
late. Both builds give the same bits, so the choice never changes a result.

Below that size the *parallel* build runs on the calling thread alone (``numba``'s
thread count set to 1 for the call: no other thread is woken or waited for). Its
loop body is the faster code: Numba compiles a parallel loop body as a separate
function with ``noalias`` arguments, and the plain serial build of the same source
measured 1.1-3.8x slower (the broad phase's distance folds, 64K scenes, one thread,
issue 13); running the parallel build on one thread costs ~3 us more per call
(2.45 GHz Zen 3: 3.5 us against 0.5 us for a 100-item loop).
The serial build stays as the tests' oracle of the same bits.
"""

from __future__ import annotations

import types

import numba
import numba.np.ufunc.parallel as _numba_parallel
from numba import njit

#: Work items (pairs, vertices, ...) below which a parallel region does not pay.
#: At ~20-50 ns per item, 1<<15 items is ~1 ms of serial work: a descheduled
#: worker (a few ms on a loaded 2-core machine) would cost more than it saves.
PARALLEL_MIN_WORK = 1 << 15


def named(fn, name):
    """A copy of `fn` under another qualified name.

    Numba's on-disk cache is keyed by the qualified name: each compiled variant
    gets its own, so the serial and parallel builds never share a cache entry.
    """
    f = types.FunctionType(fn.__code__, fn.__globals__, name, fn.__defaults__, fn.__closure__)
    f.__qualname__ = name
    return f


def use_parallel(work: int, min_work: int = PARALLEL_MIN_WORK) -> bool:
    """True when `work` items justify a parallel region (and there is more than one thread)."""
    return work >= min_work and thread_count() > 1


class _Dual:
    """Serial and parallel builds of one kernel; called as ``kernel(work, *args)``."""

    def __init__(self, fn, name, min_work, jit_options):
        self.serial = njit(cache=True, **jit_options)(named(fn, name + "_serial"))
        self.parallel = njit(cache=True, parallel=True, **jit_options)(named(fn, name + "_parallel"))
        self.min_work = min_work

    def __call__(self, work, *args):
        if use_parallel(work, self.min_work):
            return self.parallel(*args)
        return one_thread(self.parallel, *args)


def _thread_count_calls():
    """Numba's thread-count getter and setter: the ctypes entry points behind
    `numba.get_num_threads` / `set_num_threads` when this Numba has them (set once
    its threads are launched), else those public functions.

    The public pair takes a lock and checks its argument on every call: ~2-3 us each
    on a 2.45 GHz Zen 3, which made `one_thread` cost 14 us a call, where the entry
    points cost 0.3-0.8 us and the call ~3.5 us (issue 13: a client replay's queries
    on a 600-vertex scene make ~20 such calls each).
    """
    numba.get_num_threads()  # launches the threads: the entry points exist from here on
    get = getattr(_numba_parallel, "_get_num_threads", None)
    put = getattr(_numba_parallel, "_set_num_threads", None)
    if callable(get) and callable(put):
        return get, put
    return numba.get_num_threads, numba.set_num_threads


_get_threads = _set_threads = None


def thread_count() -> int:
    """`numba.get_num_threads()` (the calling thread's count), through `_thread_count_calls`."""
    global _get_threads, _set_threads
    if _get_threads is None:
        _get_threads, _set_threads = _thread_count_calls()
    return _get_threads()


def one_thread(kernel, *args):
    """``kernel(*args)`` with Numba's thread count (thread-local) at 1 for the call."""
    n = thread_count()
    if n == 1:
        return kernel(*args)
    _set_threads(1)
    try:
        return kernel(*args)
    finally:
        _set_threads(n)


def parallel_kernel(fn, name, min_work=PARALLEL_MIN_WORK, **jit_options):
    """Compile `fn` (a function with ``prange`` loops) serially and in parallel.

    Parameters
    ----------
    fn : function
        Kernel source; its loops must give the same bits in both builds (each
        iteration writes only its own slot, or reduces over fixed chunks).
    name : str
        Unique base name for Numba's cache.
    min_work : int
        Work below which the serial build runs.
    **jit_options
        Extra ``njit`` options (never ``fastmath`` for distance kernels).

    Returns
    -------
    callable
        ``kernel(work, *args)``.
    """
    return _Dual(fn, name, min_work, jit_options)
