"""Planar truncation ("Divide and Truncate", SIGGRAPH 2026) and the isotropic filter.

The two step filters of an OGC trust-region client, as IPC Toolkit's
``ipctk.ogc.TrustRegion`` implements them (``filter_step`` and
``planar_filter_step``), so that penfree's own replay reproduces the client
without ipctk:

* **isotropic**: every vertex keeps its proposed move only inside the ball of
  radius ``b_v`` (its trust-region radius) about its trust-region centre;
  the move is scaled down to the ball's boundary otherwise.
* **planar**: for every collision candidate found at the last CD pass (vertex-face
  and edge-edge stencils within the inflation radius), the closest points at the
  *current* positions give a direction ``n`` and a division plane between the
  two primitives, placed by how fast each side approaches it. Every stencil
  vertex moving toward the plane is truncated to ``s`` times its time of arrival
  there (``s`` = `RELAXED_RADIUS_SCALING`, ``2 gamma_p``); the component along
  the plane is never what stops it. Afterwards every vertex is also kept inside
  the ball of the *inflation radius* about its centre (the fallback for pairs
  beyond the query). Each vertex is scaled by the smallest ratio it received.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..errors import InputError
from .broad_phase import edge_edge_candidates, vertex_face_candidates

#: ipctk ``TrustRegion.relaxed_radius_scaling`` (2 gamma_p with gamma_p = 0.45).
RELAXED_RADIUS_SCALING = 0.9
#: Below this distance a candidate has no usable direction and is skipped (ipctk).
PLANAR_MIN_DIST = 1e-10
#: A displacement this close to parallel with the plane never crosses it (ipctk).
PLANAR_PARALLEL_EPS = 1e-15
#: Arrival times below this are the stencil's own vertices lying on the plane
#: up to rounding: no crossing (ipctk).
PLANAR_T_EPS = 1e-10

KIND_EDGE_EDGE = 0
KIND_VERTEX_FACE = 1


#: Edges count as parallel when sin^2 of their angle is below this (relative to
#: |u|^2 |v|^2), as in IPC Toolkit's ``edge_edge_distance_type``.
EE_PARALLEL_SIN2 = 2.5e-16


@njit(cache=True)
def _line_param(p, a, b):
    """Unclamped parameter of the projection of p on the line a + t (b - a)."""
    u = b - a
    den = u @ u
    return 0.0 if den == 0.0 else ((p - a) @ u) / den


@njit(cache=True)
def _set(coef, c0, c1, c2, c3):
    coef[0] = c0
    coef[1] = c1
    coef[2] = c2
    coef[3] = c3


@njit(cache=True)
def _ee_parallel(P, coef):
    """Closest features of two parallel edges (IPC Toolkit's parallel classification)."""
    ea = P[1] - P[0]
    n2 = ea @ ea
    alpha = ((P[2] - P[0]) @ ea) / n2
    beta = ((P[3] - P[0]) @ ea) / n2
    if alpha < 0:
        eac = 2 if 0 <= beta <= 1 else 0
        ebc = 0 if beta <= alpha else (1 if beta <= 1 else 2)
    elif alpha > 1:
        eac = 2 if 0 <= beta <= 1 else 1
        ebc = 0 if beta >= alpha else (1 if 0 <= beta else 2)
    else:
        eac = 2
        ebc = 0
    _ee_features(P, eac, ebc, coef)


@njit(cache=True)
def _ee_features(P, eac, ebc, coef):
    """Coefficients for features eac / ebc (0: first endpoint, 1: second, 2: the edge)."""
    if eac < 2 and ebc < 2:
        _set(coef, 1.0 - eac, float(eac), -(1.0 - ebc), -float(ebc))
    elif eac == 2 and ebc < 2:
        s = _line_param(P[2 + ebc], P[0], P[1])
        _set(coef, 1.0 - s, s, -(1.0 - ebc), -float(ebc))
    elif eac < 2:
        t = _line_param(P[eac], P[2], P[3])
        _set(coef, 1.0 - eac, float(eac), -(1.0 - t), -t)
    else:
        u = P[1] - P[0]
        v = P[3] - P[2]
        w = P[0] - P[2]
        a, b, c, d, e = u @ u, u @ v, v @ v, u @ w, v @ w
        D = a * c - b * b
        s = (b * e - c * d) / D
        t = (a * e - b * d) / D
        _set(coef, 1.0 - s, s, -(1.0 - t), -t)


@njit(cache=True)
def _ee_coefficients(P, coef):
    """IPC Toolkit's ``edge_edge_distance_type`` and the coefficients of the type."""
    u = P[1] - P[0]
    v = P[3] - P[2]
    w = P[0] - P[2]
    a, b, c, d, e = u @ u, u @ v, v @ v, u @ w, v @ w
    D = a * c - b * b
    if a == 0.0 and c == 0.0:
        _ee_features(P, 0, 0, coef)
        return
    if a == 0.0:
        _ee_features(P, 0, 2, coef)
        return
    if c == 0.0:
        _ee_features(P, 2, 0, coef)
        return
    n = np.cross(u, v)
    if n @ n < EE_PARALLEL_SIN2 * a * c:
        _ee_parallel(P, coef)
        return
    eac, ebc = 2, 2
    sN = b * e - c * d
    if sN <= 0.0:
        tN, tD, eac = e, c, 0
    elif sN >= D:
        tN, tD, eac = e + b, c, 1
    else:
        tN, tD = a * e - b * d, D
    if tN <= 0.0:
        ebc = 0
        eac = 0 if -d <= 0.0 else (1 if -d >= a else 2)
    elif tN >= tD:
        ebc = 1
        eac = 0 if -d + b <= 0.0 else (1 if -d + b >= a else 2)
    _ee_features(P, eac, ebc, coef)


@njit(cache=True)
def _edge_side(p, e0, e1, normal):
    """(along, across) of p in the basis (e1 - e0, (e1 - e0) x normal), solved as ipctk does."""
    r0 = e1 - e0
    r1 = np.cross(r0, normal)
    q = p - e0
    g00, g01, g11 = r0 @ r0, r0 @ r1, r1 @ r1
    b0, b1 = r0 @ q, r1 @ q
    det = g00 * g11 - g01 * g01
    return (g11 * b0 - g01 * b1) / det, (g00 * b1 - g01 * b0) / det


@njit(cache=True)
def _pt_coefficients(P, coef):
    """IPC Toolkit's ``point_triangle_distance_type`` and the coefficients of the type."""
    p, t0, t1, t2 = P[0], P[1], P[2], P[3]
    normal = np.cross(t1 - t0, t2 - t0)
    a0, c0 = _edge_side(p, t0, t1, normal)
    if 0.0 < a0 < 1.0 and c0 >= 0.0:
        _set(coef, 1.0, -(1.0 - a0), -a0, 0.0)
        return
    a1, c1 = _edge_side(p, t1, t2, normal)
    if 0.0 < a1 < 1.0 and c1 >= 0.0:
        _set(coef, 1.0, 0.0, -(1.0 - a1), -a1)
        return
    a2, c2 = _edge_side(p, t2, t0, normal)
    if 0.0 < a2 < 1.0 and c2 >= 0.0:
        _set(coef, 1.0, -a2, 0.0, -(1.0 - a2))
        return
    if a0 <= 0.0 and a2 >= 1.0:
        _set(coef, 1.0, -1.0, 0.0, 0.0)
    elif a1 <= 0.0 and a0 >= 1.0:
        _set(coef, 1.0, 0.0, -1.0, 0.0)
    elif a2 <= 0.0 and a1 >= 1.0:
        _set(coef, 1.0, 0.0, 0.0, -1.0)
    else:  # the interior: barycentric coordinates of the projection
        u = t1 - t0
        v = t2 - t0
        w = p - t0
        n2 = normal @ normal
        bu = (np.cross(w, v) @ normal) / n2
        bv = (np.cross(u, w) @ normal) / n2
        _set(coef, 1.0, -(1.0 - bu - bv), -bu, -bv)


@njit(cache=True)
def stencil_coefficients(P, kind, coef):
    """Closest-point coefficients of a stencil: ``dv = sum_j coef_j P_j``.

    Parameters
    ----------
    P : (4, 3) float64
        Rows ``ea0, ea1, eb0, eb1`` (edge-edge) or ``p, t0, t1, t2`` (vertex-face).
    kind : int
        `KIND_EDGE_EDGE` or `KIND_VERTEX_FACE`.
    coef : (4,) float64
        Output: positive entries weight the first primitive, negative the second,
        so ``dv`` points from the second primitive's closest point to the first's.

    Notes
    -----
    The closest features are classified exactly as IPC Toolkit classifies them
    (``edge_edge_distance_type`` with its parallel branch,
    ``point_triangle_distance_type``), so that near-parallel edges, where several
    feature pairs are almost equally close, pick the same pair and the division
    plane is the same.
    """
    if kind == KIND_EDGE_EDGE:
        _ee_coefficients(P, coef)
    else:
        _pt_coefficients(P, coef)


@njit(cache=True)
def _plane_ratio(x, dx, n, p, scaling):
    denom = dx[0] * n[0] + dx[1] * n[1] + dx[2] * n[2]
    if abs(denom) < PLANAR_PARALLEL_EPS:
        return 1.0
    t = -((x[0] - p[0]) * n[0] + (x[1] - p[1]) * n[1] + (x[2] - p[2]) * n[2]) / denom
    if t < PLANAR_T_EPS or t >= 1.0 / scaling:
        return 1.0
    return scaling * t


@njit(cache=True)
def _planar_ratios(x, dx, stencils, kinds, scaling, ratio):
    P = np.empty((4, 3))
    D = np.empty((4, 3))
    coef = np.zeros(4)
    dv = np.empty(3)
    n = np.empty(3)
    p = np.empty(3)
    for c in range(stencils.shape[0]):
        nv = 4
        for j in range(nv):
            P[j] = x[stencils[c, j]]
            D[j] = dx[stencils[c, j]]
        coef[:] = 0.0
        stencil_coefficients(P, kinds[c], coef)
        for k in range(3):
            dv[k] = coef[0] * P[0, k] + coef[1] * P[1, k] + coef[2] * P[2, k] + coef[3] * P[3, k]
        dist = np.sqrt(dv @ dv)
        if dist < PLANAR_MIN_DIST:
            continue
        for k in range(3):
            n[k] = dv[k] / dist
        c2 = np.zeros(3)
        delta1 = 0.0
        delta2 = 0.0
        for j in range(nv):
            dn = D[j] @ n
            if coef[j] > 0.0:
                delta1 = max(delta1, -dn)
            elif coef[j] < 0.0:
                for k in range(3):
                    c2[k] -= coef[j] * P[j, k]
                delta2 = max(delta2, dn)
        lam = 0.5 if (delta1 == 0.0 and delta2 == 0.0) else delta2 / (delta1 + delta2)
        for k in range(3):
            p[k] = c2[k] + lam * dv[k]
        for j in range(nv):
            r = _plane_ratio(P[j], D[j], n, p, scaling)
            v = stencils[c, j]
            if r < ratio[v]:
                ratio[v] = r


def ball_ratio(x, dx, centers, radii):
    """Largest ``beta in (0, 1]`` with ``|x + beta dx - c| <= r`` per vertex (ipctk's formula).

    Parameters
    ----------
    x, dx, centers : (N, 3) float64
    radii : (N,) float64 or float

    Returns
    -------
    (N,) float64
        1 where ``x + dx`` is inside the ball (or ``dx = 0``).
    """
    a = np.einsum("ij,ij->i", dx, dx)
    rel = x - centers
    b = 2.0 * np.einsum("ij,ij->i", dx, rel)
    c = np.einsum("ij,ij->i", rel, rel) - np.asarray(radii, dtype=np.float64) ** 2
    inside = np.linalg.norm(x + dx - centers, axis=1) <= radii
    beta = np.ones(x.shape[0])
    out = ~inside & (a > 0)
    a, b, c = a[out], b[out], c[out]
    sq = np.sqrt(np.maximum(b * b - 4.0 * a * c, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        # numerically stable positive root, as in ipctk
        beta[out] = np.where(b >= 0, -2.0 * c / (b + sq), (-b + sq) / (2.0 * a))
    return beta


def isotropic_filter(x, dx, centers, radii):
    """``filter_step``: truncated copy of `dx` and the number of truncated vertices."""
    beta = ball_ratio(x, dx, centers, radii)
    trunc = beta < 1.0
    out = dx.copy()
    out[trunc] *= beta[trunc, None]
    return out, int(np.count_nonzero(trunc))


def planar_filter(x, dx, centers, inflation_radius, stencils, kinds, scaling=RELAXED_RADIUS_SCALING):
    """``planar_filter_step``: truncated copy of `dx` and the number of truncated vertices.

    Parameters
    ----------
    x : (N, 3) float64
        Current positions (the closest points are taken here).
    dx : (N, 3) float64
        Proposed displacements.
    centers : (N, 3) float64
        Trust-region centres (positions at the last CD pass).
    inflation_radius : float
        The client's inflation radius (the isotropic fallback's radius).
    stencils : (K, 4) int64
        Candidate stencils (`candidate_stencils`).
    kinds : (K,) int64
        `KIND_EDGE_EDGE` or `KIND_VERTEX_FACE` per stencil.
    scaling : float
        ``relaxed_radius_scaling`` of the client.

    Returns
    -------
    dx_filtered : (N, 3) float64
    n_truncated : int

    Examples
    --------
    >>> import numpy as np
    >>> x = np.array([[0.0, 0, 0], [1, 0, 0], [0.5, -1, 0.1], [0.5, 1, 0.1]])
    >>> dx = np.array([[0, 0, 0.1], [0, 0, 0.1], [0, 0, 0.0], [0, 0, 0.0]])
    >>> st, kd = np.array([[0, 1, 2, 3]]), np.array([KIND_EDGE_EDGE])
    >>> out, n = planar_filter(x, dx, x, 1.0, st, kd)
    >>> round(float(out[0, 2]), 6), n   # 0.9 of the way to the plane at z = 0.1
    (0.09, 2)
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    dx = np.ascontiguousarray(dx, dtype=np.float64)
    stencils = np.ascontiguousarray(stencils, dtype=np.int64).reshape(-1, 4)
    kinds = np.ascontiguousarray(kinds, dtype=np.int64).reshape(-1)
    if x.shape != dx.shape or kinds.shape[0] != stencils.shape[0]:
        raise InputError(f"planar_filter needs x, dx (N, 3) and one kind per stencil; got {x.shape}, {dx.shape}, "
                         f"{stencils.shape}, {kinds.shape}")
    ratio = np.ones(x.shape[0])
    if stencils.shape[0]:
        _planar_ratios(x, dx, stencils, kinds, float(scaling), ratio)
    ratio = np.minimum(ratio, ball_ratio(x, dx, centers, float(inflation_radius)))
    trunc = ratio < 1.0
    out = dx.copy()
    out[trunc] *= ratio[trunc, None]
    return out, int(np.count_nonzero(trunc))


def candidate_stencils(x, E, F, radius):
    """Edge-edge and vertex-face stencils whose static boxes lie within `radius`.

    Parameters
    ----------
    x : (N, 3) float64
    E : (M, 2) int64
        Edges (for a triangle scene the edges of the faces).
    F : (K, 3) int64
        Faces (may be empty).
    radius : float
        Pairs closer than this (per axis, boxes inflated by ``radius / 2``) are
        kept: a superset of the pairs within `radius`, as a CD pass finds them.

    Returns
    -------
    stencils : (C, 4) int64
        Rows ``ea0, ea1, eb0, eb1`` or ``p, t0, t1, t2``.
    kinds : (C,) int64
    """
    infl = float(radius)
    parts, kinds = [], []
    if E.shape[0]:
        ee = edge_edge_candidates(x, x, E, infl)
        parts.append(np.concatenate([E[ee[:, 0]], E[ee[:, 1]]], axis=1))
        kinds.append(np.full(ee.shape[0], KIND_EDGE_EDGE))
    if F.shape[0]:
        used = np.unique(F)
        vf = vertex_face_candidates(x, x, F, infl, vertices=used)
        parts.append(np.concatenate([vf[:, :1], F[vf[:, 1]]], axis=1))
        kinds.append(np.full(vf.shape[0], KIND_VERTEX_FACE))
    if not parts:
        return np.zeros((0, 4), np.int64), np.zeros(0, np.int64)
    return np.ascontiguousarray(np.concatenate(parts), dtype=np.int64), np.concatenate(kinds).astype(np.int64)
