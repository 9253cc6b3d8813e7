"""The client's collision mesh: the scene followed by its obstacles.

A simulator of the OGC family runs its CD passes over one collision mesh that holds
the cloth or rods *and* the colliders: a vertex resting on the ground gets a small
trust region from the ground, and the client's passes follow. `replay_step` replays a
step over such a mesh when it is given the sequence's obstacles:

- **a mesh obstacle** adds its vertices and faces (or edges): at frame ``s`` in the
  start states (``x_s`` and ``x``), at frame ``s + 1`` in the targets (``x_pred`` and
  the iterations' target), or ``2 P[s] - P[s - 1]`` when the recording ends at ``s``
  (`predeform`'s single step). The client moves its vertices like any other (ipctk's
  ``TrustRegion`` filters every vertex of its mesh; a static obstacle has no motion).
- **a half-space** adds one triangle in its plane, centred under the bounding box of
  the step's recorded `x` (the same for every replay of a step), whose inscribed circle
  has a radius of ``2 (rho + reach)`` rounded up to a power of two (``rho``: the
  largest distance of a replay's scene positions from that centre; ``reach``: the
  largest distance the client queries, thickness included). Every scene vertex lies
  over the triangle, farther than ``reach`` inside its edges, so the distances the
  client finds to it are the distances to the plane; one triangle has no inner edge
  to add edge-edge terms a plane has not.

The scene's own vertices keep their indices ``0 .. N - 1``; the obstacles' follow in
the order of the list. Pairs of two obstacle primitives are left out, as a simulator
leaves them out (ipctk: ``make_static_obstacle_filter(N)``; the own client:
`cross_separations` and `scene_pairs`): a box standing on the ground is no contact.
"""

from __future__ import annotations

import numpy as np

from ...errors import InputError
from ..contact.broad_phase import fold_min_sq
from .bounds import scene_arrays

#: A half-space's triangle: one face over its three corners.
_GROUND_FACE = np.array([[0, 1, 2]], dtype=np.int64)


class ClientScene:
    """The topology of a scene with `obstacles`, and its states.

    Parameters
    ----------
    V : (N, 3) float
        Any positions of the scene (validated with its topology; N is what is kept).
    edges, faces : int arrays or None
        The scene's topology (as `scene_arrays` takes it).
    obstacles : sequence of `penfree.sequence.Obstacle`

    Attributes
    ----------
    E : (M, 2) int64, F : (K, 3) int64
        The client's primitives over all vertices (a triangle scene's edges are its
        faces' edges, as `scene_arrays` gives them): the scene's (``E_scene``,
        ``F_scene``) followed by the obstacles' (``E_obstacles``, ``F_obstacles``).
    n, m : int
        The scene's vertex count and the whole mesh's.

    Examples
    --------
    >>> from penfree.sequence import Obstacle
    >>> x = np.array([[0.0, 0, 1], [1, 0, 1]])
    >>> sc = ClientScene(x, [[0, 1]], None, [Obstacle("ground", normal=np.array([0.0, 0, 1]), offset=0.0)])
    >>> sc.m, sc.F.tolist()
    (5, [[2, 3, 4]])
    >>> X = sc.states(1, [x, x, x, x], reach=0.1)[0]
    >>> X[2:, 2].tolist()
    [0.0, 0.0, 0.0]
    """

    def __init__(self, V, edges, faces, obstacles):
        V, self.E_scene, self.F_scene = scene_arrays(V, edges, faces)
        self.n = V.shape[0]
        self.obstacles = tuple(obstacles)
        Es, Fs, m = [np.zeros((0, 2), np.int64)], [np.zeros((0, 3), np.int64)], self.n
        for ob in self.obstacles:
            if ob.is_half_space:
                Fs.append(_GROUND_FACE + m)
                m += 3
                continue
            if ob.edges is not None:
                Es.append(np.asarray(ob.edges, dtype=np.int64).reshape(-1, 2) + m)
            if ob.faces is not None:
                Fs.append(np.asarray(ob.faces, dtype=np.int64).reshape(-1, 3) + m)
            m += ob.positions.shape[-2]  # (M, 3) or (T, M, 3), in memory or streamed
        self.m = m
        _, self.E_obstacles, self.F_obstacles = scene_arrays(np.zeros((m, 3)), np.concatenate(Es), np.concatenate(Fs))
        self.E = np.concatenate([self.E_scene, self.E_obstacles])
        self.F = np.concatenate([self.F_scene, self.F_obstacles])

    def cross_separations(self, X, R) -> np.ndarray:
        """(m,) float64: each vertex's distance to the other side (scene to obstacles,
        obstacles to scene; SPEC section 7's terms, obstacle pairs left out as the
        client leaves them out), capped at `R`."""
        X = np.ascontiguousarray(X, dtype=np.float64)
        n = self.n
        Vs = np.arange(n, dtype=np.int64)[:, None]
        Vo = np.arange(n, self.m, dtype=np.int64)[:, None]
        partial = np.full((1, self.m), np.inf)
        for A, B in ((self.E_scene, self.E_obstacles), (Vs, self.F_obstacles), (Vo, self.F_scene)):
            if len(A) and len(B):
                fold_min_sq(X, A, B, 0.5 * float(R), partial, self_query=False)
        return np.minimum(np.sqrt(partial[0]), float(R))

    def scene_pairs(self, stencils) -> np.ndarray:
        """(C,) bool: the stencils (rows of vertex ids) that touch the scene (the client
        leaves pairs of obstacle primitives out)."""
        return (np.asarray(stencils) < self.n).any(axis=1)

    def states(self, s, xs, reach, n_start=2, ref=0) -> list:
        """The scene states `xs` (``(N, 3)`` each: the start states first, then the
        targets) extended by the obstacles: at frame `s` in the first `n_start`, at
        their target (module doc) in the rest; a half-space's triangle under ``xs[ref]``,
        `reach` inside its edges. Returns ``(m, 3)`` float64 arrays."""
        xs = [np.asarray(x, dtype=np.float64) for x in xs]
        for x in xs:
            if x.shape != (self.n, 3):
                raise InputError(f"client scene states must be ({self.n}, 3); got {x.shape}")
        if not self.obstacles:
            return xs
        s = 0 if s is None else int(s)
        centre = 0.5 * (xs[ref].min(axis=0) + xs[ref].max(axis=0)) if self.n else np.zeros(3)
        rho = max((float(np.linalg.norm(x - centre, axis=1).max()) for x in xs), default=0.0) if self.n else 0.0
        start, target = [], []
        for ob in self.obstacles:
            if ob.is_half_space:
                P = _ground_triangle(ob, centre, rho, float(reach))
                start.append(P)
                target.append(P)
            else:
                P = np.asarray(ob.frame(s), dtype=np.float64)
                start.append(P)
                target.append(_target_frame(ob, s, P))
        start, target = np.concatenate(start), np.concatenate(target)
        return [np.ascontiguousarray(np.concatenate([x, start if k < n_start else target]))
                for k, x in enumerate(xs)]


def _target_frame(ob, s, P) -> np.ndarray:
    """A mesh obstacle at frame ``s + 1``, or moved on at its last velocity past the
    recording's end (`P`: its frame `s`)."""
    if np.ndim(ob.positions) == 2:
        return P
    T = len(ob.positions)
    if s + 1 < T:
        return np.asarray(ob.frame(s + 1), dtype=np.float64)
    return 2.0 * P - np.asarray(ob.frame(s - 1), dtype=np.float64) if s >= 1 else P


def _ground_triangle(ob, centre, rho, reach) -> np.ndarray:
    """(3, 3): the half-space's triangle under `centre` (module doc): inradius
    ``2 (rho + reach)`` rounded up to a power of two, so that the replays of a step
    share it (and the own client's memo of their start states holds)."""
    nrm = np.asarray(ob.normal, dtype=np.float64)
    scale = float(np.linalg.norm(nrm))
    nrm = nrm / scale
    c = centre - (centre @ nrm - float(ob.offset) / scale) * nrm
    u = np.cross(nrm, np.eye(3)[int(np.argmin(np.abs(nrm)))])
    u /= np.linalg.norm(u)
    v = np.cross(nrm, u)
    inradius = 2.0 ** np.ceil(np.log2(max(2.0 * (rho + reach), 1e-300)))
    # an equilateral triangle's corners lie at twice its inradius from its centre
    return np.array([c + 2.0 * inradius * (np.cos(a) * u + np.sin(a) * v)
                     for a in (np.pi / 2, np.pi / 2 + 2 * np.pi / 3, np.pi / 2 + 4 * np.pi / 3)])


__all__ = ["ClientScene"]
