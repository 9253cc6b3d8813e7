"""Pair-level checks over one state's near pairs, for the step gate and the pipeline:
`near_pairs` (one static proximity query), `check_pairs` (the deform-result reading of
`verify_step` restricted to those pairs) and `start_intersections` (the pre-existing
contacts a deform result reports)."""

from __future__ import annotations

import numpy as np

from .path import _Body, _Collector, _inflation, _narrow, _pairs_self, _self_candidates, _start_check


def near_pairs(x, edges, faces, radius):
    """The scene's own pairs that may lie within `radius` of each other at `x` (one query).

    Returns
    -------
    list of (kind, ij, idx)
        Candidates of the static broad phase with boxes inflated by half the radius
        (a superset of the pairs closer than it), in the form `check_pairs` takes.
    """
    body = _Body(x, x, edges, faces, "scene")
    return _self_candidates(body, body.x_t0, body.x_t0, _inflation(radius, body.x_t0))


def check_pairs(pairs, x_t0, x_t1, thickness) -> bool:
    """True when none of `pairs` (from `near_pairs`) violates along x_t0 -> x_t1.

    Deform-result reading (`verify_step` with ``pre_existing=True``): a pair within
    `thickness` at the start must stay disjoint, one touching at the start is left
    as it was; every other pair must stay `thickness` apart (conservative CCD).
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
