"""Static triangle-triangle and segment-triangle predicates against exact oracles."""

from fractions import Fraction

import numpy as np
import pytest

from penfree.core.contact.intersection import segments_triangles_intersect, triangles_intersect
from penfree.errors import InputError

from oracles import ee_sq, pe_sq, pt_sq  # exact Fraction distance oracles

T0 = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
CASES = [
    # id, tri_a, tri_b, intersect
    ("piercing", T0, [[0.2, 0.2, -1], [0.2, 0.2, 1], [3, 3, 0]], True),
    ("separated-above", T0, [[0, 0, 1], [1, 0, 1], [0, 1, 1]], False),
    ("coplanar-overlap", T0, [[0.1, 0.1, 0], [2, 0.1, 0], [0.1, 2, 0]], True),
    ("coplanar-contained", T0, [[0.1, 0.1, 0], [0.2, 0.1, 0], [0.1, 0.2, 0]], True),
    ("coplanar-disjoint", T0, [[1, 1, 0], [2, 1, 0], [1, 2, 0]], False),
    ("touching-vertex-on-face", T0, [[0.25, 0.25, 0], [0.25, 0.25, 1], [1, 1, 1]], True),
    ("touching-edge-edge", T0, [[0.5, -1, 0], [0.5, 1, 0], [0.5, 0, 1]], True),
    ("edge-near-miss", T0, [[0.5, 0.5 + 2**-40, -1], [0.5, 0.5 + 2**-40, 1], [3, 3, 0]], False),
    ("degenerate-segment-triangle", T0, [[0.2, 0.2, -1], [0.2, 0.2, 1], [0.2, 0.2, 0]], True),
]


@pytest.mark.parametrize("a,b,expected", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_named(a, b, expected):
    a, b = np.array(a, float)[None], np.array(b, float)[None]
    assert triangles_intersect(a, b).tolist() == [expected]
    assert triangles_intersect(b, a).tolist() == [expected]  # symmetric
    assert triangles_intersect(a, b, exact=False)[0] or not expected  # kernel alone: never a miss


def _tri_tri_sq(a, b):
    """Exact squared distance of two triangles: 0 if an edge of one pierces the other,
    else the smallest vertex-triangle or edge-edge distance (the closest points of
    disjoint triangles include a vertex or a pair of edge points)."""
    A = [[Fraction(c) for c in p] for p in a]
    B = [[Fraction(c) for c in p] for p in b]
    if any(_pierces(A[i], A[(i + 1) % 3], B) or _pierces(B[i], B[(i + 1) % 3], A) for i in range(3)):
        return Fraction(0)
    return min(
        min(pt_sq(p, *B) for p in A), min(pt_sq(p, *A) for p in B),
        min(ee_sq(A[i], A[(i + 1) % 3], B[j], B[(j + 1) % 3]) for i in range(3) for j in range(3)),
    )


def _pierces(e0, e1, T):
    """Exact: does segment e0e1 cross the plane of T at a point inside T (non-coplanar)?"""
    def det(a, b, c):
        return a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0]) + a[2] * (b[0] * c[1] - b[1] * c[0])
    d = lambda p, q: [x - y for x, y in zip(p, q)]  # noqa: E731
    s0 = det(d(T[1], T[0]), d(T[2], T[0]), d(e0, T[0]))
    s1 = det(d(T[1], T[0]), d(T[2], T[0]), d(e1, T[0]))
    if s0 == s1 or (s0 > 0 and s1 > 0) or (s0 < 0 and s1 < 0):
        return False
    s = s0 / (s0 - s1)
    p = [x + s * (y - x) for x, y in zip(e0, e1)]
    return pt_sq(p, *T) == 0


def test_random_small_integer_triangles_against_exact_distance():
    rng = np.random.default_rng(3)
    a = rng.integers(-2, 3, size=(300, 3, 3)).astype(float)
    b = rng.integers(-2, 3, size=(300, 3, 3)).astype(float)
    got = triangles_intersect(a, b)
    truth = np.array([_tri_tri_sq(x, y) == 0 for x, y in zip(a, b)])
    assert 30 < truth.sum() < 270
    assert got.tolist() == truth.tolist()
    h = 0.5
    got_h = triangles_intersect(a, b, h)
    truth_h = np.array([_tri_tri_sq(x, y) <= Fraction(h) ** 2 for x, y in zip(a, b)])
    assert np.all(got_h[truth_h])  # conservative with thickness
    assert got_h.sum() - truth_h.sum() <= 3  # and tight except within ~1e-10 of h


def test_segments_and_validation():
    seg = np.array([[[0.2, 0.2, -1], [0.2, 0.2, 1]], [[2, 2, -1], [2, 2, 1]]])
    tri = np.array([T0, T0], float)
    assert segments_triangles_intersect(seg, tri).tolist() == [True, False]
    assert segments_triangles_intersect(seg, tri, 2.1).tolist() == [True, False]  # distance 1.5 sqrt(2)
    assert segments_triangles_intersect(seg, tri, 2.13).tolist() == [True, True]
    assert pe_sq([Fraction(0)] * 3, [Fraction(1), Fraction(0), Fraction(0)], [Fraction(2), Fraction(0), Fraction(0)]) == 1
    with pytest.raises(InputError, match=r"\(Q, 3, 3\)"):
        triangles_intersect(np.zeros((2, 2, 3)), np.zeros((2, 3, 3)))
    with pytest.raises(InputError, match="same number"):
        segments_triangles_intersect(seg, tri[:1])
