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
(ties count as contact). A primitive clear at the start that no single plane keeps
clear over the whole step is tried again on the step bisected (up to
`solid_kernels.PIECE_DEPTH` levels: 64 pieces, each a straight-line motion with its
own plane at its start, against the solid of the piece's ends: for a moving solid, the
interpolation above at the piece's times), so a sheet sliding over a ball passes where
one plane for the whole step cannot. It still refuses some paths that clear a curved solid and
never accepts one that enters it. Primitives whose swept box stays farther than the
thickness from the solid's box are not tested (the boxes' distance bounds the
distance).

The arithmetic runs in Numba, one primitive at a time (`penfree.core.contact.solid_kernels`);
this module validates the solids and reads the verdicts.

Readings, as for half-spaces (`penfree.core.contact.obstacles.half_space_verdict`):
raw (a recording is judged: a primitive within the thickness at the start is a
start violation) and deform-result (``pre_existing``: a primitive within the
thickness at the start only has to stay outside the solid; one that starts
touching or inside it is pre-existing and must not go deeper).
"""

from __future__ import annotations

import numpy as np

from ...errors import InputError
from . import solid_kernels as _k


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
    """``(profile, L, c, L^-1, packed)`` of one solid, validated (`packed`: the kernels' row)."""
    p = np.asarray(profile, dtype=np.float64).reshape(5)
    L = np.asarray(L, dtype=np.float64).reshape(3, 3)
    c = np.asarray(c, dtype=np.float64).reshape(3)
    if not (np.isfinite(p).all() and np.isfinite(L).all() and np.isfinite(c).all()) or (p < 0).any():
        raise InputError(f"{where}: profile must be finite and >= 0 and the transform finite")
    if not abs(np.linalg.det(L)) > 0:
        raise InputError(f"{where}: the transform's linear part must be nonsingular")
    Linv = np.linalg.inv(L)
    return p, L, c, Linv, _k.pack_frame(p, L, c, Linv)


def _support(frame, axis, n):
    """``h_S(n)`` per row of `n` (K, 3) and a bound on its rounding error:

        h_S(n) = n . c + max_i( z_i m_a + disc_i |m_perp| + round_i |m| ),   m = L n.
    """
    return _k.support_rows(frame[4], int(axis), np.ascontiguousarray(n, dtype=np.float64))


def _local_closest(frame, axis, y):
    """The signed distance of local points `y` (K, 3) to the local solid, its outward
    unit normal there, and the closest point (`y` itself for points inside)."""
    return _k.local_closest_rows(frame[4], int(axis), np.ascontiguousarray(y, dtype=np.float64))


def full_directions(frame, axis, P):
    """Candidate directions per primitive that are exact up to the search's precision:
    the solid's normal at the point of each edge nearest to it (golden section: the local
    signed distance is convex along an edge), and for triangles the face normal (exact
    when the closest point lies inside the face; turned to the side whose supporting
    plane leaves the larger gap). For a lone vertex: the normal at its
    closest point and the direction to it.

    Parameters
    ----------
    P : (K, k, 3) float64
        The primitives' vertices (k = 1, 2, 3).

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
    P = np.ascontiguousarray(P, dtype=np.float64)
    out = np.empty((len(P), 4, 3))
    upper, touching = np.empty(len(P)), np.zeros(len(P), bool)
    m = 0
    for i in range(len(P)):
        m, upper[i], touching[i] = _k.full_directions(frame[4], int(axis), P[i], out[i])
    return [out[:, j] for j in range(m)], upper, touching


def _box(frame, axis):
    """The world solid's axis-aligned box ``(lo (3,), hi (3,))``, rigorous."""
    h, err = _support(frame, axis, np.vstack([np.eye(3), -np.eye(3)]))
    return -(h[3:] + err[3:]), h[:3] + err[:3]


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
    solid (`solid_kernels.quick_directions`), then the searched ones
    (`full_directions`) for the primitives still undecided; a primitive clear at the
    start that is still undecided then has its path bisected
    (module docstring).
    """
    (lo0, hi0), (lo1, hi1) = (_box(f, solid.axis) for f in solid.ends)
    lo, hi = np.minimum(lo0, lo1), np.maximum(hi0, hi1)
    reach = thickness * (1.0 + 1e-12) + 1e-14 * float(max(np.abs(lo).max(), np.abs(hi).max()))
    lo, hi = lo - reach, hi + reach
    x_t0 = np.ascontiguousarray(x_t0, dtype=np.float64)
    x_t1 = np.ascontiguousarray(x_t1, dtype=np.float64)
    F0, F1 = solid.ends[0][4], solid.ends[1][4]
    out, sep = [], np.inf
    for S in simplices:
        S = np.ascontiguousarray(S, dtype=np.int64)
        flags, lbs = np.zeros(len(S), np.int8), np.full(len(S), np.inf)
        if len(S):
            _k.verdict_kernel(len(S), x_t0, x_t1, S, F0, F1, solid.static, solid.axis, float(thickness),
                              bool(pre_existing), lo, hi, flags, lbs)
            sep = min(sep, float(lbs.min()))
        out.append(tuple(np.flatnonzero(flags & bit) for bit in (_k.START, _k.PATH, _k.PRE)))
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
        From one supporting plane per primitive (`solid_kernels.quick_directions`): exact
        for a vertex under a similarity transform, within the curvature of the solid
        across a primitive otherwise; 0 for a primitive touching or inside the solid.
    """
    frame = _frame(*shape.at(s), where=f"shape at frame {s}")
    axis = shape.axis
    lo, hi = _box(frame, axis)
    lo, hi = lo - radius, hi + radius
    x = np.ascontiguousarray(x, dtype=np.float64)
    d = np.full(len(x), float(radius))
    if len(F) and len(E):
        E = _edges_of_no_face(E, F)
    for S in (np.arange(len(x), dtype=np.int64)[:, None], E, F):
        S = np.ascontiguousarray(S, dtype=np.int64)
        if not len(S):
            continue
        lbs = np.empty(len(S))
        _k.separation_kernel(len(S), x, S, frame[4], axis, float(radius), lo, hi, lbs)
        _k.fold_into_vertices(d, S, lbs)
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
