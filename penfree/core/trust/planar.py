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
from numba import njit, prange

from ...errors import InputError
from ..parallel import chunk_count, parallel_kernel
from ..contact.broad_phase import edge_edge_candidates, pair_rows, vertex_face_candidates

#: ipctk ``TrustRegion.relaxed_radius_scaling`` (2 gamma_p with gamma_p = 0.45).
RELAXED_RADIUS_SCALING = 0.9
#: Below this distance a candidate has no usable direction and is skipped (ipctk).
PLANAR_MIN_DIST = 1e-10
#: A displacement this close to parallel with the plane never crosses it (ipctk).
PLANAR_PARALLEL_EPS = 1e-15
#: Arrival times below this are the stencil's own vertices lying on the plane
#: up to rounding: no crossing (ipctk).
PLANAR_T_EPS = 1e-10
#: The planar ratios run over at most this many chunks of stencils (each with its own
#: row of ratios, reduced by min), of at least this many stencils each.
_PLANAR_CHUNKS = 8
_STENCILS_PER_CHUNK = 4096

KIND_EDGE_EDGE = 0
KIND_VERTEX_FACE = 1


#: Edges count as parallel when sin^2 of their angle is below this (relative to
#: |u|^2 |v|^2), as in IPC Toolkit's ``edge_edge_distance_type``.
EE_PARALLEL_SIN2 = 2.5e-16


@njit(cache=True, inline="always")
def _dd(P, i, j, k, l):
    """``(P[i] - P[j]) . (P[k] - P[l])`` without temporaries."""
    return ((P[i, 0] - P[j, 0]) * (P[k, 0] - P[l, 0]) + (P[i, 1] - P[j, 1]) * (P[k, 1] - P[l, 1])
            + (P[i, 2] - P[j, 2]) * (P[k, 2] - P[l, 2]))


@njit(cache=True, inline="always")
def _line_param(P, ip, ia, ib):
    """Unclamped parameter of the projection of P[ip] on the line P[ia] + t (P[ib] - P[ia])."""
    den = _dd(P, ib, ia, ib, ia)
    return 0.0 if den == 0.0 else _dd(P, ip, ia, ib, ia) / den


@njit(cache=True, inline="always")
def _set(coef, c0, c1, c2, c3):
    coef[0] = c0
    coef[1] = c1
    coef[2] = c2
    coef[3] = c3


@njit(cache=True)
def _ee_features(P, eac, ebc, coef):
    """Coefficients for features eac / ebc (0: first endpoint, 1: second, 2: the edge)."""
    if eac < 2 and ebc < 2:
        _set(coef, 1.0 - eac, float(eac), -(1.0 - ebc), -float(ebc))
    elif eac == 2 and ebc < 2:
        s = _line_param(P, 2 + ebc, 0, 1)
        _set(coef, 1.0 - s, s, -(1.0 - ebc), -float(ebc))
    elif eac < 2:
        t = _line_param(P, eac, 2, 3)
        _set(coef, 1.0 - eac, float(eac), -(1.0 - t), -t)
    else:
        # s = (b e - c d) / (a c - b^2), t = (a e - b d) / (a c - b^2) through
        # Lagrange's identity as cross products, n = u x v:
        # s = n . (v x w) / |n|^2, t = n . (u x w) / |n|^2. The dot-product form
        # cancels catastrophically for nearly parallel edges (stacked cloth layers:
        # a c - b^2 ~ 1e-6 a c leaves s, t with errors ~1e-10, and the closest-point
        # direction tilts out of the layer by that much times the edges' height
        # difference, enough to truncate vertices moving straight down).
        ux, uy, uz = P[1, 0] - P[0, 0], P[1, 1] - P[0, 1], P[1, 2] - P[0, 2]
        vx, vy, vz = P[3, 0] - P[2, 0], P[3, 1] - P[2, 1], P[3, 2] - P[2, 2]
        wx, wy, wz = P[0, 0] - P[2, 0], P[0, 1] - P[2, 1], P[0, 2] - P[2, 2]
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        n2 = nx * nx + ny * ny + nz * nz
        s = (nx * (vy * wz - vz * wy) + ny * (vz * wx - vx * wz) + nz * (vx * wy - vy * wx)) / n2
        t = (nx * (uy * wz - uz * wy) + ny * (uz * wx - ux * wz) + nz * (ux * wy - uy * wx)) / n2
        _set(coef, 1.0 - s, s, -(1.0 - t), -t)


@njit(cache=True, inline="always")
def _ee_coefficients(P, coef):
    """IPC Toolkit's ``edge_edge_distance_type`` and the coefficients of the type."""
    a, b, c = _dd(P, 1, 0, 1, 0), _dd(P, 1, 0, 3, 2), _dd(P, 3, 2, 3, 2)
    d, e = _dd(P, 1, 0, 0, 2), _dd(P, 3, 2, 0, 2)
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
    ux, uy, uz = P[1, 0] - P[0, 0], P[1, 1] - P[0, 1], P[1, 2] - P[0, 2]
    vx, vy, vz = P[3, 0] - P[2, 0], P[3, 1] - P[2, 1], P[3, 2] - P[2, 2]
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    if nx * nx + ny * ny + nz * nz < EE_PARALLEL_SIN2 * a * c:
        # parallel: IPC Toolkit's parallel classification
        alpha = _dd(P, 2, 0, 1, 0) / a
        beta = _dd(P, 3, 0, 1, 0) / a
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


@njit(cache=True, inline="always")
def _edge_side(P, ip, i0, i1, nx, ny, nz):
    """(along, across) of P[ip] in the basis (e, e x normal), e = P[i1] - P[i0], as ipctk solves it."""
    rx, ry, rz = P[i1, 0] - P[i0, 0], P[i1, 1] - P[i0, 1], P[i1, 2] - P[i0, 2]
    sx, sy, sz = ry * nz - rz * ny, rz * nx - rx * nz, rx * ny - ry * nx
    qx, qy, qz = P[ip, 0] - P[i0, 0], P[ip, 1] - P[i0, 1], P[ip, 2] - P[i0, 2]
    g00 = rx * rx + ry * ry + rz * rz
    g01 = rx * sx + ry * sy + rz * sz
    g11 = sx * sx + sy * sy + sz * sz
    b0 = rx * qx + ry * qy + rz * qz
    b1 = sx * qx + sy * qy + sz * qz
    det = g00 * g11 - g01 * g01
    return (g11 * b0 - g01 * b1) / det, (g00 * b1 - g01 * b0) / det


@njit(cache=True, inline="always")
def _point_edge(P, ia, ib):
    """``(t, d^2)``: the clamped parameter of P[0]'s nearest point on P[ia] P[ib], and its squared distance."""
    t = min(max(_line_param(P, 0, ia, ib), 0.0), 1.0)
    d2 = 0.0
    for k in range(3):
        e = P[0, k] - (P[ia, k] + t * (P[ib, k] - P[ia, k]))
        d2 += e * e
    return t, d2


@njit(cache=True)
def _degenerate_pt_coefficients(P, coef):
    """A triangle without area (collinear or coincident vertices): its nearest edge.
    (The type classification divides by the normal's length: ZeroDivisionError.)"""
    t0, d0 = _point_edge(P, 1, 2)
    t1, d1 = _point_edge(P, 2, 3)
    t2, d2 = _point_edge(P, 3, 1)
    if d0 <= d1 and d0 <= d2:
        _set(coef, 1.0, -(1.0 - t0), -t0, 0.0)
    elif d1 <= d2:
        _set(coef, 1.0, 0.0, -(1.0 - t1), -t1)
    else:
        _set(coef, 1.0, -t2, 0.0, -(1.0 - t2))


@njit(cache=True, inline="always")
def _pt_coefficients(P, coef):
    """IPC Toolkit's ``point_triangle_distance_type`` and the coefficients of the type."""
    ux, uy, uz = P[2, 0] - P[1, 0], P[2, 1] - P[1, 1], P[2, 2] - P[1, 2]
    vx, vy, vz = P[3, 0] - P[1, 0], P[3, 1] - P[1, 1], P[3, 2] - P[1, 2]
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    if nx * nx + ny * ny + nz * nz == 0.0:
        _degenerate_pt_coefficients(P, coef)
        return
    a0, c0 = _edge_side(P, 0, 1, 2, nx, ny, nz)
    if 0.0 < a0 < 1.0 and c0 >= 0.0:
        _set(coef, 1.0, -(1.0 - a0), -a0, 0.0)
        return
    a1, c1 = _edge_side(P, 0, 2, 3, nx, ny, nz)
    if 0.0 < a1 < 1.0 and c1 >= 0.0:
        _set(coef, 1.0, 0.0, -(1.0 - a1), -a1)
        return
    a2, c2 = _edge_side(P, 0, 3, 1, nx, ny, nz)
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
        wx, wy, wz = P[0, 0] - P[1, 0], P[0, 1] - P[1, 1], P[0, 2] - P[1, 2]
        n2 = nx * nx + ny * ny + nz * nz
        bu = ((wy * vz - wz * vy) * nx + (wz * vx - wx * vz) * ny + (wx * vy - wy * vx) * nz) / n2
        bv = ((uy * wz - uz * wy) * nx + (uz * wx - ux * wz) * ny + (ux * wy - uy * wx) * nz) / n2
        _set(coef, 1.0, -(1.0 - bu - bv), -bu, -bv)


@njit(cache=True, inline="always")
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
    plane is the same. Scalar arithmetic only (no temporaries in the kernel).
    """
    if kind == KIND_EDGE_EDGE:
        _ee_coefficients(P, coef)
    else:
        _pt_coefficients(P, coef)


def _planar_ratios_py(x, dx, moving, stencils, kinds, scaling, partial):
    # Chunk k of the stencils lowers only partial[k] (min is exact: the reduced ratios
    # do not depend on the chunks or the threads).
    n_chunks = partial.shape[0]
    m = stencils.shape[0]
    for k in prange(n_chunks):
        _planar_ratios_range(x, dx, moving, stencils, kinds, scaling, partial[k], k * m // n_chunks,
                             (k + 1) * m // n_chunks)


_planar_ratios = parallel_kernel(_planar_ratios_py, "_planar_ratios")


@njit(cache=True)
def _planar_ratios_range(x, dx, moving, stencils, kinds, scaling, ratio, c0, c1):
    P = np.empty((4, 3))
    D = np.empty((4, 3))
    coef = np.zeros(4)
    for c in range(c0, c1):
        if not (moving[stencils[c, 0]] or moving[stencils[c, 1]] or moving[stencils[c, 2]]
                or moving[stencils[c, 3]]):
            continue  # every |D_j . n| below PLANAR_PARALLEL_EPS: no vertex of it is truncated
        for j in range(4):
            v = stencils[c, j]
            for k in range(3):
                P[j, k] = x[v, k]
                D[j, k] = dx[v, k]
        stencil_coefficients(P, kinds[c], coef)
        dvx = coef[0] * P[0, 0] + coef[1] * P[1, 0] + coef[2] * P[2, 0] + coef[3] * P[3, 0]
        dvy = coef[0] * P[0, 1] + coef[1] * P[1, 1] + coef[2] * P[2, 1] + coef[3] * P[3, 1]
        dvz = coef[0] * P[0, 2] + coef[1] * P[1, 2] + coef[2] * P[2, 2] + coef[3] * P[3, 2]
        dist = np.sqrt(dvx * dvx + dvy * dvy + dvz * dvz)
        if dist < PLANAR_MIN_DIST:
            continue
        nx, ny, nz = dvx / dist, dvy / dist, dvz / dist
        c2x = c2y = c2z = 0.0
        delta1 = 0.0
        delta2 = 0.0
        for j in range(4):
            dn = D[j, 0] * nx + D[j, 1] * ny + D[j, 2] * nz
            if coef[j] > 0.0:
                delta1 = max(delta1, -dn)
            elif coef[j] < 0.0:
                c2x -= coef[j] * P[j, 0]
                c2y -= coef[j] * P[j, 1]
                c2z -= coef[j] * P[j, 2]
                delta2 = max(delta2, dn)
        lam = 0.5 if (delta1 == 0.0 and delta2 == 0.0) else delta2 / (delta1 + delta2)
        px, py, pz = c2x + lam * dvx, c2y + lam * dvy, c2z + lam * dvz
        for j in range(4):
            denom = D[j, 0] * nx + D[j, 1] * ny + D[j, 2] * nz
            if abs(denom) < PLANAR_PARALLEL_EPS:
                continue  # moving along the plane: never crosses it
            t = -((P[j, 0] - px) * nx + (P[j, 1] - py) * ny + (P[j, 2] - pz) * nz) / denom
            if t < PLANAR_T_EPS or t >= 1.0 / scaling:
                continue
            r = scaling * t
            v = stencils[c, j]
            if r < ratio[v]:
                ratio[v] = r


def _moving(dx):
    """(N,) bool: the vertices whose move can cross a division plane. A stencil of none
    is skipped by `_planar_ratios_range` without a change: with every component below
    a quarter of `PLANAR_PARALLEL_EPS`, ``|D_j . n|`` for a unit ``n`` (to rounding)
    stays below the threshold, so the kernel would skip each of its vertices."""
    return np.abs(dx).max(axis=1, initial=0.0) >= 0.25 * PLANAR_PARALLEL_EPS


def ball_ratio(x, dx, centers, radii):
    """Largest ``beta in (0, 1]`` with ``|x + beta dx - c| <= r`` per vertex (ipctk's formula).

    Parameters
    ----------
    x, dx, centers : (N, 3) float64
    radii : (N,) float64 or float

    Returns
    -------
    (N,) float64
        1 where ``x + dx`` is inside the ball (or ``dx = 0``); NaN where ipctk 1.6.1's
        formula has no root: for a vertex at the centre of a ball of radius 0 (a pair
        within the thickness, e.g. a crossing) it divides 0 by 0, and for a vertex
        outside its ball (one such vertex after an unhindered move) whose line misses
        the ball its discriminant is negative. Its ``beta < 1`` test then lets the
        vertex move unhindered, and so does `isotropic_filter`. (Clamping the
        discriminant at 0 instead gave such a vertex a negative or infinite ratio:
        positions of NaN, on which the broad phase crashed.)
    """
    a = np.einsum("ij,ij->i", dx, dx)
    rel = x - centers
    b = 2.0 * np.einsum("ij,ij->i", dx, rel)
    c = np.einsum("ij,ij->i", rel, rel) - np.asarray(radii, dtype=np.float64) ** 2
    inside = np.linalg.norm(x + dx - centers, axis=1) <= radii
    beta = np.ones(x.shape[0])
    out = ~inside & (a > 0)
    a, b, c = a[out], b[out], c[out]
    with np.errstate(divide="ignore", invalid="ignore"):
        sq = np.sqrt(b * b - 4.0 * a * c)  # NaN where negative, as ipctk's sqrt
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
        partial = np.ones((chunk_count(stencils.shape[0], _PLANAR_CHUNKS, _STENCILS_PER_CHUNK), x.shape[0]))
        _planar_ratios(stencils.shape[0], x, dx, _moving(dx), stencils, kinds, float(scaling), partial)
        ratio = partial.min(axis=0)
    # ipctk's std::min(t, beta) keeps t where beta is NaN (no root): np.fmin, not np.minimum
    ratio = np.fmin(ratio, ball_ratio(x, dx, centers, float(inflation_radius)))
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
    return pair_stencils(x.shape[0], E, F, *candidate_pairs(x, x, E, F, radius))


def candidate_pairs(x0, x1, E, F, radius) -> tuple:
    """``(ee, vf)``: the edge-edge pairs (rows of `E`) and vertex-face pairs (vertex,
    row of `F`) whose boxes over the motion from `x0` to `x1`, inflated by `radius`,
    overlap (`candidate_stencils` at ``x0 = x1``; `stencil_list` over a region), each
    sorted lexicographically; (0, 2) where `E` or `F` is empty."""
    infl = float(radius)
    none = np.zeros((0, 2), np.int64)
    ee = edge_edge_candidates(x0, x1, E, infl) if E.shape[0] else none
    # every vertex (the default), as ipctk pairs them: a segment's or a free vertex meets faces too
    vf = vertex_face_candidates(x0, x1, F, infl) if F.shape[0] else none
    return ee, vf


def pair_stencils(n, E, F, ee, vf) -> tuple:
    """``(stencils, kinds)``: the vertex rows of `candidate_pairs`'s pairs (of a scene of
    `n` vertices), edge-edge first, and their kinds (both int64, C-contiguous)."""
    st = np.concatenate([pair_rows(E, E, ee), pair_rows(np.arange(n, dtype=np.int64)[:, None], F, vf)])
    kinds = np.concatenate([np.full(ee.shape[0], KIND_EDGE_EDGE), np.full(vf.shape[0], KIND_VERTEX_FACE)])
    return np.ascontiguousarray(st, dtype=np.int64), kinds.astype(np.int64)
