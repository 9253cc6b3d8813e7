"""Collision-aware choice of a step's map: fewest predicted CD passes, not closeness.

Closeness to the prediction alone is the wrong objective: a map that compresses the
scene shrinks the OGC trust regions at the deformed state and can multiply the
collision-detection passes. What decides the passes is the distance to the target
*relative to the bounds at the deformed state*. This module predicts that ratio for a
candidate map without any new neighbourhood query:

* the per-vertex separations ``d_v`` at the start state (one `per_vertex_separation`
  call per step, the query a simulator already ran at its last detection), and
* a rigorous lower bound ``sigma`` of ``sigma_min(A)``: every distance between two
  points (hence between two primitives) shrinks by at most that factor under ``A``, so
  ``d_v(x_def) >= min(r_q, sigma d_v(x))`` and the predicted bound
  ``b_hat_v = gamma * max(0, min(r_q, sigma d_v) - thickness)`` is never larger than
  the bound recomputed at the deformed state (never optimistic),

then ``r_v = |x_pred_v - x_def_v| / b_hat_v`` gives the predicted hit rate, ``K_1pct``
and ``K_any`` exactly as `stats.ratio_stats` defines them, in O(N) per candidate.

A moving vertex whose *start* bound is zero (inside the thickness, or touching or
crossing something: a pre-existing intersection, which an invertible affine map keeps)
is stuck whatever the map, and is left out of K for every candidate, as
`stats.ratio_stats` leaves it out for doing nothing. Counting it as ``r = inf`` instead
would make every moving candidate's ``K_1pct`` unbounded as soon as more than 1% of the
vertices are stuck, and a recording with a few crossings would never move. Only a vertex
whose positive start bound the candidate's sigma may shrink to zero gets ``r = inf``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ... import constants as K
from ...errors import InputError
from . import models as _fit
from .certificate import certified_margin, certify_map, fast_margin_bound
from .projection import project
from .auto_kernels import predict_kernel, upper_quantile
from .step import StepResult

_I3 = np.eye(3)


@dataclass
class Candidate:
    """One certified candidate map ``x_def = x + D (x - c) + u``.

    `A` is the exact float64 matrix the certificate passed, and ``D = A - I`` is
    computed from it (exact for the entries near 1), so ``I + D`` is never re-rounded.
    """

    name: str
    A: np.ndarray
    D: np.ndarray
    u: np.ndarray
    rank: int
    projection: str
    certificate_margin: float
    sigma_lb: float
    predicted: dict = field(default_factory=dict)


def sigma_min_lower_bound(A) -> float:
    """Rigorous lower bound of the smallest singular value of a 3x3 float64 `A`.

    LAPACK's SVD is backward stable: the computed singular values are those of
    ``A + E`` with ``||E||_2 <= p(3) eps ||A||_2``; by Weyl, each moves by at most
    ``||E||_2``. `SIGMA_ROUNDING_C` covers p(3) with a wide factor of safety.
    """
    A = np.asarray(A, dtype=np.float64)
    s = np.linalg.svd(A, compute_uv=False)
    return max(0.0, float(s[-1]) - K.SIGMA_ROUNDING_C * np.finfo(np.float64).eps * float(s[0]))


def predicted_bounds(d_start, sigma, r_q, thickness, gamma=K.DEFAULT_GAMMA):
    """Lower bound of the OGC bounds at the deformed state from the start separations.

    Parameters
    ----------
    d_start : (N,) float64
        ``min(r_q, terms)`` at the start state (`penfree.core.trust.bounds.per_vertex_separation`).
    sigma : float
        Lower bound of sigma_min(A) (`sigma_min_lower_bound`).
    r_q, thickness, gamma : float

    Returns
    -------
    (N,) float64
        ``gamma * max(0, min(r_q, sigma * d_start) - thickness)``, shrunk by a relative
        `PREDICT_SLACK_REL` so that rounding of the stored `x_def` cannot make it exceed
        the recomputed bound.
    """
    d = np.minimum(r_q, sigma * (1.0 - K.PREDICT_SLACK_REL) * d_start)
    return gamma * np.maximum(0.0, d - thickness)


def predict_passes(x_def, y, b, b_start=None) -> dict:
    """Hit rate, K_1pct, K_any and r_q99 of `y` from `x_def` with bounds `b`, O(N).

    Same definitions as `stats.ratio_stats` (blocked vertices left out of K, numpy's
    "higher" percentile), using a partition instead of a sort. With `b_start` (the
    start bounds, when `b` are a moving map's predicted lower bounds), a moving vertex
    with ``b = 0`` is left out only where its start bound is 0 too (the vertex is
    stuck whatever the map); elsewhere it has ``r = inf`` (the actual bound may be tiny
    and positive), and K is then `K_UNBOUNDED` when the percentile is infinite.
    """
    dist = np.linalg.norm(np.asarray(y, dtype=np.float64) - np.asarray(x_def, dtype=np.float64), axis=1)
    n_all = dist.size
    moving = dist > 0
    zero_b = moving & ~(b > 0)
    blocked = zero_b if b_start is None else zero_b & ~(np.asarray(b_start) > 0)
    ok = moving & ~zero_b
    r = np.zeros(n_all)
    r[ok] = dist[ok] / b[ok]
    r[zero_b & ~blocked] = np.inf
    keep = r[~blocked]
    out = {"hit_rate": float(np.count_nonzero(~blocked & (r <= 1.0)) / n_all), "n_blocked": int(blocked.sum())}
    if keep.size == 0:
        out.update(k_any=1, k_1pct=1, r_q99=0.0, r_max=0.0)
        return out
    idx = -((-K.K_PERCENTILE * (keep.size - 1)) // 100)
    q99 = float(np.partition(keep, idx)[idx])
    r_max = float(keep.max())
    out.update(r_q99=q99, r_max=r_max, k_1pct=_passes_from(q99), k_any=_passes_from(r_max))
    return out


def _passes_from(r):
    """``max(1, ceil(r))``, or `K_UNBOUNDED` for r = inf."""
    return max(1, math.ceil(r)) if r < K.K_UNBOUNDED else K.K_UNBOUNDED


def _summary(hits, n_blocked, n_all, quantile):
    """The `predict_passes` dict from the counts and ``quantile() -> (r_q99, r_max)``."""
    out = {"hit_rate": float(hits / n_all), "n_blocked": int(n_blocked)}
    if n_blocked == n_all:
        out.update(k_any=1, k_1pct=1, r_q99=0.0, r_max=0.0)
        return out
    q99, r_max = quantile()
    out.update(r_q99=q99, r_max=r_max, k_1pct=_passes_from(q99), k_any=_passes_from(r_max))
    return out


def predict_map_passes(x_prev, x, D, u, c, d_start, sigma, r_q, thickness=0.0, gamma=K.DEFAULT_GAMMA,
                       r_buf=None) -> dict:
    """`predict_passes` of the map ``x_def = x + D (x - c) + u`` without forming x_def.

    Parameters
    ----------
    x_prev, x : (N, 3) float32 or float64
        Finite (not checked here: `select_step` has its moments catch NaN/Inf); the
        target is ``x_pred = 2 x - x_prev``.
    D : (3, 3) float64
    u, c : (3,) float64
    d_start : (N,) float64
        Start separations (`predicted_bounds`).
    sigma : float
        Lower bound of sigma_min(I + D).
    r_q, thickness, gamma : float
    r_buf : (N,) float64 or None
        Scratch for the per-vertex ratios, reused across candidates; on return it
        holds them (blocked vertices as -inf), in some order.

    Returns
    -------
    dict
        The keys and definitions of `predict_passes`.

    Notes
    -----
    One fused pass (`selection_kernels.predict_kernel`) forms x_def in float64,
    rounds it to x's dtype (the stored x_def), and divides its distance to x_pred by
    ``predicted_bounds(d_start, sigma, r_q, thickness, gamma)``; the 99th percentile
    ("higher") is then `upper_quantile` of the ratios (what `numpy.partition` gives). Compared
    with ``predict_passes(apply_map(x, D, u, c)[0], x_pred, predicted_bounds(...))``
    the only difference is the rounding of x_def: `apply_map` may fuse and reorder
    its multiply-adds, so x_def can differ in its last bit (tests/core/fit/test_auto.py).

    Examples
    --------
    >>> import numpy as np
    >>> x = np.zeros((4, 3)); x[:, 0] = np.arange(4.0)
    >>> p = predict_map_passes(x - 0.1, x, np.zeros((3, 3)), np.zeros(3), np.zeros(3), np.ones(4), 1.0, 1.0)
    >>> p["k_1pct"], p["n_blocked"]
    (1, 0)
    """
    x = _fit.as_positions(x, "x", check_finite=False)
    x_prev = _fit.as_positions(x_prev, "x_prev", x.shape[0], check_finite=False)
    n = x.shape[0]
    d_start = np.ascontiguousarray(d_start, dtype=np.float64)
    if d_start.shape != (n,):
        raise InputError(f"d_start must be ({n},) to match x; got shape {d_start.shape}")
    if r_buf is None:
        r = np.empty(n)
    elif r_buf.shape != (n,) or r_buf.dtype != np.float64 or not r_buf.flags.c_contiguous:
        raise InputError(f"r_buf must be C-contiguous ({n},) float64; got {r_buf.shape} {r_buf.dtype}")
    else:
        r = r_buf
    D = np.ascontiguousarray(D, dtype=np.float64)
    u = np.ascontiguousarray(u, dtype=np.float64)
    c = np.ascontiguousarray(c, dtype=np.float64)
    if D.shape != (3, 3) or u.shape != (3,) or c.shape != (3,):
        raise InputError(f"D, u, c must be (3, 3), (3,), (3,); got {D.shape}, {u.shape}, {c.shape}")
    return _predict(x_prev, x, D, u, c, d_start, float(sigma), float(r_q), float(thickness), float(gamma), r)


def _predict(x_prev, x, D, u, c, d_start, sigma, r_q, thickness, gamma, r):
    """`predict_map_passes` on validated arrays (the per-candidate call of `select_step`)."""
    n = x.shape[0]
    # Doing nothing leaves x_def = x bit for bit: its bounds are the start bounds
    # exactly (no rounding slack). A zero start bound blocks the vertex for every map.
    nothing = not (D.any() or u.any())
    s = 1.0 if nothing else sigma * (1.0 - K.PREDICT_SLACK_REL)  # as predicted_bounds forms it
    hits, n_blocked = predict_kernel(x_prev, x, D, u, c, d_start, s, r_q, thickness, gamma, r)

    def quantile():
        # Blocked vertices hold -inf, below every kept ratio: shift the index past them.
        n_keep = n - n_blocked
        return upper_quantile(r, n_blocked + -((-K.K_PERCENTILE * (n_keep - 1)) // 100))

    return _summary(hits, n_blocked, n, quantile)


def _certified(name, D, u, rank, m, margin, projection):
    """Certify (projecting if allowed) and wrap; None when nothing certifies."""
    A = _I3 + D
    D = A - _I3
    mode = "none"
    if not _passes(A, margin):
        if projection == "none":
            return None
        D, mode = project(D, projection, margin, residual=lambda X: _fit.residual_gain(m, X),
                          known_uncertified=projection == "auto")
        A = _I3 + D
        D = A - _I3
        if not _passes(A, margin):
            return None
    bound = fast_margin_bound(A)
    if not bound >= margin:
        bound = certified_margin(A, margin)
    return Candidate(name, A, D, u, rank, mode, float(bound), sigma_min_lower_bound(A))


def _passes(A, margin):
    return certify_map(A, margin)


def candidate_maps(m, margin=0.0, projection="auto", repeat=False) -> list:
    """All certified candidates of a step, simplest first.

    ``none`` (doing nothing), ``translation``, ``rigid``, ``similarity``, ``affine``,
    the affine map with its singular values clamped into ``[1 - delta, 1 + delta]``
    (`SELECT_CLAMP_LEVELS`, reflection-free) and the blends ``I + alpha D_affine``
    (`SELECT_BLEND_LEVELS`); with `repeat`, after ``affine``, ``rigid-repeat``: the step's own
    rigid motion applied again (`models.fit_rigid_repeat`, constant angular
    velocity). Every returned map passes the exact certificate.
    """
    zero = np.zeros((3, 3))
    out = [Candidate("none", _I3.copy(), zero, np.zeros(3), 0, "none", 1.0, 1.0),
           Candidate("translation", _I3.copy(), zero, m.u.copy(), 0, "none", 1.0, 1.0)]
    D_aff = aff = None
    for name in K.MODELS[1:]:
        _, D, u, rank = _fit.fit_model(m, name)
        c = _certified(name, D, u, rank, m, margin, projection)
        if name == "affine":
            D_aff, rank_aff, aff = D, rank, c
        if c is not None:
            out.append(c)
    if repeat:
        D, u, rank = _fit.fit_rigid_repeat(m)
        c = _certified("rigid-repeat", D, u, rank, m, margin, "none") if np.any(D) else None
        if c is not None:
            out.append(c)
    if D_aff is None or not np.any(D_aff):
        return out
    U, S, Vt = np.linalg.svd(_I3 + D_aff)
    if np.linalg.det(U @ Vt) < 0:  # reflection-free: flip the weakest pair
        U[:, -1] *= -1.0
        S[-1] *= -1.0
    for delta in K.SELECT_CLAMP_LEVELS:
        Sc = np.clip(S, 1.0 - delta, 1.0 + delta)
        if np.array_equal(Sc, S):
            # Nothing to clamp: the candidate is the affine map itself (U S V^T would
            # only re-round it), certified exactly as the affine candidate was.
            if aff is not None:
                out.append(replace(aff, name=f"affine-clamp{delta:g}", A=aff.A.copy(), D=aff.D.copy(),
                                   u=aff.u.copy(), predicted={}))
            continue
        c = _certified(f"affine-clamp{delta:g}", (U * Sc) @ Vt - _I3, m.u.copy(), rank_aff, m, margin, projection)
        if c is not None:
            out.append(c)
    for alpha in K.SELECT_BLEND_LEVELS:
        c = _certified(f"affine-blend{alpha:g}", alpha * D_aff, m.u.copy(), rank_aff, m, margin, projection)
        if c is not None:
            out.append(c)
    return out


def choose(cands: list) -> int:
    """Index of the chosen candidate (each with `predicted` filled).

    Fewest predicted ``K_1pct``; among equal ``K_1pct`` the smaller predicted
    ``r_q99`` wins only when it is smaller by more than `SELECT_TIE_RTOL` (relative)
    plus `SELECT_TIE_ATOL` (absolute, above rounding noise),
    so near-ties go to the simpler candidate; candidate 0 (doing nothing) is kept
    unless something beats it.
    """
    best = 0
    for i in range(1, len(cands)):
        p, q = cands[i].predicted, cands[best].predicted
        if p["k_1pct"] < q["k_1pct"] or (
            p["k_1pct"] == q["k_1pct"]
            and p["r_q99"] < (1.0 - K.SELECT_TIE_RTOL) * q["r_q99"] - K.SELECT_TIE_ATOL
        ):
            best = i
    return best


def select_step(x_prev, x, d_start, *, r_q, thickness=0.0, gamma=K.DEFAULT_GAMMA, weights=None,
                margin=0.0, projection="auto", out=None):
    """Fit every candidate of a step and keep the one with the fewest predicted passes.

    Parameters
    ----------
    x_prev, x : (N, 3) float
        Frames s - 1 and s; the target is ``x_pred = 2 x - x_prev``.
    d_start : (N,) float64
        Per-vertex separations at `x`, capped at `r_q` (`per_vertex_separation`, and
        `obstacle_separation` when the scene has obstacles: a vertex resting on the
        floor then gets a small predicted bound. Obstacles do not move with the map,
        so for their terms the prediction is an estimate, not a lower bound).
    r_q : float
        The step's query radius (``contact_radius + max_v |x_pred_v - x_v|``).
    thickness, gamma, weights, margin, projection
        As in `fit_step` and `trust_region_bounds`.
    out : (N, 3) array or None
        Where to write the chosen `x_def`.
    Returns
    -------
    result : StepResult
        The chosen map (``model`` is the candidate's name, e.g. ``"rigid"``,
        ``"affine-clamp0.1"`` or ``"none"``), certified with `margin`.
    table : list of dict
        Per candidate (simplest first): name, chosen, sigma_lb, certificate_margin and
        the predicted hit_rate, k_1pct, k_any, r_q99, r_max, n_blocked.

    Notes
    -----
    Integration contract: the predictions assume the simulator keeps the query
    radius of `x` (rule ``step``) after moving to the chosen ``x_def``; a client
    that recomputes it from ``x_def`` (ipctk's ``warm_start_time_step``, rule
    ``own``) gets smaller trust regions and may need more passes than predicted
    (README, "Using penfree inside a simulator"; `penfree.predeform`). To choose by
    an OGC client's replayed CD passes instead of the static K_1pct, the pipeline
    re-orders `ranked_candidates` (with ``repeat=True``: plus the ``rigid-repeat``
    candidate) with `penfree.core.pipeline.client_select`.

    Cost: one moment pass, then per distinct candidate one fused O(N) pass that
    predicts without forming x_def (`predict_map_passes`) and one pass over the ratios
    for the percentile; x_def is written once, for the chosen map. No neighbourhood
    query.
    """
    t0 = time.perf_counter()
    x, x_prev, m, cands = ranked_candidates(x_prev, x, d_start, r_q=r_q, thickness=thickness, gamma=gamma,
                                            weights=weights, margin=margin, projection=projection)
    k = rank(cands)[0]
    result = candidate_result(x_prev, x, m, cands[k], t0, out=out)
    return result, candidate_table(cands, k)


def ranked_candidates(x_prev, x, d_start, *, r_q, thickness=0.0, gamma=K.DEFAULT_GAMMA, weights=None,
                      margin=0.0, projection="auto", repeat=False, predict_from=None):
    """Validated ``x, x_prev``, the moments and every certified candidate with its prediction.

    Parameters as in `select_step` (`repeat`: add the ``rigid-repeat`` candidate of
    `candidate_maps`). The candidates are fit toward ``2 x - x_prev``; their passes are
    predicted toward ``2 x - predict_from`` (default `x_prev`; `strategy.landing_prediction`
    gives another). Order the candidates with `rank`; build the applied one with
    `candidate_result`.
    """
    # NaN/Inf positions are caught by fit_moments from its sums (no extra pass here).
    x = _fit.as_positions(x, "x", check_finite=False)
    x_prev = _fit.as_positions(x_prev, "x_prev", x.shape[0], check_finite=False)
    w = _fit.as_weights(weights, x.shape[0])
    d_start = np.ascontiguousarray(d_start, dtype=np.float64)
    if d_start.shape != (x.shape[0],):
        raise InputError(f"d_start must be ({x.shape[0]},) to match x; got shape {d_start.shape}")
    r_q, thickness, gamma = float(r_q), float(thickness), float(gamma)
    m = _fit.fit_moments(x_prev, x, w, validate=False)
    cands = candidate_maps(m, margin, projection, repeat)
    target_prev = x_prev if predict_from is None else _fit.as_positions(predict_from, "predict_from", x.shape[0])
    r_buf = np.empty(x.shape[0])
    seen = {}
    for cand in cands:
        # Clamps and blends often coincide with the plain fit (singular values already
        # inside the clamp): the same A, u and sigma give the same prediction.
        key = (cand.A.tobytes(), cand.u.tobytes(), cand.sigma_lb)
        if key not in seen:
            seen[key] = _predict(target_prev, x, cand.D, cand.u, m.c, d_start, float(cand.sigma_lb), r_q, thickness,
                                 gamma, r_buf)
        cand.predicted = dict(seen[key])
    return x, x_prev, m, cands


def rank(cands) -> list:
    """Indices of `cands` in order of preference: `choose` applied to what is left, repeatedly.

    A candidate that fails a later safety check (obstacles, near pairs) gives way to
    the next one; candidate 0 (doing nothing) always passes it.
    """
    rest = list(range(len(cands)))
    order = []
    while rest:
        order.append(rest.pop(choose([cands[i] for i in rest])))
    return order


def candidate_result(x_prev, x, m, cand, t0, out=None) -> StepResult:
    """The `StepResult` of applying candidate `cand` (x_def written once, into `out` if given)."""
    x_def, stats = _fit.apply_map(x, cand.D, cand.u, m.c, out=out, x_prev=x_prev)
    return StepResult(
        A=cand.A.copy(), b=cand.u - cand.D @ m.c, x_def=x_def, D=cand.D, u=cand.u, c=m.c.copy(),
        model=cand.name, projection=cand.projection, certificate_margin=cand.certificate_margin,
        rank=cand.rank, **stats, time_fit_s=time.perf_counter() - t0, model_fitted="auto",
    )


def candidate_table(cands, k) -> list:
    """Per candidate: name, chosen (index `k`), sigma_lb, certificate_margin and the predictions."""
    return [dict(name=c.name, chosen=i == k, sigma_lb=c.sigma_lb, certificate_margin=c.certificate_margin,
                 **c.predicted) for i, c in enumerate(cands)]
