"""Neighbour lists reused across frames (Verlet lists with a skin).

Consecutive states of a recording (frame s, its deformed state, frame s + 1, ...) are
close to each other, yet every proximity query would start from scratch.
A `NeighbourList` builds the candidate pairs within ``r_b = r + skin`` of a *build
state* once and answers later queries at other states from them, as molecular-dynamics
codes do, until the states have moved too far; then it rebuilds.

(Longer than the ~400 lines of STYLE.md: about half of it is the Numba kernels that
gather the listed pairs and fold their distances, which share the list's private
layout with the class that drives them; splitting them out would export that layout.)

Superset property (why reuse is exact). Let the list be built at ``x_b`` with radius
``r_b``: it holds every non-adjacent pair (edge-edge, vertex-face and, when asked for,
edge-face) whose static boxes, inflated by ``r_b / 2`` on every side, overlap. Query at
``x`` with radius ``r`` and let ``delta >= max_v |x_v - x_b[v]|``. Every point of a
primitive is a convex combination of its vertices with fixed weights, so it moved by at
most ``delta`` too; for two primitives A, B with points p in A, q in B at distance
``dist_x(A, B) = |p - q|``, the same combinations at ``x_b`` are at most
``|p - q| + 2 delta`` apart, hence ``dist_{x_b}(A, B) <= dist_x(A, B) + 2 delta``. If
``r + 2 delta <= r_b``, every pair within ``r`` at ``x`` was within ``r_b`` at ``x_b``;
the per-axis gap of two boxes never exceeds the Euclidean distance of the primitives,
so their boxes inflated by ``r_b / 2`` overlapped and the pair is in the list. The list
is therefore a superset of what a fresh query within ``r`` finds, and per-vertex minima
over its pairs, capped at ``r``, equal a fresh `per_vertex_separation` bit for bit (the
same distance kernels on the same pairs decide every value below ``r``). Rounding is
covered by computing ``delta`` with an upward factor and by padding the inflation with
``1e-14`` of the coordinate magnitude, as `verify._inflation` does. With the fixed
radius of the usual formulation (``r_b = r + skin``) the condition reads "no vertex
moved more than ``skin / 2`` since the build".

Motion is measured from the build state in two ways and the better bound is used: the
largest displacement ``delta`` (reach ``r + 2 delta``), and the residual of the best affine
map ``x = A x_b + b + e``: for points p, q of two primitives, ``x``-distance >=
``sigma_min(A) |p_b - q_b| - 2 max|e|``, so the reach is ``(r + 2 eps) / sigma_min``. A
recording that stretches, shears or turns smoothly moves every vertex far but leaves a
small affine residual (64K cloth reference: 0.0006 against 0.0076 per step).

The skin is chosen at each build from the recent motion by a cost model
(`NeighbourList.choose_skin`): the reach grows by ``g`` per query; a list with skin ``s``
lasts ``s / g`` queries, a build costs about `BUILD_COST` fresh queries and a listed
query `LISTED_COST`, and pair counts grow like ``(1 + s / r)^2``. When no skin beats a
fresh query (the scene moves a query radius per step), the query is answered fresh and
no list is kept (in the 64K reference recordings a vertex moves about a query radius
per step, and that is what happens: benchmarks/bench_neighbours.py, BENCHMARKS.md).
`NeighbourList.info` reports the skin, the builds, reuses and fresh queries.

Parallel and deterministic: a listed query folds the listed pairs' squared distances
into per-worker minima (a ``prange`` over workers, one per thread, each with its own
row of minima, reduced by ``min``, claiming chunks of the row-ordered pairs one after
another: `parallel.claim`), skipping a pair whose box gap at the query state
provably exceeds every minimum it could lower, as the grid's folds do (`broad_phase`:
the same bound and rounding slack, so the minima are those of every pair). No shared
writes, and ``min`` is exact, so results do not depend on the thread count. (Evaluating
every listed pair and gathering per vertex cost 49 ms per query on the 64K yarn, 2.3M
pairs; the pruned fold 26 ms.) `StepBounds` (`penfree.core.trust.stats`) keeps one list
per step for the deformed states of a report.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .broad_phase import _PRUNE_SLACK, _box_arrays, _gap_sq, _Plan, fold_pair_min
from .distance import edge_edge_sq, point_triangle_sq
from .locality import SceneLabels
from ..parallel import chunk_count, claim, parallel_kernel, work_counter
from ...errors import InputError
from ..topology import as_positions, as_topology, scene_edges

#: Skins tried by the cost model, relative to the query radius.
SKIN_CANDIDATES_REL = (0.0625, 0.125, 0.25, 0.5, 1.0, 2.0)
#: Cost of a build and of a query answered from the list, in fresh queries at the
#: build radius (the build enumerates and stores the pairs in one pass; a listed
#: query only evaluates distances): measured 1.0-1.2x (skin 0) and 0.16-0.17x on the
#: 64K cloth and yarn scenes, but builds at larger skins cost more than the pair
#: growth predicts (5.6x a fresh query at skin r_q on the yarn); with 1.2 the model
#: kept lists on the cloth reference and lost (0.82x), with 2.0 it answers fresh.
BUILD_COST = 2.0
LISTED_COST = 0.2
#: The cost model counts a list's life up to this many queries.
SKIN_LIFE_CAP = 32.0
#: Pair counts grow like (r_b / r)^this: 2 for pairs on a surface (a sheet, a layer
#: of yarn); below an edge length they grow slower still (the nearest non-adjacent
#: primitives are already within reach).
PAIR_GROWTH_EXPONENT = 2.0
#: Upward factor on the measured displacement and padding of the box inflation
#: (relative to the coordinate magnitude): covers the rounding of both.
_DELTA_UP = 1.0 + 1e-12
_PAD_REL = 1e-14
#: Rounding allowance of the affine-corrected bound, relative to the coordinate
#: magnitudes (forming the centred residual in float64 costs a few ulps of them;
#: 1e-12 is ~4500 ulps).
_AFFINE_PAD_REL = 1e-12
#: Chunks of the listed pairs that a listed query's workers claim (`_listed_min_py`), at
#: least this many pairs each.
_LISTED_CHUNKS = 256
_LISTED_CHUNK_PAIRS = 1024
#: Smallest eigenvalue ratio of the centred second moments for the affine bound.
_AFFINE_RCOND = 1e-10


def _ee_sq_py(x, E, P, out):
    for k in prange(P.shape[0]):
        i, j = P[k, 0], P[k, 1]
        out[k] = edge_edge_sq(x[E[i, 0]], x[E[i, 1]], x[E[j, 0]], x[E[j, 1]])


def _vf_sq_py(x, F, P, out):
    for k in prange(P.shape[0]):
        v, f = P[k, 0], P[k, 1]
        out[k] = point_triangle_sq(x[v], x[F[f, 0]], x[F[f, 1]], x[F[f, 2]])


def _listed_min_py(x, TA, TB, P, partial, gap_off, n_chunks, counter):
    # Worker w (a row of `partial`) claims chunk after chunk of the pairs (in row order,
    # `parallel.claim`) and folds their squared distances into partial[w] (min is exact:
    # any chunking, claiming or thread count gives the same minima). A pair whose box
    # gap bound (`broad_phase._gap_sq`, reduced by the rounding slack `gap_off`)
    # provably exceeds every minimum it could lower is skipped, as in the grid's folds.
    m = P.shape[0]
    for w in prange(partial.shape[0]):
        dmin = partial[w]
        c = claim(counter)
        while c < n_chunks:
            for q in range(c * m // n_chunks, (c + 1) * m // n_chunks):
                i, j = P[q, 0], P[q, 1]
                lx, ly, lz, hx, hy, hz = _prim_box(x, TA, i)
                m0, m1, m2, M0, M1, M2 = _prim_box(x, TB, j)
                fold_pair_min(x, TA, i, TB, j, dmin,
                              _gap_sq(lx, ly, lz, hx, hy, hz, m0, m1, m2, M0, M1, M2, gap_off))
            c = claim(counter)


@njit(cache=True, inline="always")
def _prim_box(x, T, i):
    v = T[i, 0]
    lx, ly, lz = x[v, 0], x[v, 1], x[v, 2]
    hx, hy, hz = lx, ly, lz
    for a in range(1, T.shape[1]):
        v = T[i, a]
        lx, ly, lz = min(lx, x[v, 0]), min(ly, x[v, 1]), min(lz, x[v, 2])
        hx, hy, hz = max(hx, x[v, 0]), max(hy, x[v, 1]), max(hz, x[v, 2])
    return lx, ly, lz, hx, hy, hz


# Each loop writes only its own slot (or chunk), so the serial and parallel builds give
# the same bits; `parallel_kernel` picks one by the size of the work (robust under
# contention: a small region never waits for a descheduled thread).
_ee_sq = parallel_kernel(_ee_sq_py, "_nl_ee_sq")
_vf_sq = parallel_kernel(_vf_sq_py, "_nl_vf_sq")
_listed_min = parallel_kernel(_listed_min_py, "_nl_listed_min")


@njit(cache=True)
def _max_disp_sq(x, y):
    m = 0.0
    for i in range(x.shape[0]):
        d = (x[i, 0] - y[i, 0]) ** 2 + (x[i, 1] - y[i, 1]) ** 2 + (x[i, 2] - y[i, 2]) ** 2
        if d > m or d != d:
            m = d
    return m


def max_displacement(x, y) -> float:
    """Upper bound of ``max_v |x_v - y_v|`` (rounding included); inf on NaN."""
    if x.shape[0] == 0:
        return 0.0
    m = _max_disp_sq(x, y)
    return float(np.sqrt(m) * _DELTA_UP) if m == m else np.inf


@njit(cache=True)
def _affine_fit(x_b, x):
    # Moments shifted by the first vertex (no cancellation far from the origin),
    # then the least-squares A of x - c ~ A (x_b - c_b), and max |residual|^2.
    n = x.shape[0]
    sb = np.zeros(3)
    sx = np.zeros(3)
    C = np.zeros((3, 3))
    G = np.zeros((3, 3))
    p = np.empty(3)
    q = np.empty(3)
    for i in range(n):
        for a in range(3):
            p[a] = x_b[i, a] - x_b[0, a]
            q[a] = x[i, a] - x[0, a]
        for a in range(3):
            sb[a] += p[a]
            sx[a] += q[a]
            for c in range(3):
                C[a, c] += p[a] * p[c]
                G[a, c] += q[a] * p[c]
    mb = sb / n
    mx = sx / n
    for a in range(3):
        for c in range(3):
            C[a, c] -= n * mb[a] * mb[c]
            G[a, c] -= n * mx[a] * mb[c]
    c_b = x_b[0] + mb
    c_x = x[0] + mx
    mag = np.zeros(2)
    for i in range(n):
        for a in range(3):
            mag[0] = max(mag[0], abs(x[i, a]))
            mag[1] = max(mag[1], abs(x_b[i, a]))
    return C, G, c_b, c_x, mag


@njit(cache=True)
def _residual_sq(x_b, x, A, c_b, c_x):
    m = 0.0
    for i in range(x.shape[0]):
        d = 0.0
        for a in range(3):
            y = A[a, 0] * (x_b[i, 0] - c_b[0]) + A[a, 1] * (x_b[i, 1] - c_b[1]) + A[a, 2] * (x_b[i, 2] - c_b[2])
            e = (x[i, a] - c_x[a]) - y
            d += e * e
        if d > m or d != d:
            m = d
    return m


def affine_residual(x_b, x):
    """``(s_min, eps)``: x = A x_b + b + e with |e_v| <= eps, s_min <= sigma_min(A); or None.

    A, b is the least-squares affine map from x_b to x (float64, two serial passes).
    The bound holds for *any* A, b, so the fit only has to be good, not exact; eps
    and s_min are made conservative against rounding: eps is padded by
    `_AFFINE_PAD_REL` of the coordinate magnitudes, s_min reduced by the same
    relative amount of sigma_max. None when the data do not span 3D (a rod, a
    flat sheet: x_b does not determine A) or A is singular.
    """
    if x.shape[0] < 4:
        return None
    C, G, c_b, c_x, mag = _affine_fit(x_b, x)
    lam = np.linalg.eigvalsh(C)
    if not lam[0] > _AFFINE_RCOND * lam[2]:
        return None
    A = np.ascontiguousarray(np.linalg.solve(C, G.T).T)
    if not np.isfinite(A).all():
        return None
    eps2 = _residual_sq(x_b, x, A, c_b, c_x)
    if not np.isfinite(eps2):
        return None
    sv = np.linalg.svd(A, compute_uv=False)
    # |x - c_x| <= 2 |x|max and |A (x_b - c_b)| <= 2 sqrt(3) sigma_max |x_b|max per entry
    scale = 2.0 * (mag[0] + mag[1] * (1.0 + np.sqrt(3.0) * sv[0]))
    eps = float(np.sqrt(eps2)) * _DELTA_UP + _AFFINE_PAD_REL * scale
    s_min = float(sv[2]) - _AFFINE_PAD_REL * float(sv[0])
    if not s_min > 0.0:
        return None
    return s_min, eps


class NeighbourList:
    """Candidate pairs within ``r + skin`` of a build state, reused across states.

    Parameters
    ----------
    E : (M, 2) int64
        Edges (for a triangle scene: the edges of the faces), as `scene_arrays` gives.
    F : (K, 3) int64
        Faces; empty for a segment scene.
    skin : float or None
        Fixed skin (a list is always kept); None chooses it per build from the recent
        motion, or answers a query fresh when no skin would pay (see `choose_skin`).
    edge_face : bool
        Also keep edge-face pairs (for start-state intersection checks).

    Attributes
    ----------
    info : dict
        ``queries``, ``builds``, ``reused`` (queries answered from an existing list),
        ``fresh`` (answered by a fresh query), ``skin`` and ``build_radius`` of the
        current list, ``n_pairs`` in it, ``growth`` (the reach growth per query).

    Notes
    -----
    See the module docstring for the superset property. Queries must pass positions
    of the same N.

    Examples
    --------
    >>> from penfree.core.trust.bounds import scene_arrays, per_vertex_separation
    >>> x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 0.5, 0.1], [1, 0.5, 0.1]])
    >>> x, E, F = scene_arrays(x, [[0, 1], [2, 3]], None)
    >>> nl = NeighbourList(E, F, skin=0.5)
    >>> bool(np.array_equal(nl.separations(x, 1.0), per_vertex_separation(x, E, F, 1.0)))
    True
    """

    def __init__(self, E, F, *, skin=None, edge_face=False):
        self.E = np.ascontiguousarray(E, dtype=np.int64)
        self.F = np.ascontiguousarray(F, dtype=np.int64)
        self.fixed_skin = None if skin is None else float(skin)
        self.edge_face = bool(edge_face)
        # number of vertices: from the first query unless given by `for_scene`
        self.n = None
        self.x_b = None  # build state of the current list (None: no list)
        self.r_b = -np.inf
        self.x_ref = None  # state the motion is measured from (x_b, or the last query)
        self._since = 0  # queries since x_ref
        self._growth = np.nan  # reach growth per query, from the recent motion
        self._query = None
        self._labels = SceneLabels(self.E, self.F)
        self.info = {"queries": 0, "builds": 0, "reused": 0, "fresh": 0, "skin": np.nan,
                     "build_radius": np.nan, "n_pairs": 0, "growth": np.nan}

    # --- validity --------------------------------------------------------------------

    def reach(self, x, radius, ref) -> float:
        """A radius at `ref` that holds every pair within `radius` at `x`.

        The smaller of the identity bound ``radius + 2 delta`` (delta the largest
        displacement) and the affine-corrected bound ``(radius + 2 eps) / s_min``
        (x = A ref + b + e, |e| <= eps, s_min <= sigma_min(A)); the second wins for
        smooth deformations (eps << delta), see `affine_residual`.
        """
        best = radius + 2.0 * max_displacement(x, ref)
        aff = affine_residual(ref, x)
        if aff is not None:
            s_min, eps = aff
            best = min(best, (radius + 2.0 * eps) / s_min)
        return best

    def coverage(self, x) -> float:
        """The largest radius at `x` within which the current list holds every pair
        (the inverse of `reach` at the build state: ``max(r_b - 2 delta, s_min r_b - 2
        eps)``, shrunk by 1e-9 against rounding); -inf without a list."""
        if self.x_b is None or self.x_b.shape != x.shape:
            return -np.inf
        best = self.r_b - 2.0 * max_displacement(x, self.x_b)
        aff = affine_residual(self.x_b, x)
        if aff is not None:
            s_min, eps = aff
            best = max(best, s_min * self.r_b - 2.0 * eps)
        return best * (1.0 - 1e-9)

    def _observe(self, x, radius):
        """Reach of `x` from the reference state; updates the growth estimate."""
        if self.x_ref is None or self.x_ref.shape != x.shape:
            return np.inf
        need = self.reach(x, radius, self.x_ref)
        if need <= radius:
            return need  # the same state again (another radius): no motion to learn from
        self._since += 1
        g = (need - radius) / self._since
        self._growth = g if not np.isfinite(self._growth) else max(g, 0.5 * self._growth)
        self.info["growth"] = self._growth
        return need

    def choose_skin(self, radius):
        """Skin for a build at `radius`, or None when a fresh query is cheaper.

        Cost model per query, relative to a fresh query at `radius`: a build costs
        `BUILD_COST` and a listed query `LISTED_COST` fresh queries at the build radius
        (measured, benchmarks/bench_neighbours.py), and pair counts grow like
        ``(r_b / r)^PAIR_GROWTH_EXPONENT``. A list with skin s lasts ``s / growth`` queries.
        """
        if self.fixed_skin is not None:
            return self.fixed_skin
        g = self._growth
        if not np.isfinite(g) or radius <= 0.0:
            return None  # no motion seen yet: answer fresh, learn the motion
        best, best_cost = None, 1.0
        for rel in SKIN_CANDIDATES_REL:
            skin = rel * radius
            life = max(1.0, skin / g) if g > 0 else SKIN_LIFE_CAP
            cost = (1.0 + rel) ** PAIR_GROWTH_EXPONENT * (BUILD_COST / min(life, SKIN_LIFE_CAP) + LISTED_COST)
            if cost < best_cost:
                best, best_cost = skin, cost
        return best

    def relabelling(self, x):
        """The scene's `locality.Relabelling` (decided once, from the first state `x`
        asked about), or None when its labels carry locality: for the fresh passes run
        beside this list over the same scene (`verify.affine`)."""
        return self._labels.for_state(x)

    # --- building --------------------------------------------------------------------

    def _build(self, x, radius, skin):
        r_b = radius + skin
        mag = float(np.abs(x).max()) if x.size else 0.0
        infl = 0.5 * r_b * _DELTA_UP + _PAD_REL * mag
        n = x.shape[0]
        E, F = self.E, self.F
        self.P_ee = np.zeros((0, 2), np.int64)
        self.P_vf = np.zeros((0, 2), np.int64)
        self.P_ef = np.zeros((0, 2), np.int64)
        if E.shape[0] > 1:
            lo, hi = _box_arrays(x, x, E, infl)
            self.P_ee = _Plan(lo, hi, E, lo, hi, E, True).pairs()
        self._V = np.arange(n, dtype=np.int64)[:, None]  # vertex rows of the vf pairs: every vertex
        if F.shape[0]:  # (`topology.separation_vertices`); a pair's row is its vertex
            loA, hiA = _box_arrays(x, x, self._V, infl)
            loF, hiF = _box_arrays(x, x, F, infl)
            self.P_vf = _Plan(loA, hiA, self._V, loF, hiF, F, False).pairs()
            if self.edge_face and E.shape[0]:
                loE, hiE = _box_arrays(x, x, E, infl)
                self.P_ef = _Plan(loE, hiE, E, loF, hiF, F, False).pairs()
        self.x_b = x.copy()
        self.x_ref = self.x_b
        self._since = 0
        self.r_b = r_b
        self.info.update(builds=self.info["builds"] + 1, skin=skin, build_radius=r_b,
                         n_pairs=int(self.P_ee.shape[0] + self.P_vf.shape[0]))

    def ensure(self, x, radius, *, need_list=False) -> str:
        """Make the list answer (`x`, `radius`): ``"reused"``, ``"built"`` or ``"fresh"``.

        ``"fresh"`` (only without `need_list`) means no list was built: the caller
        should run a fresh query, which the cost model found cheaper.
        """
        x = np.ascontiguousarray(x, dtype=np.float64)
        radius = float(radius)
        self.info["queries"] += 1
        need = self._observe(x, radius)
        if self.x_b is not None and self.x_ref is self.x_b and need <= self.r_b:
            self.info["reused"] += 1
            return "reused"
        skin = self.choose_skin(radius)
        if skin is None and not need_list:
            self.x_b, self.r_b = None, -np.inf
            self.x_ref, self._since = x.copy(), 0
            self.info["fresh"] += 1
            return "fresh"
        self._build(x, radius, 0.0 if skin is None else skin)
        return "built"

    @classmethod
    def for_scene(cls, x, *, edges=None, faces=None, **kw):
        """A list for a scene given as in `trust_region_bounds` (validated once).

        Examples
        --------
        >>> x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 0.5, 0.1], [1, 0.5, 0.1]])
        >>> nl = NeighbourList.for_scene(x, edges=[[0, 1], [2, 3]], skin=0.1)
        >>> nl.separations(x, 1.0).round(3).tolist()
        [0.51, 0.51, 0.51, 0.51]
        """
        x = as_positions(x, "x")
        n = x.shape[0]
        E = scene_edges(as_topology(edges, 2, n, "edges"), as_topology(faces, 3, n, "faces"))
        nl = cls(E, as_topology(faces, 3, n, "faces"), **kw)
        nl.n = int(np.asarray(x).shape[0])
        return nl

    def _positions(self, x, radius):
        x = as_positions(x, "x")
        if self.n is not None and x.shape[0] != self.n:
            raise InputError(f"x must be ({self.n}, 3) like the scene of this neighbour list; got {x.shape}")
        r = float(radius)
        if not (np.isfinite(r) and r >= 0.0):
            raise InputError(f"radius must be finite and >= 0; got {radius}")
        return x, r

    # --- queries ---------------------------------------------------------------------

    def pair_sq(self, x):
        """Squared distances at `x` of the listed ``(ee (K1,), vf (K2,))`` pairs."""
        d_ee = np.empty(self.P_ee.shape[0])
        d_vf = np.empty(self.P_vf.shape[0])
        if d_ee.size:
            _ee_sq(d_ee.size, x, self.E, self.P_ee, d_ee)
        if d_vf.size:
            _vf_sq(d_vf.size, x, self.F, self.P_vf, d_vf)
        return d_ee, d_vf

    def separations(self, x, radius) -> np.ndarray:
        """Per-vertex separations, equal to ``per_vertex_separation(x, E, F, radius)``.

        Parameters
        ----------
        x : (N, 3) float64
        radius : float >= 0

        Returns
        -------
        d : (N,) float64
            ``min(radius, distance to the nearest non-adjacent primitive)``.
        """
        x, radius = self._positions(x, radius)
        if self.n is None:
            self.n = x.shape[0]
        if self.ensure(x, radius) == "fresh":
            from .proximity import SeparationQuery

            if self._query is None:  # fresh queries, each at the reach of the last
                self._query = SeparationQuery(self.E, self.F)
            return self._query(x, float(radius))
        return self.listed_separations(x, radius)

    def listed_separations(self, x, radius) -> np.ndarray:
        """`separations` from the current list as it is, without the validity check:
        for a caller that has shown ``coverage(x) >= radius`` (`StepBounds`).

        Parameters
        ----------
        x : (N, 3) float64, C-contiguous
        radius : float >= 0
        """
        from .proximity import capped_separations, start_minima

        # minima from the cap, as `per_vertex_separation`: the same capped result
        partial = start_minima(x.shape[0], radius)
        gap_off = -_PRUNE_SLACK * (float(np.abs(x).max()) if x.size else 0.0)
        for P, TA, TB in ((self.P_ee, self.E, self.E), (self.P_vf, self._V, self.F)):
            if P.shape[0]:
                _listed_min(P.shape[0], x, TA, TB, P, partial, gap_off,
                            chunk_count(P.shape[0], _LISTED_CHUNKS, _LISTED_CHUNK_PAIRS), work_counter())
        return capped_separations(partial, radius)

    def pairs(self, x, radius) -> dict:
        """Listed pairs, a superset of the pairs within `radius` at `x`.

        Returns
        -------
        dict
            ``ee (K, 2)`` edge pairs (i < j), ``vf (K, 2)`` (vertex, face), and with
            ``edge_face=True`` ``ef (K, 2)`` (edge, face) whose boxes came within the
            build radius; pairs sharing a vertex are never listed.
        """
        x, radius = self._positions(x, radius)
        if self.n is None:
            self.n = x.shape[0]
        self.ensure(x, radius, need_list=True)
        return {"ee": self.P_ee, "vf": self.P_vf, "ef": self.P_ef}
