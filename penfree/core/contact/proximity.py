"""Per-vertex proximity of a static state: the smallest distance from each vertex's
primitives to the non-adjacent primitives around them, within a radius.

The broad phase finds the pairs whose static boxes, inflated by half the radius,
overlap (every pair closer than the radius is among them: the Euclidean distance is
at least the per-axis box gap), and the pair distances are folded into per-vertex
minima inside the same parallel pass, so no candidate list is ever stored. The
trust-region bounds (`penfree.core.trust.bounds`) and the neighbour lists
(`penfree.core.contact.neighbours`) are built on it.

Reach (why a query below the radius is exact). The radius is usually set by the
step's motion, and most scenes' separations lie well below it: every vertex of a
sheet has its ring-2 neighbours, every vertex of a bundle its neighbour strands,
within a fraction of an edge (64K samples: the largest separation is 0.33-0.78 of
the query radius, and the same to 1% from frame to frame). A query at a smaller
`reach` rho < r costs what its smaller boxes cost (1.8-2.3x less at rho = 0.55 r).
Its minimum m_v for vertex v is exact whenever ``m_v < tau = rho - slack``: a pair
it did not visit has boxes (inflated by rho / 2) that do not overlap, hence a
distance above rho less the boxes' and kernels' rounding (a few ulps of the
coordinates, ~1e-12 relative), which `slack` covers 1e3 times over. Vertices at or
above tau (and only those) are completed at the full radius by folds restricted
to the pairs that can lower them: their edges against every edge, the vertex
against every face, every vertex against their faces (`_complete`). Every term of
v (SPEC section 7) involves one of v's primitives, the same kernels compute the
same values (edge-edge distances are symmetric bit for bit in their two
segments: both orders form the same products), and ``min`` is exact, so the
result equals the query at the full radius bit for bit. `SeparationQuery` takes
each query's reach from the last one's separations.

Cell shapes. The grid's cells change how rows scan, never the pairs found. A bundle
of yarns at its separations' reach scans ~400 entries per row in cubes sized by the
long axis and ~130 in per-axis cells (64K yarn: the query 1.25-1.5x faster), a sheet
the same in both: `SeparationQuery` chooses each fold's shape once per octave of the
query radius (`separation_cells`, `broad_phase.choose_cells`), and keeps the grid key's
axis order that each fold took in the octave's first query (`broad_phase.fold_min_sq`'s
`axes`: the boxes are then made in that order, and no order is chosen or applied).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ...constants import REDUCTION_CHUNKS
from ...errors import InputError
from ..topology import separation_vertices
from .broad_phase import _box_arrays, _Plan, choose_cells, fold_min_sq
from .locality import SceneLabels

#: Cap on the per-worker partial minima, in float64 entries (32 MiB).
_PARTIAL_ENTRIES_MAX = 1 << 22
#: Rounding allowance of a query at a reach below its radius, relative to the reach
#: plus the largest coordinate: a vertex whose minimum comes within it of the reach
#: is completed at the full radius (box and distance rounding are ~1e-12 of these).
_REACH_SLACK = 1e-9
#: `SeparationQuery`: the next reach is this factor times the last query's largest
#: separation below its radius (separations moved 1% between frames of the 64K
#: samples; a miss costs only the completion of the vertices above the reach) ...
REACH_HEADROOM = 1.1
#: ... unless more than this fraction of the vertices was at the radius (isolated
#: parts, nothing within the radius): completing them all would cost more than it saves.
REACH_CAPPED_MAX = 0.02
#: Above this fraction of vertices to complete, one query at the full radius is cheaper
#: than the restricted folds (all vertices: 1.75-2.1x a full query, 64K yarn and cloth).
COMPLETE_MAX = 0.25


def _cap_sq(radius):
    """The smallest float64 c >= radius**2 with sqrt(c) >= radius (sqrt correctly rounded)."""
    c = float(radius) * float(radius)
    while np.sqrt(c) < radius:
        c = float(np.nextafter(c, np.inf))
    return c


def partial_chunks(n) -> int:
    """Rows of per-worker partial minima for `n` vertices, one per thread: the folds'
    workers claim their chunks of work as they go (`broad_phase._min_rows_py`,
    `_deferred_py`), and min is exact, so the row count changes not a single bit; capped
    at `_PARTIAL_ENTRIES_MAX` entries."""
    return max(1, min(REDUCTION_CHUNKS, numba.get_num_threads(), _PARTIAL_ENTRIES_MAX // max(n, 1)))


def start_minima(n, radius) -> np.ndarray:
    """(workers, n) per-worker partial minima of squared distances, each at the cap
    radius**2 (`_cap_sq`) instead of inf: the result is min(sqrt(.), radius), so it is
    unchanged, and a fold can skip every pair that provably lies beyond the radius."""
    return np.full((partial_chunks(n), n), _cap_sq(radius))


def capped_separations(partial, radius) -> np.ndarray:
    """(n,) ``min(radius, sqrt(min over the chunks))`` of `start_minima`'s rows."""
    return np.minimum(np.sqrt(partial.min(axis=0)), float(radius))


def per_vertex_separation(x, E, F, radius, reach=None, cells=("cube", "cube")):
    """Per-vertex smallest distance to non-adjacent primitives, capped at `radius`.

    Parameters
    ----------
    x : (N, 3) float64, C-contiguous
    E : (M, 2) int64
        Edges (for a triangle scene: the edges of the faces).
    F : (K, 3) int64
        Faces; empty for a segment scene.
    radius : float >= 0
        Finite (an infinite radius would make every box cover the whole space):
        InputError otherwise.
    reach : float >= 0, optional
        A guess of the largest separation below `radius` (`SeparationQuery` takes it
        from the last state's). The query runs at ``min(radius, reach)`` and completes
        the vertices it leaves at that cap at `radius`: the same values bit for bit,
        faster when the guess is good (module docstring). None: one query at `radius`.
    cells : (str, str)
        Grid cell shapes of the edge-edge and the vertex-face folds
        (`broad_phase.choose_cells`, which `SeparationQuery` runs once per scene): they
        change the time, never a value.

    Returns
    -------
    d : (N,) float64
        ``d[v] = min(radius, terms)`` with the terms of SPEC section 7:
        vertex-face distances fold into the vertex and into the face's three
        vertices, edge-edge distances (edges sharing no vertex) into the four
        vertices; in a triangle scene every vertex meets the faces, also one in no
        primitive (`topology.separation_vertices`). A vertex with nothing within
        `radius` (or, in a segment scene, in no edge) gets `radius`.

    Notes
    -----
    Inputs are assumed validated (`trust_region_bounds` does it). Rows are
    split into chunks, each with its own row of partial minima, reduced with
    ``min`` (exact): the result does not depend on the number of threads.

    Examples
    --------
    >>> x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 0.5, 0.1], [1, 0.5, 0.1], [5, 0, 0], [6, 0, 0]])
    >>> E = np.array([[0, 1], [2, 3], [4, 5]])
    >>> F = np.zeros((0, 3), np.int64)
    >>> per_vertex_separation(x, E, F, 2.0).round(3).tolist()
    [0.51, 0.51, 0.51, 0.51, 2.0, 2.0]
    >>> bool(np.array_equal(per_vertex_separation(x, E, F, 2.0, reach=0.6),
    ...                     per_vertex_separation(x, E, F, 2.0)))
    True
    """
    return _query(x, E, F, radius, reach, cells)[0]


def _query(x, E, F, radius, reach, cells, axes=(None, None)):
    """`per_vertex_separation`, and the two folds' grid key axis orders (`_separations`)."""
    r = _checked(radius, "radius")
    if reach is None or not _checked(reach, "reach") < r:
        return _separations(x, E, F, r, cells, axes)
    d, axes = _separations(x, E, F, float(reach), cells, axes)
    return complete_separations(x, E, F, r, float(reach), d), axes


def complete_separations(x, E, F, radius, reach, d):
    """The separations at `radius` from `d`, those of a query capped at `reach` < `radius`.

    `d` may come from any query that visits every pair within `reach` (a fresh one, or a
    neighbour list that holds them): its values below the reach less the rounding
    slack are exact; the other vertices are completed at `radius` (module docstring).
    `d` is updated in place and returned.
    """
    r, rho = float(radius), float(reach)
    mag = float(np.abs(x).max()) if x.size else 0.0
    tau = rho - 2.0 * _REACH_SLACK * (rho + mag)
    used = separation_vertices(x.shape[0], F, E)
    d[~used] = r  # no term (a segment scene's vertex in no edge): nothing within any radius
    C = used & (d >= tau)
    n_c = int(np.count_nonzero(C))
    if n_c > COMPLETE_MAX * x.shape[0]:
        return _separations(x, E, F, r)[0]
    if n_c:
        d[C] = _complete(x, E, F, r, C)[C]
    return d


def _checked(radius, name):
    r = float(radius)
    if not (np.isfinite(r) and r >= 0.0):
        raise InputError(f"{name} must be finite and >= 0; got {radius}")
    return r


def _separations(x, E, F, radius, cells=("cube", "cube"), axes=(None, None)):
    """The query at one radius (every pair whose boxes, inflated by radius / 2, overlap),
    and the folds' grid key axis orders; `cells` the edge-edge and vertex-face folds'
    cell shapes, `axes` their axis orders (None: each fold chooses), as `fold_min_sq`
    takes and returns them."""
    n = x.shape[0]
    inflation = 0.5 * radius
    # from the cap: pairs beyond the radius are skipped from the first pair on
    partial = start_minima(n, radius)
    ee, vf = axes
    if E.shape[0]:
        ee = fold_min_sq(x, E, E, inflation, partial, self_query=True, cells=cells[0], axes=ee)
    if F.shape[0]:
        Q = _face_vertices(n)
        vf = fold_min_sq(x, Q, F, inflation, partial, self_query=False, cells=cells[1], axes=vf)
    return capped_separations(partial, radius), (ee, vf)


def _face_vertices(n):
    """(n, 1) int64: the rows of the vertex-face folds, every vertex of a triangle scene
    (`topology.separation_vertices`)."""
    return np.arange(n, dtype=np.int64)[:, None]


def separation_cells(x, E, F, radius) -> tuple:
    """``(edge-edge, vertex-face)`` cell shapes for queries of this scene at `radius`
    (`broad_phase.choose_cells` of each fold at the query's inflation)."""
    inflation = 0.5 * float(radius)
    ee = choose_cells(x, E, E, inflation, True) if E.shape[0] else "cube"
    vf = "cube"
    if F.shape[0]:
        vf = choose_cells(x, _face_vertices(x.shape[0]), F, inflation, False)
    return ee, vf


def _complete(x, E, F, radius, C):
    """Separations at `radius`, exact for the vertices of mask `C` (only): the folds of
    the pairs with a primitive that has a vertex in C (their edges against every edge,
    their vertices against every face, every vertex against their faces). Each fold
    visits only the other side's boxes that
    meet the bounding box of C's side."""
    infl = 0.5 * radius
    partial = start_minima(x.shape[0], radius)

    def fold(loA, hiA, TA, loB, hiB, TB):
        if TA.shape[0] and TB.shape[0]:
            _Plan(loA, hiA, TA, loB, hiB, TB, False, infl).min_sq_into(x, partial)

    def near(lo, hi, T, to_lo, to_hi):
        # boxes meeting the bounding box of the other side's: all that can overlap one
        k = np.flatnonzero((lo <= to_hi.max(axis=0)).all(axis=1) & (hi >= to_lo.min(axis=0)).all(axis=1))
        return lo[k], hi[k], T[k]

    if E.shape[0] > 1:
        loE, hiE = _box_arrays(x, x, E, infl)
        k = np.flatnonzero(C[E].any(axis=1))
        if k.size:
            loB, hiB, EB = loE[k], hiE[k], E[k]
            fold(*near(loE, hiE, E, loB, hiB), loB, hiB, EB)
    if F.shape[0]:
        Q = _face_vertices(x.shape[0])
        loQ, hiQ = _box_arrays(x, x, Q, infl)
        loF, hiF = _box_arrays(x, x, F, infl)
        k = np.flatnonzero(C[Q[:, 0]])
        if k.size:
            loA, hiA, QA = loQ[k], hiQ[k], Q[k]
            fold(loA, hiA, QA, *near(loF, hiF, F, loA, hiA))
        k = np.flatnonzero(C[F].any(axis=1))
        if k.size:
            loB, hiB, FB = loF[k], hiF[k], F[k]
            fold(*near(loQ, hiQ, Q, loB, hiB), loB, hiB, FB)
    return capped_separations(partial, radius)


def _octave(rho):
    """The octave [2^k, 2^(k+1)) of a query radius (`SeparationQuery` keeps a layout per octave)."""
    return math.frexp(rho)[1] if rho > 0.0 else None


def next_reach(d, radius):
    """The reach for the next state's query from this state's separations `d` at `radius`:
    `REACH_HEADROOM` times the largest below `radius`, or None (query at the radius) when
    more than `REACH_CAPPED_MAX` of the vertices are at it or none is below it."""
    below = d[d < radius]
    if below.size == 0 or d.size - below.size > REACH_CAPPED_MAX * d.size:
        return None
    return REACH_HEADROOM * float(below.max())


class SeparationQuery:
    """`per_vertex_separation` over consecutive states of one scene, each at the reach
    that the last state's separations suggest (`next_reach`): the same values as a query
    at the full radius, bit for bit, at the cost of one at the reach when the guess holds.

    Parameters
    ----------
    E : (M, 2) int64
    F : (K, 3) int64
        As `per_vertex_separation` takes them.

    Attributes
    ----------
    info : dict
        ``queries``; ``reached`` (queries run below their radius); ``completed``
        (vertices at or above the reach, the ones completed at the full radius, over
        all queries); ``reach`` (the last); ``cells`` (the last query's folds' cell
        shapes, `separation_cells`, chosen once per octave of the query radius: box
        sizes follow it; the folds' grid key axis orders are kept per octave too, from
        its first query); ``relabelled`` (whether the queries run on the scene
        renumbered along a Morton curve of the first state, `locality.relabelling`:
        a scene whose labels carry no locality; the same values bit for bit).

    Examples
    --------
    >>> x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 0.5, 0.1], [1, 0.5, 0.1]])
    >>> q = SeparationQuery(np.array([[0, 1], [2, 3]]), np.zeros((0, 3), np.int64))
    >>> [q(x + 0.1 * s, 5.0).round(3).tolist() for s in range(2)]
    [[0.51, 0.51, 0.51, 0.51], [0.51, 0.51, 0.51, 0.51]]
    >>> q.info["reached"]
    1
    """

    def __init__(self, E, F):
        self.E = np.ascontiguousarray(E, dtype=np.int64)
        self.F = np.ascontiguousarray(F, dtype=np.int64)
        self.reach = None
        self._cells_by_octave = {}
        self._axes_by_octave = {}  # the folds' grid key axis orders, from an octave's first query
        self._labels = SceneLabels(self.E, self.F)
        self.info = {"queries": 0, "reached": 0, "completed": 0, "reach": None, "cells": None,
                     "relabelled": False}

    def __call__(self, x, radius):
        """(N,) float64 separations at `x` capped at `radius` (`per_vertex_separation`)."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        r = _checked(radius, "radius")
        relabel = self._labels.for_state(x)
        self.info["relabelled"] = self._labels.relabelled
        E, F = self.E, self.F
        if relabel:
            x, E, F = relabel.positions(x), relabel.E, relabel.F
        reach = self.reach if self.reach is not None and self.reach < r else None
        rho = r if reach is None else reach
        cells = self._cells(x, E, F, rho)
        octave = _octave(rho)
        d, axes = _query(x, E, F, r, reach, cells, self._axes_by_octave.get(octave, (None, None)))
        self._axes_by_octave.setdefault(octave, axes)
        if relabel:
            d = relabel.to_caller(d)
        self.info["queries"] += 1
        if reach is not None:
            self.info["reached"] += 1
            self.info["completed"] += int(np.count_nonzero(d >= reach))
        self.info["reach"] = reach
        self.observe(d, r)
        return d

    def _cells(self, x, E, F, rho):
        """The folds' cell shapes for a query at `rho`: chosen (`separation_cells`) at
        the first query whose `rho` lies in its octave [2^k, 2^(k+1)) and kept for it."""
        octave = _octave(rho)
        if octave not in self._cells_by_octave:
            self._cells_by_octave[octave] = separation_cells(x, E, F, rho)
        self.info["cells"] = self._cells_by_octave[octave]
        return self.info["cells"]

    def observe(self, d, radius):
        """Take the next reach from separations `d` at `radius` that another source (a
        neighbour list) answered for this scene (`next_reach`)."""
        self.reach = next_reach(d, radius)
