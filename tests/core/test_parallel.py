"""The serial / parallel dispatch rule: by work size and thread count, and both builds of
a kernel give the same bits (the serial build is the oracle)."""

import numba
import numpy as np
from numba import prange

from penfree.core import parallel
from penfree.core.parallel import parallel_kernel, use_parallel


def _square_py(a, out):
    for i in prange(a.shape[0]):
        out[i] = a[i] * a[i] + 1.0


_square = parallel_kernel(_square_py, "_test_square", min_work=100)


def test_use_parallel_by_work_and_threads():
    assert not use_parallel(10, 100)
    assert use_parallel(100, 100) == (numba.get_num_threads() > 1)
    numba.set_num_threads(1)
    try:
        assert not use_parallel(10**9, 100)
    finally:
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)


def test_both_builds_same_bits():
    a = np.random.default_rng(0).normal(size=1000)
    s, p = np.empty_like(a), np.empty_like(a)
    _square.serial(a, s)
    _square.parallel(a, p)
    np.testing.assert_array_equal(s, p)
    d = np.empty_like(a)
    _square(a.size, a, d)
    np.testing.assert_array_equal(s, d)


def test_named_copies_get_their_own_cache_names():
    f = parallel.named(_square_py, "_x_named")
    assert f.__qualname__ == "_x_named" and f.__code__ is _square_py.__code__


def test_small_work_runs_the_parallel_build_on_one_thread(monkeypatch):
    # Below min_work the call runs the parallel build with one thread (its loop body is
    # the faster code) and gives the serial build's bits; the thread count comes back.
    a = np.random.default_rng(1).normal(size=50)
    s, d = np.empty_like(a), np.empty_like(a)
    _square.serial(a, s)
    seen = []
    real = _square.parallel

    def spy(*args):
        seen.append(numba.get_num_threads())
        return real(*args)

    before = numba.get_num_threads()
    monkeypatch.setattr(_square, "parallel", spy)
    _square(a.size, a, d)
    np.testing.assert_array_equal(s, d)
    assert seen == [1] and numba.get_num_threads() == before
