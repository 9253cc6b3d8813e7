"""Static intersection predicates (start-state checks of `verify`), conservative.

A closed segment [e0, e1] meets a closed triangle within distance h iff a point
moving linearly from e0 to e1 comes within h of the (static) triangle, which is
exactly a vertex-face CCD query; so these predicates inherit the guarantees
of `penfree.core.contact.ccd`: never a missed intersection, and with h = 0 (default
``exact=True``) an exact answer, since the flagged queries are decided in
rational arithmetic. Two closed triangles intersect (or come within h) iff an
edge of one meets (comes within h of) the other: the intersection of two
triangles is convex and its extreme points lie on triangle edges, and the
closest points of two disjoint triangles include a point on an edge.
"""

import numpy as np

from ...errors import InputError
from .ccd import SEPARATED, ccd_details

__all__ = ["segments_triangles_intersect", "triangles_intersect"]


def _rows(x, k, name):
    a = np.asarray(x)
    if a.ndim == 2 and a.shape == (k, 3):
        a = a[None]
    if a.ndim != 3 or a.shape[1:] != (k, 3):
        raise InputError(f"{name} must be (Q, {k}, 3); got {a.shape}")
    return np.ascontiguousarray(a, dtype=np.float64)


def segments_triangles_intersect(seg, tri, thickness=0.0, *, exact=True):
    """Do closed segments meet (come within `thickness` of) closed triangles?

    Parameters
    ----------
    seg : (Q, 2, 3) float
        Segment end points.
    tri : (Q, 3, 3) float
        Triangle corners (degenerate triangles allowed).
    thickness : float >= 0
    exact : bool
        With thickness 0, decide flagged pairs exactly (no false positives).

    Returns
    -------
    (Q,) bool
        False only when separation is proven.

    Examples
    --------
    >>> seg = np.array([[[0.2, 0.2, -1], [0.2, 0.2, 1]]])
    >>> tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]])
    >>> segments_triangles_intersect(seg, tri).tolist()
    [True]
    """
    seg = _rows(seg, 2, "seg")
    tri = _rows(tri, 3, "tri")
    if seg.shape[0] != tri.shape[0]:
        raise InputError(f"seg and tri must hold the same number of rows; got {seg.shape[0]} and {tri.shape[0]}")
    x_t0 = np.concatenate([seg[:, :1], tri], axis=1)
    x_t1 = np.concatenate([seg[:, 1:], tri], axis=1)
    status = ccd_details(x_t0, x_t1, "vf", thickness, exact=exact)[0]
    return status != SEPARATED


def triangles_intersect(tri_a, tri_b, thickness=0.0, *, exact=True):
    """Do closed triangles intersect (come within `thickness`), pair by pair?

    Parameters
    ----------
    tri_a, tri_b : (Q, 3, 3) float
        Corners of the two triangles of each pair. Meant for non-adjacent
        triangles: a pair sharing a corner always intersects.
    thickness : float >= 0
    exact : bool

    Returns
    -------
    (Q,) bool
        Conservative: False only when separation is proven.

    Examples
    --------
    >>> a = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]])
    >>> b = np.array([[[0.2, 0.2, -1], [0.2, 0.2, 1], [3, 3, 0.0]]])
    >>> triangles_intersect(a, b).tolist(), triangles_intersect(a, b + [0, 0, 5]).tolist()
    ([True], [False])
    """
    tri_a = _rows(tri_a, 3, "tri_a")
    tri_b = _rows(tri_b, 3, "tri_b")
    if tri_a.shape[0] != tri_b.shape[0]:
        raise InputError(f"tri_a and tri_b must hold the same number of rows; got {tri_a.shape[0]} and {tri_b.shape[0]}")
    q = tri_a.shape[0]
    sides = [(0, 1), (1, 2), (2, 0)]
    seg = np.concatenate([tri_a[:, list(s)] for s in sides] + [tri_b[:, list(s)] for s in sides])
    tri = np.concatenate([tri_b] * 3 + [tri_a] * 3)
    return segments_triangles_intersect(seg, tri, thickness, exact=exact).reshape(6, q).any(axis=0)
