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


@njit(cache=True)
def _seg_param(p, a, b):
    """Clamped parameter of the point of segment [a, b] closest to p."""
    ux, uy, uz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    den = ux * ux + uy * uy + uz * uz
    if den == 0.0:
        return 0.0
    t = ((p[0] - a[0]) * ux + (p[1] - a[1]) * uy + (p[2] - a[2]) * uz) / den
    return min(1.0, max(0.0, t))


@njit(cache=True)
def _dist2_coeffs(P, coef):
    """Squared norm of sum_j coef_j P_j (the distance vector of a stencil)."""
    s = 0.0
    for k in range(3):
        v = 0.0
        for j in range(4):
            v += coef[j] * P[j, k]
        s += v * v
    return s


@njit(cache=True)
def _try(P, cand, best_d, best):
    d = _dist2_coeffs(P, cand)
    if d < best_d:
        for j in range(4):
            best[j] = cand[j]
        return d
    return best_d


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
    The minimum over a closed candidate set (endpoints against the other segment,
    edges of the triangle, and the interior solution when it is inside), as
    `penfree.core.distance` does for the distances themselves.
    """
    cand = np.zeros(4)
    best_d = np.inf
    if kind == KIND_EDGE_EDGE:
        for e in range(2):  # an endpoint of a against segment b
            t = _seg_param(P[e], P[2], P[3])
            cand[:] = 0.0
            cand[e] = 1.0
            cand[2] = -(1.0 - t)
            cand[3] = -t
            best_d = _try(P, cand, best_d, coef)
        for e in range(2):  # an endpoint of b against segment a
            s = _seg_param(P[2 + e], P[0], P[1])
            cand[:] = 0.0
            cand[0] = 1.0 - s
            cand[1] = s
            cand[2 + e] = -1.0
            best_d = _try(P, cand, best_d, coef)
        u = P[1] - P[0]
        v = P[3] - P[2]
        w = P[2] - P[0]
        n = np.cross(u, v)
        n2 = n @ n
        if n2 > 0.0:
            s = (np.cross(w, v) @ n) / n2
            t = (np.cross(w, u) @ n) / n2
            if 0.0 < s < 1.0 and 0.0 < t < 1.0:
                cand[0] = 1.0 - s
                cand[1] = s
                cand[2] = -(1.0 - t)
                cand[3] = -t
                best_d = _try(P, cand, best_d, coef)
    else:
        for e in range(3):  # the point against an edge of the triangle
            i0 = 1 + e
            i1 = 1 + (e + 1) % 3
            t = _seg_param(P[0], P[i0], P[i1])
            cand[:] = 0.0
            cand[0] = 1.0
            cand[i0] = -(1.0 - t)
            cand[i1] = -t
            best_d = _try(P, cand, best_d, coef)
        u = P[2] - P[1]
        v = P[3] - P[1]
        w = P[0] - P[1]
        n = np.cross(u, v)
        n2 = n @ n
        if n2 > 0.0:
            a = (np.cross(w, v) @ n) / n2
            b = (np.cross(u, w) @ n) / n2
            if a > 0.0 and b > 0.0 and a + b < 1.0:
                cand[0] = 1.0
                cand[1] = -(1.0 - a - b)
                cand[2] = -a
                cand[3] = -b
                best_d = _try(P, cand, best_d, coef)
    return best_d


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
