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


def _paced(pace, costs, calls):
    """Run `calls` calls of `pace`'s choice, with the cost per item of each build from
    `costs(parallel, call)` fed to `record` (no clock: the choice is tested, not timing)."""
    chosen = []
    for c in range(calls):
        par = pace.pick()
        pace.record(par, costs(par, c), 1)
        chosen.append(par)
    return chosen


def test_pace_measures_both_builds_then_runs_the_cheaper_and_probes_the_other():
    pace = parallel.Pace()
    chosen = _paced(pace, lambda par, c: 1.0 if par else 3.0, 1000)
    # Two calls of each build first (the first of each is not measured), parallel first.
    assert chosen[:4] == [True, True, False, False]
    assert pace.serial == 3.0 and pace.parallel_cost() == 1.0
    # Then the serial build once every PROBE_EVERY times 3 (the ratio of the costs) calls.
    probes = [c for c in range(4, 1000) if not chosen[c]]
    assert np.diff(probes).tolist() == [3 * parallel.Pace.PROBE_EVERY] * (len(probes) - 1)


def test_pace_follows_the_load_both_ways():
    # A held core makes the parallel build stall (cost 10 against the serial build's 3
    # and its usual 1): the choice moves to serial after two stalled calls, and back
    # once the probes have seen the stalls stop for a while.
    pace = parallel.Pace()
    load = (300, 3000)  # calls during which another process holds a core
    costs = lambda par, c: (10.0 if load[0] <= c < load[1] else 1.0) if par else 3.0  # noqa: E731
    chosen = _paced(pace, costs, 8000)
    # stall shares 1/8 (expected cost 2.1) then 15/64 (3.1 > 3)
    assert chosen[300] and chosen[301] and not any(chosen[302:310])
    # Under the load the parallel build runs only as a probe, ever more rarely (its cost
    # rises towards 10: a probe every ~32 x 10/3 calls at most).
    during = [c for c in range(302, 3000) if chosen[c]]
    assert 2 <= len(during) <= 2700 // 80 and np.diff(during[-5:]).min() >= 100
    # After the load: calm probes halve the stall share each, below 2/9 (cost 3).
    first = next(c for c in range(3000, 8000) if chosen[c] and chosen[c + 1])
    assert first < 3000 + 3 * 10 / 3 * parallel.Pace.PROBE_EVERY
    assert sum(chosen[first:]) > 0.98 * (8000 - first)


def test_pace_rare_long_stalls_choose_serial():
    # 1 parallel call in 30 stalls at 60x the usual cost 1: its mean (~3) is above the
    # serial build's 1.6 though its median is not. The calls' mean cost stays near the
    # serial build's, well below the parallel one's.
    pace = parallel.Pace()
    seen = [0]

    def costs(par, c):
        if not par:
            return 1.6
        seen[0] += 1
        return 60.0 if seen[0] % 30 == 0 else 1.0

    spent = []
    for c in range(20000):
        par = pace.pick()
        spent.append(costs(par, c))
        pace.record(par, spent[-1], 1)
    assert np.mean(spent[2000:]) < 1.1 * 1.6


def test_pace_forced_builds_and_one_thread():
    pace = parallel.Pace()
    runs = []
    ser, par = (lambda v: runs.append("s") or v), (lambda v: runs.append("p") or v)
    assert pace.run(10, "serial", ser, par, 7) == 7 and pace.run(10, "parallel", ser, par, 8) == 8
    assert runs == ["s", "p"] and pace.calls == 0  # forced calls are not measured
    numba.set_num_threads(1)
    try:
        runs.clear()
        for _ in range(5):
            pace.run(10, "adaptive", ser, par, 0)
        assert runs == ["s"] * 5  # one thread: no region to pay for
    finally:
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
