"""Weighted least-squares fit of the step map in centred displacement form (SPEC section 4).

One fused Numba pass reduces the two frames to a handful of moments; every
model (translation, rigid, similarity, affine) is then fitted from those
moments alone, so candidate maps cost no further pass over the vertices.
"""

from __future__ import annotations

import types
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from .. import constants as K
from ..errors import InputError

#: Layout of the moment vector the kernel returns (offsets into it).
_W, _SP, _SD, _SPP, _SDP, _SDD, _SW2, _NMOM = 0, 1, 4, 7, 13, 22, 23, 24
_SYM = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def _moments_py(x_prev, x, w, use_w, n_chunks):
    # Shift every vertex by the first vertex (and its displacement) before
    # accumulating: second moments of coordinates 1e6 from the origin would
    # otherwise cancel catastrophically when centred afterwards.
    n = x.shape[0]
    x00, x01, x02 = np.float64(x[0, 0]), np.float64(x[0, 1]), np.float64(x[0, 2])
    d00 = x00 - np.float64(x_prev[0, 0])
    d01 = x01 - np.float64(x_prev[0, 1])
    d02 = x02 - np.float64(x_prev[0, 2])
    part = np.zeros((n_chunks, _NMOM))
    for k in prange(n_chunks):
        lo = k * n // n_chunks
        hi = (k + 1) * n // n_chunks
        sw = sw2 = 0.0
        sp0 = sp1 = sp2 = sd0 = sd1 = sd2 = 0.0
        c00 = c11 = c22 = c01 = c02 = c12 = 0.0
        g00 = g01 = g02 = g10 = g11 = g12 = g20 = g21 = g22 = 0.0
        sdd = 0.0
        for i in range(lo, hi):
            a0, a1, a2 = np.float64(x[i, 0]), np.float64(x[i, 1]), np.float64(x[i, 2])
            p0, p1, p2 = a0 - x00, a1 - x01, a2 - x02
            q0 = (a0 - np.float64(x_prev[i, 0])) - d00
            q1 = (a1 - np.float64(x_prev[i, 1])) - d01
            q2 = (a2 - np.float64(x_prev[i, 2])) - d02
            wi = w[i] if use_w else 1.0
            wp0, wp1, wp2 = wi * p0, wi * p1, wi * p2
            sw += wi
            sw2 += wi * wi
            sp0 += wp0
            sp1 += wp1
            sp2 += wp2
            sd0 += wi * q0
            sd1 += wi * q1
            sd2 += wi * q2
            c00 += wp0 * p0
            c11 += wp1 * p1
            c22 += wp2 * p2
            c01 += wp0 * p1
            c02 += wp0 * p2
            c12 += wp1 * p2
            g00 += q0 * wp0
            g01 += q0 * wp1
            g02 += q0 * wp2
            g10 += q1 * wp0
            g11 += q1 * wp1
            g12 += q1 * wp2
            g20 += q2 * wp0
            g21 += q2 * wp1
            g22 += q2 * wp2
            sdd += wi * (q0 * q0 + q1 * q1 + q2 * q2)
        row = part[k]
        row[0] = sw
        row[1], row[2], row[3] = sp0, sp1, sp2
        row[4], row[5], row[6] = sd0, sd1, sd2
        row[7], row[8], row[9], row[10], row[11], row[12] = c00, c11, c22, c01, c02, c12
        row[13], row[14], row[15] = g00, g01, g02
        row[16], row[17], row[18] = g10, g11, g12
        row[19], row[20], row[21] = g20, g21, g22
        row[22] = sdd
        row[23] = sw2
    # Partials are summed in chunk order, so the result is independent of
    # how many threads ran the chunks.
    tot = np.zeros(_NMOM + 6)
    for k in range(n_chunks):
        for j in range(_NMOM):
            tot[j] += part[k, j]
    tot[_NMOM + 0], tot[_NMOM + 1], tot[_NMOM + 2] = x00, x01, x02
    tot[_NMOM + 3], tot[_NMOM + 4], tot[_NMOM + 5] = d00, d01, d02
    return tot


# The same source compiled twice: a parallel region costs tens of microseconds
# (far more on a loaded machine), so small inputs run the chunks serially. The
# choice depends on N only, never on the thread count.
def _named(fn, name):
    # Numba's on-disk cache is keyed by the function's qualified name; give
    # each compiled variant its own, so the serial and parallel builds never
    # share a cache entry.
    f = types.FunctionType(fn.__code__, fn.__globals__, name, fn.__defaults__, fn.__closure__)
    f.__qualname__ = name
    return f


#: Reassociation lets LLVM vectorise the per-chunk sums (about 2x); it is fixed
#: at compile time, so results still do not depend on the thread count. No
#: flag that assumes finite values: NaN/Inf inputs must still poison the sums.
_FIT_FASTMATH = {"reassoc", "contract"}

_moments_serial = njit(cache=True, fastmath=_FIT_FASTMATH)(_named(_moments_py, "_moments_serial"))
_moments_parallel = njit(cache=True, parallel=True, fastmath=_FIT_FASTMATH)(
    _named(_moments_py, "_moments_parallel"))


def _moments_kernel(x_prev, x, w, use_w, n_chunks):
    big = x.shape[0] >= K.PARALLEL_MIN_VERTICES
    return (_moments_parallel if big else _moments_serial)(x_prev, x, w, use_w, n_chunks)


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
    """Validate `(N,)` weights (finite, >= 0, positive sum); None stays None."""
    if weights is None:
        return None
    w = np.ascontiguousarray(np.asarray(weights, dtype=np.float64))
    if w.shape != (n,):
        raise InputError(f"weights must be ({n},) to match x; got shape {w.shape}")
    if not np.isfinite(w).all() or (w < 0).any():
        raise InputError("weights must be finite and >= 0; got a negative or non-finite weight")
    if not w.sum() > 0:
        raise InputError("weights must have a positive sum; got all zero")
    return w


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
    use_w = weights is not None
    w = weights if use_w else np.empty(0)
    tot = _moments_kernel(x_prev, x, w, use_w, K.REDUCTION_CHUNKS)
    if not np.isfinite(tot).all():
        # Any NaN/Inf input poisons the sums; find which input to name it.
        as_positions(x, "x")
        as_positions(x_prev, "x_prev")
        raise InputError("positions must be below ~1e150 in magnitude; got sums that overflow float64")
    f = _finish_kernel(tot, use_w, x.shape[0])
    eps = max(np.finfo(x.dtype).eps, np.finfo(x_prev.dtype).eps)
    return Moments(f[0], f[1:4], f[4:7], f[7:16].reshape(3, 3), f[16:25].reshape(3, 3), f[25],
                   x.shape[0], f[26], f[27], float(eps))


@njit(cache=True)
def _finish_kernel(tot, use_w, n):
    # Centre the shifted sums: C = Spp - Sp mp^T, G = Sdp - Sd mp^T (the shift
    # by the first vertex keeps these differences free of large cancellation).
    f = np.empty(28)
    W = tot[_W]
    mp = tot[_SP:_SP + 3] / W
    mq = tot[_SD:_SD + 3] / W
    f[0] = W
    tr = 0.0
    for a in range(3):
        f[1 + a] = tot[_NMOM + a] + mp[a]
        f[4 + a] = tot[_NMOM + 3 + a] + mq[a]
    for j in range(6):
        a, b = _SYM[j]
        cab = tot[_SPP + j] - 0.5 * (tot[_SP + a] * mp[b] + tot[_SP + b] * mp[a])
        f[7 + 3 * a + b] = cab
        f[7 + 3 * b + a] = cab
        if a == b:
            tr += cab
    for a in range(3):
        for b in range(3):
            f[16 + 3 * a + b] = tot[_SDP + 3 * a + b] - tot[_SD + a] * mp[b]
    f[25] = max(tot[_SDD] - (tot[_SD] * mq[0] + tot[_SD + 1] * mq[1] + tot[_SD + 2] * mq[2]), 0.0)
    f[26] = W * W / tot[_SW2] if use_w else float(n)
    f[27] = max(abs(f[1]), abs(f[2]), abs(f[3])) + np.sqrt(max(tr, 0.0) / W)
    return f
    return Moments(W, c, u, C, G, qq, n, float(n_eff), scale, float(eps))


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
       ``3 (n_eff - 1 - r)`` degrees of freedom (zero when the fit is exact).

    Test 3 is the noise-aware cut-off. An almost straight cable with
    sub-micron lateral jitter has lateral eigenvalues far above machine
    precision, but the lateral slope ``G e / lam`` is the correlation of the
    displacement residual with that jitter divided by a tiny spread: noise
    amplified into a huge (or negative, i.e. collapsing) ``D``. Test 3 drops
    such directions so ``D`` acts as 0 there, exactly like a direction the
    data does not span. On exact affine data ``sigma = 0`` and every spanned
    direction is kept, so exact maps are recovered.
    """
    tol = K.FIT_NOISE_SLOPE_TOL if slope_tol is None else float(slope_tol)
    floor = (K.FIT_PRECISION_FACTOR * m.input_eps * m.coord_scale) ** 2 * m.W
    lam, E, keep = _subspace_kernel(m.C, m.G, m.qq, m.n_eff, floor, K.PINV_RTOL_FLOOR, tol)
    return E[:, keep], lam[keep]


@njit(cache=True)
def _subspace_kernel(C, G, qq, n_eff, floor, rtol, tol):
    lam, E = np.linalg.eigh(C)
    keep = np.zeros(3, dtype=np.bool_)
    if not lam[2] > 0:
        return lam, E, keep
    r = 0
    for k in range(3):
        keep[k] = lam[k] > rtol * lam[2] and lam[k] > floor
        r += keep[k]
    if r == 0 or not np.isfinite(tol):
        return lam, E, keep
    # Residual of the affine fit on the kept directions: the directions are
    # C-orthogonal, so each explains |G e|^2 / lam of the squared residual.
    explained = 0.0
    for k in range(3):
        if keep[k]:
            g0 = G[0, 0] * E[0, k] + G[0, 1] * E[1, k] + G[0, 2] * E[2, k]
            g1 = G[1, 0] * E[0, k] + G[1, 1] * E[1, k] + G[1, 2] * E[2, k]
            g2 = G[2, 0] * E[0, k] + G[2, 1] * E[1, k] + G[2, 2] * E[2, k]
            explained += (g0 * g0 + g1 * g1 + g2 * g2) / lam[k]
    dof = 3.0 * (n_eff - 1.0 - r)
    sigma2 = max(qq - explained, 0.0) / dof if dof > 0 else 0.0
    for k in range(3):
        keep[k] = keep[k] and sigma2 <= tol * tol * lam[k]
    return lam, E, keep


# --- models ------------------------------------------------------------------


def fit_translation(m: Moments, slope_tol=None):
    """Translation: ``D = 0``. Returns ``(D, u, rank)`` with rank 0."""
    return np.zeros((3, 3)), m.u.copy(), 0


def fit_affine(m: Moments, slope_tol=None):
    """Affine: ``D = G C^+`` on the significant subspace, 0 elsewhere.

    Returns ``(D (3,3), u (3,), rank)``; see `significant_subspace` for the cut-off.
    """
    E, lam = significant_subspace(m, slope_tol)
    D = (m.G @ E / lam) @ E.T
    return D, m.u.copy(), E.shape[1]


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
    D = np.asarray(D, dtype=np.float64)
    return float(np.sum((D @ m.C) * D) - 2.0 * np.sum(D * m.G))


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


def _apply_py(x_prev, x, D, u, c, out, evaluate, out32, n_chunks):
    # x_def = x + D (x - c) + u in float64, then cast on store. With
    # `evaluate`, also residual sums of the *stored* x_def (its float32
    # rounding when `out32`) and of x against x_pred = 2x - x_prev, formed as
    # d - (x_def - x) to keep far-from-origin digits. Never reads `out` back,
    # so the loop carries no memory dependence through it.
    n = x.shape[0]
    d00, d01, d02 = D[0, 0], D[0, 1], D[0, 2]
    d10, d11, d12 = D[1, 0], D[1, 1], D[1, 2]
    d20, d21, d22 = D[2, 0], D[2, 1], D[2, 2]
    u0, u1, u2 = u[0], u[1], u[2]
    c0, c1, c2 = c[0], c[1], c[2]
    part = np.zeros((n_chunks, 4))
    for k in prange(n_chunks):
        lo = k * n // n_chunks
        hi = (k + 1) * n // n_chunks
        s_def = m_def = s_base = m_base = 0.0
        for i in range(lo, hi):
            a0, a1, a2 = np.float64(x[i, 0]), np.float64(x[i, 1]), np.float64(x[i, 2])
            p0, p1, p2 = a0 - c0, a1 - c1, a2 - c2
            v0 = a0 + (d00 * p0 + d01 * p1 + d02 * p2 + u0)
            v1 = a1 + (d10 * p0 + d11 * p1 + d12 * p2 + u1)
            v2 = a2 + (d20 * p0 + d21 * p1 + d22 * p2 + u2)
            out[i, 0] = v0
            out[i, 1] = v1
            out[i, 2] = v2
            if evaluate:
                if out32:
                    v0 = np.float64(np.float32(v0))
                    v1 = np.float64(np.float32(v1))
                    v2 = np.float64(np.float32(v2))
                q0 = a0 - np.float64(x_prev[i, 0])
                q1 = a1 - np.float64(x_prev[i, 1])
                q2 = a2 - np.float64(x_prev[i, 2])
                e0 = q0 - (v0 - a0)
                e1 = q1 - (v1 - a1)
                e2 = q2 - (v2 - a2)
                ed = e0 * e0 + e1 * e1 + e2 * e2
                eb = q0 * q0 + q1 * q1 + q2 * q2
                s_def += ed
                s_base += eb
                m_def = max(m_def, ed)
                m_base = max(m_base, eb)
        part[k, 0], part[k, 1], part[k, 2], part[k, 3] = s_def, m_def, s_base, m_base
    res = np.zeros(4)
    for k in range(n_chunks):
        res[0] += part[k, 0]
        res[1] = max(res[1], part[k, 1])
        res[2] += part[k, 2]
        res[3] = max(res[3], part[k, 3])
    return res


_apply_serial = njit(cache=True, fastmath=_FIT_FASTMATH)(_named(_apply_py, "_apply_serial"))
_apply_parallel = njit(cache=True, parallel=True, fastmath=_FIT_FASTMATH)(_named(_apply_py, "_apply_parallel"))


def _apply_kernel(x_prev, x, D, u, c, out, evaluate, n_chunks):
    big = x.shape[0] >= K.PARALLEL_MIN_VERTICES
    out32 = out.dtype == np.float32
    return (_apply_parallel if big else _apply_serial)(x_prev, x, D, u, c, out, evaluate, out32, n_chunks)


def apply_map(x, D, u, c, out=None, x_prev=None):
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
    x = np.ascontiguousarray(x)
    if out is None:
        out = np.empty_like(x)
    elif out.shape != x.shape or out.dtype != x.dtype or not out.flags.c_contiguous:
        raise InputError(f"out must be C-contiguous {x.shape} {x.dtype}; got {out.shape} {out.dtype}")
    if np.shares_memory(out, x):
        raise InputError("out must not share memory with x")
    D = np.ascontiguousarray(D, dtype=np.float64)
    u = np.ascontiguousarray(u, dtype=np.float64)
    c = np.ascontiguousarray(c, dtype=np.float64)
    evaluate = x_prev is not None
    xp = np.ascontiguousarray(x_prev) if evaluate else x
    res = _apply_kernel(xp, x, D, u, c, out, evaluate, K.REDUCTION_CHUNKS)
    if not evaluate:
        return out, None
    n = x.shape[0]
    stats = {
        "residual_pred_rms": float(np.sqrt(res[0] / n)),
        "residual_pred_max": float(np.sqrt(res[1])),
        "baseline_pred_rms": float(np.sqrt(res[2] / n)),
        "baseline_pred_max": float(np.sqrt(res[3])),
    }
    return out, stats
