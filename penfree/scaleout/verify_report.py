"""``verify`` and ``report`` of several inputs on Dask (one merged report per input)."""

from __future__ import annotations

import math

from .cluster import client, n_workers_of, run_tasks, set_threads
from .plan import Task, expand_inputs, plan

# --- verify and report ---------------------------------------------------------------


def verify_task(task, options, threads):
    """Worker: verify the steps of `task` (a `VerifyReport`); a range reads only the frames
    its steps use (HDF5 `frame_window`: ranges are made of HDF5 files only, `plan`)."""
    from ..core.pipeline.verification import verify_file

    set_threads(threads)
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
        # a worker process runs one thread unless told; a run in this process keeps its own
        reports = run_tasks(c, verify_task, tasks, (options, threads if in_process else threads or 1), progress)
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
    from ..report.build import make_file_report, open_result, select_steps

    set_threads(threads)
    res = select_steps(open_result(task.path), options["frames"])
    return make_file_report(task.path, res, cd_share=options["cd_share"], frame_ms=options["frame_ms"],
                            replay=options["replay"], ladder=options["ladder"],
                            use_stored_stats=options.get("use_stored_stats", True),
                            verify_paths=options.get("verify_paths", False))


def report_many(specs, *, options, workers=None, scheduler=None, threads=None, progress=None, on_total=None):
    """Report entries of every input on Dask (one task per file), in input order."""
    inputs = expand_inputs(specs)
    with client(workers, scheduler) as c:
        tasks = [Task(p) for p in inputs]
        if on_total is not None:
            on_total(len(tasks))
        return inputs, run_tasks(c, report_task, tasks, (options, threads or 1), progress)
