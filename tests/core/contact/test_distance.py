"""Static distance kernels against exact rational arithmetic (fractions.Fraction).

The oracle minimises the squared distance exactly over the same closed-form
candidate set that defines it mathematically (endpoints, clamped projections,
the interior critical point when it is interior), so it is the exact distance
of the float64 inputs. Tolerance: |d - d_exact| <= RTOL * d_exact + ATOL * extent,
with extent the largest coordinate difference in the pair.
"""

from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numba import njit

from penfree.core.contact.distance import (
    _ee_gap,
    _pt_gap,
    edge_edge_distance,
    ee_sq_columns,
    edge_edge_sq,
    point_edge_distance,
    point_edge_sq,
    point_point_sq,
    point_triangle_distance,
    point_triangle_sq,
    pt_sq_columns,
)
from penfree.errors import InputError

RTOL = 1e-12
ATOL = 1e-13


RNG_SEED = 20261121  # seed of the shared `rng` fixture (tests/conftest.py)


# --- exact oracle -------------------------------------------------------------


def _F(v):
    return [Fraction(float(c)) for c in v]


def _sub(a, b):
    return [x - y for x, y in zip(a, b)]


def _dot(a, b):
    return sum(x * y for x, y in zip(a, b))


def _pe_exact(p, a, b):
    d = _sub(b, a)
    L2 = _dot(d, d)
    w = _sub(p, a)
    if L2 == 0:
        return _dot(w, w)
    t = min(max(_dot(w, d) / L2, Fraction(0)), Fraction(1))
    r = [w[k] - t * d[k] for k in range(3)]
    return _dot(r, r)


def ee_exact(a0, a1, b0, b1):
    a0, a1, b0, b1 = map(_F, (a0, a1, b0, b1))
    best = min(_pe_exact(a0, b0, b1), _pe_exact(a1, b0, b1),
               _pe_exact(b0, a0, a1), _pe_exact(b1, a0, a1))
    u, v, w = _sub(a1, a0), _sub(b1, b0), _sub(a0, b0)
    A, B, C, D, E = _dot(u, u), _dot(u, v), _dot(v, v), _dot(u, w), _dot(v, w)
    det = A * C - B * B
    if det != 0:
        s = (B * E - C * D) / det
        t = (A * E - B * D) / det
        if 0 <= s <= 1 and 0 <= t <= 1:
            r = [w[k] + s * u[k] - t * v[k] for k in range(3)]
            best = min(best, _dot(r, r))
    return best


def pt_exact(p, t0, t1, t2):
    p, t0, t1, t2 = map(_F, (p, t0, t1, t2))
    best = min(_pe_exact(p, t0, t1), _pe_exact(p, t1, t2), _pe_exact(p, t2, t0))
    u, v, w = _sub(t1, t0), _sub(t2, t0), _sub(p, t0)
    A, B, C, D, E = _dot(u, u), _dot(u, v), _dot(v, v), _dot(u, w), _dot(v, w)
    det = A * C - B * B
    if det != 0:
        a = (C * D - B * E) / det
        b = (A * E - B * D) / det
        if a >= 0 and b >= 0 and a + b <= 1:
            r = [w[k] - a * u[k] - b * v[k] for k in range(3)]
            best = min(best, _dot(r, r))
    return best


def pe_exact(p, e0, e1):
    return _pe_exact(*map(_F, (p, e0, e1)))


def _check(d, d2_exact, pts):
    exact = float(d2_exact) ** 0.5
    extent = float(np.ptp(np.asarray(pts, dtype=np.float64), axis=0).max())
    assert abs(d - exact) <= RTOL * exact + ATOL * extent, (d, exact, extent)


# --- named degenerate cases ---------------------------------------------------

EE_CASES = {
    "parallel-edges": ([0, 0, 0], [1, 0, 0], [0.25, 0.5, 0], [2, 0.5, 0]),
    "parallel-disjoint": ([0, 0, 0], [1, 0, 0], [1.5, 0.3, 0.4], [3, 0.3, 0.4]),
    "collinear-overlap": ([0, 0, 0], [1, 1, 1], [0.5, 0.5, 0.5], [2, 2, 2]),
    "collinear-gap": ([0, 0, 0], [0.1, 0.2, 0.3], [0.3, 0.6, 0.9], [0.4, 0.8, 1.2]),
    "zero-length-edge": ([0.3, 0.2, 0.1], [0.3, 0.2, 0.1], [0, 0, 0], [1, 0, 0]),
    "both-zero-length": ([0.3, 0.2, 0.1], [0.3, 0.2, 0.1], [1, 2, 3], [1, 2, 3]),
    "crossing": ([-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0]),
    "skew-interior": ([-1, 0, 0], [1, 0, 0], [0.1, -1, 0.7], [0.2, 1, 0.7]),
    "t-junction": ([0, 0, 0], [1, 0, 0], [0.5, 0, 0], [0.5, 1, 0]),
    "shared-endpoint": ([0, 0, 0], [1, 0, 0], [1, 0, 0], [1, 1, 1]),
    "near-parallel": ([0, 0, 0], [1, 0, 0], [0, 1e-3, 1e-9], [1, 1e-3 + 1e-12, -1e-9]),
    "far-from-origin": ([1e4, 1e4, 1e4], [1e4 + 1, 1e4, 1e4],
                        [1e4 + 0.5, 1e4 - 1, 1e4 + 0.25], [1e4 + 0.5, 1e4 + 1, 1e4 + 0.25]),
}

PT_CASES = {
    "point-in-triangle-plane": ([0.2, 0.2, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0]),
    "point-in-plane-outside": ([2, 2, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0]),
    "above-interior": ([0.25, 0.25, 0.7], [0, 0, 0], [1, 0, 0], [0, 1, 0]),
    "above-edge-region": ([0.5, -0.5, 0.3], [0, 0, 0], [1, 0, 0], [0, 1, 0]),
    "above-vertex-region": ([-1, -1, 1], [0, 0, 0], [1, 0, 0], [0, 1, 0]),
    "degenerate-triangle": ([0.5, 0.5, 0.5], [0, 0, 0], [0.1, 0.2, 0.3], [0.3, 0.6, 0.9]),
    "repeated-corner": ([0.5, 1, 0], [0, 0, 0], [1, 0, 0], [1, 0, 0]),
    "point-triangle": ([1, 2, 3], [1, 2, 3], [1, 2, 3], [1, 2, 3]),
    "sliver": ([0.5, 1e-3, 1e-3], [0, 0, 0], [1, 0, 0], [0.5, 1e-11, 0]),
    "far-from-origin": ([1e4 + 0.2, 1e4 + 0.2, 1e4 + 0.1], [1e4, 1e4, 1e4],
                        [1e4 + 1, 1e4, 1e4], [1e4, 1e4 + 1, 1e4]),
}

PE_CASES = {
    "point-on-edge-line": ([2, 2, 2], [0, 0, 0], [1, 1, 1]),
    "point-on-edge": ([0.5, 0.5, 0.5], [0, 0, 0], [1, 1, 1]),
    "zero-length-edge": ([1, 0, 0], [0.3, 0.3, 0.3], [0.3, 0.3, 0.3]),
    "perpendicular": ([0.5, 1, 0], [0, 0, 0], [1, 0, 0]),
    "beyond-end": ([2, 1, 0], [0, 0, 0], [1, 0, 0]),
}


@pytest.mark.parametrize("case", list(EE_CASES.values()), ids=list(EE_CASES))
def test_edge_edge_named(case):
    a0, a1, b0, b1 = (np.array(c, dtype=np.float64) for c in case)
    d = edge_edge_distance(a0, a1, b0, b1)[0]
    _check(d, ee_exact(a0, a1, b0, b1), case)
    # symmetric in the two segments and in the endpoint order
    assert edge_edge_distance(b1, b0, a0, a1)[0] == pytest.approx(d, rel=RTOL, abs=ATOL)


@pytest.mark.parametrize("case", list(PT_CASES.values()), ids=list(PT_CASES))
def test_point_triangle_named(case):
    p, t0, t1, t2 = (np.array(c, dtype=np.float64) for c in case)
    d = point_triangle_distance(p, t0, t1, t2)[0]
    _check(d, pt_exact(p, t0, t1, t2), case)
    assert point_triangle_distance(p, t2, t0, t1)[0] == pytest.approx(d, rel=RTOL, abs=ATOL)


@pytest.mark.parametrize("case", list(PE_CASES.values()), ids=list(PE_CASES))
def test_point_edge_named(case):
    p, e0, e1 = (np.array(c, dtype=np.float64) for c in case)
    _check(point_edge_distance(p, e0, e1)[0], pe_exact(p, e0, e1), case)


def test_exact_zero_cases():
    # touching primitives give exactly 0, not a rounding residue
    assert edge_edge_distance([0, 0, 0], [1, 0, 0], [0.5, 0, 0], [0.5, 1, 0])[0] == 0.0
    assert point_triangle_distance([0, 0, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0])[0] == 0.0
    assert point_edge_distance([1, 1, 1], [0, 0, 0], [1, 1, 1])[0] == 0.0


# --- random cases -------------------------------------------------------------


def _random_pairs(rng, n, k):
    pts = rng.normal(size=(n, k, 3))
    # a share of near-degenerate inputs: near-parallel, near-coplanar, short
    m = n // 4
    pts[:m, 3] = pts[:m, 2] + (pts[:m, 1] - pts[:m, 0]) * rng.uniform(0.2, 2, (m, 1)) \
        + rng.normal(scale=1e-7, size=(m, 3))
    return pts


def test_random_against_exact(rng):
    pts = _random_pairs(rng, 300, 4)
    d_ee = edge_edge_distance(pts[:, 0], pts[:, 1], pts[:, 2], pts[:, 3])
    d_pt = point_triangle_distance(pts[:, 3], pts[:, 0], pts[:, 1], pts[:, 2])
    d_pe = point_edge_distance(pts[:, 2], pts[:, 0], pts[:, 1])
    for q in range(pts.shape[0]):
        a0, a1, b0, b1 = pts[q]
        _check(d_ee[q], ee_exact(a0, a1, b0, b1), pts[q])
        _check(d_pt[q], pt_exact(b1, a0, a1, b0), pts[q])
        _check(d_pe[q], pe_exact(b0, a0, a1), pts[q])


def test_triangle_not_above_its_edges_and_plane(rng):
    # distance to a triangle never exceeds the distance to any of its edges,
    # and a point of the triangle plus a normal offset h is at distance h
    t = rng.normal(size=(200, 3, 3))
    a, b = rng.uniform(0, 0.5, (2, 200, 1))
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    h = rng.uniform(0.0, 2.0, (200, 1))
    p = t[:, 0] + a * (t[:, 1] - t[:, 0]) + b * (t[:, 2] - t[:, 0]) + h * n
    d = point_triangle_distance(p, t[:, 0], t[:, 1], t[:, 2])
    np.testing.assert_allclose(d, h[:, 0], rtol=1e-12, atol=1e-12)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        assert np.all(d <= point_edge_distance(p, t[:, i], t[:, j]) + 1e-15)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-10, 10, allow_nan=False, width=32), min_size=12, max_size=12),
       st.integers(0, 2**31))
def test_rigid_motion_invariance(coords, seed):
    x = np.array(coords, dtype=np.float64).reshape(4, 3)
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    y = x @ Q.T + rng.uniform(-5, 5, 3)
    ext = float(np.ptp(x, axis=0).max()) + 1.0
    tol = 1e-11 * ext  # rounding of the rotation itself, extent-relative
    assert abs(edge_edge_distance(*y)[0] - edge_edge_distance(*x)[0]) <= tol
    assert abs(point_triangle_distance(*y)[0] - point_triangle_distance(*x)[0]) <= tol


# --- kernels are callable from other @njit code -------------------------------


@njit(cache=False)
def _all_four(V):
    return (point_point_sq(V[0], V[1]), point_edge_sq(V[0], V[1], V[2]),
            edge_edge_sq(V[0], V[1], V[2], V[3]), point_triangle_sq(V[0], V[1], V[2], V[3]))


def test_njit_callable(rng):
    V = rng.normal(size=(4, 3))
    pp, pe, ee, pt = _all_four(V)
    assert pp == pytest.approx(float(np.sum((V[0] - V[1]) ** 2)), rel=1e-14)
    assert pe == pytest.approx(point_edge_distance(V[0], V[1], V[2])[0] ** 2, rel=1e-12)
    assert ee == pytest.approx(edge_edge_distance(V[0], V[1], V[2], V[3])[0] ** 2, rel=1e-12)
    assert pt == pytest.approx(point_triangle_distance(V[0], V[1], V[2], V[3])[0] ** 2, rel=1e-12)


def test_input_errors():
    with pytest.raises(InputError, match=r"EA1 must be \(Q, 3\)"):
        edge_edge_distance(np.zeros((2, 3)), np.zeros((2, 2)), np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(InputError, match="rows"):
        point_edge_distance(np.zeros((2, 3)), np.zeros((3, 3)), np.zeros((3, 3)))
    with pytest.raises(InputError, match="finite"):
        point_triangle_distance(np.full((1, 3), np.nan), np.zeros((1, 3)), np.zeros((1, 3)),
                                np.zeros((1, 3)))


# --- projection gap bounds ------------------------------------------------------

# The bounds may exceed the exact distance by their own rounding only: ~100 ulps of the
# largest coordinate (`distance._ee_gap`); the folds subtract 1e-9 of it.
GAP_SLACK_REL = 1e-13


@njit(cache=True)
def _gaps(P):
    # (ee, pt) gap bounds of rows (a0, a1, b0, b1): segments a0a1 / b0b1, point b1 /
    # triangle (a0, a1, b0), as `test_random_against_exact` pairs them.
    out = np.empty((P.shape[0], 2))
    for k in range(P.shape[0]):
        a0, a1, b0, b1 = P[k, 0], P[k, 1], P[k, 2], P[k, 3]
        out[k, 0] = _ee_gap(a0[0], a0[1], a0[2], a1[0], a1[1], a1[2], b0[0], b0[1], b0[2], b1[0], b1[1], b1[2])
        out[k, 1] = _pt_gap(b1[0], b1[1], b1[2], a0[0], a0[1], a0[2], a1[0], a1[1], a1[2], b0[0], b0[1], b0[2])
    return out


def _assert_below(gap, d2_exact, pts):
    # gap - slack <= exact distance, compared in exact arithmetic (squares of non-negatives)
    g = Fraction(float(gap)) - Fraction(GAP_SLACK_REL * float(np.abs(pts).max()))
    assert gap >= 0.0
    assert g <= 0 or g * g <= d2_exact, (gap, float(d2_exact) ** 0.5, pts)


def _gap_rows(cases):
    return np.array([[c for c in case] for case in cases], dtype=np.float64)


def test_gap_bounds_below_the_exact_distance(rng):
    # Random pairs (near-parallel, near-touching, far from the origin among them) and
    # the named cases, against the exact distance; far apart pairs get a positive bound.
    pts = np.concatenate([_random_pairs(rng, 300, 4), _random_pairs(rng, 100, 4) * 1e-3 + 1e6,
                          _gap_rows(EE_CASES.values()),
                          _gap_rows([[t0, t1, t2, p] for p, t0, t1, t2 in PT_CASES.values()])])
    gaps = _gaps(pts)
    for q in range(pts.shape[0]):
        a0, a1, b0, b1 = pts[q]
        _assert_below(gaps[q, 0], ee_exact(a0, a1, b0, b1), pts[q])
        _assert_below(gaps[q, 1], pt_exact(b1, a0, a1, b0), pts[q])
    assert (gaps > 0).mean() > 0.2


@pytest.mark.parametrize("offset", [0.0, 1e6], ids=["near-origin", "far-from-origin"])
def test_gap_bounds_of_a_sheets_neighbours(offset):
    # The pairs a start pass meets on a flat triangulated grid (spacing 1): parallel edges
    # across a square (along the midpoints' line), parallel diagonals side by side (only
    # the part normal to one segment separates them, also when they are offset along
    # themselves), collinear edges, a vertex beside a
    # triangle; each bound is positive, at most the exact distance, and tight where the
    # gap direction is the closest points' (parallel edges, the collinear gap).
    o = np.full(3, offset)
    rows = {
        "across-a-square": ([0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], 1.0),
        "parallel-diagonals": ([0, 1, 0], [1, 0, 0], [1, 1, 0], [2, 0, 0], 0.5 ** 0.5),
        "collinear": ([0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], 1.0),
        # along w a gap of 5e-4 (a small positive one must not end the search)
        "diagonals-offset-along-themselves": ([0, 0, 0], [0.999, -0.999, 0.04], [0, 1, -0.04], [1, 0, 0], None),
        "diagonal-and-edge": ([0, 0, 0], [1, 1, 0], [1, 0, 0], [2, 0, 0], None),
    }
    P = np.array([[a, b, c, d] for a, b, c, d, _ in rows.values()], dtype=np.float64) + o
    gaps = _gaps(P)
    for q, (name, row) in enumerate(rows.items()):
        _assert_below(gaps[q, 0], ee_exact(*P[q]), P[q])
        assert gaps[q, 0] > 0.3, name
        if row[4] is not None:
            assert gaps[q, 0] == pytest.approx(row[4], rel=1e-9, abs=1e-9 * offset), name
    tri = np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.1]]], dtype=np.float64) + o  # the square's 4th corner
    g = _gaps(tri)[0, 1]
    _assert_below(g, pt_exact(tri[0, 3], tri[0, 0], tri[0, 1], tri[0, 2]), tri[0])
    assert g > 0.3


def test_gap_bounds_prove_nothing_out_of_range():
    # Directions too short or too long for the rounding bound: the bounds are 0, never
    # inf or NaN (coordinates ~1e-120 square to below 1e-200, ~1e120 to above 1e200).
    base = np.array([[[0, 0, 0], [1, 0, 0], [0, 3, 0], [1, 3, 0]]], dtype=np.float64)
    for scale in (1e-120, 1e120):
        g = _gaps(base * scale)
        assert np.all(g == 0.0), scale
    assert np.all(_gaps(base) > 0.0)


# The kernels as they were written before their clamps and interior tests looked at the
# numerators first (issue 13): dividing first, every case. The new form must give the
# same bits on every input, the boundary cases included.
@njit
def _pp_div(px, py, pz, qx, qy, qz):
    dx, dy, dz = px - qx, py - qy, pz - qz
    return dx * dx + dy * dy + dz * dz


@njit
def _pe_div(px, py, pz, ax, ay, az, bx, by, bz):
    dx, dy, dz = bx - ax, by - ay, bz - az
    L2 = dx * dx + dy * dy + dz * dz
    if L2 == 0.0:
        return _pp_div(px, py, pz, ax, ay, az)
    wx, wy, wz = px - ax, py - ay, pz - az
    t = (wx * dx + wy * dy + wz * dz) / L2
    if t <= 0.0:
        return _pp_div(px, py, pz, ax, ay, az)
    if t >= 1.0:
        return _pp_div(px, py, pz, bx, by, bz)
    cx, cy, cz = wy * dz - wz * dy, wz * dx - wx * dz, wx * dy - wy * dx
    return (cx * cx + cy * cy + cz * cz) / L2


@njit
def _dot3(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit
def _lower(best, d):
    # The kernels' own update (`if d < best`), NaN handling included.
    return d if d < best else best


@njit
def _pe_terms(points, segments):
    """The kernels' fold of the division-first point-edge terms, point k against
    segment k (rows (a, b)), in order."""
    best = np.nan
    for k in range(points.shape[0]):
        p, a, b = points[k], segments[k, 0], segments[k, 1]
        d = _pe_div(p[0], p[1], p[2], a[0], a[1], a[2], b[0], b[1], b[2])
        best = d if k == 0 else _lower(best, d)
    return best


@njit
def _ee_div(a0, a1, b0, b1):
    eb, ea = np.stack((b0, b1)), np.stack((a0, a1))
    best = _pe_terms(np.stack((a0, a1, b0, b1)), np.stack((eb, eb, ea, ea)))
    u, v, w = a1 - a0, b1 - b0, b0 - a0
    n = np.cross(u, v)
    n2 = _dot3(n, n)
    if n2 == 0.0:
        return best
    s, t = _dot3(np.cross(w, v), n) / n2, _dot3(np.cross(w, u), n) / n2
    if s > 0.0 and s < 1.0 and t > 0.0 and t < 1.0:
        r = s * u - t * v - w
        best = _lower(best, _dot3(r, r))
    return best


@njit
def _pt_div(p, t0, t1, t2):
    best = _pe_terms(np.stack((p, p, p)), np.stack((np.stack((t0, t1)), np.stack((t1, t2)), np.stack((t2, t0)))))
    u, v, w = t1 - t0, t2 - t0, p - t0
    n = np.cross(u, v)
    n2 = _dot3(n, n)
    if n2 == 0.0:
        return best
    a, b = _dot3(np.cross(w, v), n) / n2, _dot3(np.cross(u, w), n) / n2
    if a > 0.0 and b > 0.0 and a + b < 1.0:
        r = w - a * u - b * v
        best = _lower(best, _dot3(r, r))
    return best


def _same_bits(a, b):
    a, b = np.float64(a), np.float64(b)
    return (np.isnan(a) and np.isnan(b)) or a.view(np.uint64) == b.view(np.uint64)


def _boundary_cases(rng):
    """(4, 3) float64 arrays: random primitives at many scales, and the boundary cases:
    a point projecting exactly onto an endpoint (t = 0, 1, and just inside or outside by
    an ulp), zero-length and collinear segments, parallel and crossing edges, slivers,
    squares that overflow to inf, NaN and inf coordinates."""
    cases = []
    for scale in (1e-300, 1e-8, 1.0, 1e8, 1e160):
        for _ in range(300):
            cases.append(rng.normal(size=(4, 3)) * scale + rng.normal(size=3) * scale * rng.integers(0, 2))
    a, b = np.zeros(3), np.array([1.0, 0.0, 0.0])
    for t in (0.0, 1.0, np.nextafter(0.0, 1.0), np.nextafter(1.0, 0.0), np.nextafter(1.0, 2.0), -0.0, 0.5):
        for off in (0.0, 1e-300, 0.3):
            cases.append(np.array([[t, off, 0.0], a, b, [t, 1.0, off]]))
    cases += [np.array([a, a, b, b]), np.array([a, b, 2 * b, 3 * b]), np.array([a, b, a + [0, 1, 0], b + [0, 1, 0]]),
              np.array([a, b, [0.5, -1, 0], [0.5, 1, 0]]), np.array([a, b, [0.5, 0, 1e-30], [0.5 + 1e-30, 0, 0]]),
              np.array([[1e200, 0, 0], a, b, [0, 1e200, 0]]), np.array([[np.nan, 0, 0], a, b, b]),
              np.array([[np.inf, 0, 0], a, b, b]), np.array([a, [np.inf, 0, 0], b, [0, np.inf, 0]])]
    return [np.ascontiguousarray(c, dtype=np.float64) for c in cases]


def test_numerator_tests_give_the_division_first_bits(rng):
    # The scalar kernels decide clamped cases from numerators before dividing: the
    # same bits as dividing first, on `_boundary_cases`.
    cases = _boundary_cases(rng)
    for c in cases:
        p, q, r, s = c
        assert _same_bits(point_edge_sq(p, q, r), _pe_div(p[0], p[1], p[2], q[0], q[1], q[2], r[0], r[1], r[2]))
        assert _same_bits(edge_edge_sq(p, q, r, s), _ee_div(p, q, r, s))
        assert _same_bits(point_triangle_sq(p, q, r, s), _pt_div(p, q, r, s))


def test_branch_free_columns_give_the_scalar_kernels_bits(rng):
    # `ee_sq_columns` / `pt_sq_columns` (every candidate computed, chosen by selects, the
    # min folds' deferred pairs) against `_ee` / `_pt` on `_boundary_cases`, with the
    # pairs' segments and the triangle's corners in every order, and with the columns
    # at odd offsets of a wider array (a vectorised loop's remainder).
    cases = _boundary_cases(rng)
    rows = []
    for c in cases:
        for order in ([0, 1, 2, 3], [2, 3, 0, 1], [1, 0, 3, 2], [0, 2, 1, 3], [3, 1, 2, 0]):
            rows.append(c[order].reshape(12))
    G = np.ascontiguousarray(np.array(rows).T)
    for kernel, scalar in ((ee_sq_columns, edge_edge_sq), (pt_sq_columns, point_triangle_sq)):
        want = np.array([scalar(*r.reshape(4, 3)) for r in rows])
        for n in (G.shape[1], G.shape[1] - 3, 5, 0):
            out = np.full(G.shape[1], -1.0)
            kernel(G, out, n)
            np.testing.assert_array_equal(out[:n].view(np.uint64), want[:n].view(np.uint64))
            assert np.all(out[n:] == -1.0)
        assert np.isnan(want).any() and (want == 0.0).any() and (want > 1e15).any()  # the hard cases are in
