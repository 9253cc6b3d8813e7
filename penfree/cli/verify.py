"""``penfree verify FILE``: prove every step contact-free (exit 0) or name the pairs (exit 1)."""

import click

from ..constants import DEFAULT_MAX_PAIRS
from ..core.parallel import set_threads
from ..errors import InputError
from .options import (
    Progress, echo_json, frames_option, json_option, no_step_error, parse_frames, scaleout_options, thickness_option,
    threads_option, usd_options,
)


def _pair_text(p):
    kind, i, j = p[:3]
    text = f"{kind} {i}-{j}"
    return text + (f" toi>={p[3]:.6g}" if len(p) > 3 else "")


def _round_down(x, digits=6):
    """`x` with `digits` significant digits, never above `x` (a printed lower bound stays one)."""
    y = x
    text = f"{y:.{digits}g}"
    while float(text) > x:
        y *= 1.0 - 10.0 ** -digits
        text = f"{y:.{digits}g}"
    return text


def _step_line(step):
    r = step.result
    head = f"step {step.frame:>5} -> {step.target}: "
    pre = f"; {r.n_pre_existing} pre-existing intersections, unchanged" if r.n_pre_existing else ""
    if step.ok:
        # a lower bound of the distance of every non-adjacent pair over the step, never above the truth
        sep = "> 0" if not r.min_separation > 0 else f">= {_round_down(r.min_separation)}"
        cert = "" if step.certificate is None else f", certificate {'ok' if step.certificate else 'FAILED (unclaimed)'}"
        return head + f"OK ({r.method}, min separation {sep}{cert}){pre}"
    parts = []
    if step.strict and r.n_pre_existing:
        parts.append(f"{r.n_pre_existing} pre-existing intersection(s) (--strict) "
                     f"[{', '.join(map(_pair_text, r.pre_existing))}]")
    if not r.start_ok:
        parts.append(f"start state: {r.n_start_violations} pair(s) [{', '.join(map(_pair_text, r.start_violations))}]")
    if r.n_violations:
        parts.append(f"path: {r.n_violations} pair(s) [{', '.join(map(_pair_text, r.pairs))}]")
    if step.certificate_claimed and step.certificate is False:
        parts.append(f"certificate FAILED (margin {step.margin})")
    if r.method == "certificate" and not r.ok and not parts:
        parts.append("certificate proof does not apply (use --mode ccd)")
    return head + "VIOLATION " + "; ".join(parts)


@click.command("verify")
@click.argument("paths", metavar="FILE...", nargs=-1, required=True, type=click.Path(dir_okay=True))
@thickness_option
@frames_option
@threads_option
@json_option
@click.option("--max-pairs", type=click.IntRange(min=0), default=DEFAULT_MAX_PAIRS, show_default=True,
              help="Violating pairs listed per step (counts are always complete).")
@click.option("--mode", type=click.Choice(["auto", "ccd", "certificate"]), default="auto", show_default=True,
              help="Deform results: 'ccd' runs the full CCD on every step; 'auto' proves affine "
                   "steps from their exact certificate when it applies, else CCD; 'certificate' "
                   "never runs CCD (unprovable steps fail). All are sound.")
@click.option("--strict", is_flag=True,
              help="Deform results: a start state with pre-existing intersections fails its step "
                   "(default: reported, OK when the path leaves them unchanged).")
@usd_options
@scaleout_options
def command(paths, thickness, frames, threads, as_json, max_pairs, mode, strict, usd_prims, usd_obstacles,
            workers, scheduler):
    """Check that no two non-adjacent primitives come within THICKNESS along each step.

    A deform result is checked from positions[frame] to steps/deformed (plus the exact
    certificate of steps/A): the path must add no new intersecting or thickness-violating
    pair; intersections already in the start state are reported as pre-existing (a
    failure with --strict). A raw sequence is checked from frame s to s+1, its start
    states included. Exit 0: all steps safe; 1: a violation; 2: unusable input.
    """
    from ..scaleout import is_long, is_scaleout, verify_many

    frame_slice = parse_frames(frames)
    if is_scaleout(paths, workers, scheduler):  # several inputs / Dask: penfree.scaleout
        from . import scaleout

        if usd_prims or usd_obstacles:
            raise InputError("--prim and --obstacle are not supported with several inputs or --workers/"
                             "--scheduler; verify the USD stage on its own")
        scaleout.start_workers(scheduler)
        if not scaleout.verify(paths, thickness=thickness, frames=frame_slice, mode=mode, max_pairs=max_pairs,
                               workers=workers, scheduler=scheduler, threads=threads, as_json=as_json,
                               step_line=_step_line, strict=strict):
            click.get_current_context().exit(1)
        return
    from ..core.pipeline.verification import n_steps, verify_file
    from ..formats.result import is_result_file

    path = paths[0]
    set_threads(threads)
    total = n_steps(path, frame_slice)
    result = is_result_file(path)
    long_file = not (usd_prims or usd_obstacles) and is_long(path, "result" if result else "path")
    if long_file and frame_slice is not None and not total:  # (exact for a long file: known HDF5 steps)
        raise no_step_error(path, frame_slice, "result" if result else "sequence")
    with Progress(total, "verify") as bar:
        if long_file:
            # frames beyond MAX_TASK_BYTES: its frame ranges one after another, as a worker would
            [report] = verify_many([path], thickness=thickness, frames=frame_slice, mode=mode, max_pairs=max_pairs,
                                   strict=strict, in_process=True, step_progress=bar)
        else:
            report = verify_file(path, thickness=thickness, frames=frame_slice, mode=mode,
                                 max_pairs=max_pairs, progress=bar, strict=strict, prims=usd_prims,
                                 obstacles=usd_obstacles)
    if not report.steps:  # "all steps safe" about nothing would be a false claim
        raise no_step_error(path, frame_slice, report.kind)
    if as_json:
        echo_json(report.to_dict())
    else:
        for step in report.steps:
            click.echo(_step_line(step))
        verdict = "all steps safe" if report.ok else f"{report.n_failed} step(s) VIOLATE"
        if report.n_started_dirty:
            verdict += f"; {report.n_started_dirty} step(s) started with pre-existing intersections"
        click.echo(f"{report.origin}: {len(report.steps)} step(s) checked ({report.kind}, thickness "
                   f"{report.thickness:g}): {verdict}")
    if not report.ok:
        click.get_current_context().exit(1)
