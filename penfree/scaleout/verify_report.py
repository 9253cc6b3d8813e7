"""``verify`` and ``report`` of several inputs on Dask, or of a long recording in this process
(`cluster.InProcess`): one merged report per input."""

from __future__ import annotations

import math

from .cluster import client, n_workers_of, run_tasks, task_setup, task_threads
from .plan import expand_inputs, plan

# --- verify and report ---------------------------------------------------------------


def verify_task(task, options, threads):
    """Worker: verify the steps of `task` (a `VerifyReport`); a range reads only the frames
    its steps use (HDF5 `frame_window`: ranges are made of HDF5 files only, `plan`)."""
    from ..core.pipeline.verification import verify_file

    task_setup(threads)
    frames, window = (options["frames"], None) if task.lo is None else (None, task.frames())
    return verify_file(task.path, thickness=options["thickness"], frames=frames, mode=options["mode"],
                       max_pairs=options["max_pairs"], strict=options.get("strict", False), window=window,
                       progress=options.get("progress"))


def verify_many(specs, *, thickness=None, frames=None, mode="auto", max_pairs=10, workers=None, scheduler=None,
                threads=None, progress=None, on_total=None, strict=False, in_process=False, step_progress=None) -> list:
    """`verify_file` for every input on Dask (`in_process`: here, task after task, without
    Dask, `step_progress` called once per step verified); one merged `VerifyReport` per
    input, in order."""
    from ..formats.result import is_result_file

    inputs = expand_inputs(specs)
    with client(workers, scheduler, in_process) as c:
        n = n_workers_of(c)
        tasks = []
        for p in inputs:
            tasks.extend(plan([p], max(1, math.ceil(n / len(inputs))), frames,
                              "result" if is_result_file(p) else "path"))
        if on_total is not None:
            on_total(len(tasks))
        options = {"thickness": thickness, "frames": frames, "mode": mode, "max_pairs": max_pairs, "strict": strict}
        if in_process:
            options["progress"] = step_progress
        reports = run_tasks(c, verify_task, tasks, (options, task_threads(threads, workers, scheduler, in_process)),
                            progress)
    merged = []
    for p in inputs:
        mine = [r for t, r in zip(tasks, reports) if t.path == p]
        rep = mine[0]
        for r in mine[1:]:
            rep.steps.extend(r.steps)
        merged.append(rep)
    return merged


def report_task(task, options, threads):
    """Worker: the report entry of one result file (`make_file_report`), or the part of a
    frame range of its steps (`file_part`), which reads only the frames its steps use
    (`read_range`: ranges are made of HDF5 files only, `plan`) and takes what needs all
    the file's steps from ``options["decisions"][path]``."""
    from ..report.build import file_part, make_file_report, open_result, read_range, select_steps

    task_setup(threads)
    common = dict(replay=options["replay"], ladder=options["ladder"], client=options.get("client"),
                  use_stored_stats=options.get("use_stored_stats", True),
                  verify_paths=options.get("verify_paths", False), progress=options.get("progress"))
    if task.lo is None:
        res = select_steps(open_result(task.path), options["frames"])
        return make_file_report(task.path, res, cd_share=options["cd_share"], frame_ms=options["frame_ms"], **common)
    res, first = read_range(task.path, task.lo, task.hi)
    return file_part(res, decisions=options["decisions"][task.path], first=first, **common)


def report_many(specs, *, options, workers=None, scheduler=None, threads=None, progress=None, on_total=None,
                in_process=False, step_progress=None) -> tuple:
    """``(inputs, entries)``: the report entry of every input (`make_file_report`), in input
    order, on Dask, or with `in_process` here, task after task, without Dask
    (`step_progress` called once per step of each computing phase): a serial report of a
    long recording goes through its frame ranges so, holding one range at a time.

    A file is one task, or ranges of its steps as verify plans them (`plan`; a file whose
    frames exceed `MAX_TASK_BYTES` always, in ranges of bounded size). For a split file
    the driver reads its per-step tables only (`open_tables`), decides once what needs
    all its steps (`decide`: stored statistics, verify's path-check error, the client's
    replayed steps), and assembles its entry from the ranges' parts joined in step order
    (`concat_parts`, `assemble_entry`): the entry of a whole read.

    `options`: ``frames``, ``cd_share``, ``frame_ms``, ``replay``, ``ladder``,
    ``use_stored_stats``, ``verify_paths``, optionally ``client`` (as `make_file_report`).
    """
    from ..report.build import assemble_entry, concat_parts, decide, open_tables, select_steps

    inputs = expand_inputs(specs)
    with client(workers, scheduler, in_process) as c:
        n = n_workers_of(c)
        tasks, tables, decisions = [], {}, {}
        for p in inputs:
            mine = plan([p], max(1, math.ceil(n / len(inputs))), options["frames"], "result")
            if mine[0].lo is not None:  # frame ranges: what needs every step, on the file's tables
                res, T = open_tables(p)
                tables[p] = (select_steps(res, options["frames"], n_frames=T), T)
                decisions[p] = decide(tables[p][0], T, replay=options["replay"],
                                      verify_paths=options.get("verify_paths", False), client=options.get("client"))
            tasks.extend(mine)
        if on_total is not None:
            on_total(len(tasks))
        opts = dict(options, decisions=decisions, progress=step_progress if in_process else None)
        results = run_tasks(c, report_task, tasks, (opts, task_threads(threads, workers, scheduler, in_process)),
                            progress)
    entries = []
    for p in inputs:
        mine = [r for t, r in zip(tasks, results) if t.path == p]
        if p not in tables:
            entries.append(mine[0])
            continue
        res, T = tables[p]
        entries.append(assemble_entry(p, res, concat_parts(mine), n_frames=T, cd_share=options["cd_share"],
                                      frame_ms=options["frame_ms"]))
    return inputs, entries
