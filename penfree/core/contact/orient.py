"""Certified orientation signs in float64, and the segment-triangle filter built on them.

`orient3d_sign(a, b, c, d)` is the sign of ``det[a - d, b - d, c - d]`` when the float
evaluation proves it, else 0. Shewchuk's static filter ("Adaptive Precision
Floating-Point Arithmetic and Fast Robust Geometric Predicates", 1997): the evaluated
determinant differs from the exact one of the float64 inputs by at most
``(7 + 56 u) u * permanent`` (u = 2^-53, the permanent evaluated with absolute values,
the differences included); `_ERR_REL` is 1e-14, more than 12 times that. Below
`_TINY` the relative bound could fail by underflow, and the sign is reported unknown.

`segment_may_meet_triangle` is False only when the closed segment provably misses the
closed triangle: both end points strictly on one side of the triangle's plane, or the
segment's line passing strictly beside one triangle edge and strictly on the other
side of another (the Plücker test: a line meets a triangle iff the tetrahedra it
spans with the three edges, taken around the triangle, have no two strictly opposite
orientations; a degenerate triangle is covered, its edge lines being one line). It
lets the start-state edge-face check skip the exact test for the pairs it clears;
every other pair still goes through the exact test.

The arithmetic is written once, on coordinates (`_orient3d_xyz`,
`_segment_may_meet_xyz`); the hot loops call it with indices into a positions array
(`segment_may_meet_triangle_at`), not with (3,) rows: a row view per argument costs a
reference count update, and with five views per pair the filter ran 7-10x slower
(440K edge-face pairs of a 64K cloth: 53-60 vs 5-8 ms, one thread, issue 13). The
(3,)-row functions unpack their rows into the same kernels.
"""

from __future__ import annotations

from numba import njit

_ERR_REL = 1e-14
_TINY = 1e-250


@njit(cache=True, forceinline=True)
def _orient3d_xyz(ax, ay, az, bx, by, bz, cx, cy, cz, dx, dy, dz):
    # `orient3d_sign` on coordinates.
    adx, ady, adz = ax - dx, ay - dy, az - dz
    bdx, bdy, bdz = bx - dx, by - dy, bz - dz
    cdx, cdy, cdz = cx - dx, cy - dy, cz - dz
    p1, p2 = bdy * cdz, bdz * cdy
    q1, q2 = cdy * adz, cdz * ady
    r1, r2 = ady * bdz, adz * bdy
    det = adx * (p1 - p2) + bdx * (q1 - q2) + cdx * (r1 - r2)
    perm = (abs(p1) + abs(p2)) * abs(adx) + (abs(q1) + abs(q2)) * abs(bdx) + (abs(r1) + abs(r2)) * abs(cdx)
    if not perm > _TINY:  # tiny or NaN: no relative bound
        return 0
    err = _ERR_REL * perm
    if det > err:
        return 1
    if det < -err:
        return -1
    return 0


@njit(cache=True, inline="always")
def orient3d_sign(a, b, c, d):
    """+1 / -1 when the sign of ``det[a - d, b - d, c - d]`` is certain, else 0.

    All arguments (3,) float64 (rows of a positions array).
    """
    return _orient3d_xyz(a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2], d[0], d[1], d[2])


@njit(cache=True, forceinline=True)
def _segment_may_meet_xyz(px, py, pz, qx, qy, qz, ax, ay, az, bx, by, bz, cx, cy, cz):
    # `segment_may_meet_triangle` on coordinates.
    sp = _orient3d_xyz(ax, ay, az, bx, by, bz, cx, cy, cz, px, py, pz)
    if sp != 0 and sp == _orient3d_xyz(ax, ay, az, bx, by, bz, cx, cy, cz, qx, qy, qz):
        return False
    s1 = _orient3d_xyz(px, py, pz, qx, qy, qz, ax, ay, az, bx, by, bz)
    s2 = _orient3d_xyz(px, py, pz, qx, qy, qz, bx, by, bz, cx, cy, cz)
    s3 = _orient3d_xyz(px, py, pz, qx, qy, qz, cx, cy, cz, ax, ay, az)
    if (s1 > 0 or s2 > 0 or s3 > 0) and (s1 < 0 or s2 < 0 or s3 < 0):
        return False
    return True


@njit(cache=True, inline="always")
def segment_may_meet_triangle_at(V, p, q, a, b, c):
    """`segment_may_meet_triangle` of ``V[p], V[q]`` and ``V[a], V[b], V[c]`` (indices into
    the (N, 3) float64 positions `V`), reading coordinates instead of row views."""
    return _segment_may_meet_xyz(V[p, 0], V[p, 1], V[p, 2], V[q, 0], V[q, 1], V[q, 2],
                                 V[a, 0], V[a, 1], V[a, 2], V[b, 0], V[b, 1], V[b, 2],
                                 V[c, 0], V[c, 1], V[c, 2])


@njit(cache=True)
def segment_may_meet_triangle(p, q, a, b, c):
    """False only when the closed segment [p, q] provably misses the closed triangle abc.

    All arguments (3,) float64.
    """
    return _segment_may_meet_xyz(p[0], p[1], p[2], q[0], q[1], q[2], a[0], a[1], a[2],
                                 b[0], b[1], b[2], c[0], c[1], c[2])
