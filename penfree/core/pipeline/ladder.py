"""Speed against error over the model ladder (SPEC sections 4 and 7).

Every step of a sequence is re-fitted with each model of the ladder (translation,
rigid, similarity, affine, auto) to the same target, and each model is scored by its
mean fit time, its residual to the simulator's next frame and to the prediction, the
trust-region figures of its deformed state against the next frame (bounds recomputed
at that state: the *actual* figures, not the selection's predictions), and its
certificate margin. The ``baseline`` row is the recorded state itself (no map); the
``x_pred`` row is the unsafe ideal (the prediction itself, no certificate), a ceiling.
``auto`` is the collision-aware choice of `penfree.core.fit.auto.select_step` when the scene has
topology (the residual-only choice of `fit_step` otherwise).
"""

from __future__ import annotations

import math
import time

import numpy as np

from ...constants import DEFAULT_GAMMA, DEFAULT_REPLAY_CAP
from ..trust.stats import StepBounds, ratio_stats, replay_passes, residual_summary
from ..trust.summary import finite_mean
from .strategy import start_separations, step_target

#: The ladder, cheapest first (SPEC section 4), then the automatic choice.
LADDER_MODELS = ("translation", "rigid", "similarity", "affine", "auto")

#: Untimed calls per model before the timed ones (Numba compiles some paths lazily).
LADDER_WARMUP_CALLS = 2

#: Per-step figures kept for every model (arrays (S,) float64 in ``ladder["steps"][model]``).
LADDER_FIGURES = ("fit_ms", "residual_next_rms", "residual_pred_rms", "k_1pct_next", "k_any_next",
                  "hit_rate_next", "certificate_margin", "replay_k_1pct_next", "replay_k_any_next")
#: Per-step names kept beside them: ``model_used`` (S,) str, the model a fit actually used
#: (``auto``'s pick, a fallback; "" for the rows without a fit: ``baseline``, ``x_pred``).
LADDER_NAMES = ("model_used",)

#: Fixed models `auto` is compared with when counting how often it chose the best.
FIXED_MODELS = ("translation", "rigid", "similarity", "affine")


def _pooled_rms(a):
    a = np.asarray(a, dtype=np.float64)
    a = a[np.isfinite(a)]
    return math.sqrt(float(np.mean(a * a))) if a.size else math.nan


def _median(a):
    a = np.asarray(a, dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else math.nan


def _min(a):
    a = np.asarray(a, dtype=np.float64)
    a = a[~np.isnan(a)]
    return float(a.min()) if a.size else math.nan


def model_ladder(positions, frames, *, edges=None, faces=None, thickness=0.0, weights=None, margins=None,
                 models=LADDER_MODELS, projection="auto", gamma=DEFAULT_GAMMA, bounds_fn=None, fit_fn=None,
                 ceiling=True, replay=False, replay_cap=DEFAULT_REPLAY_CAP, components=None,
                 progress=None, contact_radius=0.0) -> dict:
    """Re-fit every step with each model and score speed against error.

    Parameters
    ----------
    positions : (T, N, 3) float
        Recorded frames.
    frames : (S,) int
        Frame index `s` of each step (the fit uses `positions[s-1]`, `positions[s]`).
    edges : (E, 2) int, faces : (F, 3) int, thickness : float
        Topology and contact distance for the trust-region bounds.
    weights : (N,) float, optional
        Fit weights.
    margins : (S,) float, optional
        Certificate margin per step (e.g. ``steps/margin_required`` of a result);
        default 0. A margin >= 1 (the deform pipeline's "no shape change may be
        certified" marker) fits a translation for every model of that step.
    models : sequence of str
        Ladder models, passed to `fit_step` as ``model``.
    projection : str
        Projection mode passed to `fit_step`.
    gamma : float
        OGC gamma_p of the bounds.
    bounds_fn : callable, optional
        ``bounds_fn(x (N, 3) float64, query_radius) -> (N,) float64``; default
        `trust_region_bounds` with this topology.
    fit_fn : callable, optional
        Stand-in for `penfree.core.fit.step.fit_step` (same signature and result fields).
    components : (N,) int, optional
        Object labels for the optional ``"per-component"`` model (default: connected
        components of the topology). That model runs the CCD between objects every step.
    ceiling : bool
        Add the ``x_pred`` row (the unsafe ideal: the prediction itself).
    replay, replay_cap
        Also the replay estimates (one bound computation per pass, model and step).
    progress : callable, optional
        Called once per finished step.

    Returns
    -------
    dict
        ``models`` (list, ``"baseline"`` first), ``n_steps``, ``n_steps_next``,
        ``rows``: one dict per model with ``model``, ``fit_ms_mean``, ``fit_ms_median``,
        ``residual_next_rms``, ``residual_pred_rms`` (RMS pooled over steps),
        ``k_1pct_next``, ``k_any_next``, ``hit_rate_next`` (means over the steps with a
        next frame; bounds at that model's deformed state with the step's `r_q`),
        ``certificate_margin_mean``, ``certificate_margin_min``, ``models_used``
        ({name: steps}, what ``auto`` picked or a fallback used);
        ``steps``: {model: {figure: (S,) float64}} for the figures in `LADDER_FIGURES`, and
        the per-step names of `LADDER_NAMES`; ``auto_best_rate``: fraction of the steps
        with a next frame on which ``auto``'s actual K_1pct was the smallest of baseline
        and the fixed models (NaN without ``auto``).

    Notes
    -----
    Each model is fitted on the first step before timing starts, so JIT compilation
    does not count as fit time. The fit time is wall time around the call (fit +
    projection + certificate + writing `x_def`); on a shared machine single calls can
    spike, which is why the median is reported beside the mean. Cost: one bound computation per model and
    step with a next frame, plus one for the baseline.

    It is `ladder_summary` of `ladder_steps`: the steps of a long recording can be
    scored a frame range at a time and their per-step figures concatenated in step
    order first (`concat_ladder_steps`), with the same result.
    """
    return ladder_summary(ladder_steps(
        positions, frames, edges=edges, faces=faces, thickness=thickness, weights=weights, margins=margins,
        models=models, projection=projection, gamma=gamma, bounds_fn=bounds_fn, fit_fn=fit_fn, ceiling=ceiling,
        replay=replay, replay_cap=replay_cap, components=components, progress=progress,
        contact_radius=contact_radius))


def ladder_steps(positions, frames, *, edges=None, faces=None, thickness=0.0, weights=None, margins=None,
                 models=LADDER_MODELS, projection="auto", gamma=DEFAULT_GAMMA, bounds_fn=None, fit_fn=None,
                 ceiling=True, replay=False, replay_cap=DEFAULT_REPLAY_CAP, components=None,
                 progress=None, contact_radius=0.0) -> dict:
    """The per-step part of `model_ladder` (same parameters): every step scored, nothing summed.

    Returns
    -------
    dict
        ``models`` (list, ``"baseline"`` first), ``has_next`` (S,) bool (the step has
        a next frame among `positions`), ``steps``: {model: {figure: (S,)}} with the
        figures of `LADDER_FIGURES` and the names of `LADDER_NAMES`. A step's figures
        depend on its frames ``s - 1``, ``s`` and ``s + 1`` only: a frame range holding
        them scores it as the whole recording does.
    """
    positions = np.asarray(positions)
    frames = np.asarray(frames, dtype=np.int64)
    T, S = positions.shape[0], frames.shape[0]
    margins = np.zeros(S) if margins is None else np.asarray(margins, dtype=np.float64)
    if bounds_fn is None:
        # one neighbour list per step, built at its start: the models' deformed states
        # are affine images of it and are answered from the list (`StepBounds`)
        bounds_fn = StepBounds.for_scene(positions[0], edges, faces, thickness, gamma)
    names = ["baseline", *models, *(["x_pred"] if ceiling else [])]
    fitter = _LadderFit(positions, models, edges=edges, faces=faces, thickness=thickness, weights=weights,
                        projection=projection, gamma=gamma, fit_fn=fit_fn, components=components)
    per = {m: {f: np.full(S, np.nan) for f in LADDER_FIGURES} for m in names}
    for m in names:
        per[m]["model_used"] = np.full(S, "", dtype=object)
    if S:
        fitter.warm_up(frames[0])
    for i, s in enumerate(frames):
        x_prev, x = positions[s - 1], positions[s]
        x64, x_pred, r_q = step_target(x_prev, x, contact_radius, thickness)
        x_next = np.asarray(positions[s + 1], dtype=np.float64) if s + 1 < T else None
        if hasattr(bounds_fn, "begin_step"):
            bounds_fn.begin_step(x64, r_q)
        states = {"baseline": (x64, 0.0, math.nan)}
        for m in models:
            per[m]["model_used"][i], states[m] = fitter.fit(m, x_prev, x, x64, r_q, float(margins[i]),
                                                            separations=getattr(bounds_fn, "separations", None))
        if ceiling:
            states["x_pred"] = (x_pred, math.nan, math.nan)
        for m, state in states.items():
            _score(per[m], i, state, x_pred, x_next, r_q, bounds_fn, replay, replay_cap)
        if progress is not None:
            progress()
    for m in names:
        per[m]["model_used"] = per[m]["model_used"].astype(str)
    return {"models": names, "has_next": frames + 1 < T, "steps": per}


def ladder_summary(part) -> dict:
    """`model_ladder`'s output from `ladder_steps` output (of all steps, or of frame ranges
    concatenated in step order by `concat_ladder_steps`): the rows, the step counts and
    ``auto_best_rate``, each from the per-step figures alone."""
    names, per = list(part["models"]), part["steps"]
    models = [m for m in names if m not in ("baseline", "x_pred")]
    has_next = np.asarray(part["has_next"], dtype=bool)
    return {"models": names, "n_steps": int(has_next.size), "n_steps_next": int(np.count_nonzero(has_next)),
            "rows": [_row(m, per[m]) for m in names], "steps": per, "auto_best_rate": _auto_best_rate(per, models)}


def concat_ladder_steps(parts) -> dict:
    """`ladder_steps` outputs of consecutive frame ranges joined in step order (the same
    models in each)."""
    names = list(parts[0]["models"])
    if any(list(p["models"]) != names for p in parts):
        raise ValueError("ladder parts of different models cannot be joined")
    return {"models": names, "has_next": np.concatenate([p["has_next"] for p in parts]),
            "steps": {m: {k: np.concatenate([p["steps"][m][k] for p in parts]) for k in parts[0]["steps"][m]}
                      for m in names}}


class _LadderFit:
    """Fits one step with one ladder model: `fit_fn`, `auto`'s selection, or per component."""

    def __init__(self, positions, models, *, edges, faces, thickness, weights, projection, gamma, fit_fn,
                 components):
        if fit_fn is None:
            from ..fit.step import fit_step as fit_fn
        self.positions, self.models, self.fit_fn = positions, models, fit_fn
        self.edges, self.faces, self.thickness = edges, faces, thickness
        self.weights, self.projection, self.gamma = weights, projection, gamma
        if "per-component" in models:
            from .components import component_labels

            self.labels = component_labels(positions.shape[1], edges, faces, components)
        # auto's collision-aware selection needs topology; without it fit_fn's residual choice
        self.select = "auto" in models and (edges is not None and len(edges) or faces is not None and len(faces))
        if self.select:
            from ..trust.bounds import scene_arrays

            _, self.E, self.F = scene_arrays(positions[0], edges, faces)

    def warm_up(self, s):
        """Untimed calls so that JIT compilation stays out of the timings."""
        for m in self.models:
            for _ in range(LADDER_WARMUP_CALLS if m not in ("auto", "per-component") else 0):
                self.fit_fn(self.positions[s - 1], self.positions[s], weights=self.weights, model=m,
                            projection=self.projection, margin=0.0)

    def fit(self, m, x_prev, x, x64, r_q, margin, separations=None):
        """``(name used, (x_def float64, fit ms, certificate margin))``; a margin >= 1 fits a translation.

        `separations(x, r_q)`, when given, answers `auto`'s start separations (the same
        values as a fresh query; the bounds provider's list, `StepBounds`)."""
        model, mg = (m, margin) if margin < 1.0 else ("translation", 0.0)
        if model == "per-component":
            from .components import per_component_step

            t0 = time.perf_counter()
            r = per_component_step(x_prev, x, self.labels, edges=self.edges, faces=self.faces,
                                   thickness=self.thickness, weights=self.weights, margin=mg,
                                   projection=self.projection)
        elif self.select and model == "auto":
            from ..fit.auto import select_step

            known = None if separations is None else separations(x64, r_q)
            # the simulator's last detection: not fit time
            d_start = start_separations(x64, self.E, self.F, r_q, known=known)
            t0 = time.perf_counter()
            r, _ = select_step(x_prev, x, d_start, r_q=r_q, thickness=self.thickness, gamma=self.gamma,
                               weights=self.weights, margin=mg, projection=self.projection)
        else:
            t0 = time.perf_counter()
            r = self.fit_fn(x_prev, x, weights=self.weights, model=model, projection=self.projection, margin=mg)
        dt_ms = (time.perf_counter() - t0) * 1e3
        name = f"{len(np.unique(r.group))} groups" if model == "per-component" else r.model
        return name, (np.asarray(r.x_def, dtype=np.float64), dt_ms, float(r.certificate_margin))


def _score(row, i, state, x_pred, x_next, r_q, bounds_fn, replay, replay_cap):
    """Step `i`'s figures of one model's state ``(x_s, fit ms, certificate margin)`` into `row`."""
    x_s, dt_ms, cm = state
    row["fit_ms"][i], row["certificate_margin"][i] = dt_ms, cm
    row["residual_pred_rms"][i] = residual_summary(x_s, x_pred)[0]
    if x_next is None:
        return
    row["residual_next_rms"][i] = residual_summary(x_s, x_next)[0]
    b = np.zeros(x_s.shape[0]) if r_q <= 0 else bounds_fn(x_s, r_q)
    rs = ratio_stats(x_s, x_next, b)
    row["k_1pct_next"][i], row["k_any_next"][i] = rs["k_1pct"], rs["k_any"]
    row["hit_rate_next"][i] = rs["hit_rate"]
    if replay:
        rp = replay_passes(x_s, x_next, lambda z: bounds_fn(z, r_q), cap=replay_cap, b0=b)
        row["replay_k_1pct_next"][i], row["replay_k_any_next"][i] = rp["k_1pct"], rp["k_any"]


def _row(m, p):
    """The ladder row of model `m` from its per-step figures `p`."""
    names, counts = np.unique(np.asarray(p["model_used"], dtype=str), return_counts=True)
    used = {str(a): int(b) for a, b in zip(names, counts) if a}
    return {
        "model": m,
        "fit_ms_mean": finite_mean(p["fit_ms"]),
        "fit_ms_median": _median(p["fit_ms"]),
        "residual_next_rms": _pooled_rms(p["residual_next_rms"]),
        "residual_pred_rms": _pooled_rms(p["residual_pred_rms"]),
        "k_1pct_next": finite_mean(p["k_1pct_next"]),
        "k_any_next": finite_mean(p["k_any_next"]),
        "k_1pct_next_sum": _sum(p["k_1pct_next"]),
        "replay_k_1pct_next": finite_mean(p["replay_k_1pct_next"]),
        "replay_k_any_next": finite_mean(p["replay_k_any_next"]),
        "hit_rate_next": finite_mean(p["hit_rate_next"]),
        "certificate_margin_mean": finite_mean(p["certificate_margin"]),
        "certificate_margin_min": _min(p["certificate_margin"]),
        "models_used": dict(sorted(used.items())),
    }


def _auto_best_rate(per, models):
    if "auto" not in models:
        return math.nan
    rivals = ["baseline", *[m for m in FIXED_MODELS if m in per]]
    best = np.min([per[m]["k_1pct_next"] for m in rivals], axis=0)
    auto = per["auto"]["k_1pct_next"]
    ok = np.isfinite(auto)
    return float(np.mean(auto[ok] <= best[ok])) if ok.any() else math.nan


def _sum(a):
    a = np.asarray(a, dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(a.sum()) if a.size else math.nan
