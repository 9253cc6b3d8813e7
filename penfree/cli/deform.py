"""``penfree deform IN -o OUT``: one certified affine map per step, written atomically."""

import os
import time

import click
import numpy as np

from .._version import __version__
from ..constants import MODELS, PROJECTIONS
from ..errors import InputError
from .options import (
    Progress, echo_json, frames_option, json_option, overwrite_option, parse_frames,
    set_threads, thickness_option, threads_option,
)


@click.command("deform")
@click.argument("input_path", metavar="IN", type=click.Path(dir_okay=True))
@click.option("-o", "--output", "output_path", required=True, type=click.Path(dir_okay=False),
              help="Result file (HDF5) to write.")
@click.option("--model", type=click.Choice(MODELS + ("auto", "per-component")), default="auto",
              show_default=True,
              help="Map family fitted toward the constant-velocity prediction; auto: the certified "
                   "candidate with the fewest predicted CD passes; per-component: one map per object.")
@click.option("--projection", type=click.Choice(PROJECTIONS), default="auto", show_default=True,
              help="How a map that fails the certificate is made safe.")
@click.option("--margin", type=click.FloatRange(0.0, 1.0, max_open=True), default=None,
              help="Required lower bound m of sigma_min(I + tD) on [0,1] "
                   "(default: thickness / smallest start gap when a thickness applies, else 0).")
@thickness_option
@frames_option
@click.option("--weights", "weights_name", default=None, metavar="DATASET",
              help="Per-vertex fit weights: a dataset of the input file (e.g. weights, masses).")
@threads_option
@overwrite_option
@click.option("--per-vertex", is_flag=True, help="Also store per-vertex residual norms.")
@click.option("--stats", "with_stats", is_flag=True,
              help="Also compute trust-region statistics (stats/...) for `penfree report`.")
@click.option("--format", "in_format", default=None, help="Input format (default: from the extension).")
@click.option("--client-model", type=click.Choice(["isotropic", "planar"]), default=None,
              help="With --model auto: choose by the predicted CD passes of an OGC client with this truncation "
                   "(radius rule step; penfree's own replay, no ipctk needed).")
@click.option("--dhat", type=click.FloatRange(min=0.0, min_open=True), default=None,
              help="With --client-model: contact offset [default: the contact radius, else the thickness].")
@json_option
def command(input_path, output_path, model, projection, margin, thickness, frames, weights_name,
            threads, overwrite, per_vertex, with_stats, in_format, client_model, dhat, as_json):
    """Fit, certify and apply a global affine map to every step of IN.

    Each step s moves frame s toward the prediction 2 x^s - x^(s-1); the straight path
    to the deformed state is certified penetration-free (exact test) before it is written.
    """
    from ..core.pipeline import deform_sequence, summarize_steps
    from ..formats import read_sequence
    from ..formats.atomic import check_output
    from ..formats.result import write_result

    check_output(output_path, overwrite, inputs=[input_path])
    frame_slice = parse_frames(frames)
    set_threads(threads)
    seq = read_sequence(input_path, format=in_format)
    weights = _read_weights(input_path, weights_name, seq) if weights_name else None
    cm = None
    if client_model:
        from ..core.client_select import ClientModel
        from ..core.client_stats import resolve_dhat

        if model != "auto":
            raise InputError(f"--client-model needs --model auto; got --model {model}")
        cm = ClientModel(truncation=client_model, edges=seq.edges, faces=seq.faces,
                         dhat=resolve_dhat(dhat, getattr(seq, "contact_radius", 0.0),
                                           seq.thickness if thickness is None else thickness))

    t0 = time.perf_counter()
    n_steps = len(range(*slice(*(frame_slice or (None, None))).indices(seq.n_frames)))
    with Progress(n_steps, "deform") as bar:
        result = deform_sequence(
            seq, model=model, projection=projection, margin=margin, thickness=thickness,
            weights=weights, frames=frame_slice, per_vertex=per_vertex, progress=bar, client_model=cm,
        )
    groups = dict(result.groups)
    if with_stats:
        from ..core.stats import compute_stats

        with Progress(len(result.steps["frame"]), "stats") as bar:
            groups["stats"] = compute_stats_for(seq, result, thickness, compute_stats, bar)
    attrs = {
        "penfree_version": __version__,
        "input": os.path.basename(input_path),
        "options": dict(result.options, weights=weights_name or ("weights" if seq.weights is not None else None),
                        client_model=client_model),
    }
    write_result(output_path, seq, result.steps, attrs, groups=groups, overwrite=overwrite)
    elapsed = time.perf_counter() - t0

    summary = summarize_steps(result.steps)
    summary.update(output=output_path, input=input_path, wall_time_s=elapsed,
                   frames_per_s=summary["steps"] / elapsed if elapsed > 0 else None)
    if as_json:
        echo_json(summary)
        return
    _print_summary(summary, seq)


def compute_stats_for(seq, result, thickness, compute_stats, progress):
    """Trust-region statistics of a fresh deform result (stats/... datasets)."""
    steps = result.steps
    return compute_stats(
        positions=seq.positions, frames=steps["frame"], deformed=steps["deformed"],
        edges=seq.edges, faces=seq.faces,
        thickness=seq.thickness if thickness is None else thickness, progress=progress,
    )


def _read_weights(path, name, seq):
    if name == "weights" and seq.weights is not None:
        return seq.weights
    import h5py

    try:
        with h5py.File(path, "r") as f:
            if name not in f:
                raise InputError(f"--weights {name}: no dataset {name!r} in {path}")
            w = np.asarray(f[name][()], dtype=np.float64)
    except OSError:
        raise InputError(f"--weights {name}: {path} is not an HDF5 file; only HDF5 inputs have named datasets") from None
    if w.shape != (seq.n_vertices,):
        raise InputError(f"weights must be ({seq.n_vertices},); got {w.shape} in {path}:/{name}")
    if not np.isfinite(w).all() or (w < 0).any() or not w.sum() > 0:
        raise InputError(f"weights must be finite, >= 0 and not all zero in {path}:/{name}")
    return w


def _print_summary(s, seq):
    models = ", ".join(f"{k} x{v}" for k, v in s["models"].items())
    projs = ", ".join(f"{k} x{v}" for k, v in s["projections"].items())
    click.echo(f"penfree deform: {s['input']} -> {s['output']}")
    click.echo(f"  steps            {s['steps']}  ({seq.n_vertices} vertices, {seq.kind}, {seq.dtype})")
    click.echo(f"  models           {models}")
    click.echo(f"  projections      {projs}")
    click.echo(f"  certified        {'all steps' if s['all_certified'] else 'NOT ALL'}; "
               f"min sigma_min bound {s['min_certificate_margin']:.4f}")
    if s["residual_next_rms_ratio"] == s["residual_next_rms_ratio"]:
        click.echo(f"  to next frame    RMS distance x{s['residual_next_rms_ratio']:.3f} of doing nothing "
                   f"({(1 - s['residual_next_rms_ratio']) * 100:+.1f}% closer)")
    click.echo(f"  to prediction    RMS distance x{s['residual_pred_rms_ratio']:.3f} of doing nothing")
    click.echo(f"  fit time         {s['mean_time_fit_ms']:.3f} ms/step; total {s['wall_time_s']:.2f} s "
               f"({s['frames_per_s']:.1f} steps/s incl. I/O)")
