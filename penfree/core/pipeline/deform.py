"""The sequence driver: runs the per-step stages over a whole recording.

`deform_sequence` is a short loop: per step, a strategy (`strategy.SingleMap`,
`strategy.Auto`, `strategy.PerComponent`) proposes maps, preferred first (and the preferred
one's shortened steps before doing nothing, `strategy.with_shortened`); the first one
that passes the shared safety gate (`gate.StepGate`: the exact certificate at deform's
margin, `gate.deform_margin`; the near-pair CCD when a thickness applies; the obstacles)
is applied. Doing nothing ends every chain and always passes. It returns plain arrays in
the layout of SPEC section 8; writing them is the formats layer's job.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from ..._version import __version__
from ...errors import CertificateError, InputError
from ..fit.certificate import certify_map
from ..verify.gate import StepGate, deform_margin
from ..verify.path import SceneTopology, check_thickness
from ..trust.stats import compute_stats, residual_summary
from ..fit.step import fit_step
from ..memory import populated_empty
from .strategy import make_strategy, step_input, with_shortened


@dataclass
class DeformOutput:
    """Per-step arrays (keys as in SPEC section 8, without the ``steps/`` prefix)."""

    steps: dict
    options: dict = field(default_factory=dict)
    groups: dict = field(default_factory=dict)


def step_indices(n_frames: int, frames=None, origin=None) -> np.ndarray:
    """Steps `s` (1 <= s < T) selected by a ``(start, stop)`` frame slice.

    A step `s` needs frames `s - 1` and `s`; it is selected when `s` lies in the slice.
    `origin` (the recording's file) is named by the error when it selects none.
    """
    start, stop = (None, None) if frames is None else frames
    idx = np.arange(n_frames)[slice(start, stop)]
    idx = idx[idx >= 1]
    if idx.size == 0:
        raise InputError(
            f"--frames {'' if start is None else start}:{'' if stop is None else stop} selects no step "
            f"of {'a ' if origin is None else str(origin) + ', a '}{n_frames}-frame sequence (a step s needs "
            f"frames s-1 and s, 1 <= s < {n_frames})"
        )
    return idx.astype(np.int64)


def required_margin(thickness, margin=None) -> float:
    """The margin every map of a step must be certified with: deform's (`gate.deform_margin`),
    or a larger explicit one."""
    rule = deform_margin(thickness)
    return rule if margin is None else max(rule, float(margin))


def deform_sequence(seq, *, model="affine", projection="auto", margin=None, thickness=None, contact_radius=None,
                    weights=None, frames=None, per_vertex=False, progress=None, check_start=False,
                    client_model=None) -> DeformOutput:
    """Fit, certify, check and apply one map per step of `seq`.

    Parameters
    ----------
    seq : Sequence
        Validated input.
    model : str
        A model of `fit_step`, or ``"auto"`` (collision-aware choice, `selection`;
        needs topology, else `fit_step`'s residual-based auto) or ``"per-component"``.
    projection : str
        As in `fit_step`.
    margin : float or None
        Required lower bound of sigma_min(M(t)) beyond deform's margin
        (`gate.deform_margin`: 0.1); None: that one.
    thickness : float or None
        Hard minimum separation; None takes the sequence's.
    contact_radius : float or None
        The simulator's contact distance (sizes the query radius of `auto`'s
        predictor); None takes the sequence's.
    weights : (N,) float64 or None
        Fit weights; None takes the sequence's (or uniform).
    frames : (start, stop) or None
        Slice of frames; step `s` is run when `s` is in it.
    per_vertex : bool
        Also keep per-vertex residual norms (S, N) float32.
    progress : callable or None
        Called once per finished step.
    client_model : client_select.ClientModel or None
        With ``model="auto"``: the candidate with the fewest CD passes of that OGC client
        (replayed by penfree's own client, radius rule ``step``) is tried first.
    check_start : bool
        Also count each start state's pre-existing intersections
        (``start_intersections``, `start_state_intersections`); costs about a static
        verification per step.

    Returns
    -------
    DeformOutput
        ``steps`` holds frame, A, b, deformed, model, projection, certificate_margin,
        margin_required, rank, residual_* / baseline_*, time_fit_s (and
        start_intersections with `check_start`).

    Notes
    -----
    Every applied map passes `gate.StepGate` (the exact certificate through
    `certify_map` among its checks) and is certified again before it is recorded; a
    step that would not be raises CertificateError instead of being written.
    """
    thickness = check_thickness(seq.thickness if thickness is None else thickness)
    contact_radius = check_thickness(seq.contact_radius if contact_radius is None else contact_radius,
                                     "contact_radius")
    weights = seq.weights if weights is None else weights
    S_idx = step_indices(seq.n_frames, frames, seq.origin)
    m = required_margin(thickness, margin)
    strategy = make_strategy(model, seq, projection, thickness, S_idx.size, client_model, contact_radius)
    out = _allocate(seq, S_idx, per_vertex)
    if check_start:
        out["start_intersections"] = start_state_intersections(seq, S_idx)
    _warm_up(seq, S_idx[0], model, projection)
    topology = SceneTopology(seq.n_vertices, seq.edges, seq.faces)  # read once, for every step's gate
    for k, s in enumerate(S_idx):
        step, outcome = run_step(seq, s, strategy, m, thickness, weights, contact_radius, topology)
        strategy.record(k, outcome)
        _record(out, k, step, outcome, seq, per_vertex)
        if progress is not None:
            progress()
    out["model"] = out["model"].astype(str)
    out["projection"] = out["projection"].astype(str)
    options = run_options(model, projection, m, thickness, contact_radius, frames, per_vertex)
    return DeformOutput(steps=out, options=options, groups=strategy.groups())


def run_step(seq, s, strategy, m, thickness, weights, contact_radius, topology=None):
    """Step `s`: the strategy's outcomes, then shortened steps, then doing nothing; the
    first that passes the step's gate (`topology`: the scene's `SceneTopology`, else
    read from `seq`). Returns ``(StepInput, Outcome)``.

    Raises CertificateError if the applied map fails the exact certificate (never
    expected: the gate certified it).
    """
    gate = StepGate(seq.positions[s], edges=seq.edges, faces=seq.faces, thickness=thickness,
                    obstacles=seq.obstacles, frame=s, topology=topology)
    step = step_input(seq, s, m, gate, weights, contact_radius)
    outcome = next(o for o in with_shortened(strategy.outcomes(step), step) if gate.passes(o.x_def, o.maps))
    for A_applied, _, _ in outcome.maps:  # belt and braces: every applied map through the one gate
        if not certify_map(A_applied, m):
            raise CertificateError(f"step {s}: the applied map failed the exact certificate (margin {m})")
    return step, outcome


def run_options(model, projection, margin, thickness, contact_radius, frames, per_vertex) -> dict:
    """The ``options`` a result records (`margin` the required one, `frames` a slice or None)."""
    return {
        "model": model, "projection": projection, "margin": margin, "thickness": thickness,
        "contact_radius": contact_radius,
        "frames": "all" if frames is None else f"{frames[0] if frames[0] is not None else ''}:"
                                               f"{frames[1] if frames[1] is not None else ''}",
        "per_vertex": bool(per_vertex),
    }


def result_attrs(input_path, options, **more_options) -> dict:
    """The attributes of a deform result file: version, input name and `options`
    (`run_options`, updated with `more_options`). The run's thickness and contact
    radius replace the input's, so that `verify` and `report` of the result check
    the separation that deform guaranteed, not the input's."""
    return {"penfree_version": __version__, "input": os.path.basename(input_path),
            "thickness": float(options["thickness"]), "contact_radius": float(options["contact_radius"]),
            "options": dict(options, **more_options)}


def _allocate(seq, S_idx, per_vertex) -> dict:
    S, N = S_idx.size, seq.n_vertices
    out = {
        "frame": S_idx,
        "A": np.empty((S, 3, 3)),
        "b": np.empty((S, 3)),
        "deformed": populated_empty((S, N, 3), seq.positions.dtype),  # filled step by step: no page faults
        "model": np.empty(S, dtype=object),
        "projection": np.empty(S, dtype=object),
        "certificate_margin": np.empty(S),
        "margin_required": np.empty(S),
        "rank": np.empty(S, dtype=np.int64),
        "time_fit_s": np.empty(S),
    }
    for who in ("residual", "baseline"):
        for tgt in ("pred", "next"):
            for agg in ("rms", "max"):
                out[f"{who}_{tgt}_{agg}"] = np.full(S, np.nan)
    if per_vertex:
        out["residual_pred_per_vertex"] = populated_empty((S, N), np.float32)
        out["residual_next_per_vertex"] = populated_empty((S, N), np.float32)
        out["residual_next_per_vertex"].fill(np.nan)
    return out


def start_state_intersections(seq, frames) -> np.ndarray:
    """(S,) int64: pairs already touching or intersecting at each step's start frame.

    `verify.start_intersections` of ``positions[s]`` for every `s` in `frames` (0 for
    a scene without topology): the steps "started dirty" that `report` counts.
    """
    from ..verify.pairs import start_intersections

    if seq.kind == "points":
        return np.zeros(len(frames), dtype=np.int64)
    return np.array([start_intersections(seq.positions[s], seq.edges, seq.faces) for s in frames], dtype=np.int64)


def deform_stats(seq, steps, *, thickness=None, contact_radius=None, progress=None) -> dict:
    """Trust-region statistics of a fresh deform output (the ``stats/`` datasets).

    Parameters
    ----------
    seq : Sequence
        The deformed recording (positions, topology, obstacles).
    steps : dict
        `DeformOutput.steps` (``frame (S,) int64``, ``deformed (S, N, 3) float``).
    thickness, contact_radius : float, optional
        The values deform ran with; default the sequence's.
    progress : callable, optional
        Called once per step.

    Returns
    -------
    dict
        `penfree.core.trust.stats.compute_stats` output.
    """
    return compute_stats(
        positions=seq.positions, frames=steps["frame"], deformed=steps["deformed"],
        edges=seq.edges, faces=seq.faces,
        thickness=seq.thickness if thickness is None else thickness, progress=progress,
        contact_radius=seq.contact_radius if contact_radius is None else contact_radius,
        obstacles=seq.obstacles,
    )


def _warm_up(seq, s, model, projection):
    """Untimed fit on a few vertices: JIT compilation (first run, or a stale cache) must
    not count as fit time."""
    pos = seq.positions
    fit_step(pos[s - 1][:4], pos[s][:4], model="affine" if model in ("auto", "per-component") else model,
             projection=projection)


def _record(out, k, step, o, seq, per_vertex):
    out["A"][k], out["b"][k] = o.A, o.b
    out["deformed"][k] = o.x_def
    out["model"][k], out["projection"][k] = o.model, o.projection
    out["certificate_margin"][k] = o.certificate_margin
    out["margin_required"][k] = step.margin
    out["rank"][k] = o.rank
    out["time_fit_s"][k] = o.time_fit_s
    targets = {"pred": step.x_pred}
    if step.s + 1 < seq.n_frames:
        targets["next"] = seq.positions[step.s + 1]
    for tgt, y in targets.items():
        out[f"residual_{tgt}_rms"][k], out[f"residual_{tgt}_max"][k] = residual_summary(o.x_def, y)
        out[f"baseline_{tgt}_rms"][k], out[f"baseline_{tgt}_max"][k] = residual_summary(step.x64, y)
        if per_vertex:
            out[f"residual_{tgt}_per_vertex"][k] = np.linalg.norm(
                np.asarray(o.x_def, dtype=np.float64) - np.asarray(y, dtype=np.float64), axis=1)


def summarize_steps(steps: dict) -> dict:
    """Sequence-level summary of `deform_sequence` output (for the CLI and --json)."""
    nxt = ~np.isnan(steps["residual_next_rms"])

    def ratio(a, b):
        return float(np.sum(a) / np.sum(b)) if np.sum(b) > 0 else math.nan

    models, counts = np.unique(steps["model"], return_counts=True)
    projs, pcounts = np.unique(steps["projection"], return_counts=True)
    return {
        "steps": int(len(steps["frame"])),
        "models": {str(m): int(c) for m, c in zip(models, counts)},
        "projections": {str(p): int(c) for p, c in zip(projs, pcounts)},
        "min_certificate_margin": float(np.min(steps["certificate_margin"])),
        # every written map passes its own certificate: its certified bound >= the margin it needed
        "all_certified": bool(np.all(np.asarray(steps["certificate_margin"]) >= steps["margin_required"])),
        "steps_started_dirty": (int(np.count_nonzero(np.asarray(steps["start_intersections"]) > 0))
                                if "start_intersections" in steps else None),
        "residual_next_rms_ratio": ratio(steps["residual_next_rms"][nxt] ** 2, steps["baseline_next_rms"][nxt] ** 2) ** 0.5
        if nxt.any() else math.nan,
        "residual_pred_rms_ratio": ratio(steps["residual_pred_rms"] ** 2, steps["baseline_pred_rms"] ** 2) ** 0.5,
        "mean_time_fit_ms": float(np.mean(steps["time_fit_s"]) * 1e3),
    }
