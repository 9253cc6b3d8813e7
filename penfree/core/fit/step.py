"""One step: fit, project, certify, deform (SPEC sections 3-5 and 10).

The orchestrator of the fit stages; `fit_step` is the public entry point.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ... import constants as K
from ...errors import CertificateError, InputError
from . import models as _fit
from .certificate import certified_margin, certify_map, fast_margin_bound
from .kernels import _offset_kernel
from .projection import project


@dataclass
class StepResult:
    """The map of one step and how it was obtained.

    Attributes
    ----------
    A : (3, 3) float64
        The map applied, ``x_def = A x + b`` up to rounding; always passes
        ``certify(A, margin)``.
    b : (3,) float64
        ``u - D c``, so that ``A x + b = x + D (x - c) + u``.
    x_def : (N, 3), dtype of `x`
        Deformed positions ``x + D (x - c) + u`` (centred form, float64 arithmetic).
    D : (3, 3) float64
        ``A - I`` (exactly, as used for `x_def`).
    u, c : (3,) float64
        Weighted mean displacement and weighted centroid of `x`.
    model : str
        Model actually used (``"translation"`` after a fallback).
    projection : str
        Projection mode used: ``none`` (D untouched), ``svd`` or ``sym``.
    certificate_margin : float
        Certified lower bound of ``sigma_min(I + t D)`` over ``t in [0, 1]``;
        ``>= margin``.
    rank : int
        Number of data directions the map uses (0 for a translation).
    residual_pred_rms, residual_pred_max : float
        Per-vertex distance of `x_def` to ``x_pred = 2 x - x_prev`` (unweighted).
    baseline_pred_rms, baseline_pred_max : float
        The same for `x` (doing nothing).
    time_fit_s : float
        Wall time of the whole call (moments, fit, projection, certificate, x_def).
    model_fitted : str
        Model fitted before any fallback (``auto`` resolved to its choice).
    fallback : str
        ``""``, ``"uncertified"`` (no projection certified the map) or
        ``"residual"`` (the map was farther from x_pred than the translation).
    certified_by : str
        ``"fast"`` or ``"exact"``: which test certified `A`.
    """

    A: np.ndarray
    b: np.ndarray
    x_def: np.ndarray
    D: np.ndarray
    u: np.ndarray
    c: np.ndarray
    model: str
    projection: str
    certificate_margin: float
    rank: int
    residual_pred_rms: float
    residual_pred_max: float
    baseline_pred_rms: float
    baseline_pred_max: float
    time_fit_s: float
    model_fitted: str = ""
    fallback: str = ""
    certified_by: str = "fast"


_I3 = np.eye(3)


def _certify_A(D, margin):
    """Round ``A = I + D``, take ``D = A - I`` back and certify that A.

    Returns ``(A, D, bound, how)``; ``bound`` is NaN when not certified.
    """
    A = _I3 + D
    D = A - _I3
    if not certify_map(A, margin):  # the one gate decides; below only which test proved it
        return A, D, math.nan, ""
    fb = fast_margin_bound(A)
    if fb > margin:
        return A, D, fb, "fast"
    return A, D, certified_margin(A, margin, exact_known=True), "exact"


def fit_step(x_prev, x, *, weights=None, model="affine", projection="auto", margin=0.0,
             out=None, evaluate=True) -> StepResult:
    """Fit, project and certify the map of one step, and deform `x` with it.

    Parameters
    ----------
    x_prev, x : (N, 3) float array
        Positions at frames ``s - 1`` and ``s``; the target is ``x_pred = 2 x - x_prev``.
    weights : (N,) float or None
        Non-negative per-vertex weights (e.g. masses), positive sum.
    model : {"affine", "similarity", "rigid", "translation", "auto"}
    projection : {"auto", "sym", "svd", "none"}
    margin : float in [0, 1)
        Required lower bound of ``sigma_min(I + t D)`` on ``[0, 1]``.
    out : (N, 3) array of x's dtype or None
        Where to write `x_def` (C-contiguous, not aliasing `x`).
    evaluate : bool
        Compute the residual summaries (reads `x_prev` again while writing
        `x_def`); False leaves them NaN, for simulator loops that need speed.

    Returns
    -------
    StepResult

    Raises
    ------
    InputError
        Shapes other than (N, 3), unequal N, non-finite values, negative or
        all-zero weights, unknown model / projection, margin outside [0, 1).

    Notes
    -----
    Integration contract (inside a simulator loop; `penfree.predeform` does all of
    it): start the step from ``x_def`` but keep the OGC query / inflation radius the
    simulator computed at ``x`` *before* the move, ``max(2 dhat, max_v |x_pred -
    x|)`` (ipctk: set ``trust_region_inflation_radius`` and call ``update`` rather
    than ``warm_start_time_step``). Recomputing it from ``|x_pred - x_def|`` shrinks
    every free vertex's trust region and can cost more CD passes than doing
    nothing (README, "Using penfree inside a simulator").

    Guarantees: (a) ``certify(result.A, margin)`` is True: the fast test is
    tried first, the exact one when it is inconclusive, and a map neither
    certifies is replaced by the translation (``D = 0``); (b) the map's
    weighted residual to ``x_pred`` never exceeds the translation's, else
    the translation is used. Weights enter the fit only; the reported
    residuals are unweighted per-vertex distances.

    Examples
    --------
    >>> import numpy as np
    >>> x = np.random.default_rng(0).random((100, 3))
    >>> r = fit_step(x - 0.01, x)
    >>> r.model, r.projection, bool(np.allclose(r.x_def, x + 0.01))
    ('affine', 'none', True)
    """
    t0 = time.perf_counter()
    x = _fit.as_positions(x, "x", check_finite=False)
    x_prev = _fit.as_positions(x_prev, "x_prev", x.shape[0], check_finite=False)
    w = _fit.as_weights(weights, x.shape[0])
    if model not in K.MODELS and model != "auto":
        raise InputError(f"model must be one of {K.MODELS + ('auto',)}; got {model!r}")
    if projection not in K.PROJECTIONS:
        raise InputError(f"projection must be one of {K.PROJECTIONS}; got {projection!r}")
    try:
        margin_f = float(margin)
    except (TypeError, ValueError):
        margin_f = math.nan
    if not 0.0 <= margin_f < 1.0:
        raise InputError(f"margin must be in [0, 1); got {margin!r}")
    margin = margin_f

    out = _fit.check_out(x, out)
    used = None
    if model == "affine" and projection in ("auto", "none"):
        # The default call, in one kernel call after the moments; when the fast test
        # certifies the map and it is no farther from x_pred than the translation, this
        # is what `_fit_general` gives, bit for bit.
        f, eps, c, u, D, A, bound, rank, gain, b = _fit.fit_affine_fast(x_prev, x, w)
        if bound > margin and not gain > 0.0 and certify_map(A, margin):  # the one gate, as always
            used = fitted = "affine"
            mode, fallback, how = "none", "", "fast"
        else:
            m = _fit.as_moments(f, x.shape[0], eps)
    else:
        m = _fit.fit_moments(x_prev, x, w, validate=False)
    if used is None:
        used, mode, A, D, u, bound, how, rank, fallback, fitted = _fit_general(m, model, projection, margin)
        D, u, c = np.ascontiguousarray(D, dtype=np.float64), np.ascontiguousarray(u, dtype=np.float64), m.c.copy()
        b = _offset_kernel(D, u, c)

    x_def, stats = _fit.apply_map(x, D, u, c, out=out, x_prev=x_prev if evaluate else None, checked=True)
    if stats is None:
        stats = dict.fromkeys(("residual_pred_rms", "residual_pred_max", "baseline_pred_rms",
                               "baseline_pred_max"), math.nan)
    return StepResult(
        A=A, b=b, x_def=x_def, D=D, u=u, c=c, model=used, projection=mode,
        certificate_margin=float(bound), rank=int(rank), **stats,
        time_fit_s=time.perf_counter() - t0, model_fitted=fitted, fallback=fallback,
        certified_by=how,
    )


def _fit_general(m, model, projection, margin):
    """Any model and projection from the moments `m`: fit, project when asked or when the
    map is not certified, certify, fall back to the translation. Returns ``(used, mode,
    A, D, u, bound, how, rank, fallback, fitted)``."""
    fitted, D, u, rank = _fit.fit_model(m, model)
    used, fallback, how = fitted, "", "fast"
    if fitted == "translation":
        mode, A, D, bound = "none", _I3.copy(), np.zeros((3, 3)), math.nan
    else:
        mode = "none"
        if projection in ("auto", "none"):
            A, D, bound, how = _certify_A(D, margin)  # keep D untouched when certified
        if projection in ("svd", "sym") or projection == "auto" and math.isnan(bound):
            D, mode = project(D, projection, margin, residual=lambda X: _fit.residual_gain(m, X),
                              known_uncertified=projection == "auto")
            A, D, bound, how = _certify_A(D, margin)
        if math.isnan(bound):
            fallback = "uncertified"
        elif _fit.residual_gain(m, D) > 0.0:
            fallback = "residual"
        if fallback:
            used, mode, rank, A, D = "translation", "none", 0, _I3.copy(), np.zeros((3, 3))
    if used == "translation":
        rank = 0
        _, _, bound, how = _certify_A(D, margin)  # D = 0 is certified for every margin < 1
        if math.isnan(bound):
            raise CertificateError(f"the identity map failed the certificate for margin {margin!r}")
    return used, mode, A, D, u, bound, how, rank, fallback, fitted
