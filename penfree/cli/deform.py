"""``penfree deform IN -o OUT``: one certified affine map per step, written atomically."""

import os
import time

import click
import numpy as np

from ..constants import MODELS, PROJECTIONS
from ..core.parallel import set_threads
from ..errors import InputError
from ..sequence import SCALE_MAX
from .options import (
    FiniteFloat, Progress, echo_json, frames_option, json_option, overwrite_option, parse_frames,
    contact_radius_option, scaleout_options, thickness_option, threads_option, usd_options,
)


@click.command("deform")
@click.argument("input_paths", metavar="IN...", nargs=-1, required=True, type=click.Path(dir_okay=True))
@click.option("-o", "--output", "output_path", required=True, type=click.Path(),
              help="Result file (HDF5) of one input file; with several files, a directory of recordings or a "
                   "glob: a directory (<dir>/<stem>.h5 each).")
@click.option("--model", type=click.Choice(MODELS + ("auto", "per-component")), default="auto",
              show_default=True,
              help="Map family fitted toward the constant-velocity prediction; auto: the certified "
                   "candidate with the fewest predicted CD passes; per-component: one map per object.")
@click.option("--projection", type=click.Choice(PROJECTIONS), default="auto", show_default=True,
              help="How a map that fails the certificate is made safe.")
@click.option("--margin", type=FiniteFloat(0.0, 1.0, max_open=True), default=None,
              help="Required lower bound m of sigma_min(I + tD) on [0,1] "
                   "(default and minimum: 0.1; with a thickness, the pairs the certificate "
                   "does not keep apart, at most 10 thicknesses, are checked by CCD).")
@thickness_option
@contact_radius_option
@frames_option
@click.option("--weights", "weights_name", default=None, metavar="DATASET",
              help="Per-vertex fit weights: a dataset of the input file (e.g. weights, masses).")
@threads_option
@overwrite_option
@click.option("--per-vertex", is_flag=True, help="Also store per-vertex residual norms.")
@click.option("--stats", "with_stats", is_flag=True,
              help="Also compute trust-region statistics (stats/...) and the start states' "
                   "pre-existing intersections for `penfree report`.")
@click.option("--check-start", is_flag=True,
              help="Count each start state's pre-existing intersections (steps/start_intersections; "
                   "about one static verification per step).")
@click.option("--format", "in_format", default=None, help="Input format (default: from the extension).")
@click.option("--client-model", type=click.Choice(["isotropic", "planar"]), default=None,
              help="With --model auto: choose by the predicted CD passes of an OGC client with this truncation "
                   "(penfree's own replay, no ipctk needed).")
@click.option("--client-radius", type=click.Choice(["step", "own"]), default=None,
              help="With --client-model: the radius rule the simulator follows: step = it keeps the inflation radius "
                   "computed at x (how a pre-deformation should be integrated) [default]; own = it calls ipctk's "
                   "warm_start_time_step from x_def, which recomputes the radius.")
@click.option("--dhat", type=FiniteFloat(min=0.0, min_open=True, max=SCALE_MAX), default=None,
              help="With --client-model: contact offset [default: the contact radius, else the thickness].")
@usd_options
@json_option
@scaleout_options
def command(input_paths, output_path, model, projection, margin, thickness, contact_radius, frames, weights_name,
            threads, overwrite, per_vertex, with_stats, check_start, in_format, client_model, client_radius, dhat,
            usd_prims, usd_obstacles, as_json, workers, scheduler):
    """Fit, certify and apply a global affine map to every step of IN.

    Each step s moves frame s toward the prediction 2 x^s - x^(s-1); the straight path
    to the deformed state is certified penetration-free (exact test) before it is written.
    """
    from ..scaleout import is_long, is_scaleout

    if dhat is not None and not client_model:
        raise InputError("--dhat is the contact offset of --client-model's replay; give --client-model too")
    if client_radius is not None and not client_model:
        raise InputError("--client-radius is the radius rule of --client-model's replay; give --client-model too")
    opts = dict(model=model, projection=projection, margin=margin, thickness=thickness,
                contact_radius=contact_radius, per_vertex=per_vertex, check_start=check_start,
                frames=parse_frames(frames), format=in_format)
    serial_only = weights_name or usd_prims or usd_obstacles or client_model
    if is_scaleout(input_paths, workers, scheduler):  # several inputs / Dask: penfree.scaleout
        if serial_only:
            raise InputError("--weights, --prim, --obstacle and --client-model are not supported with several "
                             "inputs, --workers or --scheduler")
        from . import scaleout

        scaleout.start_workers(scheduler)
        return scaleout.deform(input_paths, output_path, opts, overwrite=overwrite, with_stats=with_stats,
                               workers=workers, scheduler=scheduler, threads=threads, as_json=as_json)
    from ..core.pipeline.deform import deform_sequence, deform_stats, result_attrs, step_indices
    from ..formats import check_outputs, input_files, read_sequence
    from ..formats.result import write_result

    input_path = input_paths[0]
    if os.path.isdir(output_path):
        raise InputError(f"-o {output_path} is a directory; give a result file name (a directory only with "
                         f"several inputs)")
    from ..formats.atomic import check_file_name

    check_file_name(output_path)
    inputs = input_files(input_path, in_format)
    if os.path.isdir(input_path):  # a mesh sequence read whole: nothing may be written into it
        inputs.append(input_path)
    check_outputs([output_path], inputs, overwrite)
    frame_slice = parse_frames(frames)
    set_threads(threads)
    if not serial_only and is_long(input_path, "sequence", in_format):
        return _deform_long(input_path, output_path, opts, overwrite, with_stats, as_json)
    t0 = time.perf_counter()  # the summary's wall time: reading, the steps and writing
    seq = read_sequence(input_path, format=in_format, prims=usd_prims, obstacles=usd_obstacles)
    weights = _read_weights(input_path, weights_name, seq) if weights_name else None
    cm = None
    if client_model:
        from ..core.pipeline.client_select import ClientModel
        from ..core.trust.client_stats import resolve_dhat

        if model != "auto":
            raise InputError(f"--client-model needs --model auto; got --model {model}")
        cm = ClientModel(truncation=client_model, radius=client_radius or "step", edges=seq.edges, faces=seq.faces,
                         obstacles=tuple(seq.obstacles),
                         dhat=resolve_dhat(dhat, seq.contact_radius if contact_radius is None else contact_radius,
                                           seq.thickness if thickness is None else thickness))

    n_steps = step_indices(seq.n_frames, frame_slice, input_path).size  # (exit 2 here when it selects none)
    with Progress(n_steps, "deform") as bar:
        result = deform_sequence(
            seq, model=model, projection=projection, margin=margin, thickness=thickness,
            contact_radius=contact_radius, weights=weights, frames=frame_slice, per_vertex=per_vertex, progress=bar,
            check_start=check_start or with_stats, client_model=cm,
        )
    groups = dict(result.groups)
    if with_stats:
        with Progress(len(result.steps["frame"]), "stats") as bar:
            groups["stats"] = deform_stats(seq, result.steps, thickness=thickness, contact_radius=contact_radius,
                                           progress=bar)
    attrs = result_attrs(input_path, result.options,
                         weights=weights_name or ("weights" if seq.weights is not None else None),
                         **({"client_model": client_model, "client_radius": cm.radius} if client_model else {}))
    write_result(output_path, seq, result.steps, attrs, groups=groups, overwrite=overwrite)
    _finish(result.steps, seq, input_path, output_path, time.perf_counter() - t0, as_json)


def _finish(steps, seq, input_path, output_path, elapsed, as_json):
    """Print the run's summary (`summarize_steps` and the wall time), as JSON or text."""
    from ..core.pipeline.deform import summarize_steps

    summary = summarize_steps(steps)
    summary.update(output=output_path, input=input_path, wall_time_s=elapsed,
                   frames_per_s=summary["steps"] / elapsed if elapsed > 0 else None)
    if as_json:
        echo_json(summary)
        return
    _print_summary(summary, seq)


def _deform_long(input_path, output_path, opts, overwrite, with_stats, as_json):
    """A serial run of a recording whose frames exceed `scaleout.plan.MAX_TASK_BYTES`: its
    frame ranges one after another in this process, merged as a scale-out run merges them
    (the same result; at most about that many bytes of frames held at a time)."""
    from ..core.pipeline.deform import step_indices
    from ..formats import read_sequence
    from ..scaleout import deform_many

    t0 = time.perf_counter()
    head = read_sequence(input_path, format="hdf5", frame_window=(0, 2))  # the summary's size and kind
    # the steps selected (exit 2 before any range is read when there are none)
    n_steps = step_indices(_n_frames(input_path), opts["frames"], input_path).size
    with Progress(n_steps, "deform") as bar:
        [(_, _, steps)] = deform_many([input_path], output_path, options=dict(opts, progress=bar),
                                      overwrite=overwrite, with_stats=with_stats, in_process=True)
    _finish(steps, head, input_path, output_path, time.perf_counter() - t0, as_json)


def _n_frames(path) -> int:
    import h5py

    with h5py.File(path, "r") as f:
        return int(f["positions"].shape[0])


def _read_weights(path, name, seq):
    if name == "weights" and seq.weights is not None:
        return seq.weights
    import h5py

    from ..formats.hdf5 import open_h5
    from ..sequence import check_weights

    where = f"{path}:/{name}"
    try:
        with open_h5(path) as f:
            obj = f.get(name)
            if obj is None:
                raise InputError(f"--weights {name}: no dataset {name!r} in {where}")
            if not isinstance(obj, h5py.Dataset) or obj.dtype.kind not in "iuf":
                what = "a group" if isinstance(obj, h5py.Group) else f"a {obj.dtype} dataset"
                raise InputError(f"--weights {name}: expected a numeric ({seq.n_vertices},) dataset; got {what} in {where}")
            w = np.asarray(obj[()], dtype=np.float64)
    except InputError as exc:
        if "not an HDF5 file" in str(exc):
            raise InputError(f"--weights {name}: {path} is not an HDF5 file; only HDF5 inputs have named datasets") from None
        raise
    return check_weights(w, seq.n_vertices, where)


def _print_summary(s, seq):
    models = ", ".join(f"{k} x{v}" for k, v in s["models"].items())
    projs = ", ".join(f"{k} x{v}" for k, v in s["projections"].items())
    click.echo(f"penfree deform: {s['input']} -> {s['output']}")
    click.echo(f"  steps            {s['steps']}  ({seq.n_vertices} vertices, {seq.kind}, {seq.dtype})")
    click.echo(f"  models           {models}")
    click.echo(f"  projections      {projs}")
    click.echo(f"  certified        {'all steps' if s['all_certified'] else 'NOT ALL'}; "
               f"min sigma_min bound {s['min_certificate_margin']:.4f}")
    if s.get("steps_started_dirty"):
        click.echo(f"  start states     {s['steps_started_dirty']} step(s) start with pre-existing intersections "
                   "(kept as they were)")
    if s["residual_next_rms_ratio"] == s["residual_next_rms_ratio"]:
        click.echo(f"  to next frame    RMS distance x{s['residual_next_rms_ratio']:.3f} of doing nothing "
                   f"({(1 - s['residual_next_rms_ratio']) * 100:+.1f}% closer)")
    click.echo(f"  to prediction    RMS distance x{s['residual_pred_rms_ratio']:.3f} of doing nothing")
    click.echo(f"  fit time         {s['mean_time_fit_ms']:.3f} ms/step; total {s['wall_time_s']:.2f} s "
               f"({s['frames_per_s']:.1f} steps/s incl. I/O)")
