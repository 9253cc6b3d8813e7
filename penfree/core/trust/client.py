"""Replay of a step through an OGC trust-region client: the CD passes it really needs.

The client is IPC Toolkit's ``ipctk.ogc.TrustRegion`` (``client="ipctk"``, the
optional extra ``penfree[ogc]``) or penfree's own re-implementation of it
(``client="own"``: `trust_region_bounds` for the radii and `penfree.core.planar`
for the filters; no ipctk needed, used by `auto` to predict). One replay of a step,
from a start state ``x_s`` (the recorded ``x`` = baseline, or ``x_def``):

1. **Warm start.** Radius rule ``own``: ``warm_start_time_step`` (its inflation
   radius is ``max(2 dhat, max_v |x_pred - x_s|)``, one CD pass, an isotropic move
   toward ``x_pred`` within the radii, a second pass when more than 1% of the
   vertices were truncated). Radius rule ``step``: the inflation radius the
   simulator computed at the recorded ``x``, ``max(2 dhat, max_v |x_pred - x|)``,
   is set, then ``update`` (one CD pass) and a move toward ``x_pred`` filtered by
   the truncation under test, and ``update`` again if the filter asked for it.
2. **Iterations.** The proposed step is the rest of the way to ``x_next``
   (``x_next - x_cur``), filtered by ``filter_step`` (isotropic) or
   ``planar_filter_step`` (planar); ``update`` runs whenever the filter set
   ``should_update_trust_region`` (more than 1% of the vertices truncated).
3. **Stopping.** When every vertex is within ``tol`` of ``x_next``; or after an
   iteration that asked for no update (the vertices that reached their target stay
   there, the fewer than 1% still truncated are what the client tolerates: one
   more iteration would repeat the same filter without a CD pass); or after
   ``max_iter`` iterations.
4. **Count.** CD passes (every ``update``, the first included) and iterations.

With the sequence's obstacles (``obstacles=``), the client's collision mesh holds them
after the scene's vertices, as a simulator's does (`client_scene`): their distances
shrink the trust regions of the vertices near them.
"""

from __future__ import annotations

import numpy as np

from ... import constants as K
from ...errors import InputError
from .planar import (
    KIND_EDGE_EDGE, KIND_VERTEX_FACE, RELAXED_RADIUS_SCALING, candidate_stencils, isotropic_filter,
    planar_filter,
)
from ..contact.proximity import SeparationQuery
from .bounds import scene_arrays
from .client_scene import ClientScene
from .stencil_list import StencilList, contains, region

#: A `ClientQuery` builds a `StencilList` over a declared region at this many fresh
#: (not memoised) stencil queries within it at one radius: a replay that ends after its
#: first passes does not pay for a list.
STENCIL_LIST_AFTER = 2

TRUNCATIONS = ("isotropic", "planar")
RADIUS_RULES = ("own", "step")
CLIENTS = ("ipctk", "own")
#: How to get the real client when it is missing (printed by the CLI, exit 2).
IPCTK_HINT = "the real-client replay needs IPC Toolkit: pip install 'penfree[ogc]' (ipctk 1.6.1)"


def load_ipctk():
    """Import ipctk or raise `InputError` saying how to install it."""
    try:
        import ipctk
    except ImportError as exc:
        raise InputError(f"{IPCTK_HINT} ({exc})") from None
    if not hasattr(ipctk, "ogc") or not hasattr(ipctk.ogc, "TrustRegion"):
        raise InputError(f"{IPCTK_HINT}; the installed ipctk has no ogc.TrustRegion")
    return ipctk


def inflation_radius(x, x_pred, dhat) -> float:
    """ipctk's warm-start radius ``max(2 dhat, max_v |x_pred - x|)``."""
    d = np.linalg.norm(np.asarray(x_pred, dtype=np.float64) - np.asarray(x, dtype=np.float64), axis=1)
    return max(2.0 * float(dhat), float(d.max()) if d.size else 0.0)


def warm_start_move(x, x_pred, radii) -> tuple:
    """``warm_start_time_step``'s move (ipctk's ``trust_region.cpp``): each vertex to
    `x_pred` if within its radius, else toward it by its radius (a vertex of radius 0
    stays). Returns the moved ``(N, 3)`` positions and the count of those held back."""
    x_pred = np.asarray(x_pred, dtype=np.float64)
    dx = x_pred - x
    norm = np.linalg.norm(dx, axis=1)
    held = ~(norm <= radii)
    ratio = np.divide(radii, norm, out=np.ones_like(norm), where=held)
    return np.where(held[:, None], x + ratio[:, None] * dx, x_pred), int(np.count_nonzero(held))


class IpctkClient:
    """``ipctk.ogc.TrustRegion`` behind the small interface the replay drives."""

    def __init__(self, V, E, F, dhat, thickness, truncation, n_dynamic=None):
        ipctk = load_ipctk()
        self._ipctk = ipctk
        E_ = np.asfortranarray(E, dtype=np.int32).reshape(-1, 2)
        F_ = np.asfortranarray(F, dtype=np.int32).reshape(-1, 3)
        self.mesh = ipctk.CollisionMesh(np.asfortranarray(V, dtype=np.float64), E_, F_)
        if n_dynamic is not None and n_dynamic < np.asarray(V).shape[0]:  # obstacles follow: no pairs among them
            self.mesh.can_collide = ipctk.make_static_obstacle_filter(int(n_dynamic))
        self.tr = ipctk.ogc.TrustRegion(float(dhat))
        self.collisions = ipctk.NormalCollisions()
        self.dhat, self.thickness, self.truncation = float(dhat), float(thickness), truncation

    def set_radius(self, R):
        self.tr.trust_region_inflation_radius = float(R)

    def update(self, x):
        """One CD pass at `x`; True when a negative radius was clamped."""
        self.tr.update(self.mesh, np.asfortranarray(x), self.collisions, self.thickness)
        self.tr.should_update_trust_region = False
        r = np.asarray(self.tr.trust_region_radii)
        if not (r < 0).any():
            return False
        # ipctk 1.6.1 leaves a vertex with a pair within the thickness (a crossing, or
        # resting closer than the thickness) a negative radius, 0.45 (d - thickness),
        # which its warm start follows backwards; the OGC bound is 0 there (SPEC
        # section 7), as the own client has it.
        self.tr.trust_region_radii = np.maximum(r, 0.0)
        return True

    def warm_start(self, x, x_pred):
        """ipctk's ``warm_start_time_step``: the radius ``max(2 dhat, max_v |x_pred - x|)``,
        one CD pass, every vertex moved toward `x_pred` within its radius, a second pass
        when more than 1% were truncated. Returns the moved x and its CD passes (1 or 2).

        The native call, unless a radius at `x` is negative: then its steps are run
        here (`warm_start_move`) on the clamped radii. (Only the native call gives its
        positions bit for bit: Eigen rounds the moves differently in the last bit, and
        the planar filter's counts can follow such bits.) The check costs one more
        neighbourhood query, not a counted pass."""
        x = np.array(x, dtype=np.float64)
        x_pred = np.asarray(x_pred, dtype=np.float64)
        self.set_radius(inflation_radius(x, x_pred, self.dhat))
        if self.update(x):
            x_new, n_held = warm_start_move(x, x_pred, np.asarray(self.tr.trust_region_radii, dtype=np.float64))
            passes = 1
            if n_held > K.CLIENT_UPDATE_THRESHOLD * x.shape[0]:
                self.update(x_new)
                passes += 1
            return x_new, passes
        xs = np.array(x, dtype=np.float64, order="F")
        self.tr.warm_start_time_step(self.mesh, xs, np.asfortranarray(x_pred), self.collisions, self.dhat,
                                     self.thickness)
        # The second, conditional update re-centres the regions at the moved x.
        second = not np.array_equal(np.asarray(self.tr.trust_region_centers), x)
        self.tr.should_update_trust_region = False
        return np.ascontiguousarray(xs), 1 + int(second)

    def filter(self, x, dx):
        d = np.array(dx, dtype=np.float64, order="F")
        xf = np.asfortranarray(x, dtype=np.float64)
        if self.truncation == "planar":
            self.tr.planar_filter_step(self.mesh, xf, d)
        else:
            self.tr.filter_step(self.mesh, xf, d)
        flag = bool(self.tr.should_update_trust_region)
        return np.ascontiguousarray(d), flag


class ClientQuery:
    """The own client's neighbourhood queries of one scene, shared by its replays.

    Parameters
    ----------
    V : (N, 3) float
        Any positions of the scene (only N and the validation use them).
    edges, faces : int arrays or None
        The topology, as `replay_step` takes it; `replay_step` accepts this query only
        with these very objects.
    obstacles : sequence of `penfree.sequence.Obstacle`, optional
        The scene's obstacles (`client_scene.ClientScene`); `replay_step` accepts this
        query only with the same obstacle objects.

    Notes
    -----
    Three savings, none of which changes a result:

    - one `SeparationQuery` for all replays: its cell shapes and reach carry over
      from pass to pass, and its separations are the same bits as a fresh query's;
    - a memo of the last `CLIENT_QUERY_MEMO` start states' results (a replay's first
      pass; later passes are looked up, not kept). Every replay's first pass queries
      its start state, and the replays of a step start from few states:
      doing nothing and each candidate's ``x_def``, each replayed toward two targets by
      `client_select.choose_by_client`, and with both truncations by `client_counts`.
      A state matches only bit for bit, at the same radius;
    - the stencils of a replay's later passes from one `stencil_list.StencilList` over
      the states it moves between (`expect`): the same arrays as a fresh query's.

    Examples
    --------
    >>> x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 0.5, 0.1], [1, 0.5, 0.1]])
    >>> q = ClientQuery(x, [[0, 1], [2, 3]], None)
    >>> d = q.separations(x, 5.0, start=True)
    >>> d.round(3).tolist(), q.separations(x, 5.0) is d, q.info
    ([0.51, 0.51, 0.51, 0.51], True, {'queries': 1, 'memo_hits': 1, 'lists': 0, 'listed': 0})
    """

    def __init__(self, V, edges, faces, obstacles=()):
        self.n = np.asarray(V).shape[0]
        self.edges, self.faces, self.obstacles = edges, faces, tuple(obstacles or ())
        if self.obstacles:
            self.scene = ClientScene(V, edges, faces, self.obstacles)
            self.E, self.F = self.scene.E, self.scene.F
            self.query = SeparationQuery(self.scene.E_scene, self.scene.F_scene)  # + the scene's cross terms
        else:
            _, self.E, self.F = scene_arrays(V, edges, faces)
            self.scene = None
            self.query = SeparationQuery(self.E, self.F)  # each pass at the reach of the last
        self._memo = []  # [x's bits, {radius: separations}, {radius: (stencils, kinds)}], newest last
        self._region, self._lists, self._misses = None, {}, {}  # `expect`
        self.info = {"queries": 0, "memo_hits": 0, "lists": 0, "listed": 0}

    def _entry(self, x, start):
        bits = x.view(np.uint64)
        for k, e in enumerate(self._memo):
            if np.array_equal(e[0], bits):
                self._memo.append(self._memo.pop(k))
                return e
        if not start:  # only start states repeat
            return [None, {}, {}]
        self._memo.append([bits.copy(), {}, {}])
        del self._memo[:-K.CLIENT_QUERY_MEMO]
        return self._memo[-1]

    def separations(self, x, R, start=False):
        """(N,) float64 separations at `x` (C-contiguous float64) capped at `R`;
        `start`: a replay's start state, kept in the memo. With obstacles `x` holds
        their vertices too, and so does the result."""
        e = self._entry(x, start)
        if R in e[1]:
            self.info["memo_hits"] += 1
        else:
            e[1][R] = self._separations(x, R)
            self.info["queries"] += 1
        return e[1][R]

    def _separations(self, x, R):
        if self.scene is None:
            return self.query(x, R)
        d = np.full(x.shape[0], float(R))
        d[:self.n] = self.query(np.ascontiguousarray(x[:self.n]), R)
        return np.minimum(d, self.scene.cross_separations(x, R))

    def expect(self, states):
        """Declare the states the next passes move between (a replay's start and targets,
        as the client's arrays): their passes' stencils then come from one
        `stencil_list.StencilList` over that region, built at the region's
        `STENCIL_LIST_AFTER`-th fresh query at a radius. A region inside the last one
        keeps its lists (a replay toward the half-way point after the one toward the
        target)."""
        reg = region(states)
        if self._region is None or not contains(self._region, reg):
            self._region, self._lists, self._misses = reg, {}, {}

    def stencils(self, x, radius, start=False):
        """`planar.candidate_stencils` of `x` within `radius` (`start` as in `separations`),
        the same arrays whether a fresh query or a `StencilList` answers."""
        e = self._entry(x, start)
        if radius in e[2]:
            self.info["memo_hits"] += 1
        else:
            e[2][radius] = self._stencils(x, radius, start)
        return e[2][radius]

    def _stencils(self, x, radius, start):
        lst = self._lists.get(radius)
        if lst is None and not start and self._region is not None:
            self._misses[radius] = self._misses.get(radius, 0) + 1
            if self._misses[radius] >= STENCIL_LIST_AFTER and contains(self._region, (x, x)):
                keep = None if self.scene is None else self.scene.scene_pairs
                lst = self._lists[radius] = StencilList(*self._region, self.E, self.F, radius, keep)
                self.info["lists"] += 1
        if lst is not None and lst.covers(x):
            self.info["listed"] += 1
            return lst.stencils_at(x)
        st, kinds = candidate_stencils(x, self.E, self.F, radius)
        if self.scene is not None:
            keep = self.scene.scene_pairs(st)
            st, kinds = np.ascontiguousarray(st[keep]), np.ascontiguousarray(kinds[keep])
        return st, kinds


class OwnClient:
    """penfree's re-implementation of the client (same interface as `IpctkClient`).

    Radii ``(s / 2) min(R - thickness, d_v - thickness)`` with ``s`` =
    `RELAXED_RADIUS_SCALING` (= gamma_p 0.45 times 2), the candidates of the planar
    filter from penfree's broad phase within ``R + thickness``; the queries through a
    `ClientQuery` (the replay's own, or one shared by the replays of a scene). A pass's
    separations are queried when its radii are first read (a warm start, the isotropic
    filter): the planar filter never reads them.
    """

    def __init__(self, V, E, F, dhat, thickness, truncation, query=None):
        self.q = ClientQuery(V, E, F) if query is None else query
        self.E, self.F = self.q.E, self.q.F
        self.dhat, self.thickness, self.truncation = float(dhat), float(thickness), truncation
        self.R = 2.0 * self.dhat
        self.n = np.asarray(V).shape[0]
        self._started = False

    def set_radius(self, R):
        self.R = float(R)

    def update(self, x):
        x = np.ascontiguousarray(x, dtype=np.float64)
        self.centers = x.copy()
        start, self._started = not self._started, True  # the replay's first pass: its start state
        # the radii when asked for: the planar filter never asks (only a warm start does)
        self._pass, self._radii = (self.centers, self.R, start), None
        if self.truncation == "planar":
            self.stencils, self.kinds = self.q.stencils(x, self.R + self.thickness, start)

    @property
    def radii(self):
        """(N,) the trust-region radii of the last pass (its separations queried on first use)."""
        if self._radii is None:
            x, R, start = self._pass
            d = self.q.separations(x, R, start)
            self._radii = 0.5 * RELAXED_RADIUS_SCALING * np.maximum(0.0, d - self.thickness)
        return self._radii

    def warm_start(self, x, x_pred):
        x = np.array(x, dtype=np.float64)
        self.set_radius(inflation_radius(x, x_pred, self.dhat))
        self.update(x)
        x_new, n_held = warm_start_move(x, x_pred, self.radii)
        passes = 1
        if n_held > K.CLIENT_UPDATE_THRESHOLD * self.n:
            self.update(x_new)
            passes += 1
        return x_new, passes

    def filter(self, x, dx):
        if self.truncation == "planar":
            out, n_trunc = planar_filter(x, dx, self.centers, self.R, self.stencils, self.kinds)
        else:
            out, n_trunc = isotropic_filter(x, dx, self.centers, self.radii)
        return out, n_trunc > K.CLIENT_UPDATE_THRESHOLD * self.n


def make_client(client, V, E, F, dhat, thickness, truncation, query=None, n_dynamic=None):
    """An `IpctkClient` or `OwnClient` for one replay (`query`: the own client's shared
    `ClientQuery`, if any, which knows the obstacles; `n_dynamic`: ipctk's count of
    scene vertices, the obstacles' following)."""
    if client not in CLIENTS:
        raise InputError(f"client must be one of {CLIENTS}; got {client!r}")
    if truncation not in TRUNCATIONS:
        raise InputError(f"truncation must be one of {TRUNCATIONS}; got {truncation!r}")
    if not (np.isfinite(dhat) and dhat > 0):
        raise InputError(f"dhat must be finite and > 0 (give --dhat or a contact_radius); got {dhat}")
    if client == "ipctk":
        return IpctkClient(V, E, F, dhat, thickness, truncation, n_dynamic)
    return OwnClient(V, E, F, dhat, thickness, truncation, query)


def replay_step(x_s, x, x_pred, x_next, *, edges=None, faces=None, dhat, thickness=0.0, truncation="isotropic",
                radius="step", client="ipctk", tol=None, max_iter=K.DEFAULT_CLIENT_MAX_ITER, query=None,
                obstacles=(), frame=None) -> dict:
    """CD passes and iterations of one step replayed through the client (module doc).

    Parameters
    ----------
    x_s : (N, 3) float
        Start state: the recorded `x` (baseline) or penfree's `x_def`.
    x, x_pred, x_next : (N, 3) float
        Recorded start, prediction ``2 x - x_prev`` (the warm-start target) and the
        recorded next frame (the target of the iterations).
    edges, faces : int arrays, optional
        Topology (as `trust_region_bounds`).
    dhat : float > 0
        Contact offset of the client (``TrustRegion(dhat)``; radius floor ``2 dhat``).
    thickness : float
        ``min_distance`` of the client's CD.
    truncation : {"isotropic", "planar"}
    radius : {"step", "own"}
        ``step``: keep the inflation radius of the recorded `x`; ``own``: ipctk's
        warm start recomputes it from `x_s`.
    client : {"ipctk", "own"}
    tol : float, optional
        Distance to `x_next` counted as arrived (default `DEFAULT_CLIENT_TOL_REL`
        times ``max_v |x_next - x|``, at least 1e-12).
    max_iter : int
        Cap on iterations after the warm start.
    query : ClientQuery, optional
        The own client's queries, shared by the replays of one scene (built from these
        very `edges` and `faces` objects; ipctk runs its own); the counts are the same
        as without it.
    obstacles : sequence of `penfree.sequence.Obstacle`, optional
        Colliders in the client's collision mesh (`client_scene.ClientScene`: mesh
        obstacles at `frame` in the start states and at ``frame + 1`` in the targets,
        a half-space as one large triangle under the scene).
    frame : int
        The step's frame ``s`` (needed with mesh obstacles).

    Returns
    -------
    dict
        ``passes`` (CD passes, >= 1), ``iterations``, ``converged`` (all vertices
        within `tol` of `x_next`), ``n_truncated`` (vertices farther than `tol` at
        the end).

    Examples
    --------
    >>> import numpy as np
    >>> x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 0, 1], [1, 0, 1]])
    >>> r = replay_step(x, x, x + 0.001, x + 0.002, edges=[[0, 1], [2, 3]], dhat=0.01, client="own")
    >>> r["passes"], r["converged"]
    (1, True)
    """
    x_s = np.array(x_s, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    x_pred = np.asarray(x_pred, dtype=np.float64)
    x_next = np.asarray(x_next, dtype=np.float64)
    if radius not in RADIUS_RULES:
        raise InputError(f"radius rule must be one of {RADIUS_RULES}; got {radius!r}")
    for name, a in (("x", x), ("x_pred", x_pred), ("x_next", x_next)):
        if a.shape != x_s.shape or a.ndim != 2 or a.shape[1] != 3:
            raise InputError(f"{name} must be (N, 3) like x_s {x_s.shape}; got {a.shape}")
    obstacles = tuple(obstacles or ())
    if frame is None and any(not ob.is_half_space for ob in obstacles):
        raise InputError("replay_step: mesh obstacles need the step's frame")
    n = x.shape[0]
    if client != "own":
        query = None  # ipctk runs its own queries
    elif query is None and obstacles:  # the own client leaves obstacle pairs out through its query
        query = ClientQuery(x, edges, faces, obstacles)
    if tol is None:
        span = float(np.linalg.norm(x_next - x, axis=1).max()) if n else 0.0
        tol = max(1e-12, K.DEFAULT_CLIENT_TOL_REL * span)
    if query is not None:
        if (query.edges is not edges or query.faces is not faces or query.n != n
                or len(query.obstacles) != len(obstacles)
                or any(a is not b for a, b in zip(query.obstacles, obstacles))):
            raise InputError("replay_step: the query was built for another scene (pass the edges, faces and "
                             "obstacle objects it was built from, and positions of its N)")
        E, F, scene = query.E, query.F, query.scene
    elif obstacles:  # ipctk
        scene = ClientScene(x, edges, faces, obstacles)
        E, F = scene.E, scene.F
    else:
        E = np.zeros((0, 2), np.int64) if edges is None else np.asarray(edges)
        F = np.zeros((0, 3), np.int64) if faces is None else np.asarray(faces)
        if F.size:  # a triangle scene: the client's edges are the face edges
            _, E, F = scene_arrays(x, E, F)
        scene = None
    if scene is not None:  # the largest radius the client can query, for a ground's triangle
        reach = max(inflation_radius(x, x_pred, dhat), inflation_radius(x_s, x_pred, dhat)) + float(thickness)
        x_s, x, x_pred, x_next = scene.states(frame, [x_s, x, x_pred, x_next], reach, ref=1)
    cl = make_client(client, x, E, F, dhat, thickness, truncation, query, n_dynamic=n)
    if client == "own" and truncation == "planar":  # every pass lies between these (`stencil_list`)
        cl.q.expect((x_s, x_pred, x_next))
    if radius == "own":
        xc, passes = cl.warm_start(x_s, x_pred)
    else:
        cl.set_radius(inflation_radius(x, x_pred, dhat))
        cl.update(x_s)
        dx, flag = cl.filter(x_s, x_pred - x_s)
        xc = x_s + dx
        passes = 1
        if flag:
            cl.update(xc)
            passes += 1
    iterations = 0
    for _ in range(int(max_iter)):
        dx = x_next - xc
        if float(np.abs(dx).max(initial=0.0)) <= tol and not (np.linalg.norm(dx, axis=1) > tol).any():
            break
        dx, flag = cl.filter(xc, dx)
        xc = xc + dx
        iterations += 1
        if not flag:
            break
        cl.update(xc)
        passes += 1
    left = int(np.count_nonzero(np.linalg.norm(x_next[:n] - xc[:n], axis=1) > tol))
    return {"passes": passes, "iterations": iterations, "converged": left == 0, "n_truncated": left}


__all__ = ["replay_step", "ClientQuery", "inflation_radius", "load_ipctk", "make_client", "TRUNCATIONS", "RADIUS_RULES",
           "CLIENTS", "IPCTK_HINT", "KIND_EDGE_EDGE", "KIND_VERTEX_FACE"]
