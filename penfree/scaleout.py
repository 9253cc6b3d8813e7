"""Scale-out on Dask: many recordings, or one long recording, without a job script.

`penfree deform`, `verify` and `report` accept several inputs (files, directories,
globs); with several inputs, ``--workers N`` or ``--scheduler ADDRESS`` the work runs on
`dask.distributed` (an optional extra: ``pip install 'penfree[dask]'``).

Partitioning. ``deform`` and ``verify`` split each file into ranges of steps; a step `s`
reads frames ``s - 1``, ``s`` and ``s + 1`` only, so ranges of steps need overlapping
frames and nothing else: a ``deform`` range reads just the frames ``lo - 1 .. hi`` of
its file (HDF5 ``frame_window``) and runs the library on them, its frame numbers
shifted back to the file's; ``verify`` tasks read their file and select their steps
with a frame slice. A file that is one task is
deformed and written (atomically) by that task on its worker. Each ``deform`` range of a
split file writes a partial result beside the output (``.<stem>.parts/``, each part
written under a temporary name and renamed); one more task, which Dask runs once all
ranges of the file are done, merges them in frame order into the layout of a serial run,
writes it atomically and removes the parts. Only file names and the small per-step
tables travel back to the driver; results are compressed and written by the workers in
parallel. ``report`` runs one task per file (statistics and ladder are per file).

Results are those of a serial run, bit for bit: every step is computed by the same
code from the same frames, and the per-step tables are merged in frame order (the
selection table's candidate columns in order of first appearance, as a serial run
orders them). One progress callback counts finished tasks; a failed task names its
file and frame range.
"""

from __future__ import annotations

import glob
import math
import os
import shutil
import uuid
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from .errors import InputError
from .formats.partials import merge_partials, parts_dir, write_partial

#: Extensions a directory input expands to (the primary format).
DIRECTORY_PATTERNS = ("*.h5", "*.hdf5")
#: Tasks per worker the partitioner aims for (balance without tiny tasks).
TASKS_PER_WORKER = 2
#: A frame range holds at least this many steps.
MIN_STEPS_PER_TASK = 4

DASK_MISSING = ("several inputs, --workers and --scheduler need Dask, which is not installed; "
                "install it with: pip install 'penfree[dask]'")


def require_dask():
    """Import `dask.distributed`; InputError (exit 2) with the install line when absent."""
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise InputError(DASK_MISSING) from None
    return distributed


def expand_inputs(specs, missing_ok=False) -> list:
    """Input files from files, directories and glob patterns, in a stable order.

    A directory expands to its ``*.h5`` / ``*.hdf5`` files (sorted); a directory
    without any is itself one input (a numbered mesh-file sequence). A pattern
    expands to its sorted matches. Duplicates are dropped, first occurrence kept.
    A path that does not exist is an InputError, or passed on with `missing_ok`
    (for the reader to report in its own words).
    """
    out = []
    for spec in specs:
        spec = os.fspath(spec)
        if os.path.isdir(spec):
            found = sorted({p for pat in DIRECTORY_PATTERNS for p in glob.glob(os.path.join(glob.escape(spec), pat))})
            out.extend(found or [spec])
        elif os.path.exists(spec) or (missing_ok and not glob.has_magic(spec)):
            out.append(spec)
        elif glob.has_magic(spec):
            found = sorted(glob.glob(spec))
            if not found:
                raise InputError(f"no file matches the pattern {spec!r}")
            out.extend(found)
        else:
            raise InputError(f"no such file or directory: {spec}")
    seen, unique = set(), []
    for p in out:
        key = os.path.realpath(p)
        if key not in seen:
            seen.add(key)
            unique.append(p)
    return unique


def is_scaleout(specs, workers=None, scheduler=None) -> bool:
    """True when the command should take the scale-out path."""
    if workers is not None or scheduler is not None or len(specs) != 1:
        return True
    spec = os.fspath(specs[0])
    if os.path.isdir(spec):
        return any(glob.glob(os.path.join(glob.escape(spec), pat)) for pat in DIRECTORY_PATTERNS)
    return not os.path.exists(spec) and glob.has_magic(spec)


def output_paths(inputs, outdir) -> list:
    """``<outdir>/<input stem>.h5`` per input; InputError when two stems collide."""
    outs = [os.path.join(outdir, os.path.splitext(os.path.basename(os.path.normpath(p)))[0] + ".h5") for p in inputs]
    if len(set(outs)) != len(outs):
        dup = sorted({o for o in outs if outs.count(o) > 1})[0]
        raise InputError(f"two inputs would write the same output {dup}; rename one of them")
    return outs


# --- partitioning ----------------------------------------------------------------------


@dataclass(frozen=True)
class Task:
    """One unit of work: a file and a half-open range ``[lo, hi)`` of its steps (None: all).

    Steps are numbered as the library does: for a raw sequence and `deform`, step `s`
    (1 <= s < T) goes from frame s - 1 to s (``kind="sequence"``); for `verify` of a raw
    sequence, step `s` goes from frame s to s + 1 (``kind="path"``); for a result, `s` is
    its ``steps/frame`` (``kind="result"``).
    """

    path: str
    lo: int | None = None
    hi: int | None = None
    kind: str = "sequence"

    def label(self) -> str:
        return self.path if self.lo is None else f"{self.path} frames {self.lo}:{self.hi}"

    def frames(self):
        """The library's ``frames=(start, stop)`` slice selecting exactly these steps."""
        if self.kind == "path":  # s -> s + 1 needs frame s + 1 selected too
            return (self.lo, self.hi + 1)
        return (self.lo, self.hi)


def _steps_of(path, kind):
    """(T, steps) of a file, or (None, None) when it is not HDF5 (one task then)."""
    try:
        import h5py

        with h5py.File(path, "r") as f:
            T = int(f["positions"].shape[0])
            if kind == "result":
                return T, np.unique(np.asarray(f["steps/frame"][()], dtype=np.int64))
    except Exception:  # not HDF5 (or unreadable here): the real reader reports it in the task
        return None, None
    return T, (np.arange(1, T) if kind == "sequence" else np.arange(0, T - 1))


def _ranges(n, n_parts):
    """Split range(n) into <= n_parts contiguous ranges of >= MIN_STEPS_PER_TASK."""
    n_parts = max(1, min(n_parts, n // MIN_STEPS_PER_TASK))
    cuts = [(k * n) // n_parts for k in range(n_parts + 1)]
    return [(a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]


def plan(paths, n_workers, frames=None, kind="sequence") -> list:
    """Tasks for `paths`: one per file, plus step ranges within a file when there are
    fewer files than ``TASKS_PER_WORKER * n_workers`` (see `Task` for the kinds).

    With a user frame slice, ranges are cut inside the selected steps; a raw sequence
    to verify with a frame slice stays one task (its steps need both frames selected).
    """
    want = TASKS_PER_WORKER * max(1, n_workers)
    per_file = max(1, math.ceil(want / max(1, len(paths))))
    tasks = []
    for p in paths:
        T, steps = _steps_of(p, kind) if per_file > 1 else (None, None)
        if steps is not None and frames is not None:
            if kind == "path":
                steps = None
            else:
                steps = steps[np.isin(steps, np.arange(T)[slice(*frames)])]
        if steps is None or steps.size < 2 * MIN_STEPS_PER_TASK:
            tasks.append(Task(p, kind=kind))
            continue
        for a, b in _ranges(steps.size, per_file):
            tasks.append(Task(p, int(steps[a]), int(steps[b - 1]) + 1, kind))
    return tasks


# --- the cluster and the task loop -------------------------------------------------


@contextmanager
def client(workers=None, scheduler=None):
    """A `distributed.Client`: on `scheduler`, else on a local cluster of `workers` processes."""
    distributed = require_dask()
    if scheduler is not None:
        try:
            c = distributed.Client(scheduler, timeout="10s")
        except (OSError, TimeoutError) as exc:
            raise InputError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
        try:
            yield c
        finally:
            c.close()
        return
    n = workers or os.cpu_count() or 1
    # One thread per worker process: workers run Numba kernels themselves.
    with distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                                  silence_logs=40) as cluster, distributed.Client(cluster) as c:
        yield c


def n_workers_of(c) -> int:
    return max(1, len(c.scheduler_info().get("workers", {})))


def run_tasks(c, fn, tasks, args=(), progress=None) -> list:
    """Run ``fn(task, *args)`` for every task on client `c`; results in task order.

    A failed task raises InputError naming its file and range (the others are cancelled).
    """
    futures = [c.submit(fn, t, *args, pure=False, key=_key()) for t in tasks]
    return gather(futures, [t.label() for t in tasks], progress)


def _key() -> str:
    return f"penfree-{uuid.uuid4().hex}"


def gather(futures, labels, progress=None) -> list:
    """Results of `futures` in order, calling `progress` once per finished one.

    A failure raises InputError naming the `labels` entry of the future that failed;
    the others are cancelled.
    """
    from distributed import as_completed

    index = {f.key: k for k, f in enumerate(futures)}
    results = [None] * len(futures)
    try:
        for fut in as_completed(futures):
            k = index[fut.key]
            try:
                results[k] = fut.result()
            except InputError as exc:
                raise InputError(f"{labels[k]}: {exc}") from None
            except Exception as exc:  # a worker failure: name the task, no traceback
                raise InputError(f"task failed on {labels[k]}: {type(exc).__name__}: {exc}") from None
            if progress is not None:
                progress()
    finally:
        for f in futures:
            f.cancel()
    return results


def _set_threads(threads):
    if threads:
        import numba

        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))


# --- deform ------------------------------------------------------------------------


def _deform(task, options, with_stats, threads):
    """`(seq, steps, groups)` of the steps of `task` (read and run on the worker)."""
    from .core.pipeline.deform import deform_sequence, deform_stats
    from .formats import read_sequence

    _set_threads(threads)
    first = 0  # the file's frame number of the first frame read
    if task.lo is None:
        seq = read_sequence(task.path, format=options.get("format"))
        frames = options.get("frames")
    else:  # a range (HDF5 only, see `plan`): read frames lo - 1 .. hi, the ones its steps use
        first = task.lo - 1
        seq = read_sequence(task.path, format=options.get("format"), frame_window=(first, task.hi + 1))
        frames = (1, task.hi - first)
    out = deform_sequence(seq, model=options["model"], projection=options["projection"], margin=options["margin"],
                          thickness=options["thickness"], contact_radius=options.get("contact_radius"),
                          frames=frames, per_vertex=options["per_vertex"],
                          check_start=bool(options.get("check_start")) or with_stats)
    groups = dict(out.groups)
    if with_stats:
        groups["stats"] = deform_stats(seq, out.steps, thickness=options["thickness"],
                                       contact_radius=options.get("contact_radius"))
        groups["stats"]["frame"] = groups["stats"]["frame"] + first
    out.steps["frame"] = out.steps["frame"] + first
    return seq, out.steps, groups


def deform_task(task, out_path, options, with_stats, threads):
    """Worker: deform the steps of `task`, write the partial result, return its path."""
    _, steps, groups = _deform(task, options, with_stats, threads)
    return write_partial(out_path, steps, groups)


def deform_file_task(task, out_path, options, with_stats, threads, overwrite):
    """Worker: deform a whole file (`task` without a range) and write its result itself.

    Returns the per-step arrays without ``deformed`` (the summary the driver prints):
    positions never travel back through the scheduler, and the result files of several
    inputs are written (compressed) by the workers in parallel.
    """
    seq, steps, groups = _deform(task, options, with_stats, threads)
    _write_output(task.path, out_path, seq, steps, groups, options, overwrite)
    return _light(steps)


def merge_task(path, out_path, parts, options, overwrite):
    """Worker: merge the partial results of `path`'s frame ranges and write its result."""
    from .formats import read_sequence

    steps, groups = merge_partials(sorted(parts))
    seq = read_sequence(path, format=options.get("format"))
    _write_output(path, out_path, seq, steps, groups, options, overwrite)
    shutil.rmtree(parts_dir(out_path), ignore_errors=True)
    return _light(steps)


def _light(steps) -> dict:
    return {k: v for k, v in steps.items() if k != "deformed"}


def _write_output(path, out_path, seq, steps, groups, options, overwrite):
    """The result of `path` as a serial ``penfree deform`` writes it."""
    from ._version import __version__
    from .formats.result import write_result

    opts = _options_of(options, seq, options.get("frames"))
    attrs = {"penfree_version": __version__, "input": os.path.basename(path),
             "options": dict(opts, weights="weights" if seq.weights is not None else None)}
    write_result(out_path, seq, steps, attrs, groups=groups, overwrite=overwrite)


def deform_many(specs, outdir, *, options, overwrite=False, with_stats=False, workers=None, scheduler=None,
                threads=None, progress=None, on_total=None) -> list:
    """Deform every input on Dask; write ``<outdir>/<stem>.h5`` per input.

    Parameters
    ----------
    specs : list of str
        Files, directories or glob patterns.
    outdir : str
        Output directory (created if missing).
    options : dict
        ``model``, ``projection``, ``margin``, ``thickness``, ``frames`` ((start, stop)
        or None), ``per_vertex``, ``format`` as for `deform_sequence` / the CLI.
    progress : callable, optional
        Called once per finished task. on_total(n) is called first with the task count.

    Returns
    -------
    list of (input, output, steps) in input order; `steps` without ``deformed``.

    Notes
    -----
    A file that is one task is deformed and written by that task; a file split into
    frame ranges is written by one more task, which merges the ranges' partial
    results once they are done. Every result is written atomically; if a task fails,
    the results of the files already finished stay (each complete), no partial
    result stays.
    """
    from .formats.atomic import check_output

    inputs = expand_inputs(specs)
    if os.path.exists(outdir) and not os.path.isdir(outdir):
        raise InputError(f"-o {outdir}: with several inputs -o names a directory; got an existing file")
    outs = output_paths(inputs, outdir)
    for o in outs:
        check_output(o, overwrite, inputs=inputs)
    threads = threads or 1
    with client(workers, scheduler) as c:
        tasks = plan(inputs, n_workers_of(c), options.get("frames"))
        os.makedirs(outdir, exist_ok=True)
        futures, labels, final = [], [], []
        for path, out in zip(inputs, outs):
            mine = [t for t in tasks if t.path == path]
            if len(mine) == 1 and mine[0].lo is None:
                fut = c.submit(deform_file_task, mine[0], out, options, with_stats, threads, overwrite,
                               pure=False, key=_key())
                labels.append(mine[0].label())
            else:
                parts = [c.submit(deform_task, t, out, options, with_stats, threads, pure=False, key=_key())
                         for t in mine]
                futures.extend(parts)
                labels.extend(t.label() for t in mine)
                fut = c.submit(merge_task, path, out, parts, options, overwrite, pure=False, key=_key())
                labels.append(f"{path} (merging its frame ranges)")
            futures.append(fut)
            final.append(fut)
        if on_total is not None:
            on_total(len(futures))
        try:
            results = gather(futures, labels, progress)
        finally:  # partial results never outlive the run, merged or not
            for o in outs:
                shutil.rmtree(parts_dir(o), ignore_errors=True)
    index = {f.key: k for k, f in enumerate(futures)}
    return [(path, out, results[index[f.key]]) for path, out, f in zip(inputs, outs, final)]


def _options_of(options, seq, frames):
    """The ``options`` attribute a serial `deform_sequence` run records."""
    from .core.pipeline.deform import required_margin, run_options

    thickness = seq.thickness if options["thickness"] is None else float(options["thickness"])
    contact_radius = seq.contact_radius if options.get("contact_radius") is None else float(options["contact_radius"])
    return run_options(options["model"], options["projection"], required_margin(thickness, options["margin"]),
                       thickness, contact_radius, frames, options["per_vertex"])


# --- verify and report ---------------------------------------------------------------


def verify_task(task, options, threads):
    """Worker: verify the steps of `task` (a `VerifyReport`)."""
    from .core.pipeline.verification import verify_file

    _set_threads(threads)
    frames = options["frames"] if task.lo is None else task.frames()
    return verify_file(task.path, thickness=options["thickness"], frames=frames, mode=options["mode"],
                       max_pairs=options["max_pairs"], strict=options.get("strict", False))


def verify_many(specs, *, thickness=None, frames=None, mode="auto", max_pairs=10, workers=None, scheduler=None,
                threads=None, progress=None, on_total=None, strict=False) -> list:
    """`verify_file` for every input on Dask; one merged `VerifyReport` per input, in order."""
    from .formats.result import is_result_file

    inputs = expand_inputs(specs)
    with client(workers, scheduler) as c:
        n = n_workers_of(c)
        tasks = []
        for p in inputs:
            tasks.extend(plan([p], max(1, math.ceil(n / len(inputs))), frames,
                              "result" if is_result_file(p) else "path"))
        if on_total is not None:
            on_total(len(tasks))
        options = {"thickness": thickness, "frames": frames, "mode": mode, "max_pairs": max_pairs, "strict": strict}
        reports = run_tasks(c, verify_task, tasks, (options, threads or 1), progress)
    merged = []
    for p in inputs:
        mine = [r for t, r in zip(tasks, reports) if t.path == p]
        rep = mine[0]
        for r in mine[1:]:
            rep.steps.extend(r.steps)
        merged.append(rep)
    return merged


def report_task(task, options, threads):
    """Worker: the report entry of one result file (`make_file_report`)."""
    from .report.build import make_file_report, open_result, select_steps

    _set_threads(threads)
    res = select_steps(open_result(task.path), options["frames"])
    return make_file_report(task.path, res, cd_share=options["cd_share"], frame_ms=options["frame_ms"],
                            replay=options["replay"], ladder=options["ladder"])


def report_many(specs, *, options, workers=None, scheduler=None, threads=None, progress=None, on_total=None):
    """Report entries of every input on Dask (one task per file), in input order."""
    inputs = expand_inputs(specs)
    with client(workers, scheduler) as c:
        tasks = [Task(p) for p in inputs]
        if on_total is not None:
            on_total(len(tasks))
        return inputs, run_tasks(c, report_task, tasks, (options, threads or 1), progress)
