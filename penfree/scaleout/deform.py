"""``deform`` on Dask: whole-file tasks that write their result, frame ranges that write
partial results, and the task that merges a split file's partials, all inside a folder
of the run's own; the results are moved to their names once every task succeeded."""

from __future__ import annotations

import os
import shutil
import tempfile

import numpy as np

from ..errors import InputError
from .cluster import client, gather, n_workers_of, new_key, task_setup, task_threads
from .plan import deform_outputs, expand_inputs, plan

# --- deform ------------------------------------------------------------------------


def _deform(task, options, with_stats, threads):
    """`(seq, steps, groups)` of the steps of `task` (read and run on the worker)."""
    from ..core.pipeline.deform import deform_sequence, deform_stats
    from ..formats import read_sequence

    task_setup(threads)
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
                          check_start=bool(options.get("check_start")) or with_stats, progress=options.get("progress"))
    groups = dict(out.groups)
    if with_stats:
        groups["stats"] = deform_stats(seq, out.steps, thickness=options["thickness"],
                                       contact_radius=options.get("contact_radius"))
        groups["stats"]["frame"] = groups["stats"]["frame"] + first
    out.steps["frame"] = out.steps["frame"] + first
    return seq, out.steps, groups


def deform_task(task, parts, options, with_stats, threads):
    """Worker: deform the steps of `task`, write the partial result into the folder `parts`
    (the run's own), return its path."""
    from ..formats.partials import write_partial

    _, steps, groups = _deform(task, options, with_stats, threads)
    return write_partial(parts, steps, groups)


def deform_file_task(task, out_path, options, with_stats, threads):
    """Worker: deform a whole file (`task` without a range) and write its result itself.

    `out_path` lies in the run's own folder (`deform_many` moves it to its name once every
    task succeeded). Returns the per-step arrays without ``deformed`` and the per-vertex
    ones (`_light`; the summary the driver prints): positions never travel back through
    the scheduler, and the result files of several inputs are written (compressed) by the
    workers in parallel.
    """
    seq, steps, groups = _deform(task, options, with_stats, threads)
    _write_output(task.path, out_path, seq, steps, groups, options)
    return _light(steps)


def merge_task(path, out_path, parts, options):
    """Worker: merge the partial results of `path`'s frame ranges, write its result to
    `out_path` (in the run's own folder) and remove those partial results.

    The input's frames and the deformed states go into the result one frame at a time
    (`formats.frames`): a long recording is never held whole here, as its range tasks
    each read only their own frames. Ranges are made of HDF5 inputs only (`plan`).
    """
    import h5py

    from ..formats import read_sequence
    from ..formats.frames import StoredFrames
    from ..formats.hdf5 import read_whole_shape
    from ..formats.partials import merge_partials

    task_setup(None)
    steps, groups = merge_partials(sorted(parts), stream=True)
    seq = read_sequence(path, format=options.get("format"), frame_window=(0, 2))  # all but the frames, validated
    with h5py.File(path, "r") as f:
        seq.positions = StoredFrames(f["positions"], path)
        for ob in seq.obstacles:
            if ob.positions is not None and np.ndim(ob.positions) == 3:  # per frame: read 2 frames above
                g = f[f"obstacles/{ob.name}"]
                name = "positions" if "positions" in g else "vertices"
                ob.positions = StoredFrames(g[name], path, f"obstacles/{ob.name}/{name}")
            if ob.shape is not None and (ob.shape.profile.ndim == 2 or ob.shape.transform.ndim == 3):
                # per frame too, read for 2 frames above: a few numbers a frame, read whole
                ob.shape = read_whole_shape(f, ob.name, path, seq.positions.shape[0])
        _write_output(path, out_path, seq, steps, groups, options)
    for p in parts:  # written by this run's range tasks
        os.unlink(p)
    return _light(steps)


def _light(steps) -> dict:
    """The per-step arrays the driver's summary reads: not ``deformed`` nor the per-vertex
    rows (``--per-vertex``: ``(S, N)`` each, streamed by a merge from files it then removes;
    a few hundred 64K recordings' would fill the driver's memory)."""
    from ..formats.partials import is_per_vertex

    return {k: v for k, v in steps.items() if k != "deformed" and not is_per_vertex(k)}


def _write_output(path, out_path, seq, steps, groups, options):
    """The result of `path` as a serial ``penfree deform`` writes it (into the run's folder)."""
    from ..core.pipeline.deform import result_attrs
    from ..formats.result import write_result

    if not os.path.isdir(os.path.dirname(out_path)):  # the run stopped and removed its folder: do not remake it
        raise FileNotFoundError(f"the run's folder {os.path.dirname(out_path)} is gone (the run stopped)")
    opts = _options_of(options, seq, options.get("frames"))
    attrs = result_attrs(path, opts, weights="weights" if seq.weights is not None else None)
    write_result(out_path, seq, steps, attrs, groups=groups, overwrite=False)


def deform_many(specs, output, *, options, overwrite=False, with_stats=False, workers=None, scheduler=None,
                threads=None, progress=None, on_total=None, in_process=False) -> list:
    """Deform every input on Dask; write `output` for one input, else ``<output>/<stem>.h5``.

    With `in_process` the same tasks run here one after another, without Dask
    (`cluster.InProcess`): a serial ``penfree deform`` of a long recording goes through
    its frame ranges so, holding one range at a time.

    Parameters
    ----------
    specs : list of str
        Files, directories or glob patterns.
    output : str
        One input file (a single spec naming it): its result file, as a serial run.
        Several inputs (several specs, a directory of recordings or a pattern): the
        output directory (created if missing); a name ending in ``.h5`` is refused.
    options : dict
        ``model``, ``projection``, ``margin``, ``thickness``, ``frames`` ((start, stop)
        or None), ``per_vertex``, ``format`` as for `deform_sequence` / the CLI; with
        `in_process`, ``progress`` may be a callable called once per step deformed.
    progress : callable, optional
        Called once per finished task. on_total(n) is called first with the task count.

    Returns
    -------
    list of (input, output, steps) in input order; `steps` without ``deformed`` and the
    per-vertex rows (`_light`).

    Raises
    ------
    InputError
        Before any task: an output that exists (without `overwrite`) or is an input, an
        input whose layout, topology or attributes do not validate as a serial run reads
        them (`_check_input`), an output directory that cannot be created or
        written. During the run: the failed task's file and frame range, in one line.

    Notes
    -----
    The run works in a folder of its own, a new ``.pfXXXXXXXX.tmp`` in the output
    directory: a file that is one task is deformed and written there by that task; a
    file split into frame ranges gets a ``<stem>.parts`` folder there for its ranges'
    partial results, which one more task merges once they are done. Only when every
    task succeeded are the results moved to their names, together and atomically
    (`penfree.formats.atomic`). If anything fails or the run is interrupted, no output
    appears; the run's folder and the directories it created are removed, and nothing
    else: no other file or folder in the output directory is touched.
    """
    from ..formats import check_outputs, input_files
    from ..formats.atomic import check_file_name, make_parents, remove_dirs

    inputs = expand_inputs(specs)
    outs = deform_outputs(specs, inputs, output)
    fmt = options.get("format")
    for o in outs:
        check_file_name(o)
    check_outputs(outs, [f for p in inputs for f in input_files(p, fmt)], overwrite)
    for p in inputs:  # a bad layout, topology or attribute fails here, before a cluster starts
        _check_input(p, fmt)
    outdir = os.path.dirname(os.path.abspath(outs[0]))
    try:
        created = make_parents(outdir)
    except OSError as exc:
        raise InputError(f"cannot create output directory {outdir}: {exc.strerror or exc}") from None
    try:
        stage = _own_folder(outdir)
        try:
            results, index, final = _run(c_args=(workers, scheduler, in_process), stage=stage, inputs=inputs,
                                         outs=outs, options=options, with_stats=with_stats,
                                         threads=task_threads(threads, workers, scheduler, in_process),
                                         progress=progress, on_total=on_total)
            _commit([os.path.join(stage, os.path.basename(o)) for o in outs], outs, overwrite)
        finally:  # the run's own folder (on a local cluster its workers are gone by now)
            shutil.rmtree(stage, ignore_errors=True)
    except BaseException:
        remove_dirs(created)
        raise
    return [(path, out, results[index[f.key]]) for path, out, f in zip(inputs, outs, final)]


def _check_input(path, fmt):
    """Read and validate `path` as a serial run does, an HDF5 file's first two frames only.

    The driver must not read a long recording whole (tens of thousands of frames need not
    fit in its memory, and the reads would be serial): its range tasks read the frames
    they use, each validated as read, and a frame that fails fails its task, which
    leaves no output (`deform_many`)."""
    from ..formats import detect_format, read_sequence

    if (fmt or detect_format(path)) == "hdf5":
        read_sequence(path, format="hdf5", frame_window=(0, 2))
    else:
        read_sequence(path, format=fmt)


def _own_folder(outdir) -> str:
    """A new folder for this run in `outdir` (penfree's temporary name, unique to the run)."""
    from ..formats.atomic import TMP_PREFIX, TMP_SUFFIX

    try:
        return tempfile.mkdtemp(prefix=TMP_PREFIX, suffix=TMP_SUFFIX, dir=outdir)
    except OSError as exc:
        raise InputError(f"cannot write in output directory {outdir}: {exc.strerror or exc}") from None


def _commit(staged, outs, overwrite):
    """Move the results `staged` in the run's folder to `outs`, all or none."""
    from ..formats.atomic import atomic_file, write_phase

    with write_phase():  # made visible together at its end; any failure removes them all
        for src, out in zip(staged, outs):
            with atomic_file(out, overwrite=overwrite) as tmp:
                os.replace(src, tmp)


def _run(c_args, stage, inputs, outs, options, with_stats, threads, progress, on_total):
    """Submit and gather the tasks of `deform_many` (results into `stage`); ``(results, index, final)``."""
    with client(*c_args) as c:
        tasks = plan(inputs, n_workers_of(c), options.get("frames"))
        futures, labels, final = [], [], []
        for path, out in zip(inputs, outs):
            staged = os.path.join(stage, os.path.basename(out))
            mine = [t for t in tasks if t.path == path]
            if len(mine) == 1 and mine[0].lo is None:
                fut = c.submit(deform_file_task, mine[0], staged, options, with_stats, threads,
                               pure=False, key=new_key())
                labels.append(mine[0].label())
            else:
                parts_dir = os.path.splitext(staged)[0] + ".parts"
                os.mkdir(parts_dir)
                parts = [c.submit(deform_task, t, parts_dir, options, with_stats, threads, pure=False, key=new_key())
                         for t in mine]
                futures.extend(parts)
                labels.extend(t.label() for t in mine)
                fut = c.submit(merge_task, path, staged, parts, options, pure=False, key=new_key())
                labels.append(f"{path} (merging its frame ranges)")
            futures.append(fut)
            final.append(fut)
        if on_total is not None:
            on_total(len(futures))
        results = gather(futures, labels, progress)
    return results, {f.key: k for k, f in enumerate(futures)}, final


def _options_of(options, seq, frames):
    """The ``options`` attribute a serial `deform_sequence` run records."""
    from ..core.pipeline.deform import required_margin, run_options

    thickness = seq.thickness if options["thickness"] is None else float(options["thickness"])
    contact_radius = seq.contact_radius if options.get("contact_radius") is None else float(options["contact_radius"])
    return run_options(options["model"], options["projection"], required_margin(thickness, options["margin"]),
                       thickness, contact_radius, frames, options["per_vertex"])
