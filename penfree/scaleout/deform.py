"""``deform`` of several inputs on Dask: whole-file tasks that write their result, frame
ranges that write partial results, and the task that merges a split file's partials."""

from __future__ import annotations

import os
import shutil

from ..errors import InputError
from ..formats.partials import merge_partials, parts_dir, write_partial
from .cluster import client, gather, n_workers_of, new_key, set_threads
from .plan import expand_inputs, output_paths, plan

# --- deform ------------------------------------------------------------------------


def _deform(task, options, with_stats, threads):
    """`(seq, steps, groups)` of the steps of `task` (read and run on the worker)."""
    from ..core.pipeline.deform import deform_sequence, deform_stats
    from ..formats import read_sequence

    set_threads(threads)
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
    from ..formats import read_sequence

    steps, groups = merge_partials(sorted(parts))
    seq = read_sequence(path, format=options.get("format"))
    _write_output(path, out_path, seq, steps, groups, options, overwrite)
    shutil.rmtree(parts_dir(out_path), ignore_errors=True)
    return _light(steps)


def _light(steps) -> dict:
    return {k: v for k, v in steps.items() if k != "deformed"}


def _write_output(path, out_path, seq, steps, groups, options, overwrite):
    """The result of `path` as a serial ``penfree deform`` writes it."""
    from ..core.pipeline.deform import result_attrs
    from ..formats.result import write_result

    opts = _options_of(options, seq, options.get("frames"))
    attrs = result_attrs(path, opts, weights="weights" if seq.weights is not None else None)
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
    results once they are done. Every result is written atomically; if a task fails
    or the run is interrupted, the results of the files already finished stay (each
    complete); no partial result stays, and on a local cluster no temporary file of a
    result that a stopped worker was writing.
    """
    from ..formats.atomic import check_output

    inputs = expand_inputs(specs)
    if os.path.exists(outdir) and not os.path.isdir(outdir):
        raise InputError(f"-o {outdir}: with several inputs -o names a directory; got an existing file")
    outs = output_paths(inputs, outdir)
    for o in outs:
        check_output(o, overwrite, inputs=inputs)
    threads = threads or 1
    before = _temporaries(outdir)
    done = False
    try:
        results, index, final = _run(c_args=(workers, scheduler), outdir=outdir, inputs=inputs, outs=outs, options=options,
                                     with_stats=with_stats, threads=threads, overwrite=overwrite,
                                     progress=progress, on_total=on_total)
        done = True
    finally:
        if not done and scheduler is None:
            # The local cluster is closed, its workers are gone: a result a worker was
            # writing when the run stopped (failure, Ctrl-C) left its temporary file.
            for name in _temporaries(outdir) - before:
                _remove(os.path.join(outdir, name))
    return [(path, out, results[index[f.key]]) for path, out, f in zip(inputs, outs, final)]


def _temporaries(outdir) -> set:
    from ..formats.atomic import TMP_PREFIX, TMP_SUFFIX

    if not os.path.isdir(outdir):
        return set()
    return {n for n in os.listdir(outdir) if n.startswith(TMP_PREFIX) and n.endswith(TMP_SUFFIX)}


def _remove(path):
    try:
        os.unlink(path)
    except OSError:
        pass


def _run(c_args, outdir, inputs, outs, options, with_stats, threads, overwrite, progress, on_total):
    """Submit and gather the tasks of `deform_many`; ``(results, index, final)``."""
    with client(*c_args) as c:
        tasks = plan(inputs, n_workers_of(c), options.get("frames"))
        os.makedirs(outdir, exist_ok=True)
        futures, labels, final = [], [], []
        for path, out in zip(inputs, outs):
            mine = [t for t in tasks if t.path == path]
            if len(mine) == 1 and mine[0].lo is None:
                fut = c.submit(deform_file_task, mine[0], out, options, with_stats, threads, overwrite,
                               pure=False, key=new_key())
                labels.append(mine[0].label())
            else:
                parts = [c.submit(deform_task, t, out, options, with_stats, threads, pure=False, key=new_key())
                         for t in mine]
                futures.extend(parts)
                labels.extend(t.label() for t in mine)
                fut = c.submit(merge_task, path, out, parts, options, overwrite, pure=False, key=new_key())
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
    return results, {f.key: k for k, f in enumerate(futures)}, final


def _options_of(options, seq, frames):
    """The ``options`` attribute a serial `deform_sequence` run records."""
    from ..core.pipeline.deform import required_margin, run_options

    thickness = seq.thickness if options["thickness"] is None else float(options["thickness"])
    contact_radius = seq.contact_radius if options.get("contact_radius") is None else float(options["contact_radius"])
    return run_options(options["model"], options["projection"], required_margin(thickness, options["margin"]),
                       thickness, contact_radius, frames, options["per_vertex"])
