"""The several-inputs path of ``deform``, ``verify`` and ``report`` (Dask): parse, call
`penfree.scaleout`, print. One progress bar counts all tasks."""

import click

from .options import Progress, echo_json, no_step_error


class _Bar:
    """A `Progress` whose total is known only once the tasks are planned."""

    def __init__(self, label):
        self.label, self.bar = label, None

    def total(self, n):
        self.bar = Progress(n, self.label)

    def __call__(self):
        if self.bar is not None:
            self.bar()

    def close(self):
        if self.bar is not None:
            self.bar.close()


def start_workers(scheduler):
    """Without a `scheduler`, start now the process the local cluster's workers will be
    forked from (`penfree.scaleout.cluster.start_worker_server`): it prepares itself
    while the command goes on reading and checking its inputs."""
    if scheduler is None:
        from ..scaleout.cluster import start_worker_server

        start_worker_server()


def deform(specs, output, options, *, overwrite, with_stats, workers, scheduler, threads, as_json):
    from ..core.pipeline.deform import summarize_steps
    from ..scaleout import deform_many

    bar = _Bar("deform")
    try:
        done = deform_many(specs, output, options=options, overwrite=overwrite, with_stats=with_stats,
                           workers=workers, scheduler=scheduler, threads=threads, progress=bar, on_total=bar.total)
    finally:
        bar.close()
    rows = []
    for path, out, steps in done:
        s = summarize_steps(steps)
        rows.append(dict(s, input=path, output=out))
    if as_json:
        echo_json({"files": rows})
        return
    for r in rows:
        click.echo(f"penfree deform: {r['input']} -> {r['output']}: {r['steps']} steps, "
                   f"certified {'all' if r['all_certified'] else 'NOT ALL'}, "
                   f"RMS to next frame x{r['residual_next_rms_ratio']:.3f} of doing nothing")


def verify(specs, *, thickness, frames, mode, max_pairs, workers, scheduler, threads, as_json, step_line,
           strict=False):
    from ..scaleout import verify_many

    bar = _Bar("verify")
    try:
        reports = verify_many(specs, thickness=thickness, frames=frames, mode=mode, max_pairs=max_pairs,
                              workers=workers, scheduler=scheduler, threads=threads, progress=bar,
                              on_total=bar.total, strict=strict)
    finally:
        bar.close()
    for rep in reports:
        if not rep.steps:
            raise no_step_error(rep.origin, frames, rep.kind)
    if as_json:
        echo_json({"ok": all(r.ok for r in reports), "files": [r.to_dict() for r in reports]})
    else:
        for rep in reports:
            for step in rep.steps:
                if not step.ok:
                    click.echo(f"{rep.origin}: " + step_line(step))
            verdict = "all steps safe" if rep.ok else f"{rep.n_failed} step(s) VIOLATE"
            click.echo(f"{rep.origin}: {len(rep.steps)} step(s) checked ({rep.kind}, thickness "
                       f"{rep.thickness:g}): {verdict}")
    return all(r.ok for r in reports)


def report_entries(specs, options, *, workers, scheduler, threads):
    """(inputs, report entries) computed on Dask, a task per file or frame range."""
    from ..scaleout import report_many

    bar = _Bar("report")
    try:
        return report_many(specs, options=options, workers=workers, scheduler=scheduler, threads=threads,
                           progress=bar, on_total=bar.total)
    finally:
        bar.close()

