"""Analytic solids (`penfree.sequence.AnalyticShape`) against a step's straight path.

An analytic collider is checked against its containing mesh like any mesh obstacle,
and against its exact solid here. The mesh alone misses a primitive that starts
between the shape and its mesh: no mesh face lies between them, so nothing stops
it from entering the shape.

**The test.** Each solid is convex, with an exact support function (its local form
is the convex hull of two rounded discs on an axis, `penfree.sequence.AnalyticShape`):

    h_S(n) = n . c + max_i( z_i m_a + disc_i |m_perp| + round_i |m| ),   m = L n,

for any direction n (not necessarily unit), where the world solid is
``local @ L + c``. The plane ``n . x = h_S(n)`` supports S, so a point x with
``n . x - h_S(n) >= d |n|`` is at least d from S. For each primitive near the
solid, this module picks one direction n per primitive (from its closest point to
the solid at the start) and checks the primitive's
vertices at both ends of the step against that one plane:

- every point of the primitive along the path is a convex combination of its
  vertices' end positions, and ``n . x - h_S(n)`` is affine in x, so the smallest
  value over the whole swept primitive is at a vertex at t = 0 or t = 1;
- a solid moving between frames (verify's kinematic obstacles) is taken as the
  Minkowski interpolation ``(1 - t) S0 + t S1`` (for a translation, the translated
  solid), whose support is ``(1 - t) h_S0 + t h_S1``: affine in t, so the ends
  decide again. Deform holds obstacles at the step's frame (S0 = S1).

The direction only decides how permissive the test is, never whether it is sound:
every plane used is a supporting plane, evaluated with a rigorous rounding bound
(ties count as contact). It refuses some paths that clear a curved solid (a
primitive that ends past its own tangent plane) and never accepts one that
enters it. Primitives whose swept box stays farther than the thickness from the
solid's box are not tested (the boxes' distance bounds the distance).

Readings, as for half-spaces (`penfree.core.contact.obstacles.half_space_verdict`):
raw (a recording is judged: a primitive within the thickness at the start is a
start violation) and deform-result (``pre_existing``: a primitive within the
thickness at the start only has to stay outside the solid; one that starts
touching or inside it is pre-existing and must not go deeper).
"""

from __future__ import annotations

import numpy as np

from ...errors import InputError

#: Relative slack on every rounded quantity of the plane test: a few hundred units
#: in the last place of the terms involved (a handful of operations each).
_REL = 1e-13


class SolidFrames:
    """A solid at the two ends of a step, the form `verify_step` takes.

    Parameters
    ----------
    axis : int
        The local axis of revolution (0, 1, 2).
    at_t0, at_t1 : tuple
        ``(profile (5,), L (3, 3), c (3,))`` at each end
        (`penfree.sequence.AnalyticShape.at`).
    """

    def __init__(self, axis, at_t0, at_t1):
        self.axis = int(axis)
        self.ends = tuple(_frame(*f, where=f"solid at t{k}") for k, f in enumerate((at_t0, at_t1)))
        self.static = all(np.array_equal(a, b) for a, b in zip(self.ends[0][:3], self.ends[1][:3]))


def _frame(profile, L, c, where):
    p = np.asarray(profile, dtype=np.float64).reshape(5)
    L = np.asarray(L, dtype=np.float64).reshape(3, 3)
    c = np.asarray(c, dtype=np.float64).reshape(3)
    if not (np.isfinite(p).all() and np.isfinite(L).all() and np.isfinite(c).all()) or (p < 0).any():
        raise InputError(f"{where}: profile must be finite and >= 0 and the transform finite")
    if not abs(np.linalg.det(L)) > 0:
        raise InputError(f"{where}: the transform's linear part must be nonsingular")
    return p, L, c, np.linalg.inv(L)


def _support(frame, axis, n):
    """``h_S(n)`` per row of `n` (K, 3) and a bound on its rounding error."""
    p, L, c, _ = frame
    half, a0, b0, a1, b1 = 0.5 * p[0], p[1], p[2], p[3], p[4]
    m = n @ L.T  # m = L n per row
    ma = m[:, axis]
    perp = np.hypot(m[:, (axis + 1) % 3], m[:, (axis + 2) % 3])
    mn = np.sqrt(np.einsum("ij,ij->i", m, m))
    h = n @ c + np.maximum(-half * ma + a0 * perp + b0 * mn, half * ma + a1 * perp + b1 * mn)
    nn = np.sqrt(np.einsum("ij,ij->i", n, n))
    scale = nn * (np.linalg.norm(c) + np.linalg.norm(L) * (half + max(a0, a1) + max(b0, b1)))
    return h, _REL * scale + 1e-300


def _local_closest(frame, axis, y):
    """The signed distance of local points `y` (K, 3) to the local solid, its outward
    unit normal there, and the closest point (`y` itself for points inside)."""
    p = frame[0]
    half = 0.5 * p[0]
    z_i, a_i, b_i = (-half, half), (p[1], p[3]), (p[2], p[4])
    u_ax, v_ax = (axis + 1) % 3, (axis + 2) % 3
    z = y[:, axis]
    u = np.hypot(y[:, u_ax], y[:, v_ax])
    # the 2D dual: max over theta in [-pi/2, pi/2] of min_i (cos(u - a_i) + sin(z - z_i) - b_i)
    cand = [np.full_like(u, -0.5 * np.pi), np.full_like(u, 0.5 * np.pi)]
    for zi, ai in zip(z_i, a_i):
        cand.append(np.clip(np.arctan2(z - zi, u - ai), -0.5 * np.pi, 0.5 * np.pi))
    A, B, C = a_i[1] - a_i[0], z_i[1] - z_i[0], b_i[0] - b_i[1]
    R = np.hypot(A, B)
    if R > 0 and abs(C) <= R:  # where the two ends' supports are equal
        psi, delta = np.arctan2(B, A), np.arccos(np.clip(C / R, -1.0, 1.0))
        for th in (psi + delta, psi - delta):
            th = (th + np.pi) % (2.0 * np.pi) - np.pi
            if -0.5 * np.pi <= th <= 0.5 * np.pi:
                cand.append(np.full_like(u, th))
    th = np.stack(cand, axis=1)
    cos, sin = np.cos(th), np.sin(th)
    g = np.minimum(cos * (u[:, None] - a_i[0]) + sin * (z[:, None] - z_i[0]) - b_i[0],
                   cos * (u[:, None] - a_i[1]) + sin * (z[:, None] - z_i[1]) - b_i[1])
    k = np.argmax(g, axis=1)
    rows = np.arange(len(y))
    g, cos, sin = g[rows, k], cos[rows, k], sin[rows, k]
    radial = np.zeros_like(y)
    on_axis = u <= 0.0
    safe = np.where(on_axis, 1.0, u)
    radial[:, u_ax] = np.where(on_axis, 1.0, y[:, u_ax] / safe)
    radial[:, v_ax] = np.where(on_axis, 0.0, y[:, v_ax] / safe)
    normal = cos[:, None] * radial
    normal[:, axis] += sin
    q = y - np.maximum(g, 0.0)[:, None] * normal
    return g, normal, q


def closest_points(frame, axis, x):
    """Points of the world solid near world points `x` (K, 3): the image of the local
    closest point (the closest point itself under a similarity transform), the solid's
    outward normal there (a world direction, not unit) and the signed local distance."""
    _, L, c, Linv = frame
    g, normal, q = _local_closest(frame, axis, (x - c) @ Linv)
    return q @ L + c, normal @ Linv.T, g


def _face_normals(P, away):
    """Triangles' normals (K, 3) turned to the side of `away` (K, 3); zero rows otherwise."""
    f = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    return np.where((np.einsum("ij,ij->i", f, away) < 0)[:, None], -f, f)


def quick_directions(frame, axis, P):
    """Cheap candidate directions per primitive (K, k, 3): from the solid's point nearest
    the primitive's centroid, the direction to the centroid and the solid's normal there;
    for triangles also the face normal. Enough for most primitives that are clear."""
    centre = P.mean(axis=1)
    q, normal, _ = closest_points(frame, axis, centre)
    out = [centre - q, normal]
    if P.shape[1] == 3:
        out.append(_face_normals(P, normal))
    return out


def _support_points(frame, axis, n):
    """A point of the world solid maximising ``n . x`` per row of `n` (K, 3)."""
    p, L, c, _ = frame
    half = 0.5 * p[0]
    m = n @ L.T
    u_ax, v_ax = (axis + 1) % 3, (axis + 2) % 3
    perp = np.hypot(m[:, u_ax], m[:, v_ax])
    mn = np.sqrt(np.einsum("ij,ij->i", m, m))
    top = half * m[:, axis] + p[3] * perp + p[4] * mn >= -half * m[:, axis] + p[1] * perp + p[2] * mn
    z, disc, rnd = np.where(top, half, -half), np.where(top, p[3], p[1]), np.where(top, p[4], p[2])
    y = (rnd / np.where(mn > 0, mn, 1.0))[:, None] * m
    y[:, axis] += z
    radial = np.zeros_like(m)
    ok = perp > 0
    radial[:, u_ax] = np.where(ok, m[:, u_ax] / np.where(ok, perp, 1.0), 0.0)
    radial[:, v_ax] = np.where(ok, m[:, v_ax] / np.where(ok, perp, 1.0), 0.0)
    return (y + disc[:, None] * radial) @ L + c


#: Golden-section steps along an edge: the bracket shrinks to 0.618^40 ~ 4e-9 of the edge.
_SECTION_STEPS = 40
_PHI = 0.5 * (5.0 ** 0.5 - 1.0)


def _edge_minimum(frame, axis, A, B):
    """The point of each segment A -> B (K, 3) where the solid's local signed distance (a
    convex function along it) is smallest, by golden section: ``(p, q, normal, inside)``
    with q the solid's point for p, its outward normal there (a world direction), and
    whether p lies in the solid (a proof of contact)."""
    _, _, c, Linv = frame
    yA, yB = (A - c) @ Linv, (B - c) @ Linv
    lo, hi = np.zeros(len(A)), np.ones(len(A))

    def g(t):
        return _local_closest(frame, axis, yA + t[:, None] * (yB - yA))[0]

    t1, t2 = hi - _PHI, lo + _PHI
    g1, g2 = g(t1), g(t2)
    for _ in range(_SECTION_STEPS):
        left = g1 <= g2  # the minimum lies in [lo, t2]
        hi = np.where(left, t2, hi)
        lo = np.where(left, lo, t1)
        t2n = np.where(left, t1, lo + _PHI * (hi - lo))
        t1n = np.where(left, hi - _PHI * (hi - lo), t2)
        known = np.where(left, g1, g2)
        fresh = g(np.where(left, t1n, t2n))
        g1, g2 = np.where(left, fresh, known), np.where(left, known, fresh)
        t1, t2 = t1n, t2n
    t = 0.5 * (lo + hi)
    for end in (0.0, 1.0):  # the minimum may sit at an end (the bracket only nears it)
        at_end = np.full(len(A), end)
        better = g(at_end) < g(t)
        t = np.where(better, at_end, t)
    p = A + t[:, None] * (B - A)
    q, normal, g = closest_points(frame, axis, p)
    return p, q, normal, g <= 0.0


def full_directions(frame, axis, P):
    """Candidate directions per primitive (K, k, 3) that are exact up to the search's
    precision: the solid's normal at the point of each edge nearest to it (golden
    section: the local signed distance is convex along an edge), and for triangles the
    face normal (exact when the closest point lies inside the face).

    Returns
    -------
    directions : list of (K, 3)
    upper : (K,)
        An upper bound of each primitive's distance: |p - q| of the edges' pairs, and for
        a triangle the solid's point nearest its plane against its foot there, when the
        foot lies inside the triangle.
    touching : (K,) bool
        A proof that the primitive touches or enters the solid: a point of it (on an
        edge, or that foot) lies in the solid.
    """
    k = P.shape[1]
    if k == 1:
        q, normal, g = closest_points(frame, axis, P[:, 0])
        return [normal, P[:, 0] - q], np.linalg.norm(P[:, 0] - q, axis=1), g <= 0.0
    out, upper, touching, nearest = [], np.full(len(P), np.inf), np.zeros(len(P), bool), None
    for i, j in ((0, 1),) if k == 2 else ((0, 1), (1, 2), (2, 0)):
        p, q, normal, inside = _edge_minimum(frame, axis, P[:, i], P[:, j])
        out.append(normal)
        upper = np.minimum(upper, np.linalg.norm(p - q, axis=1))
        touching |= inside
        nearest = q if nearest is None else nearest
    if k == 3:
        f = _face_normals(P, P.mean(axis=1) - nearest)  # from the solid toward the face
        out.append(f)
        s = _support_points(frame, axis, f)  # the solid's point reaching farthest toward the face
        ff = np.einsum("ij,ij->i", f, f)
        foot = s + (np.einsum("ij,ij->i", P[:, 0] - s, f) / np.where(ff > 0, ff, 1.0))[:, None] * f
        over = ff > 0
        for i in range(3):
            e, w = P[:, (i + 1) % 3] - P[:, i], foot - P[:, i]
            over &= np.einsum("ij,ij->i", np.cross(e, w), f) >= 0
        upper = np.where(over, np.minimum(upper, np.linalg.norm(foot - s, axis=1)), upper)
        _, _, g = closest_points(frame, axis, foot)
        touching |= over & (g <= 0.0)
    return out, upper, touching


def _nonzero(n):
    """Directions `n` (K, 3) with zero rows replaced by +z (a primitive touching the solid,
    where any plane shows a gap <= 0)."""
    return np.where((np.abs(n).max(axis=1) > 0)[:, None], n, (0.0, 0.0, 1.0))


def _plane_gaps(frame, axis, P, n, thickness, support=None):
    """``(d, err, |n|)``: ``d = min_k (n . P_k) - h_S(n)`` per primitive and its rounding bound
    (`support`: ``_support(frame, axis, n)`` when known)."""
    nn = np.sqrt(np.einsum("ij,ij->i", n, n))
    h, err = _support(frame, axis, n) if support is None else support
    d = np.einsum("ikj,ij->ik", P, n).min(axis=1) - h
    return d, err + _REL * nn * (3.0 * np.abs(P).max(axis=(1, 2)) + thickness), nn


def _box(frame, axis):
    """The world solid's axis-aligned box ``(lo (3,), hi (3,))``, rigorous."""
    e = np.vstack([np.eye(3), -np.eye(3)])
    h, err = _support(frame, axis, e)
    return -(h[3:] + err[3:]), h[:3] + err[:3]


class _Planes:
    """The best verdicts over the candidate directions tried so far, per primitive."""

    def __init__(self, K):
        self.through = np.zeros(K, bool)  # some plane keeps it >= thickness at both ends
        self.free_both = np.zeros(K, bool)  # some plane keeps it strictly outside at both ends
        self.clear0 = np.zeros(K, bool)  # some plane proves it >= thickness at the start
        self.free0 = np.zeros(K, bool)  # ... strictly outside at the start
        self.lb = np.full(K, -np.inf)  # the best lower bound over the path (for `sep`)
        self.best0 = np.full(K, -np.inf)  # the best start gap (per |n|) so far, and along that
        self.not_deeper = np.zeros(K, bool)  # direction: no closer to (deeper into) the solid at the end

    def add(self, rows, solid, P0, P1, n, thickness):
        n = _nonzero(n)
        with np.errstate(invalid="ignore", over="ignore"):
            sup = _support(solid.ends[0], solid.axis, n)
            d0, e0, nn = _plane_gaps(solid.ends[0], solid.axis, P0, n, thickness, sup)
            d1, e1, _ = _plane_gaps(solid.ends[1], solid.axis, P1, n, thickness, sup if solid.static else None)
            hn = thickness * nn
            c0, c1 = d0 - hn > e0, d1 - hn > e1
            f0, f1 = d0 > e0, d1 > e1
            lb = np.minimum(d0 - e0, d1 - e1) / nn
        self.through[rows] |= c0 & c1
        self.free_both[rows] |= f0 & f1
        self.clear0[rows] |= c0
        self.free0[rows] |= f0
        self.lb[rows] = np.fmax(self.lb[rows], np.where(np.isfinite(lb), lb, -np.inf))
        with np.errstate(invalid="ignore", over="ignore"):
            g0 = (d0 - e0) / nn
            kept = d1 >= d0  # up to their rounding: the rule of a pre-existing contact, not the guarantee
        better = np.isfinite(g0) & (g0 > self.best0[rows])
        self.best0[rows[better]] = g0[better]
        self.not_deeper[rows[better]] = kept[better]


def solid_verdict(x_t0, x_t1, simplices, solid: SolidFrames, thickness, pre_existing=False):
    """Primitives whose straight path comes within `thickness` of an analytic solid.

    Parameters
    ----------
    x_t0, x_t1 : (N, 3) float64
    simplices : list of (K, k) int64
        The scene's primitives: faces (k = 3), edges (k = 2), lone vertices (k = 1).
    solid : SolidFrames
    thickness : float
    pre_existing : bool
        The deform-result reading (module docstring).

    Returns
    -------
    verdicts : list of ``(start, path, pre)`` per entry of `simplices`
        Row indices into it: start violations (empty with `pre_existing`), path
        violations, pre-existing contacts (only with `pre_existing`).
    sep : float
        A lower bound of the distance to the solid over the path of the tested
        primitives that are not listed (inf if none).

    Notes
    -----
    A primitive passes when one supporting plane keeps it at least `thickness` from
    the solid at both ends. With `pre_existing`, a primitive that does not move
    (against a solid that does not) always passes, so the step ``x_def = x`` does;
    one that provably starts within the thickness (a point of it and a point of the
    solid closer than that) only has to stay strictly outside; one that provably
    starts touching or inside (a point of it in the solid: pre-existing) must not go
    deeper: along the direction that shows it least deep, its vertices' smallest gap
    to the supporting plane must not shrink (for a half-space, the rule of
    `half_space_verdict`); every other moving primitive has to pass, also one that
    no plane proves outside and no point proves touching.
    Directions are tried in two rounds: cheap ones for every primitive near the
    solid (`quick_directions`), then the searched ones (`full_directions`) for the
    primitives still undecided.
    """
    lo = np.minimum(*(_box(f, solid.axis)[0] for f in solid.ends))
    hi = np.maximum(*(_box(f, solid.axis)[1] for f in solid.ends))
    reach = thickness * (1.0 + 1e-12) + 1e-14 * float(max(np.abs(lo).max(), np.abs(hi).max()))
    lo, hi = lo - reach, hi + reach
    none = np.zeros(0, np.int64)
    frame0 = solid.ends[0]
    out, sep = [], np.inf
    for S in simplices:
        S = np.asarray(S, dtype=np.int64)
        if not len(S):
            out.append((none, none, none))
            continue
        P0, P1 = x_t0[S], x_t1[S]
        near = ((np.minimum(P0.min(axis=1), P1.min(axis=1)) <= hi)
                & (np.maximum(P0.max(axis=1), P1.max(axis=1)) >= lo)).all(axis=1)
        idx = np.flatnonzero(near)
        if not len(idx):
            out.append((none, none, none))
            continue
        P0, P1 = P0[idx], P1[idx]
        K = len(idx)
        moved = (P0 != P1).any(axis=(1, 2)) | (not solid.static)
        planes = _Planes(K)
        every = np.arange(K)
        for n in quick_directions(frame0, solid.axis, P0):
            planes.add(every, solid, P0, P1, n, thickness)
        # undecided: moving without a plane through (raw: also a start not proved clear)
        todo = np.flatnonzero(~planes.through & (moved if pre_existing else True))
        within, touching = np.zeros(K, bool), np.zeros(K, bool)
        if len(todo):
            dirs, upper, touch = full_directions(frame0, solid.axis, P0[todo])
            for n in dirs:
                planes.add(todo, solid, P0[todo], P1[todo], n, thickness)
            within[todo], touching[todo] = upper < thickness, touch
        if not pre_existing:
            start = ~planes.clear0
            path = ~planes.through & ~start
            pre = np.zeros(K, bool)
        else:
            start = np.zeros(K, bool)
            pre = ~planes.free0
            path = moved & ~planes.through & ~(within & planes.free_both) & ~(touching & planes.not_deeper)
        listed = start | path | pre
        if (~listed & planes.through).any():
            sep = min(sep, max(0.0, float(planes.lb[~listed & planes.through].min())))
        out.append((idx[start], idx[path], idx[pre]))
    return out, sep


def solid_separation(x, E, F, shape, radius, s=0):
    """Per-vertex lower bounds of the distance to an analytic solid at frame `s`, capped
    at `radius`: each vertex's own distance, and each edge's and face's folded into its
    vertices (the solid's side of the OGC terms: vertex - face, face - vertex, edge - edge).

    Parameters
    ----------
    x : (N, 3) float64
    E : (M, 2) int64, F : (K, 3) int64
        Every scene edge and face. An edge of a face is covered by the face (its distance
        is at least the face's, which is folded into the same vertices), so with faces
        only the edges of no face are measured.
    shape : `penfree.sequence.AnalyticShape`
    radius : float

    Returns
    -------
    (N,) float64
        From one supporting plane per primitive (`quick_directions`): exact for a vertex
        under a similarity transform, within the curvature of the solid across a primitive
        otherwise; 0 for a primitive touching or inside the solid.
    """
    frame = _frame(*shape.at(s), where=f"shape at frame {s}")
    axis = shape.axis
    lo, hi = _box(frame, axis)
    lo, hi = lo - radius, hi + radius
    d = np.full(len(x), float(radius))
    if len(F) and len(E):
        E = _edges_of_no_face(E, F)
    for S in (np.arange(len(x), dtype=np.int64)[:, None], E, F):
        if not len(S):
            continue
        P = x[S]
        idx = np.flatnonzero(((P.min(axis=1) <= hi) & (P.max(axis=1) >= lo)).all(axis=1))
        if not len(idx):
            continue
        P = P[idx]
        best = np.full(len(idx), -np.inf)
        for n in quick_directions(frame, axis, P):
            n = _nonzero(n)
            with np.errstate(invalid="ignore", over="ignore"):
                g, err, nn = _plane_gaps(frame, axis, P, n, 0.0)
                best = np.fmax(best, (g - err) / nn)
        lb = np.clip(np.nan_to_num(best, nan=0.0, neginf=0.0), 0.0, radius)
        for j in range(S.shape[1]):
            np.minimum.at(d, S[idx, j], lb)
    return d


_NO_FACE_MEMO: list = []  # [(E, F, result)]: the topology of the last scene (the same arrays every step)


def _edges_of_no_face(E, F):
    """The rows of `E` that are no edge of a face of `F` (remembered for the same arrays)."""
    for e, f, out in _NO_FACE_MEMO:
        if e is E and f is F:
            return out
    n = int(max(E.max(), F.max())) + 1
    key = lambda a, b: np.minimum(a, b) * n + np.maximum(a, b)  # noqa: E731
    face_keys = np.concatenate([key(F[:, i], F[:, (i + 1) % 3]) for i in range(3)])
    out = E[~np.isin(key(E[:, 0], E[:, 1]), face_keys)]
    _NO_FACE_MEMO[:] = [(E, F, out)]
    return out
