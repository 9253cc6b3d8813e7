"""Step verification (SPEC section 6): is the straight path x_t0 -> x_t1 contact-free?

One step is checked in two parts:

- start state: non-adjacent primitives must not intersect (triangle scenes:
  an edge meeting a face it shares no vertex with, exact segment-triangle
  test) nor be within `thickness` (vertex-face and edge-edge pairs; touching
  when thickness is 0). The latter are the path hits that already hold at
  t = 0 (a static pair's box lies inside its swept box), re-checked statically;
- path: every vertex-face and edge-edge pair (segments: edge-edge) whose
  swept boxes overlap goes through the conservative CCD of `penfree.core.contact.ccd`
  (no false negatives; exact for thickness 0), and the same between the
  scene and each obstacle moving linearly (not obstacles against each other).

Pairs are identified by a kind and two indices: ``"ee"`` (edge i, edge j of
`VerifyResult.edges`), ``"vf"`` (vertex i, face j), ``"ef"`` (edge i meets
face j, start only). Against an obstacle the kind gets ``":<name>"`` and the
scene primitive comes first: ``"ee:floor"`` (scene edge, obstacle edge),
``"vf:floor"`` (scene vertex, obstacle face), ``"fv:floor"`` (scene face,
obstacle vertex), ``"ef:floor"``, ``"fe:floor"``. Obstacle edges are their
edges merged with the edges of their faces (`penfree.core.topology.scene_edges`).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit

from ...constants import CCD_MAX_EXACT, DEFAULT_MAX_PAIRS
from ...errors import InputError
from ...sequence import SCALE_MAX
from ..contact.broad_phase import (
    edge_edge_candidates,
    edge_face_candidates,
    edge_edge_candidates_between,
    pair_rows,
    vertex_face_candidates,
    vertex_face_candidates_between,
)
from ..contact.ccd import SEPARATED, ccd_indexed
from ..contact.distance import indexed_distance
from ..topology import as_positions, as_topology, referenced_vertices, scene_edges
from .result import VerifyResult

#: Candidate pairs handed to the narrow phase at once (bounds the per-block
#: index and result arrays).
_BLOCK = 1 << 18


class SceneTopology:
    """The primitives of a scene of `n` vertices, validated once for the many states a
    caller checks (`StepGate` is made for every step of a recording, and its near-pair
    query read the topology again each time: 1.0-1.5 ms of a 64K cloth's step).

    Attributes: ``F`` (faces), ``E_given`` (the edges as given: a face's edges among
    them too, or not), ``E`` (the scene's edge set, `scene_edges`) and
    ``all_referenced`` (every vertex in a primitive; computed on first use).
    """

    def __init__(self, n, edges, faces, name="scene"):
        self.n = int(n)
        self.F = as_topology(faces, 3, n, f"{name} faces") if faces is not None else np.zeros((0, 3), np.int64)
        self.E_given = as_topology(edges, 2, n, f"{name} edges") if edges is not None else np.zeros((0, 2), np.int64)
        self.E = scene_edges(self.E_given, self.F)

    @functools.cached_property
    def all_referenced(self) -> bool:
        return bool(referenced_vertices(self.n, self.F, self.E).all())


class _Body:
    """Positions at t0 and t1 and the topology of the scene or of one obstacle
    (`topology`: a `SceneTopology` of these vertices made before, else from `edges`
    and `faces`)."""

    def __init__(self, x_t0, x_t1, edges, faces, name, topology=None):
        self.x_t0 = as_positions(x_t0, f"{name} positions at t0")
        self.x_t1 = as_positions(x_t1, f"{name} positions at t1")
        if self.x_t1.shape != self.x_t0.shape:
            raise InputError(f"{name} positions at t1 must be {self.x_t0.shape} like at t0; got {self.x_t1.shape}")
        n = self.x_t0.shape[0]
        if topology is None:
            topology = SceneTopology(n, edges, faces, name)
        elif topology.n != n:
            raise InputError(f"{name}: a topology of {topology.n} vertices for {n} positions")
        self.topology = topology
        self.F, self.E_given, self.E = topology.F, topology.E_given, topology.E
        # every vertex, also of a scene without primitives (particles still meet obstacle faces)
        self.V = np.arange(n, dtype=np.int64)


def _inflation(thickness, *arrays):
    """Box inflation catching every pair within `thickness`, despite the rounding of the boxes."""
    if thickness == 0.0:
        return 0.0  # exact min/max boxes: touching primitives have touching boxes
    m = max((float(np.abs(a).max()) for a in arrays if a.size), default=0.0)
    return 0.5 * thickness * (1.0 + 1e-12) + 1e-14 * m


class _Collector:
    """Accumulates violating pairs (kind, i, j, toi) and the certified separation."""

    def __init__(self):
        self.kinds, self.ij, self.toi = [], [], []
        self.sep = np.inf
        self.n_candidates = 0

    def add(self, kind, ij, status, toi, sep):
        self.n_candidates += len(status)
        hit = status != SEPARATED
        if len(status):
            self.sep = min(self.sep, float(np.where(hit, 0.0, sep).min()))
        if hit.any():
            self.kinds.append(np.full(int(hit.sum()), kind, dtype=object))
            self.ij.append(ij[hit])
            self.toi.append(toi[hit])

    def first(self, max_pairs):
        if not self.kinds:
            return [], 0
        kinds = np.concatenate(self.kinds)
        ij = np.concatenate(self.ij)
        toi = np.concatenate(self.toi)
        order = np.lexsort((ij[:, 1], ij[:, 0], toi))[:max_pairs]
        return [(str(kinds[k]), int(ij[k, 0]), int(ij[k, 1]), float(toi[k])) for k in order], len(toi)


def _narrow(col, kind, ij, idx, X0, X1, ccd_kind, thickness, start=None, pre=None):
    """CCD of pairs ij whose 4 vertex rows (into X0/X1) are idx (K, 4), in blocks.

    With `start`, the path hits are checked again at t = 0 (static): every pair
    within thickness at the start is a path hit too (its swept box contains its
    start box), so this finds all start-state proximity violations.

    With `pre` (a collector; the deform-result reading of SPEC section 6), a hit
    whose pair starts within `thickness` only has to stay disjoint (re-checked with
    thickness 0), and a pair that already touches or intersects at the start is
    pre-existing: it goes to `pre` instead of `col`, but only when none of its vertices
    moves (`_excuse`).
    """
    for s in range(0, len(ij), _BLOCK):
        sl = slice(s, s + _BLOCK)
        status, toi, sep, _ = ccd_indexed(X0, X1, idx[sl], ccd_kind, thickness)
        if pre is not None:
            _excuse(pre, kind, ij[sl], idx[sl], X0, X1, ccd_kind, thickness, status, sep)
        col.add(kind, ij[sl], status, toi, sep)
        hit = np.flatnonzero(status != SEPARATED)
        if start is not None and len(hit):
            s0, t0, g0, _ = ccd_indexed(X0, X0, idx[sl][hit], ccd_kind, thickness)
            start.add(kind, ij[sl][hit], s0, t0, g0)


def _excuse(pre, kind, ij, idx, X0, X1, ccd_kind, thickness, status, sep):
    """Clear (in place) the hits of `status` that the start state explains.

    A pair within `thickness` at t = 0 (resting contact) passes when its path keeps
    it disjoint (thickness-0 CCD; `sep` gets that bound). Resting means clearly
    inside: the static CCD flags it (conservative, so it may flag a pair just
    outside) and its computed distance is below the thickness by more than its
    rounding; a pair at the thickness itself keeps the full thickness check. A pair
    that touches or intersects at t = 0 and does not move is pre-existing: it is added
    to `pre` and cleared. A touching pair that moves stays a hit, whatever moves it:
    an obstacle does not move with the map, two objects' maps push one through the
    other, and even under one nonsingular map (which would keep it touching) the
    written positions are that map rounded: a vertex lying on a face ended 4e-4 beneath
    it (float32, 1e4 from the origin) with its triangle's other vertices above.
    """
    hit = np.flatnonzero(status != SEPARATED)
    if thickness > 0.0 and len(hit):
        near = ccd_indexed(X0, X0, idx[hit], ccd_kind, thickness)[0] != SEPARATED
        rest = hit[near]
        d0 = indexed_distance(X0, idx[rest], ccd_kind)
        scale = float(np.abs(X0).max()) if X0.size else 0.0
        rest = rest[d0 < thickness * (1.0 - 1e-9) - 1e-12 * scale]
        st, _, sp, _ = ccd_indexed(X0, X1, idx[rest], ccd_kind, 0.0)
        clear = rest[st == SEPARATED]
        status[clear], sep[clear] = SEPARATED, sp[st == SEPARATED]
        hit = np.flatnonzero(status != SEPARATED)
    if len(hit):
        # In chunks of CCD_MAX_EXACT: every pair decided exactly, none excused unproven.
        touch = np.concatenate([ccd_indexed(X0, X0, idx[hit[c:c + CCD_MAX_EXACT]], ccd_kind, 0.0)[0] != SEPARATED
                                for c in range(0, len(hit), CCD_MAX_EXACT)])
        old = hit[touch]
        old = old[(X0[idx[old]] == X1[idx[old]]).all(axis=(1, 2))]  # only a pair that does not move
        pre.add(kind, ij[old], status[old], np.zeros(len(old)), np.zeros(len(old)))
        status[old], sep[old] = SEPARATED, 0.0


def _all_kept(keep, T):
    """(M,) bool: the rows of `T` all of whose vertices `keep` marks (one gather per column:
    ``keep[T].all(axis=1)`` reduced a 3-wide axis at 2 ms per 64K cloth step)."""
    out = keep[T[:, 0]]
    for c in range(1, T.shape[1]):
        out &= keep[T[:, c]]
    return out


def _self_candidates(body, X0, X1, inflation, keep=None):
    """``[(kind, ij, idx)]`` of the scene's own pairs whose boxes over X0 -> X1 overlap.

    With `keep` ((N,) bool), only among the primitives all of whose vertices are kept
    (`pairs.near_pairs`); ``ij`` indexes the body's edges, vertices and faces either way.
    """
    out = []
    E, e = body.E, None
    if keep is not None:
        e = np.flatnonzero(_all_kept(keep, body.E))
        E = body.E[e]
    if len(E) > 1:
        ee = edge_edge_candidates(X0, X1, E, inflation)
        out.append(("ee", ee if e is None else e[ee], pair_rows(E, E, ee)))
    F, f, V = body.F, None, body.V
    if keep is not None:
        f = np.flatnonzero(_all_kept(keep, body.F))
        F, V = body.F[f], body.V[keep[body.V]]
    if len(F):
        vf = vertex_face_candidates(X0, X1, F, inflation, V)
        ij = vf if f is None else np.stack([vf[:, 0], f[vf[:, 1]]], axis=1)
        out.append(("vf", ij, pair_rows(body.V[:, None], F, vf)))
    return out


def _pairs_self(col, body, thickness, static, start=None, pre=None):
    X0 = body.x_t0
    X1 = body.x_t0 if static else body.x_t1
    for kind, ij, idx in _self_candidates(body, X0, X1, _inflation(thickness, X0, X1)):
        _narrow(col, kind, ij, idx, X0, X1, kind, thickness, start, pre)


def _pairs_between(col, body, ob, name, thickness, start=None, pre=None):
    n = body.x_t0.shape[0]
    X0 = np.concatenate([body.x_t0, ob.x_t0])
    X1 = np.concatenate([body.x_t1, ob.x_t1])
    infl = _inflation(thickness, X0, X1)
    if len(body.E) and len(ob.E):
        ee = edge_edge_candidates_between(X0, X1, body.E, ob.E + n, infl)
        idx = np.concatenate([body.E[ee[:, 0]], ob.E[ee[:, 1]] + n], axis=1)
        _narrow(col, f"ee:{name}", ee, idx, X0, X1, "ee", thickness, start, pre)
    if len(body.V) and len(ob.F):
        vf = vertex_face_candidates_between(X0, X1, body.V, ob.F + n, infl)
        idx = np.concatenate([vf[:, :1], ob.F[vf[:, 1]] + n], axis=1)
        _narrow(col, f"vf:{name}", vf, idx, X0, X1, "vf", thickness, start, pre)
    if len(ob.V) and len(body.F):
        fv = vertex_face_candidates_between(X0, X1, ob.V + n, body.F, infl)
        idx = np.concatenate([fv[:, :1], body.F[fv[:, 1]]], axis=1)
        _narrow(col, f"fv:{name}", fv[:, ::-1] - np.array([0, n]), idx, X0, X1, "vf", thickness, start, pre)


@njit(cache=True)
def _share_no_vertex(E, F, k, f):
    out = np.empty(k.shape[0], dtype=np.bool_)
    for i in range(k.shape[0]):
        a = E[k[i], 0]
        b = E[k[i], 1]
        ok = True
        for c in range(3):
            if F[f[i], c] == a or F[f[i], c] == b:
                ok = False
        out[i] = ok
    return out


def _edge_face(col, kind, V, E, F, swap=False):
    """Static: closed edges E meeting closed faces F (index arrays into V), shared vertices skipped.

    The broad phase keeps the pairs whose boxes overlap and which its certified float
    filter cannot prove apart (`broad_phase.edge_face_candidates`); for those, each
    edge becomes a point moving from its first to its second end point, and the
    vertex-face CCD against the static face is the exact segment-triangle test (as in
    `penfree.core.contact.intersection`).
    """
    if not len(E) or not len(F):
        return
    V = np.ascontiguousarray(V, dtype=np.float64)
    cand = edge_face_candidates(V, E, F)
    edge_face_exact(col, kind, V, E, F, cand[:, 0], cand[:, 1], swap)


def edge_face_exact(col, kind, V, E, F, k, f, swap=False):
    """The exact test of `_edge_face` on candidate pairs (edge ``E[k]``, face ``F[f]``).

    Each edge becomes a point swept from its first to its second end point (rows
    ``n + j`` of V0 / V1) and goes through the vertex-face CCD against the static
    face; pairs are reported as ``(k, f)``, or ``(f, k)`` with `swap`.
    """
    n = V.shape[0]
    V0 = np.concatenate([V, V[E[k, 0]]])
    V1 = np.concatenate([V, V[E[k, 1]]])
    idx = np.concatenate([(n + np.arange(len(k)))[:, None], F[f]], axis=1)
    for s in range(0, len(k), _BLOCK):
        sl = slice(s, s + _BLOCK)
        status, _, _, _ = ccd_indexed(V0, V1, idx[sl], "vf", 0.0)
        ij = np.stack([f[sl], k[sl]], axis=1) if swap else np.stack([k[sl], f[sl]], axis=1)
        zeros = np.zeros(len(ij))
        col.add(kind, ij, status, zeros, zeros)


def _start_check(scene, obstacles, self_pairs=True):
    """Edge-face intersections at the start (proximity violations come from the path check)."""
    col = _Collector()
    if len(scene.F) and self_pairs:
        _edge_face(col, "ef", scene.x_t0, scene.E, scene.F)
    n = scene.x_t0.shape[0]
    for name, ob in obstacles:
        V = np.concatenate([scene.x_t0, ob.x_t0])
        _edge_face(col, f"ef:{name}", V, scene.E, ob.F + n)
        _edge_face(col, f"fe:{name}", V, ob.E + n, scene.F, swap=True)
    return col


def _bodies(x_t0, x_t1, edges, faces, obstacles):
    """The scene, its mesh obstacles ``[(name, _Body)]``, half-spaces ``[(name, normal, offset)]``
    and analytic solids ``[(name, SolidFrames)]``."""
    from ..contact.solids import SolidFrames

    scene = _Body(x_t0, x_t1, edges, faces, "scene")
    obs, halves, solids = [], [], []
    for k, ob in enumerate(obstacles or []):
        if isinstance(ob, SolidFrames):
            solids.append((str(k), ob))
            continue
        if len(ob) == 2:
            normal = np.asarray(ob[0], dtype=np.float64)
            if normal.shape != (3,) or not np.isfinite(normal).all() or not normal.any():
                raise InputError(f"obstacles[{k}] normal must be a finite non-zero (3,) vector; got {normal.shape}")
            halves.append((str(k), normal, float(ob[1])))
            continue
        if len(ob) != 4:
            raise InputError(f"obstacles[{k}] must be (positions_t0, positions_t1, faces, edges) or "
                             f"(normal, offset); got {len(ob)} items")
        p0, p1, fo, eo = ob
        if fo is None and eo is None:
            raise InputError(f"obstacles[{k}] needs faces or edges; got neither")
        obs.append((str(k), _Body(p0, p1, eo, fo, f"obstacles[{k}]")))
    return scene, obs, halves, solids


def _add_listed(kind, start, path, pre, found):
    """Scene primitives found against a one-piece obstacle (a half-space, a solid) into the
    collectors: `found` = (start, path, pre) index arrays; pair j is 0."""
    for col, idx in zip((start, path, pre), found):
        if col is not None and len(idx):
            ij = np.stack([idx, np.zeros_like(idx)], axis=1)
            col.add(kind, ij, np.ones(len(idx), np.int8), np.zeros(len(idx)), np.zeros(len(idx)))


def _half_spaces(halves, scene, thickness, start, path, pre):
    """Exact half-space verdicts of every scene vertex into the collectors (pair j is 0)."""
    from ..contact.obstacles import half_space_verdict

    for name, normal, offset in halves:
        st, bad, old, sep = half_space_verdict(scene.x_t0, scene.x_t1, normal, offset, thickness,
                                               pre_existing=pre is not None)
        _add_listed(f"hs:{name}", start, path, pre, (st, bad, old))
        path.sep = min(path.sep, sep)


def _scene_simplices(scene):
    """The scene's primitives for a solid: faces, the edges given (a face covers its own
    edges, so only the extra ones matter; a repeated one is checked twice), the vertices
    of neither."""
    F, E = scene.F, scene.E_given
    used = np.zeros(len(scene.V), bool)
    used[F.ravel()] = True
    used[E.ravel()] = True
    return (("sf", F), ("se", E), ("sv", np.flatnonzero(~used)[:, None]))


def _solids(solids, scene, thickness, start, path, pre):
    """Exact-solid verdicts of the scene's primitives into the collectors (pair j is 0)."""
    from ..contact.solids import solid_verdict

    if not solids:
        return
    simplices = _scene_simplices(scene)
    for name, solid in solids:
        verdicts, sep = solid_verdict(scene.x_t0, scene.x_t1, [S for _, S in simplices], solid, thickness,
                                      pre_existing=pre is not None)
        for (tag, _), found in zip(simplices, verdicts):
            _add_listed(f"{tag}:{name}", start, path, pre, found)
        path.sep = min(path.sep, sep)


def check_thickness(thickness, name="thickness"):
    """`thickness` (or another distance named `name`) as a float; InputError unless
    finite, >= 0 and at most `SCALE_MAX`, the range a file's attributes are held to
    (beyond it the squared distances of the CCD and the certificate overflow)."""
    try:
        t = float(thickness)
    except (TypeError, ValueError):
        t = math.nan
    if not (np.isfinite(t) and 0.0 <= t <= SCALE_MAX):
        raise InputError(f"{name} must be finite, >= 0 and at most {SCALE_MAX:g}; got {thickness!r}")
    return t


def verify_step(x_t0, x_t1, *, edges=None, faces=None, thickness=0.0, obstacles=None,
                max_pairs=DEFAULT_MAX_PAIRS, obstacle_names=None, start_intersections=True,
                pre_existing=False, self_pairs=True) -> VerifyResult:
    """Prove (or refute) that the straight path x_t0 -> x_t1 keeps primitives apart.

    Parameters
    ----------
    x_t0, x_t1 : (N, 3) float
        Start and end positions; each vertex moves linearly. Any float dtype,
        computed in float64.
    edges : (E, 2) int, optional
        Segments (rods, yarn). With faces, extra edges are checked too.
    faces : (F, 3) int, optional
        Triangles (cloth); their edges are derived with `penfree.core.topology.scene_edges`.
    thickness : float >= 0
        Hard minimum separation: pairs closer than it (or touching, at 0) violate.
    obstacles : list
        Each either a mesh ``(positions_t0 (M, 3), positions_t1 (M, 3), faces or None,
        edges or None)`` moving linearly, a half-space ``(normal (3,), offset)``
        (free side ``normal . x > offset``, decided exactly per vertex), or an
        analytic solid (`penfree.core.contact.solids.SolidFrames`, decided per
        primitive by a supporting plane), checked against the scene only.
    max_pairs : int
        How many violating pairs to list (counts are always complete).
    obstacle_names : list of str, optional
        Names used in pair kinds (default "0", "1", ...).
    start_intersections : bool
        False skips the edge-face intersection test of the start state, for a
        start known to be intersection-free: the end state of a step that
        verified ok is (an edge can only come to meet a face through a
        vertex-face or edge-edge contact, which that step excluded).
        Start-state proximity violations are found either way.
    pre_existing : bool
        The reading for deform results (SPEC section 6): the start state is not
        judged. A pair within `thickness` at the start must only stay disjoint;
        pairs that already touch or intersect (and start edge-face intersections)
        are listed in ``pre_existing``, not as violations. The step is ok when the
        path adds no new intersecting or thickness-violating pair.
    self_pairs : bool
        False checks the scene against the obstacles only.

    Returns
    -------
    VerifyResult

    Notes
    -----
    Conservative: a near-miss closer than ~1e-10 of a pair's extent may be
    reported with thickness > 0; with thickness 0 the CCD is exact. Pairs
    sharing a vertex are adjacent and skipped. A violating start state is
    reported (``start_ok`` False) and makes the step not ok, unless
    `pre_existing`: then a pair is excused only when the exact thickness-0 test
    proves it touching at t = 0 (along a nonsingular affine path it stays as it
    was; an edge sliding out of a face it crosses meets the face's edges, a new
    contact that is not excused).

    Examples
    --------
    >>> x0 = np.array([[-1, 0, 1], [1, 0, 1], [0, -1, 0], [0, 1, 0.0]])
    >>> x1 = x0 - [[0, 0, 2], [0, 0, 2], [0, 0, 0], [0, 0, 0]]
    >>> r = verify_step(x0, x1, edges=[[0, 1], [2, 3]])
    >>> r.ok, r.pairs[0][:3]
    (False, ('ee', 0, 1))
    """
    thickness = check_thickness(thickness)
    max_pairs = int(max_pairs)
    scene, obs, halves, solids = _bodies(x_t0, x_t1, edges, faces, obstacles)
    if obstacle_names is not None:
        names = [str(nm) for nm in obstacle_names]
        obs = [(names[int(k)], b) for k, b in obs]
        halves = [(names[int(k)], nv, o) for k, nv, o in halves]
        solids = [(names[int(k)], sd) for k, sd in solids]
    checked = _start_check(scene, obs, self_pairs) if start_intersections else _Collector()
    start, pre = (_Collector(), checked) if pre_existing else (checked, None)
    path = _Collector()
    if self_pairs:
        _pairs_self(path, scene, thickness, static=False, start=None if pre_existing else start, pre=pre)
    for name, ob in obs:
        _pairs_between(path, scene, ob, name, thickness, start=None if pre_existing else start, pre=pre)
    _half_spaces(halves, scene, thickness, None if pre_existing else start, path, pre)
    _solids(solids, scene, thickness, None if pre_existing else start, path, pre)
    start_list, n_start = start.first(max_pairs)
    pairs, n_viol = path.first(max_pairs)
    pre_list, n_pre = pre.first(max_pairs) if pre is not None else ([], 0)
    return VerifyResult(
        ok=n_start == 0 and n_viol == 0, start_ok=n_start == 0,
        start_violations=[p[:3] for p in start_list], n_start_violations=n_start,
        # pairs the broad phase did not pass on are only known to stay beyond the thickness
        pairs=pairs, n_violations=n_viol, min_separation=min(path.sep, thickness),
        n_candidates=path.n_candidates, edges=scene.E if len(scene.E) else None,
        pre_existing=[p[:3] for p in pre_list], n_pre_existing=n_pre,
    )
