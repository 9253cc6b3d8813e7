"""Squared static distances between closed primitives (points, segments,
triangles), as Numba kernels other kernels can call, plus vectorized wrappers.

Every kernel is the minimum over a closed-form candidate set, so degenerate
input needs no special branch that could be wrong:

- point-segment: the clamped projection; a zero-length segment is a point.
- segment-segment: the four endpoint-to-segment distances, plus the
  interior-interior pair of the two supporting lines when both line
  parameters lie in [0, 1] and the lines are not parallel. When the closest
  points are not both interior, one of them is an endpoint, so the endpoint
  candidates are exact; parallel and collinear segments and zero-length
  segments are therefore handled by the endpoint candidates alone.
- point-triangle: the three point-to-edge distances, plus the distance to
  the plane when the projection lies inside the triangle; a degenerate
  (zero-area) triangle is the union of its edges.

Two gap bounds (`_ee_gap`, `_pt_gap`) give a cheap lower bound of a pair's
distance from one projection, for folds that skip pairs far from a minimum.

The scalar kernels take 1-D float64 arrays of length 3 (rows of a (N, 3)
array, e.g. ``V[i]``), return the SQUARED distance and allocate nothing.
No fastmath: the arithmetic order is the written one.

Accuracy (tested against exact rational arithmetic): the distance differs
from the exact distance of the float64 inputs by at most about
1e-12 relative plus 1e-13 times the extent of the pair (the largest
coordinate difference); a distance far below the extent of its primitives
(near-touching long segments) is therefore accurate in absolute, not in
relative terms, as any float64 evaluation is.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ...errors import InputError
from ..parallel import parallel_kernel


@njit(cache=True, forceinline=True)
def _pp(px, py, pz, qx, qy, qz):
    dx = px - qx
    dy = py - qy
    dz = pz - qz
    return dx * dx + dy * dy + dz * dz


@njit(cache=True, forceinline=True)
def _pe(px, py, pz, ax, ay, az, bx, by, bz):
    dx = bx - ax
    dy = by - ay
    dz = bz - az
    L2 = dx * dx + dy * dy + dz * dz
    if L2 == 0.0:
        return _pp(px, py, pz, ax, ay, az)
    wx = px - ax
    wy = py - ay
    wz = pz - az
    dot = wx * dx + wy * dy + wz * dz
    if L2 < np.inf:
        # The clamped cases from the numerator, without the division: for a finite
        # L2 > 0, dot <= 0 makes t <= 0 and dot >= L2 makes t >= 1 below, so the result
        # is the same bits (a NaN takes the path below, as before). Most pairs of a fold
        # are clamped: the cloth's edge-edge distances 1.22x faster (issue 13).
        if dot <= 0.0:
            return _pp(px, py, pz, ax, ay, az)
        if dot >= L2:
            return _pp(px, py, pz, bx, by, bz)
    t = dot / L2
    if t <= 0.0:
        return _pp(px, py, pz, ax, ay, az)
    if t >= 1.0:
        return _pp(px, py, pz, bx, by, bz)
    # Interior: |w x d|^2 / |d|^2 is free of the cancellation of |w - t d|^2
    # that grows with the distance of p from the nearer endpoint.
    cx = wy * dz - wz * dy
    cy = wz * dx - wx * dz
    cz = wx * dy - wy * dx
    return (cx * cx + cy * cy + cz * cz) / L2


@njit(cache=True)
def point_point_sq(p, q):
    """Squared distance between points ``p, q`` ((3,) float64)."""
    return _pp(p[0], p[1], p[2], q[0], q[1], q[2])


@njit(cache=True)
def point_edge_sq(p, e0, e1):
    """Squared distance from point ``p`` to the closed segment ``[e0, e1]``.

    All arguments (3,) float64; a zero-length segment is the point ``e0``.
    """
    return _pe(p[0], p[1], p[2], e0[0], e0[1], e0[2], e1[0], e1[1], e1[2])


@njit(cache=True, forceinline=True)
def _normal(ux, uy, uz, vx, vy, vz):
    # u x v and its squared length: the normal of `_ee`'s two lines, of `_pt`'s
    # triangle (and of their branch-free copies, which must form it the same way).
    nx = uy * vz - uz * vy
    ny = uz * vx - ux * vz
    nz = ux * vy - uy * vx
    return nx, ny, nz, nx * nx + ny * ny + nz * nz


@njit(cache=True, forceinline=True)
def _triple(ax, ay, az, bx, by, bz, nx, ny, nz):
    # (a x b) . n: the numerators of `_ee`'s line parameters and `_pt`'s barycentric
    # coordinates (and of their branch-free copies).
    return (ay * bz - az * by) * nx + (az * bx - ax * bz) * ny + (ax * by - ay * bx) * nz


@njit(cache=True)
def _ee(ea0x, ea0y, ea0z, ea1x, ea1y, ea1z, eb0x, eb0y, eb0z, eb1x, eb1y, eb1z):
    # edge_edge_sq on scalars: callers inside other kernels pass coordinates, not
    # (3,) views (a view per argument costs a reference count update per call).
    # Not IR-inlined (inline="always"): inlined into every row visit of the broad
    # phase it made a cold compile of per_vertex_separation take 25 -> ~100+ s (Numba
    # deep-copies the IR per call site); LLVM still inlines it, and the folds measured
    # within noise of the IR-inlined version (2026-12-01, quiet machine). The small
    # scalar helpers (_pp, _pe, the gaps) are ``forceinline=True`` (`broad_phase`).
    best = _pe(ea0x, ea0y, ea0z, eb0x, eb0y, eb0z, eb1x, eb1y, eb1z)
    d = _pe(ea1x, ea1y, ea1z, eb0x, eb0y, eb0z, eb1x, eb1y, eb1z)
    if d < best:
        best = d
    d = _pe(eb0x, eb0y, eb0z, ea0x, ea0y, ea0z, ea1x, ea1y, ea1z)
    if d < best:
        best = d
    d = _pe(eb1x, eb1y, eb1z, ea0x, ea0y, ea0z, ea1x, ea1y, ea1z)
    if d < best:
        best = d
    ux = ea1x - ea0x
    uy = ea1y - ea0y
    uz = ea1z - ea0z
    vx = eb1x - eb0x
    vy = eb1y - eb0y
    vz = eb1z - eb0z
    nx, ny, nz, n2 = _normal(ux, uy, uz, vx, vy, vz)
    if n2 == 0.0:
        return best
    # Closest points of the two lines: s = ((b0 - a0) x v) . n / |n|^2,
    # t = ((b0 - a0) x u) . n / |n|^2.
    wx = eb0x - ea0x
    wy = eb0y - ea0y
    wz = eb0z - ea0z
    sn = _triple(wx, wy, wz, vx, vy, vz, nx, ny, nz)
    tn = _triple(wx, wy, wz, ux, uy, uz, nx, ny, nz)
    # s = sn / n2 and t = tn / n2 in (0, 1) imply 0 < sn, tn < n2 (n2 > 0; rounding is
    # monotone): only those pairs pay the two divisions, and the test on s and t decides.
    if not (sn > 0.0 and sn < n2 and tn > 0.0 and tn < n2):
        return best
    s = sn / n2
    t = tn / n2
    if s > 0.0 and s < 1.0 and t > 0.0 and t < 1.0:
        # Distance between the two computed points rather than the line-line
        # formula (w . n)^2 / |n|^2: both points lie on the segments up to
        # rounding, so near-parallel lines (inaccurate n) can only make this
        # candidate too large, never too small, and the endpoint candidates
        # then hold the true minimum to within the segments' angle.
        rx = s * ux - t * vx - wx
        ry = s * uy - t * vy - wy
        rz = s * uz - t * vz - wz
        d = rx * rx + ry * ry + rz * rz
        if d < best:
            best = d
    return best


@njit(cache=True)
def edge_edge_sq(ea0, ea1, eb0, eb1):
    """Squared distance between the closed segments ``[ea0, ea1]`` and ``[eb0, eb1]``.

    All arguments (3,) float64. Parallel, collinear and zero-length segments
    are exact cases of the candidate set (module docstring).
    """
    return _ee(ea0[0], ea0[1], ea0[2], ea1[0], ea1[1], ea1[2],
               eb0[0], eb0[1], eb0[2], eb1[0], eb1[1], eb1[2])


@njit(cache=True)
def _pt(px, py, pz, t0x, t0y, t0z, t1x, t1y, t1z, t2x, t2y, t2z):
    # point_triangle_sq on scalars (see _ee).
    best = _pe(px, py, pz, t0x, t0y, t0z, t1x, t1y, t1z)
    d = _pe(px, py, pz, t1x, t1y, t1z, t2x, t2y, t2z)
    if d < best:
        best = d
    d = _pe(px, py, pz, t2x, t2y, t2z, t0x, t0y, t0z)
    if d < best:
        best = d
    ux = t1x - t0x
    uy = t1y - t0y
    uz = t1z - t0z
    vx = t2x - t0x
    vy = t2y - t0y
    vz = t2z - t0z
    nx, ny, nz, n2 = _normal(ux, uy, uz, vx, vy, vz)
    if n2 == 0.0:
        return best
    # Barycentric coordinates of the projection of w = p - t0 onto the plane,
    # a = ((w x v) . n) / |n|^2, b = ((u x w) . n) / |n|^2; the candidate is the
    # distance to the point t0 + a u + b v itself, which lies in the triangle
    # whenever the test passes, so a sliver (inaccurate n) can only make it
    # too large and the edge candidates then hold the minimum.
    wx = px - t0x
    wy = py - t0y
    wz = pz - t0z
    an = _triple(wx, wy, wz, vx, vy, vz, nx, ny, nz)
    bn = _triple(ux, uy, uz, wx, wy, wz, nx, ny, nz)
    # a > 0 and b > 0 imply an > 0 and bn > 0 (n2 > 0): only those pay the divisions.
    if not (an > 0.0 and bn > 0.0):
        return best
    a = an / n2
    b = bn / n2
    if a > 0.0 and b > 0.0 and a + b < 1.0:
        rx = wx - a * ux - b * vx
        ry = wy - a * uy - b * vy
        rz = wz - a * uz - b * vz
        d = rx * rx + ry * ry + rz * rz
        if d < best:
            best = d
    return best


# --- the same kernels without branches, for loops over many pairs -----------------
#
# `_pe`, `_ee` and `_pt` return early where a candidate is decided, which costs a
# mispredicted branch on many pairs of a fold. The `*_select` versions compute every
# candidate with the same expressions in the same order and choose among them with
# selects, in the scalar kernels' order of precedence, so they return the same bits
# for every input, NaN and infinity included (tested against the scalar kernels). A
# division by zero gives an IEEE value that a select then discards, hence
# ``error_model="numpy"`` (Python's model would raise). A loop over gathered
# coordinates (`ee_sq_columns`, `pt_sq_columns`) then runs without branches: the 64K
# cloth's 453K edge-edge pairs of a fold, 21.4 ns a pair through `_ee`, 12.6-13.4 with
# the gathers (issue 13).


@njit(cache=True, forceinline=True, error_model="numpy")
def _pe_select(px, py, pz, ax, ay, az, bx, by, bz):
    dx = bx - ax
    dy = by - ay
    dz = bz - az
    L2 = dx * dx + dy * dy + dz * dz
    wx = px - ax
    wy = py - ay
    wz = pz - az
    dot = wx * dx + wy * dy + wz * dz
    pa = _pp(px, py, pz, ax, ay, az)
    pb = _pp(px, py, pz, bx, by, bz)
    t = dot / L2
    cx = wy * dz - wz * dy
    cy = wz * dx - wx * dz
    cz = wx * dy - wy * dx
    r = (cx * cx + cy * cy + cz * cz) / L2
    # `_pe`'s tests from its last to its first: each later one takes precedence
    r = pb if t >= 1.0 else r
    r = pa if t <= 0.0 else r
    finite = L2 < np.inf
    r = pb if finite & (dot >= L2) else r
    r = pa if finite & (dot <= 0.0) else r
    return pa if L2 == 0.0 else r


@njit(cache=True, forceinline=True)
def _lower(best, d):
    # `d` where it is below `best`, as the scalar kernels' ``if d < best: best = d``
    # (a NaN `best` stays: the candidates are taken in the scalar kernels' order).
    return d if d < best else best


@njit(cache=True, forceinline=True, error_model="numpy")
def _ee_select(ea0x, ea0y, ea0z, ea1x, ea1y, ea1z, eb0x, eb0y, eb0z, eb1x, eb1y, eb1z):
    """`_ee` without branches: the same bits (section comment above)."""
    best = _lower(_lower(_lower(_pe_select(ea0x, ea0y, ea0z, eb0x, eb0y, eb0z, eb1x, eb1y, eb1z),
                                _pe_select(ea1x, ea1y, ea1z, eb0x, eb0y, eb0z, eb1x, eb1y, eb1z)),
                         _pe_select(eb0x, eb0y, eb0z, ea0x, ea0y, ea0z, ea1x, ea1y, ea1z)),
                  _pe_select(eb1x, eb1y, eb1z, ea0x, ea0y, ea0z, ea1x, ea1y, ea1z))
    ux, uy, uz = ea1x - ea0x, ea1y - ea0y, ea1z - ea0z
    vx, vy, vz = eb1x - eb0x, eb1y - eb0y, eb1z - eb0z
    nx, ny, nz, n2 = _normal(ux, uy, uz, vx, vy, vz)
    wx, wy, wz = eb0x - ea0x, eb0y - ea0y, eb0z - ea0z
    sn = _triple(wx, wy, wz, vx, vy, vz, nx, ny, nz)
    tn = _triple(wx, wy, wz, ux, uy, uz, nx, ny, nz)
    s = sn / n2
    t = tn / n2
    rx = s * ux - t * vx - wx
    ry = s * uy - t * vy - wy
    rz = s * uz - t * vz - wz
    inside = ((n2 != 0.0) & (sn > 0.0) & (sn < n2) & (tn > 0.0) & (tn < n2)
              & (s > 0.0) & (s < 1.0) & (t > 0.0) & (t < 1.0))
    return _lower(best, rx * rx + ry * ry + rz * rz) if inside else best


@njit(cache=True, forceinline=True, error_model="numpy")
def _pt_select(px, py, pz, t0x, t0y, t0z, t1x, t1y, t1z, t2x, t2y, t2z):
    """`_pt` without branches: the same bits (section comment above)."""
    best = _lower(_lower(_pe_select(px, py, pz, t0x, t0y, t0z, t1x, t1y, t1z),
                         _pe_select(px, py, pz, t1x, t1y, t1z, t2x, t2y, t2z)),
                  _pe_select(px, py, pz, t2x, t2y, t2z, t0x, t0y, t0z))
    ux, uy, uz = t1x - t0x, t1y - t0y, t1z - t0z
    vx, vy, vz = t2x - t0x, t2y - t0y, t2z - t0z
    nx, ny, nz, n2 = _normal(ux, uy, uz, vx, vy, vz)
    wx, wy, wz = px - t0x, py - t0y, pz - t0z
    an = _triple(wx, wy, wz, vx, vy, vz, nx, ny, nz)
    bn = _triple(ux, uy, uz, wx, wy, wz, nx, ny, nz)
    a = an / n2
    b = bn / n2
    rx = wx - a * ux - b * vx
    ry = wy - a * uy - b * vy
    rz = wz - a * uz - b * vz
    inside = (n2 != 0.0) & (an > 0.0) & (bn > 0.0) & (a > 0.0) & (b > 0.0) & (a + b < 1.0)
    return _lower(best, rx * rx + ry * ry + rz * rz) if inside else best


@njit(cache=True, error_model="numpy")
def ee_sq_columns(G, out, n):
    """``out[k]`` = `_ee` of the segments in column k of `G` (12, >= n) float64 (rows:
    ea0 x y z, ea1, eb0, eb1), for k < n; without branches (`_ee_select`)."""
    for k in range(n):
        out[k] = _ee_select(G[0, k], G[1, k], G[2, k], G[3, k], G[4, k], G[5, k],
                            G[6, k], G[7, k], G[8, k], G[9, k], G[10, k], G[11, k])


@njit(cache=True, error_model="numpy")
def pt_sq_columns(G, out, n):
    """``out[k]`` = `_pt` of the point and triangle in column k of `G` (12, >= n)
    float64 (rows: p x y z, t0, t1, t2), for k < n; without branches (`_pt_select`)."""
    for k in range(n):
        out[k] = _pt_select(G[0, k], G[1, k], G[2, k], G[3, k], G[4, k], G[5, k],
                            G[6, k], G[7, k], G[8, k], G[9, k], G[10, k], G[11, k])


#: A projection direction shorter than sqrt(_TINY_SQ) or longer than sqrt(_HUGE_SQ) is
#: not used by the gap bounds (their products could underflow or overflow, where the
#: rounding bound of `_ee_gap` does not hold): the bound is then 0.
_TINY_SQ = 1e-200
_HUGE_SQ = 1e200


@njit(cache=True, forceinline=True)
def _gap_over(num, nn):
    # The gap num / |n| along a direction n with |n|^2 = nn (0.0 where it proves nothing).
    if num > 0.0 and nn > _TINY_SQ and nn < _HUGE_SQ:
        return num / np.sqrt(nn)
    return 0.0


@njit(cache=True, forceinline=True)
def _ee_gap(ea0x, ea0y, ea0z, ea1x, ea1y, ea1z, eb0x, eb0y, eb0z, eb1x, eb1y, eb1z):
    """A lower bound of the distance of two closed segments (0.0 where it proves
    nothing): the gap between their projections onto a line, which no pair of their
    points can cross. Onto w = 2 (mid_b - mid_a) a segment projects to its midpoint's
    projection plus or minus |w . d| / 2 (d its direction), so the gap is
    (w . w - |w . da| - |w . db|) / (2 |w|); and the same onto n = w |da|^2 - (w . da)
    da, the part of w normal to segment a (n . w >= 0), which separates parallel
    segments side by side along w. The larger of the two is returned.

    Any direction gives a valid bound, so only the gap's own arithmetic errs: each
    term of the numerator by at most ~30 ulps of |n| M (M the largest coordinate; the
    differences of the coordinates and the dot products), which the division by |n|
    cancels, so the computed gap exceeds the exact one by at most ~100 ulps of M: far
    below the 1e-9 M slack its callers subtract (`broad_phase._fold_owned`).
    """
    wx = (eb0x + eb1x) - (ea0x + ea1x)
    wy = (eb0y + eb1y) - (ea0y + ea1y)
    wz = (eb0z + eb1z) - (ea0z + ea1z)
    ax = ea1x - ea0x
    ay = ea1y - ea0y
    az = ea1z - ea0z
    bx = eb1x - eb0x
    by = eb1y - eb0y
    bz = eb1z - eb0z
    ww = wx * wx + wy * wy + wz * wz
    g = _gap_over(0.5 * (ww - abs(wx * ax + wy * ay + wz * az) - abs(wx * bx + wy * by + wz * bz)), ww)
    # Both directions, the larger gap: parallel diagonals of a sheet offset along
    # themselves have a rounding-sized gap along w and their spacing along n.
    aa = ax * ax + ay * ay + az * az
    wa = wx * ax + wy * ay + wz * az
    nx = wx * aa - wa * ax
    ny = wy * aa - wa * ay
    nz = wz * aa - wa * az
    num = 0.5 * ((nx * wx + ny * wy + nz * wz) - abs(nx * ax + ny * ay + nz * az) - abs(nx * bx + ny * by + nz * bz))
    return max(g, _gap_over(num, nx * nx + ny * ny + nz * nz))


@njit(cache=True, forceinline=True)
def _pt_gap(px, py, pz, t0x, t0y, t0z, t1x, t1y, t1z, t2x, t2y, t2z):
    """A lower bound of the distance from a point to a closed triangle (0.0 where it
    proves nothing): the gap between their projections onto w = 3 (centroid - p),
    ``min_k (t_k - p) . w / |w|`` (rounding as in `_ee_gap`)."""
    wx = (t0x + t1x + t2x) - 3.0 * px
    wy = (t0y + t1y + t2y) - 3.0 * py
    wz = (t0z + t1z + t2z) - 3.0 * pz
    m = min((t0x - px) * wx + (t0y - py) * wy + (t0z - pz) * wz,
            (t1x - px) * wx + (t1y - py) * wy + (t1z - pz) * wz,
            (t2x - px) * wx + (t2y - py) * wy + (t2z - pz) * wz)
    return _gap_over(m, wx * wx + wy * wy + wz * wz)


@njit(cache=True)
def point_triangle_sq(p, t0, t1, t2):
    """Squared distance from point ``p`` to the closed triangle ``(t0, t1, t2)``.

    All arguments (3,) float64. A degenerate triangle (collinear or repeated
    corners) is the union of its edges.
    """
    return _pt(p[0], p[1], p[2], t0[0], t0[1], t0[2], t1[0], t1[1], t1[2], t2[0], t2[1], t2[2])


# --- vectorized wrappers ------------------------------------------------------


@njit(cache=True, parallel=True)
def _point_edge_many(P, E0, E1, out):
    for q in prange(P.shape[0]):
        out[q] = np.sqrt(point_edge_sq(P[q], E0[q], E1[q]))


@njit(cache=True, parallel=True)
def _edge_edge_many(EA0, EA1, EB0, EB1, out):
    for q in prange(EA0.shape[0]):
        out[q] = np.sqrt(edge_edge_sq(EA0[q], EA1[q], EB0[q], EB1[q]))


@njit(cache=True, parallel=True)
def _point_triangle_many(P, T0, T1, T2, out):
    for q in prange(P.shape[0]):
        out[q] = np.sqrt(point_triangle_sq(P[q], T0[q], T1[q], T2[q]))


def _indexed_distance_py(x, idx, vf, out):
    for q in prange(idx.shape[0]):
        a, b, c, d = idx[q, 0], idx[q, 1], idx[q, 2], idx[q, 3]
        if vf:
            out[q] = np.sqrt(point_triangle_sq(x[a], x[b], x[c], x[d]))
        else:
            out[q] = np.sqrt(edge_edge_sq(x[a], x[b], x[c], x[d]))


# Each row writes its own slot: both builds give the same bits (penfree.core.parallel).
_indexed_distance = parallel_kernel(_indexed_distance_py, "_dist_indexed")


def indexed_distance(x, idx, kind) -> np.ndarray:
    """Distances of pairs given by vertex rows into `x`, without gathering them.

    Parameters
    ----------
    x : (N, 3) float64, C-contiguous, finite
    idx : (K, 4) int64 in [0, N)
        Rows (p, t0, t1, t2) for ``kind == "vf"``, else (ea0, ea1, eb0, eb1).
    kind : str

    Returns
    -------
    (K,) float64: the same bits as `point_triangle_distance` / `edge_edge_distance` on
    the gathered rows (the same kernels on the same values). Inputs are assumed
    validated (the callers' scenes are).
    """
    idx = np.ascontiguousarray(idx, dtype=np.int64)
    out = np.empty(idx.shape[0], dtype=np.float64)
    if idx.shape[0]:
        _indexed_distance(idx.shape[0], x, idx, kind == "vf", out)
    return out


def _rows(arrays, names):
    out = []
    n = None
    for a, name in zip(arrays, names):
        a = np.asarray(a)
        if a.ndim == 1 and a.shape[0] == 3:
            a = a[None, :]
        if a.ndim != 2 or a.shape[1] != 3:
            raise InputError(f"{name} must be (Q, 3); got {a.shape}")
        if n is None:
            n = a.shape[0]
        elif a.shape[0] != n:
            raise InputError(f"{name} must have {n} rows like {names[0]}; got {a.shape[0]}")
        a = np.ascontiguousarray(a, dtype=np.float64)
        if not np.isfinite(a).all():
            raise InputError(f"{name} must be finite; got NaN or inf")
        out.append(a)
    return out, n


def point_edge_distance(P, E0, E1) -> np.ndarray:
    """Distances from points to closed segments, row by row.

    Parameters
    ----------
    P, E0, E1 : (Q, 3) array_like of float
        Point and segment endpoints of each query (a single (3,) row is accepted).

    Returns
    -------
    (Q,) float64 distances (not squared).

    Examples
    --------
    >>> point_edge_distance([[0.0, 1.0, 0.0]], [[-1.0, 0, 0]], [[1.0, 0, 0]])
    array([1.])
    """
    (P, E0, E1), n = _rows((P, E0, E1), ("P", "E0", "E1"))
    out = np.empty(n, dtype=np.float64)
    _point_edge_many(P, E0, E1, out)
    return out


def edge_edge_distance(EA0, EA1, EB0, EB1) -> np.ndarray:
    """Distances between closed segments ``[EA0, EA1]`` and ``[EB0, EB1]``, row by row.

    Parameters
    ----------
    EA0, EA1, EB0, EB1 : (Q, 3) array_like of float

    Returns
    -------
    (Q,) float64 distances (not squared).

    Examples
    --------
    >>> edge_edge_distance([[0.0, 0, 0]], [[1.0, 0, 0]], [[0.5, -1, 2]], [[0.5, 1, 2]])
    array([2.])
    """
    (EA0, EA1, EB0, EB1), n = _rows((EA0, EA1, EB0, EB1), ("EA0", "EA1", "EB0", "EB1"))
    out = np.empty(n, dtype=np.float64)
    _edge_edge_many(EA0, EA1, EB0, EB1, out)
    return out


def point_triangle_distance(P, T0, T1, T2) -> np.ndarray:
    """Distances from points to closed triangles, row by row.

    Parameters
    ----------
    P, T0, T1, T2 : (Q, 3) array_like of float

    Returns
    -------
    (Q,) float64 distances (not squared).

    Examples
    --------
    >>> point_triangle_distance([[0.2, 0.2, 3.0]], [[0.0, 0, 0]], [[1.0, 0, 0]], [[0.0, 1, 0]])
    array([3.])
    """
    (P, T0, T1, T2), n = _rows((P, T0, T1, T2), ("P", "T0", "T1", "T2"))
    out = np.empty(n, dtype=np.float64)
    _point_triangle_many(P, T0, T1, T2, out)
    return out
