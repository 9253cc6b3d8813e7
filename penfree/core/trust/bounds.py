"""Per-vertex trust-region bounds of the OGC family (SPEC section 7) and the
smallest separation of a state.

Both rest on one per-vertex quantity: the smallest distance from a vertex's
primitives to the non-adjacent primitives around them, searched within a
query radius. The broad phase finds the pairs whose static boxes, inflated
by half the radius, overlap (every pair closer than the radius is among
them: the Euclidean distance is at least the per-axis box gap), and the pair
distances are folded into per-vertex minima inside the same parallel pass,
so no candidate list is ever stored.
"""

from __future__ import annotations

import numpy as np

from ...constants import DEFAULT_GAMMA, DEFAULT_RADIUS_FRACTION
from ...errors import InputError
from ..contact.broad_phase import fold_min_sq
from ..contact.proximity import per_vertex_separation
from ..topology import as_positions, as_topology, scene_edges

def scene_arrays(x, edges, faces):
    """Validated ``x (N, 3) float64``, ``E (M, 2) int64``, ``F (K, 3) int64``.

    For a triangle scene E holds the edges of the faces (plus any extra
    segments given); degenerate segments (i, i) are dropped. Other stages
    (pipeline, ladder) call this once per sequence and then
    `per_vertex_separation` per step.
    """
    x = as_positions(x, "x")
    n = x.shape[0]
    E = as_topology(edges, 2, n, "edges")
    F = as_topology(faces, 3, n, "faces")
    # Triangle scene: the edge-edge terms run over the edges of the faces (and any
    # extra segments given alongside).
    return x, scene_edges(E, F), F


def _radius(value, name):
    r = float(value)
    if not (np.isfinite(r) and r >= 0.0):
        raise InputError(f"{name} must be finite and >= 0; got {value}")
    return r


def obstacle_separation(x, E, F, obstacles, radius, s=0):
    """Per-vertex distance to the obstacles (held at frame `s`), capped at `radius`.

    Parameters
    ----------
    x : (N, 3) float64, C-contiguous
    E : (M, 2) int64, F : (K, 3) int64
        Scene topology as `scene_arrays` returns it.
    obstacles : list of `penfree.sequence.Obstacle`
    radius : float >= 0
    s : int
        Frame of kinematic obstacles.

    Returns
    -------
    (N,) float64
        ``min(radius, terms)``: a half-space gives the vertex's distance to its plane
        (0 on or behind it); a mesh the terms of SPEC section 7 between scene and
        obstacle primitives (scene vertex - obstacle face, obstacle vertex - scene face
        folded into the face's vertices, edge - edge), on the scene's side only; an
        analytic collider the same terms against its exact solid (lower bounds,
        `penfree.core.contact.solids.solid_separation`).
    """
    n = x.shape[0]
    d = np.full(n, float(radius))
    for ob in obstacles or ():
        if ob.is_half_space:
            d = np.minimum(d, _half_space_separation(x, E, F, ob))
        elif ob.shape is not None:
            from ..contact.solids import solid_separation

            d = np.minimum(d, solid_separation(x, E, F, ob.shape, radius, s))
        else:
            d = np.minimum(d, _mesh_separation(x, E, F, ob, radius, s))
    return d


def _half_space_separation(x, E, F, ob):
    """A vertex's distance to the plane (0 on or behind it): the vertex-face term against
    a floor, which has no vertices of its own near the scene."""
    nv = np.asarray(ob.normal, dtype=np.float64)
    return np.maximum((x @ nv - ob.offset) / float(np.linalg.norm(nv)), 0.0)


def _mesh_separation(x, E, F, ob, radius, s):
    n = x.shape[0]
    P = np.asarray(ob.frame(s), dtype=np.float64)
    _, Eo, Fo = scene_arrays(P, ob.edges, ob.faces)
    X = np.ascontiguousarray(np.concatenate([x, P]))
    Eo, Fo = Eo + n, Fo + n
    Vs = np.arange(n, dtype=np.int64)[:, None]  # every vertex meets the obstacle's faces (as a half-space)
    Vo = np.ascontiguousarray(np.unique(np.concatenate([Eo.ravel(), Fo.ravel()])).astype(np.int64)[:, None])
    partial = np.full((1, X.shape[0]), np.inf)
    infl = 0.5 * radius
    for A, B in ((E, Eo), (Vs, Fo), (Vo, F)):
        if len(A) and len(B):
            fold_min_sq(X, A, B, infl, partial, self_query=False)
    return np.minimum(np.sqrt(partial[0, :n]), radius)


def trust_region_bounds(x, *, edges=None, faces=None, thickness=0.0, gamma=DEFAULT_GAMMA,
                        query_radius=None, obstacles=None, frame=0, query=None) -> np.ndarray:
    """Per-vertex OGC trust-region bounds ``b_v = gamma * max(0, d_v - thickness)``.

    Parameters
    ----------
    x : (N, 3) float
        The start state (any float dtype; computed in float64).
    edges : (E, 2) int, optional
        Segments (rods, yarn). With `faces` given too, they are added to the
        face edges.
    faces : (F, 3) int, optional
        Triangles (cloth). Gives vertex-face terms and edge-edge terms over
        the edges of the faces.
    thickness : float >= 0
        Contact distance.
    gamma : float >= 0
        OGC gamma_p (0.45 in the authors' code).
    query_radius : float >= 0, optional
        r_q. The statistics pass ``contact_radius + max_v |x_pred[v] - x[v]|``.
        None: ``thickness + 0.1 * (bounding-box diagonal of x)``, which can
        be far larger than a step's motion and then costs many more pairs.
    obstacles : list of `penfree.sequence.Obstacle`, optional
        Colliders: their distances count in ``d_v`` (`obstacle_separation`), so a
        vertex resting on the floor gets a small bound, as in the simulator.
    frame : int
        Frame at which kinematic obstacles are taken.
    query : `penfree.core.contact.proximity.SeparationQuery`, optional
        Answers the scene's separations (the same values; for consecutive states of
        one scene, each query at the reach of the last one's). Must be of this
        scene's topology (`scene_arrays`).

    Returns
    -------
    b : (N,) float64
        ``d_v = min(r_q, terms)`` with the terms of SPEC section 7 (see
        `per_vertex_separation`); 0 where a gap is already below the
        thickness, never negative; ``gamma * (r_q - thickness)`` for a vertex
        with nothing within r_q (or, in a segment scene, in no edge).

    Notes
    -----
    Equals IPC Toolkit's ``Candidates.compute_per_vertex_safe_distances``
    (inflation radius r_q, min distance thickness) times gamma. Static
    distances of the closed primitives; adjacency = sharing a vertex index.

    Examples
    --------
    >>> x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 0.5, 0.1], [1, 0.5, 0.1]])
    >>> trust_region_bounds(x, edges=[[0, 1], [2, 3]], query_radius=1.0).round(4).tolist()
    [0.2295, 0.2295, 0.2295, 0.2295]
    """
    x, E, F = scene_arrays(x, edges, faces)
    thickness = _radius(thickness, "thickness")
    gamma = _radius(gamma, "gamma")
    if query_radius is None:
        diag = float(np.linalg.norm(np.ptp(x, axis=0))) if x.shape[0] else 0.0
        r_q = thickness + DEFAULT_RADIUS_FRACTION * diag
    else:
        r_q = _radius(query_radius, "query_radius")
    d = per_vertex_separation(x, E, F, r_q) if query is None else query(x, r_q)
    if obstacles:
        d = np.minimum(d, obstacle_separation(x, E, F, obstacles, r_q, frame))
    return gamma * np.maximum(0.0, d - thickness)


def min_separation(V, E=None, F=None, *, radius) -> float:
    """Smallest distance between non-adjacent primitives, searched within `radius`.

    Parameters
    ----------
    V : (N, 3) float
    E : (M, 2) int, optional
        Segments: edge-edge pairs.
    F : (K, 3) int, optional
        Triangles: vertex-face pairs and edge-edge pairs over the face edges.
    radius : float >= 0

    Returns
    -------
    float
        The smallest distance, or `radius` itself when no pair is closer
        (read: "at least `radius`"). Pairs sharing a vertex are adjacent and
        skipped.

    Examples
    --------
    >>> V = np.array([[0.0, 0, 0], [1, 0, 0], [0.5, -1, 0.3], [0.5, 1, 0.3]])
    >>> min_separation(V, E=[[0, 1], [2, 3]], radius=1.0)
    0.3
    """
    x, E_, F_ = scene_arrays(V, E, F)
    r = _radius(radius, "radius")
    if x.shape[0] == 0:
        return r
    return float(per_vertex_separation(x, E_, F_, r).min())
