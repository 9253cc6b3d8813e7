"""The serial / parallel dispatch rule: by work size and thread count, and both builds of
a kernel give the same bits (the serial build is the oracle)."""

import os
import subprocess
import sys
import textwrap
import time

import numba
import numpy as np
import pytest
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


def _claims_py(counter, n_chunks, taken, workers):
    for w in prange(workers.shape[0]):
        c = parallel.claim(counter)
        while c < n_chunks:
            taken[c] += 1
            workers[w] += 1
            c = parallel.claim(counter)


_claims = parallel_kernel(_claims_py, "_test_claims", min_work=0)


def test_claim_hands_out_every_chunk_once():
    # Workers claiming chunks from one counter (an atomic fetch-and-add): every chunk is
    # taken exactly once, on one thread and on two, by either build; each worker's last
    # claim overshoots once.
    for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
        numba.set_num_threads(threads)
        try:
            for kernel in (_claims.serial, _claims.parallel):
                for n_chunks, n_workers in ((0, 2), (1, 2), (1000, 2), (1000, 7), (5, 1)):
                    counter = parallel.work_counter()
                    taken = np.zeros(n_chunks, dtype=np.int64)
                    workers = np.zeros(n_workers, dtype=np.int64)
                    kernel(counter, n_chunks, taken, workers)
                    assert np.all(taken == 1)
                    assert workers.sum() == n_chunks
                    assert counter[0] == n_chunks + n_workers
        finally:
            numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)


def _range_claims_py(counter, taken, seq):
    # seq[w] lists the chunks worker w claimed, in its order (-1 after the last).
    for w in prange(counter[-1]):
        n = 0
        c, k = parallel.claim_next(counter, w, 0)
        while c >= 0:
            taken[c] += 1
            seq[w, n] = c
            n += 1
            c, k = parallel.claim_next(counter, w, k)


_range_claims = parallel_kernel(_range_claims_py, "_test_range_claims", min_work=0)


def test_range_counter_splits_the_chunks_into_one_range_per_worker():
    np.testing.assert_array_equal(parallel.range_counter(10, workers=3), [0, 3, 6, 3, 6, 10, 3])
    np.testing.assert_array_equal(parallel.range_counter(2, workers=3), [0, 0, 1, 0, 1, 2, 3])
    np.testing.assert_array_equal(parallel.range_counter(0, workers=2), [0, 0, 0, 0, 2])
    assert parallel.range_counter(5)[-1] == parallel.thread_count()


def test_claims_by_ranges_hand_out_every_chunk_once_own_range_first():
    # Every chunk is taken exactly once, on one thread and on two, by either build, for
    # more or fewer workers than chunks. Each worker takes its own range first, then the
    # next ranges in turn, each range's chunks in order (a thread works through
    # contiguous rows); on one thread, worker 0 takes every chunk in order.
    for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
        numba.set_num_threads(threads)
        try:
            for kernel in (_range_claims.serial, _range_claims.parallel):
                for n_chunks, n_workers in ((0, 2), (1, 2), (2, 3), (1000, 2), (1000, 7), (5, 1), (3, 7)):
                    counter = parallel.range_counter(n_chunks, workers=n_workers)
                    ends = counter[n_workers:2 * n_workers].copy()
                    taken = np.zeros(n_chunks, dtype=np.int64)
                    seq = np.full((n_workers, n_chunks), -1, dtype=np.int64)
                    kernel(counter, taken, seq)
                    assert np.all(taken == 1)
                    for w in range(n_workers):
                        got = seq[w][seq[w] >= 0]
                        owner = np.searchsorted(ends, got, side="right")  # the range of each chunk
                        turn = (owner - w) % n_workers  # 0: its own range, 1: the next one, ...
                        assert np.all(np.diff(turn) >= 0)
                        for r in np.unique(owner):
                            assert np.all(np.diff(got[owner == r]) > 0)
                    if kernel is _range_claims.serial or threads == 1:
                        np.testing.assert_array_equal(seq[0][:n_chunks], np.arange(n_chunks))
        finally:
            numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)


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


def _by_parallel_call(serial, cost_of_call):
    """`costs(parallel, call)` for `_paced`: `serial` for the serial build, and
    ``cost_of_call(k)`` for the k-th call of the parallel build (from 1)."""
    count = [0]

    def costs(par, c):
        if not par:
            return serial
        count[0] += 1
        return cost_of_call(count[0])

    return costs


def test_pace_measures_both_builds_then_runs_the_cheaper_and_probes_the_other():
    pace = parallel.Pace()
    chosen = _paced(pace, lambda par, c: 1.0 if par else 3.0, 1000)
    # Three calls of each build first (the first of each is not measured), serial first.
    assert chosen[:6] == [False] * 3 + [True] * 3
    assert pace.serial == 3.0 and pace.parallel_cost() == 1.0
    # Then the serial build once every PROBE_EVERY times 3 (the ratio of the costs) calls.
    probes = [c for c in range(6, 1000) if not chosen[c]]
    assert np.diff(probes).tolist() == [3 * parallel.Pace.PROBE_EVERY] * (len(probes) - 1)


def test_pace_one_cold_early_call_does_not_keep_the_slower_build():
    # The first measured parallel call is 3x its usual cost (a cold cache, issue 13: the
    # apply pass at 64K measured 310 us once, then 90 us against the serial 156 us). The
    # second sample replaces it (noise only adds time), so the parallel build runs from
    # the first choice on, not after the probes have averaged the outlier away.
    pace = parallel.Pace()
    chosen = _paced(pace, _by_parallel_call(1.7, lambda k: 3.0 if k == 2 else 1.0), 200)
    assert pace.usual == 1.0
    assert all(chosen[6:6 + 3 * parallel.Pace.PROBE_EVERY // 2])
    assert sum(chosen[6:]) > 0.97 * (200 - 6)


def test_pace_cost_estimates_drop_at_once_and_rise_gradually():
    pace = parallel.Pace()
    samples = {True: iter([9.0, 1.0, 1.0]), False: iter([9.0, 5.0, 4.0])}
    _paced(pace, lambda par, c: next(samples[par]), 6)
    assert pace.usual == 1.0 and pace.serial == 4.0  # the lower sample at once
    assert pace.pick()
    pace.record(True, 2.0, 1)
    assert pace.usual == 1.0 + parallel.Pace.ALPHA * (2.0 - 1.0)  # a higher one by ALPHA
    pace.record(True, 3.0, 1, warm=False)  # a call after a pause only ever lowers it
    assert pace.usual == 1.0 + parallel.Pace.ALPHA * (2.0 - 1.0)
    pace.record(True, 0.5, 1, warm=False)
    assert pace.usual == 0.5


def test_pace_returns_to_parallel_though_its_probes_pay_the_wake_up():
    # In seconds, one item a call: the serial build 170 us; the parallel one 100 us in a
    # row, 300 us right after serial calls (its threads slept: issue 13 measured 53 us
    # in a row and ~250 us after 10 ms of other work), 1 ms while another process holds
    # a core (calls 100-1000). After the load, the calm probes (each after serial calls,
    # so each 300 us) end the stall share and the parallel build runs again; a probe's
    # wake-up is neither a stall (0.2 ms over its usual time) nor raises its usual cost.
    pace = parallel.Pace()
    chosen = []
    for c in range(6000):
        par = pace.pick()
        warm = bool(chosen) and chosen[-1]
        cost = (1e-3 if 100 <= c < 1000 else (1e-4 if warm else 3e-4)) if par else 1.7e-4
        pace.record(par, cost, 1, warm=warm)
        chosen.append(par)
    assert sum(chosen[10:100]) >= 88 and sum(chosen[102:1000]) < 900 // 32  # serial probes; parallel ones
    assert sum(chosen[2000:]) > 0.98 * 4000
    assert pace.usual == 1e-4


def test_pace_run_calls_a_parallel_call_after_a_pause_cold(monkeypatch):
    # run() tells record() whether the threads may have slept: a parallel call that
    # starts COLD_GAP_S after the last parallel call of any Pace.
    seen = []
    monkeypatch.setattr(parallel.Pace, "record", lambda self, par, s, work, warm=True: seen.append((par, warm)))
    monkeypatch.setattr(parallel.Pace, "pick", lambda self: True)
    monkeypatch.setattr(parallel, "thread_count", lambda: 2)
    pace = parallel.Pace()
    for pause in (0.0, 0.0, 2 * parallel.Pace.COLD_GAP_S, 0.0):
        time.sleep(pause)
        pace.run(1, "adaptive", len, len, "ab")
    assert [warm for _, warm in seen[1:]] == [True, False, True]


def test_pace_does_not_measure_a_call_that_compiled_or_loaded_a_specialisation(monkeypatch):
    # Issue 13: the first float64 call after float32 ones loaded its specialisation from
    # the cache (3.9 ms against 50 us); measured, it counted as a stall and held the
    # serial build for 500 calls.
    seen = []
    monkeypatch.setattr(parallel.Pace, "record", lambda self, par, s, work, warm=True: seen.append(par))
    monkeypatch.setattr(parallel, "thread_count", lambda: 2)

    class Dispatcher:  # Numba's: one compiled specialisation per argument type
        def __init__(self):
            self.overloads = {}

        def __call__(self, dtype):
            self.overloads.setdefault(dtype, object())

    pace, serial, par = parallel.Pace(), Dispatcher(), Dispatcher()
    for dtype in ("f4", "f4", "f8", "f8", "f4"):
        pace.run(1, "adaptive", serial, par, dtype)
    assert seen == [False] * 3  # the first call of each dtype is not measured


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
    costs = _by_parallel_call(1.6, lambda k: 60.0 if k % 30 == 0 else 1.0)
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


def test_chunk_count_bounds():
    # at least one chunk; at most `most`; no chunk below `least_each` items when there is work for one
    assert parallel.chunk_count(0, 8, 4) == 1
    assert parallel.chunk_count(3, 8, 4) == 1
    assert parallel.chunk_count(10, 8, 4) == 2
    assert parallel.chunk_count(10**6, 8, 4) == 8


def test_limit_spin_wait_sets_the_spin_count_unless_the_user_chose():
    env = {}
    assert parallel.limit_spin_wait(env)
    assert env == {"GOMP_SPINCOUNT": str(parallel.SPIN_COUNT)}
    for user in ({"GOMP_SPINCOUNT": "300000"}, {"OMP_WAIT_POLICY": "active"}, {"OMP_WAIT_POLICY": "passive"}):
        env = dict(user)
        assert not parallel.limit_spin_wait(env)
        assert env == user


_SPIN_PROBE = textwrap.dedent("""
    import glob, sys, threading, time
    import numpy as np
    from penfree.core import parallel
    if sys.argv[1] == "limit":
        assert parallel.limit_spin_wait()
    import numba
    from numba import njit, prange

    @njit(parallel=True)
    def total(a):
        s = 0.0
        for i in prange(a.shape[0]):
            s += a[i]
        return s

    def cpu_ns():  # CPU time of each of this process's threads
        out = {}
        for d in glob.glob("/proc/self/task/*"):
            with open(d + "/schedstat") as f:
                out[d] = int(f.read().split()[0])
        return out

    main = f"/proc/self/task/{threading.get_native_id()}"
    a = np.ones(1 << 16)
    total(a)
    print(numba.threading_layer())
    spins = []
    for _ in range(5):
        total(a)
        before = cpu_ns()
        time.sleep(0.1)
        after = cpu_ns()
        spins.append(sum(v - before.get(k, 0) for k, v in after.items() if k != main) / 1e6)
    print(min(spins))
""")


def _idle_worker_ms(mode):
    out = subprocess.run([sys.executable, "-c", _SPIN_PROBE, mode], capture_output=True, text=True, check=True,
                         env={k: v for k, v in os.environ.items() if k not in ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")})
    layer, ms = out.stdout.split()
    return layer, float(ms)


def test_idle_openmp_workers_stop_spinning_soon_after_a_region():
    # The CPU time the worker threads take in the 100 ms after a parallel region, while
    # the main thread sleeps: libgomp's default spins ~8 ms (a busy machine's core, taken
    # from the command's own main thread), `limit_spin_wait` before the first region
    # ~0.7 ms. The smallest of five windows, so that a descheduled probe cannot inflate it.
    if not sys.platform.startswith("linux") or numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("needs /proc and two threads")
    layer, default_ms = _idle_worker_ms("default")
    if layer != "omp" or default_ms < 3.0:
        pytest.skip(f"threading layer {layer}, idle workers spin {default_ms:.2f} ms without the limit")
    layer, limited_ms = _idle_worker_ms("limit")
    assert limited_ms < 2.0 < default_ms
