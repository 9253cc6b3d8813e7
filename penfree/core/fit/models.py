"""Weighted least-squares fit of the step map in centred displacement form (SPEC section 4).

One fused Numba pass reduces the two frames to a handful of moments; every
model (translation, rigid, similarity, affine) is then fitted from those
moments alone, so candidate maps cost no further pass over the vertices. The
Numba kernels live in `penfree.core.fit.kernels`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ... import constants as K
from ...errors import InputError
from .certificate import FAST_BOUND_ALLOWANCE
from .kernels import (_affine_step_kernel, _apply_kernel, _finish_kernel, _gain_kernel, _moments_kernel, _slopes_kernel,
                      _subspace_kernel)


@dataclass(frozen=True)
class Moments:
    """Weighted centred moments of one step; every model is fitted from these.

    Attributes
    ----------
    W : float
        Sum of weights.
    c : (3,) float64
        Weighted mean of `x`.
    u : (3,) float64
        Weighted mean of the displacement `d = x_pred - x = x - x_prev`.
    C : (3, 3) float64
        ``sum w P P^T`` with ``P = x - c``.
    G : (3, 3) float64
        ``sum w Q P^T`` with ``Q = d - u``.
    qq : float
        ``sum w |Q|^2`` (the translation model's weighted squared residual).
    n : int
        Number of vertices.
    n_eff : float
        Kish effective sample size ``W^2 / sum w^2`` (``n`` when unweighted).
    coord_scale : float
        Typical coordinate magnitude ``|c|_inf + sqrt(trace C / W)``.
    input_eps : float
        Machine epsilon of the input dtype (float32 inputs are a noise floor).
    """

    W: float
    c: np.ndarray
    u: np.ndarray
    C: np.ndarray
    G: np.ndarray
    qq: float
    n: int
    n_eff: float
    coord_scale: float
    input_eps: float


def as_positions(a, name: str, n: int | None = None, check_finite: bool = True) -> np.ndarray:
    """Validate an `(N, 3)` float array; return it C-contiguous (float32/float64 kept).

    With ``check_finite=False`` the caller promises to detect NaN/Inf later
    (`fit_moments` does so from its sums, saving a pass over the vertices).
    """
    arr = np.asarray(a)
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] < 1:
        raise InputError(f"{name} must be (N, 3) with N >= 1; got shape {arr.shape}")
    if n is not None and arr.shape[0] != n:
        raise InputError(f"{name} must have the same N as x ({n}); got {arr.shape[0]}")
    if arr.dtype not in (np.float32, np.float64):
        if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
            raise InputError(f"{name} must be a float array; got dtype {arr.dtype}")
        arr = arr.astype(np.float64)
    arr = np.ascontiguousarray(arr)
    if check_finite and not np.isfinite(arr).all():
        raise InputError(f"{name} must be finite; got NaN or Inf")
    return arr


def as_weights(weights, n: int) -> np.ndarray | None:
    """Validate `(N,)` weights (real, finite, >= 0, positive sum); None stays None.

    The fit depends on the weights' ratios only: weights whose largest lies outside
    [2^-64, 2^64] are scaled by a power of two (exactly) to a largest weight in
    [0.5, 1), so that weights of 1e-300 or 1e300 neither underflow nor overflow the
    fit's sums. Other weights are kept as given (the moments' ``W``, ``C``, ``G`` are
    then their sums).
    """
    if weights is None:
        return None
    raw = np.asarray(weights)
    if raw.dtype.kind not in "iuf":
        raise InputError(f"weights must be real numbers; got dtype {raw.dtype}")
    w = np.ascontiguousarray(raw, dtype=np.float64)
    if w.shape != (n,):
        raise InputError(f"weights must be ({n},) to match x; got shape {w.shape}")
    if not np.isfinite(w).all() or (w < 0).any():
        raise InputError("weights must be finite and >= 0; got a negative or non-finite weight")
    top = float(w.max()) if n else 0.0
    if not top > 0:
        raise InputError("weights must have a positive sum; got all zero")
    e = int(np.frexp(top)[1])
    return w if -64 < e <= 64 else np.ldexp(w, -e)


def fit_moments(x_prev, x, weights=None, *, validate: bool = True) -> Moments:
    """Reduce one step to its weighted centred moments (one fused parallel pass).

    Parameters
    ----------
    x_prev, x : (N, 3) float32 or float64
        Previous and current positions; the fit target is ``x_pred = 2 x - x_prev``.
    weights : (N,) float64 or None
        Non-negative per-vertex weights; None means all ones.
    validate : bool
        Skip validation when the caller already validated (e.g. `fit_step`).

    Returns
    -------
    Moments

    Notes
    -----
    Computed in float64 whatever the input dtype; the displacement is formed
    as ``x - x_prev`` directly. The reduction uses ``REDUCTION_CHUNKS`` fixed
    chunks, so results are bitwise independent of the Numba thread count.

    Examples
    --------
    >>> import numpy as np
    >>> x = np.eye(3); m = fit_moments(x - 0.1, x)
    >>> np.allclose(m.u, 0.1)
    True
    """
    if validate:
        x = as_positions(x, "x", check_finite=False)
        x_prev = as_positions(x_prev, "x_prev", x.shape[0], check_finite=False)
        weights = as_weights(weights, x.shape[0])
    tot = _moments_kernel(x_prev, x, weights, K.REDUCTION_CHUNKS)
    if not np.isfinite(tot).all():
        _non_finite(x_prev, x)
    return as_moments(_finish_kernel(tot, weights is not None, x.shape[0]), x.shape[0], input_eps(x_prev, x))


def _non_finite(x_prev, x):
    # Any NaN/Inf input poisons the moment sums; find which input to name it.
    as_positions(x, "x")
    as_positions(x_prev, "x_prev")
    raise InputError("positions must be below ~1e150 in magnitude; got sums that overflow float64")


_EPS = {np.dtype(np.float32): float(np.finfo(np.float32).eps), np.dtype(np.float64): float(np.finfo(np.float64).eps)}


def input_eps(x_prev, x) -> float:
    """Machine epsilon of the coarser of the two inputs' dtypes (float32 or float64)."""
    return max(_EPS[x.dtype], _EPS[x_prev.dtype])


def as_moments(f, n, eps) -> Moments:
    """`Moments` of `n` vertices from `_finish_kernel`'s vector `f` (inputs' epsilon `eps`)."""
    return Moments(f[0], f[1:4], f[4:7], f[7:16].reshape(3, 3), f[16:25].reshape(3, 3), f[25],
                   n, f[26], f[27], eps)


def fit_affine_fast(x_prev, x, weights):
    """The affine fit and the fast certificate of its map, for `fit_step`'s default call.

    One moment pass and one small kernel (`kernels._affine_step_kernel`): the same
    values, bit for bit, as `fit_moments`, `fit_affine`, ``A = I + D`` (and ``D = A - I``
    back), `fast_margin_bound(A)` and `residual_gain`, without their Python calls.
    Inputs as validated by `fit_step`. Returns ``(f, eps, c, u, D, A, fast_bound, rank,
    gain, b)``, where ``as_moments(f, N, eps)`` is `fit_moments`' result (built only when
    needed: 2 us of a 0.1 ms call) and `c`, `u` are copies of its ``c`` and ``u``;
    raises like `fit_moments` on non-finite input.
    """
    tot = _moments_kernel(x_prev, x, weights, K.REDUCTION_CHUNKS)
    eps = input_eps(x_prev, x)
    f, D, A, fb, rank, gain, b, finite = _affine_step_kernel(
        tot, weights is not None, x.shape[0], eps, K.FIT_PRECISION_FACTOR,
        K.PINV_RTOL_FLOOR, K.FIT_NOISE_SLOPE_TOL, FAST_BOUND_ALLOWANCE)
    if not finite:
        _non_finite(x_prev, x)
    return f, eps, f[1:4].copy(), f[4:7].copy(), D, A, float(fb), int(rank), float(gain), b


# --- rank: the noise-aware cut-off -------------------------------------------


def significant_subspace(m: Moments, slope_tol: float | None = None):
    """Directions of the data's spread that the fit may use, and the rank.

    Parameters
    ----------
    m : Moments
    slope_tol : float or None
        Largest standard error allowed for the fitted slope ``D e`` along a kept
        direction ``e``; default ``constants.FIT_NOISE_SLOPE_TOL``. ``numpy.inf``
        disables the statistical test (plain pseudo-inverse, as ``lstsq``).

    Returns
    -------
    E : (3, r) float64
        Orthonormal eigenvectors of C that are kept.
    lam : (r,) float64
        Their eigenvalues (weighted spread ``sum w (P.e)^2``).

    Notes
    -----
    A direction ``e`` (eigenvector of C, eigenvalue ``lam``) is kept only if
    all three hold:

    1. ``lam > PINV_RTOL_FLOOR * lam_max`` (float64 rounding of the sums);
    2. its RMS spread ``sqrt(lam / W)`` exceeds ``FIT_PRECISION_FACTOR`` times
       the input quantisation ``input_eps * coord_scale`` (a float32 scene 1e3
       from the origin cannot resolve sub-0.1 mm shape);
    3. the slope it would carry is statistically determined: its standard
       error ``sqrt(sigma^2 / lam)`` is at most ``slope_tol``, where
       ``sigma^2`` is the residual variance per coordinate and unit weight of
       the affine fit on the directions that pass 1-2, with
       ``3 (n_eff - 1 - r)`` degrees of freedom (zero when the fit is exact, or
       when the residual sum is within float64 rounding, 1e3 ulps, of the
       displacement's: a large exact scale change is not noise).

    Test 3 is the noise-aware cut-off. An almost straight cable with
    sub-micron lateral jitter has lateral eigenvalues far above machine
    precision, but the lateral slope ``G e / lam`` is the correlation of the
    displacement residual with that jitter divided by a tiny spread: noise
    amplified into a huge (or negative, i.e. collapsing) ``D``. Test 3 drops
    such directions so ``D`` acts as 0 there, exactly like a direction the
    data does not span. On exact affine data ``sigma = 0`` and every spanned
    direction is kept, so exact maps are recovered.
    """
    lam, E, keep = _subspace(m, slope_tol)
    return E[:, keep], lam[keep]


def _subspace(m: Moments, slope_tol):
    """`significant_subspace` as ``(lam (3,), E (3, 3), keep (3,) bool)``, all three directions."""
    tol = K.FIT_NOISE_SLOPE_TOL if slope_tol is None else float(slope_tol)
    s = K.FIT_PRECISION_FACTOR * m.input_eps * m.coord_scale
    floor = s * s * m.W  # as `kernels._affine_step_kernel` forms it
    return _subspace_kernel(m.C, m.G, m.qq, m.n_eff, floor, K.PINV_RTOL_FLOOR, tol)


# --- models ------------------------------------------------------------------


def fit_translation(m: Moments, slope_tol=None):
    """Translation: ``D = 0``. Returns ``(D, u, rank)`` with rank 0."""
    return np.zeros((3, 3)), m.u.copy(), 0


def fit_affine(m: Moments, slope_tol=None):
    """Affine: ``D = G C^+`` on the significant subspace, 0 elsewhere.

    Returns ``(D (3,3), u (3,), rank)``; see `significant_subspace` for the cut-off.
    """
    lam, E, keep = _subspace(m, slope_tol)
    return _slopes_kernel(m.G, E, lam, keep), m.u.copy(), int(keep.sum())


def _minimal_rotation(a, b):
    """The rotation by the smallest angle taking unit `a` to unit `b` (identity about both)."""
    v = np.cross(a, b)
    cos = float(a @ b)
    if cos < -1.0 + 1e-12:
        # Antipodal: any axis perpendicular to `a` is minimal; take a fixed one.
        k = np.cross(a, np.eye(3)[np.argmin(np.abs(a))])
        k /= np.linalg.norm(k)
        return 2.0 * np.outer(k, k) - np.eye(3)
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + cos)


def _rotation(m: Moments, slope_tol):
    """Best proper rotation of the centred data onto the centred target, rank-aware.

    Returns ``(R, Hk, trace_Ck, rank)`` with ``Hk = Pi sum w P Y^T`` (``Y = P + Q``,
    ``Pi`` the projector on the significant subspace).
    """
    E, lam = significant_subspace(m, slope_tol)
    r = E.shape[1]
    if r == 0:
        return np.eye(3), np.zeros((3, 3)), 0.0, 0
    Pi = E @ E.T
    Hk = Pi @ (m.C + m.G.T)
    if r == 1:
        h = Hk.T @ E[:, 0]  # sum w (P.e) Y: where the line goes
        nh = np.linalg.norm(h)
        R = np.eye(3) if not nh > 0 else _minimal_rotation(E[:, 0], h / nh)
    else:
        U, _, Vt = np.linalg.svd(Hk)
        d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
        R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, Hk, float(lam.sum()), r


def fit_rigid(m: Moments, slope_tol=None):
    """Rigid: Kabsch rotation without reflection, ``D = R - I``; ``(D, u, rank)``.

    Notes
    -----
    Only significant directions are matched (`significant_subspace`): for a
    collinear set the spin about the line is unobserved and the minimal
    rotation (no spin; identity about the normal of the line and its image)
    is taken; for rank 0, ``D = 0``.
    """
    R, _, _, r = _rotation(m, slope_tol)
    return R - np.eye(3), m.u.copy(), r


def fit_similarity(m: Moments, slope_tol=None):
    """Similarity: ``D = s R - I`` with the least-squares optimal scale ``s > 0``."""
    R, Hk, trC, r = _rotation(m, slope_tol)
    s = float(np.trace(R @ Hk)) / trC if trC > 0 else 1.0
    if not s > 0:
        s = 1.0  # no correlation at all: keep the identity scale
    return s * R - np.eye(3), m.u.copy(), r


def fit_rigid_repeat(m: Moments, slope_tol=None):
    """The step's own rigid motion applied again (constant angular velocity).

    The Kabsch rotation ``R`` taking the centred ``x_prev`` onto the centred ``x``
    (``sum w (P - Q) P^T = C - G``), and the map ``x_def = c + R u + R (x - c)``:
    the rigid motion ``T(p) = R (p - c_prev) + c`` that took ``x_prev`` to ``x``,
    applied to ``x``. For a body rotating at a constant angular velocity about a
    fixed axis (and translating at a constant velocity) ``T(x)`` is the next frame
    exactly (to rounding), where the target ``x_pred = 2 x - x_prev`` of the other
    models is off by ``O(theta^2)`` of the radius.

    Returns ``(D, u, rank)`` with ``D = R - I``; ``rank < 2`` (a line or a point: the
    spin about it is unobserved) gives the translation ``D = 0, u``.
    """
    E, _ = significant_subspace(m, slope_tol)
    r = E.shape[1]
    if r < 2:
        return np.zeros((3, 3)), m.u.copy(), r
    H = E @ E.T @ (m.C - m.G)  # sum w P_prev P^T on the significant subspace
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R - np.eye(3), R @ m.u, r


_FITTERS = {
    "translation": fit_translation,
    "rigid": fit_rigid,
    "similarity": fit_similarity,
    "affine": fit_affine,
}


def residual_gain(m: Moments, D) -> float:
    """``sum w |Q - D P|^2 - sum w |Q|^2``: the change of the weighted squared
    residual to ``x_pred`` against the translation (negative = better).

    Computed from the moments as ``trace(D C D^T) - 2 trace(D G^T)``, without
    the large ``sum w |Q|^2`` term, so it does not cancel.
    """
    D = np.ascontiguousarray(D, dtype=np.float64)
    return float(_gain_kernel(D, m.C, m.G))


def weighted_rms(m: Moments, D) -> float:
    """Weighted RMS residual ``sqrt(sum w |Q - D P|^2 / W)`` of the map ``D``."""
    return float(np.sqrt(max(m.qq + residual_gain(m, D), 0.0) / m.W))


def choose_model(m: Moments, slope_tol=None):
    """``auto``: the cheapest model whose weighted RMS residual is within
    ``AUTO_MODEL_RTOL`` of the best model's (plus ``AUTO_MODEL_ATOL_REL`` times
    the translation's, the rounding floor of residuals computed from moments).

    Returns ``(model, D, u, rank)``.
    """
    fits = [(name, *_FITTERS[name](m, slope_tol)) for name in K.MODELS]
    rms = [weighted_rms(m, f[1]) for f in fits]
    limit = (1.0 + K.AUTO_MODEL_RTOL) * min(rms) + K.AUTO_MODEL_ATOL_REL * rms[0]
    for f, r in zip(fits, rms):
        if r <= limit:
            return f
    return fits[-1]


def fit_model(m: Moments, model: str = "affine", slope_tol=None):
    """Fit one model of the ladder (or ``"auto"``) from the moments.

    Returns ``(model_used, D (3,3), u (3,), rank)``.
    """
    if model == "auto":
        return choose_model(m, slope_tol)
    if model not in _FITTERS:
        raise InputError(f"model must be one of {K.MODELS + ('auto',)}; got {model!r}")
    return (model, *_FITTERS[model](m, slope_tol))


# --- applying the map ----------------------------------------------------------


def check_out(x, out):
    """`out` for `x`'s deformed positions: a new array when None, else checked (C-contiguous,
    x's shape and dtype, not sharing memory with `x`)."""
    if out is None:
        return np.empty_like(x)
    if out.shape != x.shape or out.dtype != x.dtype or not out.flags.c_contiguous:
        raise InputError(f"out must be C-contiguous {x.shape} {x.dtype}; got {out.shape} {out.dtype}")
    if np.shares_memory(out, x):
        raise InputError("out must not share memory with x")
    return out


def apply_map(x, D, u, c, out=None, x_prev=None, *, checked=False):
    """Write ``x_def = x + D (x - c) + u`` (centred form, float64 arithmetic).

    Parameters
    ----------
    x : (N, 3) float32 or float64
    D : (3, 3) float64
    u, c : (3,) float64
    out : (N, 3) array of x's dtype, C-contiguous, or None
        Written in place when given (may not alias `x`).
    x_prev : (N, 3) or None
        When given, also returns unweighted residual summaries against
        ``x_pred = 2 x - x_prev``.
    checked : bool
        The caller (`fit_step`) has made `x`, `x_prev` C-contiguous, `D`, `u`, `c`
        C-contiguous float64, and `out` an array `check_out` accepts.

    Returns
    -------
    out : (N, 3) of x's dtype
    stats : dict or None
        ``residual_pred_rms``, ``residual_pred_max`` (of `out`) and
        ``baseline_pred_rms``, ``baseline_pred_max`` (of `x`), per-vertex
        Euclidean norms, RMS over vertices.

    Examples
    --------
    >>> import numpy as np
    >>> out, _ = apply_map(np.zeros((2, 3)), np.zeros((3, 3)), np.ones(3), np.zeros(3))
    >>> out[0].tolist()
    [1.0, 1.0, 1.0]
    """
    if not checked:
        x = np.ascontiguousarray(x)
        out = check_out(x, out)
        D = np.ascontiguousarray(D, dtype=np.float64)
        u = np.ascontiguousarray(u, dtype=np.float64)
        c = np.ascontiguousarray(c, dtype=np.float64)
        if x_prev is not None:
            x_prev = np.ascontiguousarray(x_prev)
    evaluate = x_prev is not None
    xp = x_prev if evaluate else x
    res = _apply_kernel(xp, x, D, u, c, out, evaluate, K.REDUCTION_CHUNKS)
    if not evaluate:
        return out, None
    n = x.shape[0]
    s_def, m_def, s_base, m_base = res.tolist()  # Python floats: math.sqrt of NaN is NaN
    stats = {
        "residual_pred_rms": math.sqrt(s_def / n),
        "residual_pred_max": math.sqrt(m_def),
        "baseline_pred_rms": math.sqrt(s_base / n),
        "baseline_pred_max": math.sqrt(m_base),
    }
    return out, stats
