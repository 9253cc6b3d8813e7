"""The sequence driver: runs the per-step stages over a whole recording.

`deform_sequence` wires fit, projection and certificate (through `fit_step`), the
start-gap query that turns a thickness into a certificate margin, and the residual
summaries against the simulator's next frame. It returns plain arrays in the layout of
SPEC section 8; writing them is the formats layer's job.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..constants import MARGIN_GAP_RADIUS_FACTOR
from ..errors import CertificateError, InputError
from .certificate import certify_map
from .stats import query_radius, residual_summary
from .step import fit_step


@dataclass
class DeformOutput:
    """Per-step arrays (keys as in SPEC section 8, without the ``steps/`` prefix)."""

    steps: dict
    options: dict = field(default_factory=dict)
    groups: dict = field(default_factory=dict)


def step_indices(n_frames: int, frames=None) -> np.ndarray:
    """Steps `s` (1 <= s < T) selected by a ``(start, stop)`` frame slice.

    A step `s` needs frames `s - 1` and `s`; it is selected when `s` lies in the slice.
    """
    start, stop = (None, None) if frames is None else frames
    idx = np.arange(n_frames)[slice(start, stop)]
    idx = idx[idx >= 1]
    if idx.size == 0:
        raise InputError(
            f"--frames {'' if start is None else start}:{'' if stop is None else stop} selects no step "
            f"of a {n_frames}-frame sequence (a step s needs frames s-1 and s, 1 <= s < {n_frames})"
        )
    return idx.astype(np.int64)


def step_margin(x, seq, thickness, margin, d0=None):
    """Certificate margin of one step: the explicit `margin`, else thickness / d0.

    With thickness `h > 0` every gap must stay >= h along the path. Gaps shrink by at
    most sigma_min(M(t)), so sigma_min >= h / d0 (d0 the smallest start gap between
    non-adjacent primitives) suffices. d0 is searched within a radius of
    `MARGIN_GAP_RADIUS_FACTOR * h`; no pair inside it means d0 >= that radius, and the
    margin h / radius is still sufficient (only more conservative than needed).

    `d0` may be given (any lower bound of the smallest gap, e.g. the minimum of
    per-vertex separations capped at a radius >= thickness).

    Returns ``(margin, d0)``; margin is ``None`` when the start state already violates
    the thickness (d0 <= h): no shape change can be certified then, only a translation.
    """
    if margin is not None:
        return float(margin), math.nan
    if thickness <= 0 or seq.kind == "points":
        return 0.0, math.nan
    if d0 is None:
        from .trust_region import min_separation

        radius = MARGIN_GAP_RADIUS_FACTOR * thickness
        d0 = float(min_separation(x, E=seq.edges, F=seq.faces, radius=radius))
    if d0 <= thickness:
        return None, d0
    return thickness / d0, d0


def deform_sequence(
    seq,
    *,
    model="affine",
    projection="auto",
    margin=None,
    thickness=None,
    weights=None,
    frames=None,
    per_vertex=False,
    progress=None,
    client_model=None,
) -> DeformOutput:
    """Fit, project and certify one affine map per step of `seq`.

    Parameters
    ----------
    seq : Sequence
        Validated input.
    model : str
        A model of `fit_step`, or ``"auto"`` (collision-aware choice,
        `selection.select_step`; needs topology, else `fit_step`'s residual-based auto)
        or ``"per-component"`` (`components.per_component_step`).
    projection : str
        As in `fit_step`.
    margin : float or None
        Required lower bound of sigma_min(M(t)). None: thickness / d0 per step when a
        thickness applies, else 0.
    thickness : float or None
        Contact distance; None takes the sequence's.
    weights : (N,) float64 or None
        Fit weights; None takes the sequence's (or uniform).
    frames : (start, stop) or None
        Slice of frames; step `s` is run when `s` is in it.
    per_vertex : bool
        Also keep per-vertex residual norms (S, N) float32.
    progress : callable or None
        Called once per finished step.
    client_model : client_select.ClientModel or None
        With ``model="auto"``: choose by that OGC client's predicted CD passes
        (`selection.select_step`).

    Returns
    -------
    DeformOutput
        ``steps`` holds frame, A, b, deformed, model, projection, certificate_margin,
        margin_required, start_gap, rank, residual_* / baseline_*, time_fit_s.

    Notes
    -----
    Every applied A passes the exact certificate (`certify`) with the step's margin;
    a step that fails it raises CertificateError instead of being written.
    """
    thickness = seq.thickness if thickness is None else float(thickness)
    weights = seq.weights if weights is None else weights
    pos = seq.positions
    T, N = pos.shape[0], pos.shape[1]
    S_idx = step_indices(T, frames)
    S = S_idx.size

    out = {
        "frame": S_idx,
        "A": np.empty((S, 3, 3)),
        "b": np.empty((S, 3)),
        "deformed": np.empty((S, N, 3), dtype=pos.dtype),
        "model": np.empty(S, dtype=object),
        "projection": np.empty(S, dtype=object),
        "certificate_margin": np.empty(S),
        "margin_required": np.empty(S),
        "start_gap": np.full(S, np.nan),
        "rank": np.empty(S, dtype=np.int64),
        "time_fit_s": np.empty(S),
    }
    for who in ("residual", "baseline"):
        for tgt in ("pred", "next"):
            for agg in ("rms", "max"):
                out[f"{who}_{tgt}_{agg}"] = np.full(S, np.nan)
    if per_vertex:
        out["residual_pred_per_vertex"] = np.empty((S, N), dtype=np.float32)
        out["residual_next_per_vertex"] = np.full((S, N), np.nan, dtype=np.float32)

    per_component = model == "per-component"
    if per_component:
        from .components import component_labels, per_component_step

        labels = component_labels(N, seq.edges, seq.faces, seq.components)
        C = int(labels.max()) + 1
        # NaN / -1 for steps that could not use per-component maps (start within thickness)
        comp = {"labels": labels, "A": np.full((S, C, 3, 3), np.nan), "b": np.full((S, C, 3), np.nan),
                "group": np.full((S, C), -1, dtype=np.int64), "rounds": np.zeros(S, dtype=np.int64)}
    select = model == "auto" and seq.kind != "points"
    if select:
        from .selection import select_step
        from .trust_region import scene_arrays, per_vertex_separation

        _, E, F = scene_arrays(pos[0], seq.edges, seq.faces)
        table_rows = [None] * S

    # Untimed warm-up on a few vertices: JIT compilation (first run, or a stale cache)
    # must not count as fit time.
    fit_step(pos[S_idx[0] - 1][:4], pos[S_idx[0]][:4], model="affine" if model in ("auto", "per-component")
             else model, projection=projection)

    for k, s in enumerate(S_idx):
        x_prev, x = pos[s - 1], pos[s]
        x64 = np.asarray(x, dtype=np.float64)
        x_pred = 2.0 * x64 - np.asarray(x_prev, dtype=np.float64)
        if select:
            r_q = query_radius(x64, x_pred, thickness)
            d_start = per_vertex_separation(x64, E, F, r_q)
            m, d0 = step_margin(x, seq, thickness, margin, d0=float(d_start.min()) if len(d_start) else r_q)
        else:
            m, d0 = step_margin(x, seq, thickness, margin)
        if m is None:  # start state within the thickness: only a translation is safe
            r = _applied(fit_step(x_prev, x, weights=weights, model="translation", projection=projection))
        elif per_component:
            cs = per_component_step(x_prev, x, labels, edges=seq.edges, faces=seq.faces, thickness=thickness,
                                    weights=weights, margin=m, projection=projection)
            comp["A"][k], comp["b"][k], comp["group"][k], comp["rounds"][k] = cs.A, cs.b, cs.group, cs.rounds
            r = _component_applied(cs)
        elif select:
            res, table_rows[k] = select_step(x_prev, x, d_start, r_q=r_q, thickness=thickness, weights=weights,
                                             margin=m, projection=projection, client_model=client_model)
            r = _applied(res)
        else:
            r = _applied(fit_step(x_prev, x, weights=weights, model=model, projection=projection, margin=m))
        for A_applied in r.maps:  # belt and braces: every applied map through the one gate
            if not certify_map(A_applied, m or 0.0):
                raise CertificateError(f"step {s}: the applied map failed the exact certificate (margin {m})")
        out["A"][k], out["b"][k] = r.A, r.b
        out["deformed"][k] = r.x_def
        out["model"][k], out["projection"][k] = r.model, r.projection
        out["certificate_margin"][k] = r.certificate_margin
        out["margin_required"][k] = 1.0 if m is None else m
        out["start_gap"][k] = d0
        out["rank"][k] = r.rank
        out["time_fit_s"][k] = r.time_fit_s

        targets = {"pred": x_pred}
        if s + 1 < T:
            targets["next"] = pos[s + 1]
        for tgt, y in targets.items():
            out[f"residual_{tgt}_rms"][k], out[f"residual_{tgt}_max"][k] = residual_summary(r.x_def, y)
            out[f"baseline_{tgt}_rms"][k], out[f"baseline_{tgt}_max"][k] = residual_summary(x64, y)
            if per_vertex:
                out[f"residual_{tgt}_per_vertex"][k] = np.linalg.norm(
                    np.asarray(r.x_def, dtype=np.float64) - np.asarray(y, dtype=np.float64), axis=1)
        if progress is not None:
            progress()

    groups = {"selection": selection_arrays(table_rows)} if select else {}
    if per_component:
        groups["component_maps"] = comp
    out["model"] = out["model"].astype(str)
    out["projection"] = out["projection"].astype(str)
    options = {
        "model": model,
        "projection": projection,
        "margin": "thickness/d0" if margin is None and thickness > 0 else (0.0 if margin is None else float(margin)),
        "thickness": thickness,
        "frames": "all" if frames is None else f"{frames[0] if frames[0] is not None else ''}:{frames[1] if frames[1] is not None else ''}",
        "per_vertex": bool(per_vertex),
    }
    return DeformOutput(steps=out, options=options, groups=groups)


@dataclass
class _Applied:
    """What one step applied, whichever stage produced it."""

    A: np.ndarray  # (3, 3); NaN when components moved with different maps
    b: np.ndarray
    x_def: np.ndarray
    model: str
    projection: str
    certificate_margin: float
    rank: int
    time_fit_s: float
    maps: list  # every distinct map applied, each to pass the exact certificate


def _applied(r) -> _Applied:
    return _Applied(r.A, r.b, r.x_def, r.model, r.projection, r.certificate_margin, r.rank, r.time_fit_s, [r.A])


def _component_applied(cs) -> _Applied:
    maps = list(np.unique(cs.A, axis=0))
    if len(np.unique(cs.group)) == 1:  # everything merged: one global map
        return _Applied(cs.A[0], cs.b[0], cs.x_def, next(iter(cs.models)), "auto", cs.certificate_margin,
                        cs.rank, cs.time_fit_s, maps)
    # SPEC: steps/A is *the* map applied; with several there is none (NaN), and
    # component_maps/A holds each component's map.
    return _Applied(np.full((3, 3), np.nan), np.full(3, np.nan), cs.x_def, "per-component", "per-component",
                    cs.certificate_margin, cs.rank, cs.time_fit_s, maps)


def selection_arrays(table_rows) -> dict:
    """Per-step candidate tables of `select_step` as ``selection/...`` arrays.

    ``candidates`` (C,) names in a fixed order; ``predicted_<figure>`` (S, C) with NaN
    where a candidate was not certified (or the step was not selected); ``chosen`` (S,)
    the index of the chosen candidate (-1 when the step was not selected).
    """
    names = []
    for table in table_rows:
        for row in table or ():
            if row["name"] not in names:
                names.append(row["name"])
    S, C = len(table_rows), len(names)
    figures = ("k_1pct", "k_any", "hit_rate", "r_q99", "sigma_lb", "certificate_margin")
    arrays = {f"predicted_{f}": np.full((S, C), np.nan) for f in figures}
    chosen = np.full(S, -1, dtype=np.int64)
    for k, table in enumerate(table_rows):
        for row in table or ():
            j = names.index(row["name"])
            for f in figures:
                arrays[f"predicted_{f}"][k, j] = row[f]
            if row["chosen"]:
                chosen[k] = j
    arrays["candidates"] = np.array(names, dtype=str)
    arrays["chosen"] = chosen
    return arrays


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
        "all_certified": bool(np.all(steps["certificate_margin"] >= steps["margin_required"])),
        "residual_next_rms_ratio": ratio(steps["residual_next_rms"][nxt] ** 2, steps["baseline_next_rms"][nxt] ** 2) ** 0.5
        if nxt.any() else math.nan,
        "residual_pred_rms_ratio": ratio(steps["residual_pred_rms"] ** 2, steps["baseline_pred_rms"] ** 2) ** 0.5,
        "mean_time_fit_ms": float(np.mean(steps["time_fit_s"]) * 1e3),
    }
