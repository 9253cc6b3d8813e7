"""Obstacles against a step's straight path, and their share of the trust-region bounds.

Obstacles do not move with a step's map; they are held at the step's frame (SPEC
section 5). Two forms (`penfree.sequence.Obstacle`):

- half-spaces ``normal . x > offset``: the signed distance of a point is linear in
  the point, so along a straight path it is linear in t and its minimum is at an end.
  Checking both end positions of every vertex decides the whole path, and every
  edge and face too (their points are convex combinations of their vertices). The
  comparisons are decided exactly: in floating point with a rigorous error bound,
  and with rational arithmetic for the few vertices inside that bound;
- meshes: the conservative CCD of `penfree.core.verify` (scene against obstacle
  primitives whose swept boxes overlap, i.e. within reach of the step's motion);
- analytic colliders (a mesh with an `penfree.sequence.AnalyticShape`): their exact
  solid by supporting planes (`penfree.core.contact.solids`); the mesh that contains
  it stands in for it only where a mesh is needed (the ipctk client's collision mesh).

`as_verify_obstacles` turns a sequence's obstacles into the argument of
`verify.verify_step`. The obstacle terms of the OGC bounds are
`trust_region.obstacle_separation`.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np

_U = 2.0**-53


def _signed(x, normal, offset):
    """``n . x - offset`` per row in float64 and a rigorous bound of its rounding error."""
    n = np.asarray(normal, dtype=np.float64)
    s = x @ n - offset
    # three products, two sums and a subtraction: gamma_6 (|n| . |x| + |offset|), with room
    err = 8.0 * _U * (np.abs(x) @ np.abs(n) + abs(offset)) * (1.0 + 1e-6) + 1e-300
    return s, err


def _exact_signed(x_row, normal, offset) -> Fraction:
    return sum(Fraction(float(a)) * Fraction(float(b)) for a, b in zip(normal, x_row)) - Fraction(float(offset))


def _compare(x, normal, offset, level, strict):
    """Exact ``n . x - offset > level`` (strict) or ``>= level`` per row of x (float64)."""
    s, err = _signed(x, normal, offset)
    d = s - level
    tol = err + 4.0 * _U * (np.abs(s) + abs(level))
    out = d > tol
    unsure = np.flatnonzero(np.abs(d) <= tol)
    if len(unsure):
        lv = Fraction(float(level))
        for i in unsure:
            v = _exact_signed(x[i], normal, offset)
            out[i] = v > lv if strict else v >= lv
    return out


def _clear(x, normal, offset, thickness):
    """Exact: each row at least `thickness` (Euclidean) on the free side, i.e.
    ``n . x - offset >= thickness |n|``; strictly on it when `thickness` is 0.

    ``thickness |n|`` is irrational in general: rounded, a vertex exactly h away
    could be classified as resting inside h, and then kept only on the free side
    (an audit found ends at 0.43 h). Rows near it are decided on the squares:
    ``s >= 0`` and ``s^2 >= thickness^2 (n . n)``, in rationals.
    """
    if thickness == 0.0:
        return _compare(x, normal, offset, 0.0, strict=True)
    n = np.asarray(normal, dtype=np.float64)
    h = thickness * float(np.sqrt(n @ n))
    s, err = _signed(x, n, offset)
    tol = err + 8.0 * _U * (np.abs(s) + h)  # the rounding of s and of h, with room
    out = s - h > tol
    unsure = np.flatnonzero(np.abs(s - h) <= tol)
    if len(unsure):
        t2 = Fraction(float(thickness)) ** 2 * sum(Fraction(float(c)) ** 2 for c in n)
        for i in unsure:
            v = _exact_signed(x[i], n, offset)
            out[i] = v >= 0 and v * v >= t2
    return out


def half_space_verdict(x_t0, x_t1, normal, offset, thickness, pre_existing=False):
    """Vertices whose straight path x_t0 -> x_t1 comes within `thickness` of a half-space.

    Parameters
    ----------
    x_t0, x_t1 : (N, 3) float64
    normal : (3,) float64
        The plane ``normal . x = offset``; the free side is ``normal . x > offset``.
    offset, thickness : float
    pre_existing : bool
        The deform-result reading: a vertex that starts within `thickness` (but on the
        free side) only has to stay on the free side, and one that starts on the plane
        or behind it is pre-existing and must not go deeper.

    Returns
    -------
    start : (K,) int64
        Vertices within `thickness` at the start (empty with `pre_existing`).
    path : (K,) int64
        Violating vertices (at the end position, which decides the path).
    pre : (K,) int64
        Pre-existing penetrations (only with `pre_existing`).
    sep : float
        The smallest signed distance over the ends of the vertices not listed (inf
        if none), a lower bound over the whole path.

    Notes
    -----
    Exact (see the module docstring). The signed distance is measured with the
    normal as given; a unit normal makes it a Euclidean distance.
    """
    n = np.asarray(normal, dtype=np.float64)
    scale = float(np.linalg.norm(n))
    ok0 = _clear(x_t0, n, offset, thickness)  # n . x - offset >= thickness |n|, exactly
    ok1 = _clear(x_t1, n, offset, thickness)
    none = np.zeros(0, np.int64)
    if not pre_existing:
        start, path, pre = np.flatnonzero(~ok0), np.flatnonzero(~ok1), none
    else:
        free0 = ok0 | _clear(x_t0, n, offset, 0.0)
        free1 = ok1 | _clear(x_t1, n, offset, 0.0)
        rest = free0 & ~ok0  # resting within the thickness: must stay on the free side
        pre_mask = ~free0
        deeper = pre_mask & ~_compare(x_t1 - x_t0, n, 0.0, 0.0, strict=False)  # n . (x1 - x0) < 0
        bad = (ok0 & ~ok1) | (rest & ~free1) | deeper
        start, path, pre = none, np.flatnonzero(bad), np.flatnonzero(pre_mask)
    listed = np.zeros(len(x_t0), bool)
    for idx in (start, path, pre):
        listed[idx] = True
    if (~listed).any():
        s0 = (x_t0[~listed] @ n - offset) / scale
        s1 = (x_t1[~listed] @ n - offset) / scale
        sep = max(0.0, float(min(s0.min(), s1.min())) * (1.0 - 1e-12))
    else:
        sep = np.inf
    return start.astype(np.int64), path.astype(np.int64), pre.astype(np.int64), sep


def as_verify_obstacles(obstacles, s0, s1):
    """``(list, names)`` for `verify_step`: mesh obstacles at frames s0 -> s1, half-spaces as is,
    analytic colliders as their exact solid (`penfree.core.contact.solids`) at s0 -> s1.

    An analytic collider's mesh only contains the shape: checked against it, a primitive
    resting between the shape and the mesh is a pre-existing crossing that freezes the
    step, and one that starts inside the mesh is not kept out of the shape."""
    out = []
    for ob in obstacles:
        if ob.is_half_space:
            out.append((ob.normal, ob.offset))
        elif ob.shape is not None:  # an analytic collider: its exact solid, not the mesh around it
            from .solids import SolidFrames

            out.append(SolidFrames(ob.shape.axis, ob.shape.at(s0), ob.shape.at(s1)))
        else:
            out.append((ob.frame(s0), ob.frame(s1), ob.faces, ob.edges))
    return out, [ob.name for ob in obstacles]
