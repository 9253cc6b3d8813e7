"""Pair-level checks over one state's near pairs, for the step gate and the pipeline:
`near_pairs` (one static proximity query), `check_pairs` (the deform-result reading of
`verify_step` restricted to those pairs) and `start_intersections` (the pre-existing
contacts a deform result reports)."""

from __future__ import annotations

import numpy as np

from .path import _Body, _Collector, _inflation, _narrow, _pairs_self, _self_candidates, _start_check


def near_pairs(x, edges, faces, radius, keep=None, topology=None):
    """The scene's own pairs that may lie within `radius` of each other at `x` (one query).

    Parameters
    ----------
    x : (N, 3) float
    edges, faces : topology or None
    radius : float >= 0
    keep : (N,) bool, optional
        Vertices that may be in a pair within `radius`; only primitives all of whose
        vertices are kept are searched. The caller must know that the others are not:
        a vertex whose per-vertex separation (`per_vertex_separation`, every vertex in
        a primitive) is at least `radius` is in no such pair, since each pair's
        distance is one of its vertices' terms (`StepGate.use_separations`). Ignored
        when a vertex is in no primitive (its pairs with faces are no one's term).
    topology : SceneTopology, optional
        The scene's topology, made once for many states (`edges` and `faces` are then
        not read).

    Returns
    -------
    list of (kind, ij, idx)
        Candidates of the static broad phase with boxes inflated by half the radius
        (a superset of the pairs closer than it), in the form `check_pairs` takes;
        with `keep`, those among the kept primitives (same indices: ``ij`` into the
        scene's edges, vertices and faces).
    """
    body = _Body(x, x, edges, faces, "scene", topology)
    if keep is not None and not body.topology.all_referenced:
        keep = None
    return _self_candidates(body, body.x_t0, body.x_t0, _inflation(radius, body.x_t0), keep)


def check_pairs(pairs, x_t0, x_t1, thickness) -> bool:
    """True when none of `pairs` (from `near_pairs`) violates along x_t0 -> x_t1.

    Deform-result reading (`verify_step` with ``pre_existing=True``): a pair within
    `thickness` at the start must stay disjoint, one touching at the start must not
    move; every other pair must stay `thickness` apart (conservative CCD).
    """
    X0 = np.ascontiguousarray(x_t0, dtype=np.float64)
    X1 = np.ascontiguousarray(x_t1, dtype=np.float64)
    col, pre = _Collector(), _Collector()
    for kind, ij, idx in pairs:
        _narrow(col, kind, ij, idx, X0, X1, kind, thickness, pre=pre)
    return not col.kinds


def start_intersections(x, edges=None, faces=None) -> int:
    """Pairs of non-adjacent primitives that already touch or intersect in state `x`.

    Edge-face intersections (triangle scenes) plus vertex-face and edge-edge pairs
    at distance 0 (exact static test); the count a deform result reports as its
    step's pre-existing intersections.
    """
    scene = _Body(x, x, edges, faces, "scene")
    col = _start_check(scene, [])
    _pairs_self(col, scene, 0.0, static=True)
    return int(col.first(0)[1])
