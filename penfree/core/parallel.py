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

The fit's passes (`penfree.core.fit.kernels`) are short (0.1-0.6 ms at 64K vertices)
and read every vertex once: there a parallel region pays on an idle machine and
stalls on a loaded one, and no size threshold is right for both. `Pace` chooses
between their two builds from the measured cost of each instead.
"""

from __future__ import annotations

import math
import os
import time
import types

import numba
import numba.np.ufunc.parallel as _numba_parallel
import numpy as np
from numba import njit, types as nbtypes
from numba.core import cgutils
from numba.extending import intrinsic

#: GNU OpenMP's spin count for idle worker threads that `limit_spin_wait` sets.
SPIN_COUNT = 10_000


def limit_spin_wait(environ=None) -> bool:
    """Let GNU OpenMP's idle worker threads spin ``SPIN_COUNT`` times (~0.7 ms on a Zen 4
    host) before they sleep, instead of libgomp's default 300,000 (~8 ms after every
    parallel region, measured as a worker's CPU time); True when it set ``GOMP_SPINCOUNT``.

    Numba's ``omp`` threading layer runs its regions on libgomp. Between a step's
    regions the CLI runs Python for tens to hundreds of microseconds, and with the
    default a worker spins through all of it: free on an idle machine, but where another
    process holds one of two cores the spinning worker takes CPU time from the command's
    own main thread. There `penfree deform --model auto` of the 64K cloth ran at 10.0-11.5
    steps/s on 2 threads against 15.2 on one; with this limit, 14-15 steps/s (the steps
    ~1.3x faster), and the same on an idle machine (BENCHMARKS.md, fifty-first session).

    Only the environment is set (`environ`, default ``os.environ``; so the processes the
    command starts inherit it too): libgomp reads it once, when it is loaded, which Numba
    does when it starts its threading layer, at the first parallel kernel. A user's own
    ``GOMP_SPINCOUNT`` or ``OMP_WAIT_POLICY`` is left as it is. The CLI and the tasks of
    `penfree.scaleout` call this; a library user may.
    """
    environ = os.environ if environ is None else environ
    if "GOMP_SPINCOUNT" in environ or "OMP_WAIT_POLICY" in environ:
        return False
    environ["GOMP_SPINCOUNT"] = str(SPIN_COUNT)
    return True


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


def set_threads(threads):
    """Numba's thread count for the calling thread's kernels: `threads`, at most Numba's
    pool; None keeps it. (The CLI's ``--threads``, and a Dask task's.)"""
    if threads:
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))


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


@intrinsic
def claim(typingctx, counter):
    """``counter[0]`` before adding 1 to it, atomically (an LLVM ``atomicrmw add``):
    inside a ``prange`` over worker slots, the next chunk of work no other worker took.

    For kernels whose chunks each fold into their worker's own slot by an exact
    reduction (min): which worker takes which chunk then changes nothing but the time.
    A worker whose thread is descheduled takes fewer chunks instead of holding up the
    region (a static split waits for its slowest thread: issue 13's noisy 2-vCPU hosts).
    Relaxed ordering suffices: a chunk's work reads nothing another worker writes, and
    the region's end orders every write before the caller's reduction.
    """
    if not (isinstance(counter, nbtypes.Array) and counter.ndim == 1 and counter.dtype == nbtypes.int64):
        return None
    sig = nbtypes.int64(counter)

    def codegen(context, builder, signature, args):
        return _fetch_add_one(context, builder, signature.args[0], args[0], context.get_constant(nbtypes.intp, 0))

    return sig, codegen


def _fetch_add_one(context, builder, ary_type, ary, index):
    # `claim`'s and `claim_at`'s code: an LLVM ``atomicrmw add`` of 1 at ary[index] (intp).
    ptr = cgutils.get_item_pointer(context, builder, ary_type, context.make_array(ary_type)(context, builder, ary),
                                   [index])
    return builder.atomic_rmw("add", ptr, context.get_constant(nbtypes.int64, 1), ordering="monotonic")


@intrinsic
def claim_at(typingctx, counter, k):
    """``counter[k]`` before adding 1 to it, atomically: `claim` on slot k (the cursor of
    one worker's range of chunks, `range_counter`)."""
    if not (isinstance(counter, nbtypes.Array) and counter.ndim == 1 and counter.dtype == nbtypes.int64
            and isinstance(k, nbtypes.Integer)):
        return None
    sig = nbtypes.int64(counter, k)

    def codegen(context, builder, signature, args):
        index = context.cast(builder, args[1], signature.args[1], nbtypes.intp)
        return _fetch_add_one(context, builder, signature.args[0], args[0], index)

    return sig, codegen


@njit(cache=True, inline="always")
def claim_next(counter, w, k):
    """Worker w's next chunk from a `range_counter`, and its new `k` (start at 0): its
    own range first, then the others' in turn, w + 1 first; -1 once every range is
    drained. ``c, k = claim_next(counter, w, k)`` until ``c < 0``."""
    T = counter[-1]
    while k < T:
        v = (w + k) % T
        c = claim_at(counter, v)
        if c < counter[T + v]:
            return c, k
        k += 1
    return np.int64(-1), k


def range_counter(n_chunks: int, workers: int | None = None):
    """A fresh counter for claims by ranges (`claim_next`; one per kernel call), for T
    workers (`workers`, else the calling thread's Numba thread count; a kernel's
    ``prange`` over ``counter[-1]``): ``[cursor_0 .. cursor_T-1, end_0 .. end_T-1, T]``,
    worker w's range being chunks ``[w C / T, (w + 1) C / T)``.

    Worker w claims its own range first, then the others' in turn, w + 1 first: each
    thread works through contiguous chunks, as a static split would (the rows of nearby
    chunks share grid buckets and boxes, which stay in that core's cache: chunks claimed
    one after another by both threads, as `claim` hands them out, measured 3-10% slower
    on the 64K cloth's start pass than a static split), and a late thread's chunks are
    taken by the others instead of holding up the region (with another process holding
    a core, that pass's certificate path took 60-75 ms against 71-119 ms split statically).
    """
    t = thread_count() if workers is None else workers
    bounds = (np.arange(t + 1, dtype=np.int64) * n_chunks) // t
    return np.concatenate([bounds[:-1], bounds[1:], [t]])


def chunk_count(work: int, most: int, least_each: int) -> int:
    """How many chunks to cut `work` items into: at most `most`, each of at least
    `least_each` items where there is that much work, and at least one."""
    return max(1, min(most, work // least_each))


def work_counter():
    """A fresh counter for `claim` (one per kernel call): ``[0, workers]``, the workers
    being the calling thread's Numba thread count (a kernel's ``prange`` over them; read
    inside a kernel, the count would make it uncachable: a dynamic global)."""
    return np.array([0, thread_count()], dtype=np.int64)


def _specialisations(kernel) -> int:
    """How many type specialisations a Numba dispatcher holds (0 for a plain function)."""
    return len(getattr(kernel, "overloads", ()))


def _lower_or_towards(cost, sample, alpha):
    """A cost estimate after one more `sample`: a lower sample at once (timing noise only
    adds), a higher one by `alpha` of the way (a lasting slow-down shows over calls)."""
    if cost is None or sample < cost:
        return sample
    return cost + alpha * (sample - cost)


class Pace:
    """Serial or parallel build of one kernel, whichever costs less per item lately.

    The serial build's cost per work item is an exponential moving average (weight
    `ALPHA`) of its calls' wall times. The parallel build's is a mixture: its usual
    cost (the same average over calls that did not stall) and its stalls' (calls
    above `STALL_FACTOR` times the usual: a late thread), weighted by how often it
    stalled lately (an average of 0 / 1, weight `STALL_WEIGHT` a call). Where another
    process holds one of two cores, a parallel call stalls for a scheduler time slice
    (~20 ms, 100x its usual cost, issue 13) now and then: its median stays 1.6x below
    the serial build's while its mean is above it. A call is a stall only if it is also
    `STALL_MIN_S` over its usual time: waking threads that slept through a few
    milliseconds of serial calls costs ~0.2 ms (measured), and that is not a late
    thread. The cheaper build runs; the other
    one every `PROBE_EVERY` calls times the ratio of their costs (at most
    `PROBE_SPREAD`: a probe of a build that stalls may cost a stall), and a probe,
    standing for the calls since the last, weighs `PROBE_WEIGHT` in the stall share.
    So two stalled calls move the choice to serial, and two or three calm probes in a
    row back (a few hundred calls). The first call of each build is not measured (thread
    start-up), nor any call that compiled or loaded a specialisation of the build (a new
    input dtype: milliseconds, once), and each is measured `FIRST_SAMPLES` times before any
    choice, the serial build first (so that the parallel samples follow one another).
    Noise only ever adds time, so a call cheaper than a build's usual cost replaces it
    at once (the average moves only upwards). A parallel call that starts `COLD_GAP_S`
    or more after the last one (a probe, after serial calls) also pays for waking the
    threads, which calls in a row do not: it only ever lowers the usual cost. Else one
    slow early call (a cold cache, 3x the usual) or one call after a pause would keep
    the serial build for hundreds of calls, or for good: its probes would all be cold.
    Both builds give the same bits, so the choice changes only the time; ``build``
    forces one (``"serial"`` or ``"parallel"``, for the tests' oracles and the
    benchmarks).

    Examples
    --------
    >>> pace = Pace()
    >>> pace.run(1 << 20, "adaptive", len, len, "abc")  # (work, build, serial, parallel, *args)
    3
    """

    PROBE_EVERY = 32
    PROBE_SPREAD = 16.0
    ALPHA = 0.25
    STALL_WEIGHT = 1.0 / 8.0
    PROBE_WEIGHT = 0.5
    STALL_FACTOR = 4.0
    STALL_MIN_S = 5e-4
    COLD_GAP_S = 2e-3
    FIRST_SAMPLES = 2
    _last_parallel_end = -math.inf  # of any Pace's parallel call: the threads are shared

    def __init__(self):
        self.serial = None  # seconds per item
        self.usual = None  # parallel, calls that did not stall
        self.slow = 0.0  # parallel, calls that stalled
        self.stalls = 0.0  # recent share of parallel calls that stalled
        self.seen = [0, 0]  # calls of each build so far (the first is not measured)
        self.calls = 0
        self.since = 0  # calls since the last probe
        self.probing = False

    def parallel_cost(self) -> float:
        """The parallel build's expected cost per item (stalls included)."""
        return (1.0 - self.stalls) * self.usual + self.stalls * self.slow

    def pick(self) -> bool:
        """True to run the parallel build next (both are measured before any choice)."""
        self.calls += 1
        self.probing = False
        if self.seen[0] <= self.FIRST_SAMPLES:
            return False
        if self.seen[1] <= self.FIRST_SAMPLES:
            return True
        par, ser = self.parallel_cost(), self.serial
        best = par <= ser
        # Probe the other build after PROBE_EVERY calls, times how much dearer it looked
        # (at most PROBE_SPREAD): a probe of a build that stalls costs a stall.
        ratio = max(par, ser) / max(min(par, ser), 1e-300)
        self.since += 1
        self.probing = self.since >= self.PROBE_EVERY * min(max(ratio, 1.0), self.PROBE_SPREAD)
        if self.probing:
            self.since = 0
        return best != self.probing

    def record(self, parallel: bool, seconds: float, work: int, warm: bool = True) -> None:
        """One call's wall time; `warm`: a parallel call soon after another one."""
        b = int(parallel)
        self.seen[b] += 1
        if self.seen[b] == 1:
            return
        per = seconds / max(work, 1)
        if not parallel:
            self.serial = _lower_or_towards(self.serial, per, self.ALPHA)
        elif self.usual is None:
            self.usual = per
        else:
            stalled = per > self.STALL_FACTOR * self.usual and seconds - self.usual * work > self.STALL_MIN_S
            if stalled:
                self.slow = per if self.slow == 0.0 else self.slow + self.ALPHA * (per - self.slow)
            elif not warm:
                self.usual = min(self.usual, per)
            else:
                self.usual = _lower_or_towards(self.usual, per, self.ALPHA)
            # A probe stands for the many calls since the last one: it weighs more.
            weight = self.PROBE_WEIGHT if self.probing else self.STALL_WEIGHT
            self.stalls += weight * (float(stalled) - self.stalls)

    def run(self, work, build, serial, parallel, *args):
        """``serial(*args)`` or ``parallel(*args)``: forced by `build`, else by the costs."""
        if build != "adaptive" or thread_count() == 1:
            return (parallel if build == "parallel" else serial)(*args)
        par = self.pick()
        kernel = parallel if par else serial
        known = _specialisations(kernel)
        t = time.perf_counter()
        try:
            return kernel(*args)
        finally:
            end = time.perf_counter()
            if _specialisations(kernel) == known:
                self.record(par, end - t, work, t - Pace._last_parallel_end < self.COLD_GAP_S)
            if par:
                Pace._last_parallel_end = end
