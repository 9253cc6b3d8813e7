"""512-bit vectors for marked kernels only (`penfree.core.vector_width`)."""

import llvmlite.binding as llvm
import numpy as np
import pytest
from numba import njit, prange

from penfree.core.fit import kernels
from penfree.core.parallel import named
from penfree.core.vector_width import ATTRIBUTE, wide

_FASTMATH = {"reassoc", "contract"}  # as the fit's kernels: the sums may be split over lanes


def _squares_py(x, n_chunks):
    # float64 sums of float32 squares over fixed chunks, as the fit's passes
    part = np.zeros(n_chunks)
    n = x.shape[0]
    for k in prange(n_chunks):
        s = 0.0
        for i in range(k * n // n_chunks, (k + 1) * n // n_chunks):
            s += np.float64(x[i]) * np.float64(x[i])
        part[k] = s
    return part.sum()


def _pair(parallel):
    """The same source compiled wide and at the default width (not cached: inspected)."""
    tag = "par" if parallel else "ser"
    wide_k = wide(njit(parallel=parallel, fastmath=_FASTMATH)(named(_squares_py, f"_test_wide_{tag}")))
    plain = njit(parallel=parallel, fastmath=_FASTMATH)(named(_squares_py, f"_test_plain_{tag}"))
    return wide_k, plain


def _has_avx512():
    return llvm.get_host_cpu_features().flatten().find("+avx512f") >= 0


@pytest.mark.parametrize("parallel", [False, True], ids=["serial", "parallel"])
def test_only_the_marked_kernel_gets_the_attribute(parallel):
    wide_k, plain = _pair(parallel)
    x = np.arange(10_000, dtype=np.float32)  # squares and their sums are exact integers
    exact = float(sum(i * i for i in range(10_000)))
    # the wide kernel compiles first: nothing it marks may leak into the plain one
    assert wide_k(x, 8) == plain(x, 8) == exact
    assert ATTRIBUTE in wide_k.inspect_llvm(wide_k.signatures[0])
    assert ATTRIBUTE not in plain.inspect_llvm(plain.signatures[0])


@pytest.mark.skipif(not _has_avx512(), reason="the host has no AVX-512: the width changes nothing")
@pytest.mark.parametrize("parallel", [False, True], ids=["serial", "parallel"])
def test_the_marked_loops_use_512_bit_registers(parallel):
    # The parallel build's loop is Numba's parfor gufunc, compiled inside the kernel's
    # own compile: it must be wide too (its assembly is part of the kernel's).
    wide_k, plain = _pair(parallel)
    x = np.ones(4096, dtype=np.float32)
    wide_k(x, 4), plain(x, 4)
    assert "zmm" in wide_k.inspect_asm(wide_k.signatures[0])
    if "zmm" in plain.inspect_asm(plain.signatures[0]):
        # LLVM already prefers 512-bit vectors on this CPU (AMD Zen 4 does; Intel's
        # AVX-512 cores prefer 256): the mark changes nothing here, and the check above
        # proves nothing. That no attribute leaks is checked on every host (above).
        pytest.skip(f"LLVM's default vector width for {llvm.get_host_cpu_name()} is already 512 bits")


def test_the_fit_passes_that_gain_are_marked():
    # float64 maps ran 1.1-1.2x slower wide: those builds stay at the default width.
    for k in (kernels._moments_serial, kernels._moments_parallel, kernels._apply_wide_serial,
              kernels._apply_wide_parallel):
        assert getattr(k.compile, "wide", False), k.py_func.__name__
    for k in (kernels._apply_serial, kernels._apply_parallel):
        assert not getattr(k.compile, "wide", False), k.py_func.__name__
