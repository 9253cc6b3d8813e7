"""The Dask side of the scale-out path: the client (a local cluster or a scheduler's, or
`InProcess`, which runs the same tasks one after another here), and one loop that
collects task results in order, counts progress and names a failed task."""

from __future__ import annotations

import importlib.util
import logging
import os
import sys
import uuid
from contextlib import contextmanager

from ..errors import InputError

DASK_MISSING = ("several inputs, --workers and --scheduler need Dask, which is not installed; "
                "install it with: pip install 'penfree[dask]'")


def require_dask():
    """Import `dask.distributed`; InputError (exit 2) with the install line when absent."""
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise InputError(DASK_MISSING) from None
    return distributed


#: Dask settings of the local cluster a command starts (not of a cluster given by
#: ``--scheduler``): no statistical profiling of the tasks, and the event-loop tick and
#: the system monitor (the dashboard's figures, which no one looks at here) at 1 s and
#: 5 s instead of 20 ms and 500 ms. Each of them interrupts a worker's task thread, and
#: with as many workers as cores there is no idle core to run them: four 64K-vertex yarn
#: recordings took 5.96-6.08 s on two workers against 6.27-6.79 s with Dask's defaults
#: (three runs each, alternating; issue 13). The memory monitor, which pauses a worker
#: near its memory limit, keeps its default.
LOCAL_CLUSTER_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
}


#: Whether a local cluster's workers are forked from a prepared process (`start_worker_server`)
#: rather than spawned: on Linux. Elsewhere they are spawned (macOS's system libraries are
#: not safe to fork; Windows cannot).
FORK_WORKERS = sys.platform.startswith("linux")

#: The module that process imports before it forks the first worker (`penfree.scaleout.preload`).
WORKER_PRELOAD = "penfree.scaleout.preload"

#: The fork server's environment, over this process's: one thread for OpenMP, MKL and
#: OpenBLAS (the values Dask's ``distributed.nanny.pre-spawn-environ`` gives a spawned
#: worker), so that importing NumPy there starts no thread (`preload`).
SERVER_ENVIRON = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}


def start_worker_server() -> bool:
    """Start the process a local cluster's workers will be forked from, unless it runs;
    True when workers are forked (`FORK_WORKERS`, Dask installed), False when spawned.

    A spawned worker is a new interpreter that imports Dask, penfree and Numba and fills
    Numba's CPU target itself before its first task: 0.5-0.8 s on every run, in each
    worker. Python's fork server (`multiprocessing.forkserver`) does that once
    (`WORKER_PRELOAD`), then forks each worker in a few milliseconds, and lives as long as
    this process: later clusters of this process reuse it. This returns at once and the
    server prepares itself in the background, so the CLI calls it as soon as it knows a
    command starts a local cluster: the server imports while the command reads and checks
    its inputs (`client` calls it too).

    The server runs with this process's environment as it is now, and `SERVER_ENVIRON`
    over it; its workers inherit that (a variable set later reaches them only through
    Dask's ``distributed.nanny.environ``). This process's environment is left as it was.
    The server never starts a thread (`preload`), so forking it is safe. (A fork server
    this process already runs, started by other code with its own preload, is used as it
    is: its workers then prepare themselves, as spawned ones do.)
    """
    if not FORK_WORKERS or importlib.util.find_spec("distributed") is None:  # no Dask: `require_dask` says so
        return False
    import multiprocessing.forkserver

    saved = {k: os.environ.get(k) for k in SERVER_ENVIRON}
    multiprocessing.forkserver.set_forkserver_preload([WORKER_PRELOAD])
    os.environ.update(SERVER_ENVIRON)
    try:
        multiprocessing.forkserver.ensure_running()
    except OSError:  # no Unix socket or no process to be had: workers are spawned, as elsewhere
        return False
    finally:
        for k, v in saved.items():
            if v is None:
                del os.environ[k]
            else:
                os.environ[k] = v
    return True


class Deferred:
    """A task of `InProcess`: run when its result is first asked for (`gather` asks in
    submission order), its arguments' own tasks first, as Dask resolves futures given
    as arguments (alone or in a list)."""

    def __init__(self, key, fn, args):
        self.key, self._fn, self._args = key, fn, args
        self._done, self._value = False, None

    def result(self):
        if not self._done:
            args = [_resolved(a) for a in self._args]
            self._value, self._done, self._args = self._fn(*args), True, ()
        return self._value

    def cancel(self):
        self._args = ()


def _resolved(a):
    if isinstance(a, Deferred):
        return a.result()
    if isinstance(a, list):
        return [_resolved(b) for b in a]
    return a


class InProcess:
    """The client of a run in this process, without Dask: one worker, tasks run one at a
    time in the order they were submitted (`Deferred`). Serial ``deform`` and ``verify`` of
    a long recording use it to go through frame ranges of bounded size (`plan.plan`)."""

    def submit(self, fn, *args, pure=False, key=None):
        return Deferred(key or new_key(), fn, args)

    def scheduler_info(self):
        return {"workers": {"in-process": {}}}


@contextmanager
def client(workers=None, scheduler=None, in_process=False):
    """A `distributed.Client`: on `scheduler`, else on a local cluster of `workers` processes;
    `InProcess` with `in_process`."""
    if in_process:
        yield InProcess()
        return
    distributed = require_dask()
    if scheduler is not None:
        try:
            c = distributed.Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError, TypeError) as exc:  # ValueError: a malformed address
            raise InputError(f"--scheduler {scheduler}: cannot connect ({exc}); expected the address of a running "
                             f"dask scheduler, e.g. tcp://host:8786") from None
        try:
            yield c
        finally:
            c.close()
        return
    n = local_workers(workers)
    # One thread per worker process: workers run Numba kernels themselves. Their logs are
    # silenced below CRITICAL, ERROR too ("Compute Failed" and a traceback): `gather`
    # reports a failed task itself, in one line naming its file and frame range. The
    # cluster starts here: its scheduler and nannies take `LOCAL_CLUSTER_CONFIG`, and the
    # nannies pass it on to their workers; the caller's configuration is restored at once.
    # Its workers are forked from the prepared server (`start_worker_server`) where there is one.
    import dask

    config = dict(LOCAL_CLUSTER_CONFIG)
    if start_worker_server():
        config["distributed.worker.multiprocessing-method"] = "forkserver"
    with dask.config.set(config):
        cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                                           silence_logs=logging.CRITICAL)
    from ..core.memory import skip_exit_collection

    with cluster, distributed.Client(cluster) as c:
        # they end with this cluster, which the command waits for (not a scheduler's workers)
        c.run(skip_exit_collection)
        yield c


def local_workers(workers) -> int:
    """The processes of the local cluster `client` starts: `workers`, else one per core."""
    return workers or os.cpu_count() or 1


def n_workers_of(c) -> int:
    return max(1, len(c.scheduler_info().get("workers", {})))


def run_tasks(c, fn, tasks, args=(), progress=None) -> list:
    """Run ``fn(task, *args)`` for every task on client `c`; results in task order.

    A failed task raises InputError naming its file and range (the others are cancelled).
    """
    futures = [c.submit(fn, t, *args, pure=False, key=new_key()) for t in tasks]
    return gather(futures, [t.label() for t in tasks], progress)


def new_key() -> str:
    return f"penfree-{uuid.uuid4().hex}"


def gather(futures, labels, progress=None) -> list:
    """Results of `futures` in order, calling `progress` once per finished one.

    A failure raises InputError naming the `labels` entry of the future that failed;
    the others are cancelled. `Deferred` tasks (`InProcess`) run here, in order.
    """
    index = {f.key: k for k, f in enumerate(futures)}
    results = [None] * len(futures)
    if futures and isinstance(futures[0], Deferred):
        done = iter(futures)
    else:
        from distributed import as_completed

        done = as_completed(futures)
    try:
        for fut in done:
            k = index[fut.key]
            try:
                results[k] = fut.result()
            except InputError as exc:
                raise InputError(f"{labels[k]}: {_one_line(exc)}") from None
            except Exception as exc:  # a worker failure: name the task, no traceback
                raise InputError(f"task failed on {labels[k]}: {type(exc).__name__}: {_one_line(exc)}") from None
            if progress is not None:
                progress()
    finally:
        for f in futures:
            f.cancel()
    return results


def _one_line(exc) -> str:
    return " ".join(str(exc).split())


def task_threads(threads, workers=None, scheduler=None, in_process=False):
    """The Numba thread count of a task: `threads` when given; else, in this process
    (`in_process`), None (the process keeps its own); on a local cluster the cores shared
    among its processes (`local_workers`: one per core when `workers` is None, so one
    thread each); on a `scheduler`'s workers one (their cores are not known here).

    Results do not depend on it. ``--workers 1`` on 2 cores: 2 threads (it ran one, and
    left a core idle).
    """
    if threads or in_process:
        return threads
    if scheduler is not None:
        return 1
    return max(1, (os.cpu_count() or 1) // local_workers(workers))


def task_setup(threads):
    """A task's set-up on its worker: Numba's thread count (`threads`, when given),
    freed blocks kept in the heap (`retain_freed_memory`) and OpenMP's idle threads
    spinning briefly (`parallel.limit_spin_wait`), as the CLI's process does.

    A Dask worker is a process of its own, and its nanny starts it with glibc told to
    give freed memory back at once (``MALLOC_TRIM_THRESHOLD_``): without this, every
    scratch array of every step came back as fresh pages, faulted in one at a time.
    """
    from ..core.memory import retain_freed_memory
    from ..core.parallel import limit_spin_wait, set_threads

    retain_freed_memory()
    limit_spin_wait()  # in effect from the worker's first task (libgomp loads at its first parallel kernel)
    set_threads(threads)
