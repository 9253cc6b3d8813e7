"""Numba kernels of the analytic-solid check (`penfree.core.contact.solids`), one primitive
at a time.

A solid's frame is packed into one float64 row (`pack_frame`): its profile, the linear
part L and its inverse, the translation c, the scale of its support's rounding, and the
angles where the two ends' supports are equal (the 2D dual's extra candidates). Every
function below is the scalar form of the one `solids` documents; the batch kernels
(`verdict_kernel`, `separation_kernel`) run them over the primitives in parallel, each
iteration writing only its own slots, so 1 and 2 threads give the same bits. No
fastmath: the plane test's rounding bound assumes IEEE arithmetic in the order written.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..parallel import parallel_kernel

#: Relative slack on every rounded quantity of the plane test: a few hundred units
#: in the last place of the terms involved (a handful of operations each).
REL = 1e-13
#: Golden-section steps along an edge: the bracket shrinks to 0.618^40 ~ 4e-9 of the edge.
SECTION_STEPS = 40
_PHI = 0.5 * (5.0 ** 0.5 - 1.0)
_HALF_PI = 0.5 * math.pi

# Layout of a packed frame.
_L, _C, _LI, _SCALE, _NTH, _TH, FRAME_SIZE = 5, 14, 17, 26, 27, 28, 30

#: Verdict flags of a primitive (`verdict_kernel`).
START, PATH, PRE = 1, 2, 4


def pack_frame(p, L, c, Linv):
    """The float64 row the kernels read for a solid ``(profile (5,), L, c, L^-1)``."""
    half = 0.5 * p[0]
    z_i, a_i, b_i = (-half, half), (p[1], p[3]), (p[2], p[4])
    ths = []
    A, B, C = a_i[1] - a_i[0], z_i[1] - z_i[0], b_i[0] - b_i[1]
    R = np.hypot(A, B)
    if R > 0 and abs(C) <= R:  # where the two ends' supports are equal
        psi, delta = np.arctan2(B, A), np.arccos(np.clip(C / R, -1.0, 1.0))
        for th in (psi + delta, psi - delta):
            th = (th + np.pi) % (2.0 * np.pi) - np.pi
            if -0.5 * np.pi <= th <= 0.5 * np.pi:
                ths.append(th)
    F = np.zeros(FRAME_SIZE)
    F[:5], F[_L:_C], F[_C:_LI], F[_LI:_SCALE] = p, L.ravel(), c, Linv.ravel()
    F[_SCALE] = np.linalg.norm(c) + np.linalg.norm(L) * (half + max(p[1], p[3]) + max(p[2], p[4]))
    F[_NTH] = len(ths)
    F[_TH:_TH + len(ths)] = ths
    return F


@njit(cache=True)
def _pick(axis, v0, v1, v2):
    """``(v_axis, v_u, v_v)`` with ``u = axis + 1``, ``v = axis + 2`` (mod 3)."""
    if axis == 0:
        return v0, v1, v2
    if axis == 1:
        return v1, v2, v0
    return v2, v0, v1


@njit(cache=True)
def _unpick(axis, va, vu, vv):
    """The inverse of `_pick`: ``(v0, v1, v2)``."""
    if axis == 0:
        return va, vu, vv
    if axis == 1:
        return vv, va, vu
    return vu, vv, va


@njit(cache=True)
def _times_lt(F, n0, n1, n2):
    """``L n`` (``n @ L.T``)."""
    return (F[_L] * n0 + F[_L + 1] * n1 + F[_L + 2] * n2,
            F[_L + 3] * n0 + F[_L + 4] * n1 + F[_L + 5] * n2,
            F[_L + 6] * n0 + F[_L + 7] * n1 + F[_L + 8] * n2)


@njit(cache=True)
def _end_terms(F, axis, n0, n1, n2):
    """``m = L n`` split along the axis ``(m_a, m_u, m_v)``, ``|m_perp|``, ``|m|``, and the
    local support of the bottom and the top rounded disc along m."""
    half = 0.5 * F[0]
    m0, m1, m2 = _times_lt(F, n0, n1, n2)
    ma, mu, mv = _pick(axis, m0, m1, m2)
    perp = math.hypot(mu, mv)
    mn = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
    return ma, mu, mv, perp, mn, -half * ma + F[1] * perp + F[2] * mn, half * ma + F[3] * perp + F[4] * mn


@njit(cache=True)
def support(F, axis, n0, n1, n2):
    """``h_S(n)`` and a bound on its rounding error."""
    bottom, top = _end_terms(F, axis, n0, n1, n2)[5:]
    h = n0 * F[_C] + n1 * F[_C + 1] + n2 * F[_C + 2] + max(bottom, top)
    return h, REL * math.sqrt(n0 * n0 + n1 * n1 + n2 * n2) * F[_SCALE] + 1e-300


@njit(cache=True)
def local_closest(F, axis, y0, y1, y2):
    """Signed distance of the local point y to the local solid, the outward unit normal
    there and the closest point (y itself inside): ``(g, n0, n1, n2, q0, q1, q2)``."""
    half = 0.5 * F[0]
    z, yu, yv = _pick(axis, y0, y1, y2)
    u = math.hypot(yu, yv)
    # the 2D dual: max over theta in [-pi/2, pi/2] of min_i (cos(u - a_i) + sin(z - z_i) - b_i)
    n_cand = 4 + int(F[_NTH])
    best, bc, bs = 0.0, 0.0, 0.0
    for k in range(n_cand):
        if k == 0:
            th = -_HALF_PI
        elif k == 1:
            th = _HALF_PI
        elif k == 2:
            th = min(max(math.atan2(z + half, u - F[1]), -_HALF_PI), _HALF_PI)
        elif k == 3:
            th = min(max(math.atan2(z - half, u - F[3]), -_HALF_PI), _HALF_PI)
        else:
            th = F[_TH + k - 4]
        c, s = math.cos(th), math.sin(th)
        g = min(c * (u - F[1]) + s * (z + half) - F[2], c * (u - F[3]) + s * (z - half) - F[4])
        if k == 0 or g > best:  # the first of equal maxima, as argmax
            best, bc, bs = g, c, s
    if u <= 0.0:
        ru, rv = 1.0, 0.0
    else:
        ru, rv = yu / u, yv / u
    n0, n1, n2 = _unpick(axis, bs, bc * ru, bc * rv)
    out = max(best, 0.0)
    return best, n0, n1, n2, y0 - out * n0, y1 - out * n1, y2 - out * n2


@njit(cache=True)
def _to_local(F, x0, x1, x2):
    d0, d1, d2 = x0 - F[_C], x1 - F[_C + 1], x2 - F[_C + 2]
    return (d0 * F[_LI] + d1 * F[_LI + 3] + d2 * F[_LI + 6],
            d0 * F[_LI + 1] + d1 * F[_LI + 4] + d2 * F[_LI + 7],
            d0 * F[_LI + 2] + d1 * F[_LI + 5] + d2 * F[_LI + 8])


@njit(cache=True)
def _to_world(F, y0, y1, y2):
    return (y0 * F[_L] + y1 * F[_L + 3] + y2 * F[_L + 6] + F[_C],
            y0 * F[_L + 1] + y1 * F[_L + 4] + y2 * F[_L + 7] + F[_C + 1],
            y0 * F[_L + 2] + y1 * F[_L + 5] + y2 * F[_L + 8] + F[_C + 2])


@njit(cache=True)
def closest_point(F, axis, x0, x1, x2):
    """The world solid's point for world point x (the image of the local closest point),
    its outward normal there (a world direction, not unit) and the signed local distance:
    ``(q0, q1, q2, n0, n1, n2, g)``."""
    y0, y1, y2 = _to_local(F, x0, x1, x2)
    g, n0, n1, n2, q0, q1, q2 = local_closest(F, axis, y0, y1, y2)
    w0, w1, w2 = _to_world(F, q0, q1, q2)
    return (w0, w1, w2,
            n0 * F[_LI] + n1 * F[_LI + 1] + n2 * F[_LI + 2],
            n0 * F[_LI + 3] + n1 * F[_LI + 4] + n2 * F[_LI + 5],
            n0 * F[_LI + 6] + n1 * F[_LI + 7] + n2 * F[_LI + 8], g)


@njit(cache=True)
def support_point(F, axis, n0, n1, n2):
    """A point of the world solid maximising ``n . x``."""
    half = 0.5 * F[0]
    ma, mu, mv, perp, mn, bottom, top = _end_terms(F, axis, n0, n1, n2)
    if top >= bottom:
        z, disc, rnd = half, F[3], F[4]
    else:
        z, disc, rnd = -half, F[1], F[2]
    k = rnd / (mn if mn > 0 else 1.0)
    ru = mu / perp if perp > 0 else 0.0
    rv = mv / perp if perp > 0 else 0.0
    y0, y1, y2 = _unpick(axis, k * ma + z, k * mu + disc * ru, k * mv + disc * rv)
    return _to_world(F, y0, y1, y2)


@njit(cache=True)
def _local_g(F, axis, a0, a1, a2, b0, b1, b2, t):
    return local_closest(F, axis, a0 + t * (b0 - a0), a1 + t * (b1 - a1), a2 + t * (b2 - a2))[0]


@njit(cache=True)
def edge_minimum(F, axis, A, B):
    """The point p of the segment A -> B where the solid's local signed distance (convex
    along it) is smallest, by golden section: ``(p0, p1, p2, q0, q1, q2, n0, n1, n2,
    inside)`` with q the solid's point for p, its outward normal there and whether p lies
    in the solid."""
    a0, a1, a2 = _to_local(F, A[0], A[1], A[2])
    b0, b1, b2 = _to_local(F, B[0], B[1], B[2])
    lo, hi = 0.0, 1.0
    t1, t2 = hi - _PHI, lo + _PHI
    g1, g2 = _local_g(F, axis, a0, a1, a2, b0, b1, b2, t1), _local_g(F, axis, a0, a1, a2, b0, b1, b2, t2)
    for _ in range(SECTION_STEPS):
        if g1 <= g2:  # the minimum lies in [lo, t2]
            hi = t2
            t2n, t1n = t1, hi - _PHI * (hi - lo)
            g2, g1 = g1, _local_g(F, axis, a0, a1, a2, b0, b1, b2, t1n)
        else:
            lo = t1
            t2n, t1n = lo + _PHI * (hi - lo), t2
            g1, g2 = g2, _local_g(F, axis, a0, a1, a2, b0, b1, b2, t2n)
        t1, t2 = t1n, t2n
    t = 0.5 * (lo + hi)
    for end in (0.0, 1.0):  # the minimum may sit at an end (the bracket only nears it)
        if _local_g(F, axis, a0, a1, a2, b0, b1, b2, end) < _local_g(F, axis, a0, a1, a2, b0, b1, b2, t):
            t = end
    p0, p1, p2 = A[0] + t * (B[0] - A[0]), A[1] + t * (B[1] - A[1]), A[2] + t * (B[2] - A[2])
    q0, q1, q2, n0, n1, n2, g = closest_point(F, axis, p0, p1, p2)
    return p0, p1, p2, q0, q1, q2, n0, n1, n2, g <= 0.0


@njit(cache=True)
def _face_normal(P, w0, w1, w2):
    """The triangle's normal turned to the side of the direction w."""
    e0, e1, e2 = P[1, 0] - P[0, 0], P[1, 1] - P[0, 1], P[1, 2] - P[0, 2]
    d0, d1, d2 = P[2, 0] - P[0, 0], P[2, 1] - P[0, 1], P[2, 2] - P[0, 2]
    f0, f1, f2 = e1 * d2 - e2 * d1, e2 * d0 - e0 * d2, e0 * d1 - e1 * d0
    if f0 * w0 + f1 * w1 + f2 * w2 < 0:
        return -f0, -f1, -f2
    return f0, f1, f2


@njit(cache=True)
def _dist(a0, a1, a2, b0, b1, b2):
    d0, d1, d2 = a0 - b0, a1 - b1, a2 - b2
    return math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


@njit(cache=True)
def quick_directions(F, axis, P, out):
    """Cheap candidate directions into the rows of `out`; returns how many: from the
    solid's point nearest the primitive's centroid, the direction to the centroid and the
    solid's normal there; for a triangle also the face normal."""
    k = P.shape[0]
    c0, c1, c2 = P[0, 0], P[0, 1], P[0, 2]
    for j in range(1, k):
        c0, c1, c2 = c0 + P[j, 0], c1 + P[j, 1], c2 + P[j, 2]
    c0, c1, c2 = c0 / k, c1 / k, c2 / k
    q0, q1, q2, n0, n1, n2, _ = closest_point(F, axis, c0, c1, c2)
    out[0, 0], out[0, 1], out[0, 2] = c0 - q0, c1 - q1, c2 - q2
    out[1, 0], out[1, 1], out[1, 2] = n0, n1, n2
    if k == 3:
        out[2, 0], out[2, 1], out[2, 2] = _face_normal(P, n0, n1, n2)
        return 3
    return 2


@njit(cache=True)
def full_directions(F, axis, P, out):
    """Searched directions into the rows of `out` (`solids.full_directions`); returns
    ``(count, upper, touching)``."""
    k = P.shape[0]
    if k == 1:
        q0, q1, q2, n0, n1, n2, g = closest_point(F, axis, P[0, 0], P[0, 1], P[0, 2])
        out[0, 0], out[0, 1], out[0, 2] = n0, n1, n2
        out[1, 0], out[1, 1], out[1, 2] = P[0, 0] - q0, P[0, 1] - q1, P[0, 2] - q2
        return 2, _dist(P[0, 0], P[0, 1], P[0, 2], q0, q1, q2), g <= 0.0
    n_edges = 1 if k == 2 else 3
    upper, touching = np.inf, False
    s0 = s1 = s2 = 0.0
    for e in range(n_edges):
        p0, p1, p2, q0, q1, q2, n0, n1, n2, inside = edge_minimum(F, axis, P[e], P[(e + 1) % k])
        out[e, 0], out[e, 1], out[e, 2] = n0, n1, n2
        upper = min(upper, _dist(p0, p1, p2, q0, q1, q2))
        touching = touching or inside
        if e == 0:
            s0, s1, s2 = q0, q1, q2  # the first edge's nearest solid point
    if k == 2:
        return 1, upper, touching
    # the face normal, from the solid toward the face: the side whose supporting plane
    # leaves the larger gap (for a face cutting into the solid, the first edge's nearest
    # point lies in the face and the direction toward the centroid has no sign)
    f0, f1, f2 = _face_normal(P, (P[0, 0] + P[1, 0] + P[2, 0]) / 3.0 - s0, (P[0, 1] + P[1, 1] + P[2, 1]) / 3.0 - s1,
                              (P[0, 2] + P[1, 2] + P[2, 2]) / 3.0 - s2)
    if _plane_gap_t0(F, axis, P, -f0, -f1, -f2) > _plane_gap_t0(F, axis, P, f0, f1, f2):
        f0, f1, f2 = -f0, -f1, -f2
    out[3, 0], out[3, 1], out[3, 2] = f0, f1, f2
    s0, s1, s2 = support_point(F, axis, f0, f1, f2)  # the solid's point reaching farthest toward the face
    ff = f0 * f0 + f1 * f1 + f2 * f2
    w = ((P[0, 0] - s0) * f0 + (P[0, 1] - s1) * f1 + (P[0, 2] - s2) * f2) / (ff if ff > 0 else 1.0)
    o0, o1, o2 = s0 + w * f0, s1 + w * f1, s2 + w * f2  # the foot
    over = ff > 0
    for i in range(3):
        j = (i + 1) % 3
        e0, e1, e2 = P[j, 0] - P[i, 0], P[j, 1] - P[i, 1], P[j, 2] - P[i, 2]
        v0, v1, v2 = o0 - P[i, 0], o1 - P[i, 1], o2 - P[i, 2]
        over = over and (e1 * v2 - e2 * v1) * f0 + (e2 * v0 - e0 * v2) * f1 + (e0 * v1 - e1 * v0) * f2 >= 0
    if over:
        upper = min(upper, _dist(o0, o1, o2, s0, s1, s2))
        touching = touching or closest_point(F, axis, o0, o1, o2)[6] <= 0.0
    return 4, upper, touching


@njit(cache=True)
def _nonzero(n0, n1, n2):
    """n, or +z for a zero direction (a primitive touching the solid)."""
    if max(abs(n0), abs(n1), abs(n2)) > 0:
        return n0, n1, n2
    return 0.0, 0.0, 1.0


@njit(cache=True)
def plane_gap(P, n0, n1, n2, thickness, h, err_h):
    """``(d, err)``: ``d = min_k (n . P_k) - h_S(n)`` (``h``, ``err_h`` = `support`) and
    its rounding bound."""
    d, top = np.inf, 0.0
    for j in range(P.shape[0]):
        d = min(d, P[j, 0] * n0 + P[j, 1] * n1 + P[j, 2] * n2)
        top = max(top, abs(P[j, 0]), abs(P[j, 1]), abs(P[j, 2]))
    return d - h, err_h + REL * math.sqrt(n0 * n0 + n1 * n1 + n2 * n2) * (3.0 * top + thickness)


@njit(cache=True)
def _plane_gap_t0(F, axis, P, n0, n1, n2):
    """``min_k (n . P_k) - h_S(n)``, unbounded rounding: only to choose between directions."""
    return plane_gap(P, n0, n1, n2, 0.0, support(F, axis, n0, n1, n2)[0], 0.0)[0]


@njit(cache=True)
def _gather(x, S, i, P):
    for j in range(S.shape[1]):
        v = S[i, j]
        P[j, 0], P[j, 1], P[j, 2] = x[v, 0], x[v, 1], x[v, 2]


@njit(cache=True)
def _near(P0, P1, lo, hi):
    for a in range(3):
        mn, mx = np.inf, -np.inf
        for j in range(P0.shape[0]):
            mn, mx = min(mn, P0[j, a], P1[j, a]), max(mx, P0[j, a], P1[j, a])
        if not (mn <= hi[a] and mx >= lo[a]):
            return False
    return True


@njit(cache=True)
def _add_plane(state, F0, F1, static, axis, P0, P1, d, thickness, slack=0.0, ta=0.0, tb=1.0):
    """Fold the plane test of direction `d` (3,) into a primitive's `state` (`slack`: a
    further rounding bound of the positions, per unit of |n|, added to both ends').

    P0, P1 are the primitive at times `ta` and `tb` of the step (a piece of it); a moving
    solid is there the blend of its two frames, whose support is ``(1 - t) h_0 + t h_1``
    (exact for the whole step, t = 0 and 1)."""
    n0, n1, n2 = _nonzero(d[0], d[1], d[2])
    h0, eh0 = support(F0, axis, n0, n1, n2)
    if static:
        h1, eh1 = h0, eh0
    else:
        h1, eh1 = support(F1, axis, n0, n1, n2)
        if ta != 0.0 or tb != 1.0:
            h0, eh0, h1, eh1 = (*_blend(h0, eh0, h1, eh1, ta), *_blend(h0, eh0, h1, eh1, tb))
    d0, e0 = plane_gap(P0, n0, n1, n2, thickness, h0, eh0)
    d1, e1 = plane_gap(P1, n0, n1, n2, thickness, h1, eh1)
    nn = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    e0, e1 = e0 + slack * nn, e1 + slack * nn
    hn = thickness * nn
    c0, c1 = d0 - hn > e0, d1 - hn > e1
    f0, f1 = d0 > e0, d1 > e1
    a, b = d0 - e0, d1 - e1
    lb = (a if a <= b or a != a else b) / nn  # NaN-propagating, as np.minimum
    if c0 and c1:
        state[0] = 1.0  # through: some plane keeps it >= thickness at both ends
    if f0 and f1:
        state[1] = 1.0  # free_both: ... strictly outside at both ends
    if c0:
        state[2] = 1.0  # clear0: ... >= thickness at the start
    if f0:
        state[3] = 1.0  # free0: ... strictly outside at the start
    if np.isfinite(lb) and lb > state[4]:
        state[4] = lb  # the best lower bound over the path
    g0 = a / nn
    if np.isfinite(g0) and g0 > state[5]:  # the best start gap, and along it:
        state[5] = g0
        state[6] = 1.0 if d1 >= d0 else 0.0  # not deeper at the end (the rule of a pre-existing contact)


@njit(cache=True)
def _blend(h0, eh0, h1, eh1, t):
    """The support ``(1 - t) h0 + t h1`` of a moving solid at a dyadic time t (1 - t exact)
    and its rounding bound: the two ends' bounds blended, plus the two products' and the
    sum's rounding (a unit in the last place of each term, taken four times over)."""
    a, b = (1.0 - t) * h0, t * h1
    return a + b, (1.0 - t) * eh0 + t * eh1 + 4.0 * _EPS * (abs(a) + abs(b)) + 1e-300


#: Bisections of a step's path, at most, for a primitive that no single plane keeps clear
#: over the whole step (2^6 = 64 pieces).
PIECE_DEPTH = 6
_EPS = 2.0 ** -52


@njit(cache=True)
def _at(P0, P1, t, out):
    """The vertices at time t of the straight path: ``(1 - t) P0 + t P1`` (exact at t = 0
    and 1); returns the largest coordinate magnitude, for the rounding bound."""
    top = 0.0
    for j in range(P0.shape[0]):
        for a in range(3):
            out[j, a] = (1.0 - t) * P0[j, a] + t * P1[j, a]
            top = max(top, abs(P0[j, a]), abs(P1[j, a]))
    return top


@njit(cache=True)
def _pieces_through(F0, F1, static, axis, P0, P1, Pa, Pb, dirs, state, thickness):
    """Whether the path P0 -> P1 splits into pieces [ta, tb] (by bisection, at most
    `PIECE_DEPTH` deep) each kept at least `thickness` from the solid by one plane (a
    quick direction at the piece's start) at both of its ends; and the smallest lower
    bound of the distance over the pieces. `state` is scratch for `_add_plane` (a piece's
    own test).

    A piece is a straight-line motion too, and a moving solid's support is linear in t
    over a piece as over the step (`_add_plane`), so the ends decide it as they decide
    the whole step: the gap to one plane is a minimum of linear functions of t. Its ends
    are computed points: the bound adds their rounding (a few units in the last place of
    the coordinates) to each plane gap's. A primitive moving far along a curved solid
    passes this where one plane for the whole step cannot (a sheet sliding over a ball by
    a fraction of its faces' size). The quick directions of a piece are taken against the
    solid's nearer frame (any direction is sound; they are only guesses).
    """
    stack = np.empty((PIECE_DEPTH + 2, 3))
    stack[0, 0], stack[0, 1], stack[0, 2] = 0.0, 1.0, 0.0
    n_stack, lb = 1, np.inf
    while n_stack:
        n_stack -= 1
        ta, tb, depth = stack[n_stack, 0], stack[n_stack, 1], stack[n_stack, 2]
        slack = 4.0 * _EPS * max(_at(P0, P1, ta, Pa), _at(P0, P1, tb, Pb))  # the computed ends
        state[:] = 0.0
        state[4] = state[5] = -np.inf
        near = F0 if static or ta < 0.5 else F1
        for r in range(quick_directions(near, axis, Pa, dirs)):
            _add_plane(state, F0, F1, static, axis, Pa, Pb, dirs[r], thickness, slack, ta, tb)
        if state[0] > 0.0:
            lb = min(lb, state[4])
        elif depth < PIECE_DEPTH:
            tm = 0.5 * (ta + tb)  # dyadic: exact, and so are 1 - t and the pieces' shared ends
            stack[n_stack, 0], stack[n_stack, 1], stack[n_stack, 2] = tm, tb, depth + 1
            stack[n_stack + 1, 0], stack[n_stack + 1, 1], stack[n_stack + 1, 2] = ta, tm, depth + 1
            n_stack += 2
        else:
            return False, -np.inf
    return True, lb


#: Primitives per chunk of the batch kernels (each chunk allocates its scratch once).
_CHUNK = 256


def _verdict_py(x_t0, x_t1, S, F0, F1, static, axis, thickness, pre_existing, lo, hi, flags, lbs):
    n, k = S.shape[0], S.shape[1]
    for ch in prange((n + _CHUNK - 1) // _CHUNK):
        P0, P1, Pa, Pb = np.empty((k, 3)), np.empty((k, 3)), np.empty((k, 3)), np.empty((k, 3))
        dirs, state, piece = np.empty((4, 3)), np.empty(7), np.empty(7)
        for i in range(ch * _CHUNK, min(n, (ch + 1) * _CHUNK)):
            flags[i], lbs[i] = 0, np.inf
            _gather(x_t0, S, i, P0)
            _gather(x_t1, S, i, P1)
            if not _near(P0, P1, lo, hi):
                continue
            moved = not static
            for j in range(k):
                for a in range(3):
                    moved = moved or P0[j, a] != P1[j, a]
            state[:] = 0.0
            state[4] = state[5] = -np.inf
            for r in range(quick_directions(F0, axis, P0, dirs)):
                _add_plane(state, F0, F1, static, axis, P0, P1, dirs[r], thickness)
            within = touching = False
            if state[0] == 0.0 and (moved or not pre_existing):
                m, upper, touching = full_directions(F0, axis, P0, dirs)
                for r in range(m):
                    _add_plane(state, F0, F1, static, axis, P0, P1, dirs[r], thickness)
                within = upper < thickness
                if state[0] == 0.0 and state[2] > 0.0 and moved:
                    ok, lb = _pieces_through(F0, F1, static, axis, P0, P1, Pa, Pb, dirs, piece, thickness)
                    if ok:
                        state[0], state[4] = 1.0, max(state[4], lb)
            through, free_both, clear0, free0 = state[0] > 0, state[1] > 0, state[2] > 0, state[3] > 0
            f = 0
            if not pre_existing:
                if not clear0:
                    f |= START
                elif not through:
                    f |= PATH
            else:
                if not free0:
                    f |= PRE
                if moved and not through and not (within and free_both) and not (touching and state[6] > 0):
                    f |= PATH
            flags[i] = f
            if f == 0 and through:
                lbs[i] = max(0.0, state[4])


#: Per primitive: verdict flags (`START`, `PATH`, `PRE`) and, for a passing primitive that
#: a plane keeps clear, the lower bound of its distance over the path (else inf).
verdict_kernel = parallel_kernel(_verdict_py, "_solid_verdict")


def _separation_py(x, S, F, axis, radius, lo, hi, lbs):
    n, k = S.shape[0], S.shape[1]
    for ch in prange((n + _CHUNK - 1) // _CHUNK):
        P, dirs = np.empty((k, 3)), np.empty((4, 3))
        for i in range(ch * _CHUNK, min(n, (ch + 1) * _CHUNK)):
            lbs[i] = radius
            _gather(x, S, i, P)
            if not _near(P, P, lo, hi):
                continue
            best = -np.inf
            for r in range(quick_directions(F, axis, P, dirs)):
                n0, n1, n2 = _nonzero(dirs[r, 0], dirs[r, 1], dirs[r, 2])
                h, eh = support(F, axis, n0, n1, n2)
                g, err = plane_gap(P, n0, n1, n2, 0.0, h, eh)
                v = (g - err) / math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
                if v > best:  # NaN never wins, as np.fmax
                    best = v
            if best == -np.inf:
                best = 0.0
            lbs[i] = min(max(best, 0.0), radius)


#: Per primitive: a lower bound of its distance to the solid from `quick_directions`,
#: clipped to [0, radius] (radius for primitives whose box is beyond it).
separation_kernel = parallel_kernel(_separation_py, "_solid_separation")


@njit(cache=True)
def fold_into_vertices(d, S, lbs):
    """``d[v] = min(d[v], lbs[i])`` for every vertex v of primitive i (serial: one order)."""
    for i in range(S.shape[0]):
        for j in range(S.shape[1]):
            v = S[i, j]
            if lbs[i] < d[v]:
                d[v] = lbs[i]


@njit(cache=True)
def support_rows(F, axis, n):
    """`support` per row of `n` (K, 3): ``(h (K,), err (K,))``."""
    h, err = np.empty(len(n)), np.empty(len(n))
    for i in range(len(n)):
        h[i], err[i] = support(F, axis, n[i, 0], n[i, 1], n[i, 2])
    return h, err


@njit(cache=True)
def local_closest_rows(F, axis, y):
    """`local_closest` per row of `y` (K, 3): ``(g (K,), normal (K, 3), q (K, 3))``."""
    g, normal, q = np.empty(len(y)), np.empty((len(y), 3)), np.empty((len(y), 3))
    for i in range(len(y)):
        g[i], normal[i, 0], normal[i, 1], normal[i, 2], q[i, 0], q[i, 1], q[i, 2] = local_closest(
            F, axis, y[i, 0], y[i, 1], y[i, 2])
    return g, normal, q
