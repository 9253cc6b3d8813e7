"""Analytic solids against a step's path (`penfree.core.contact.solids`).

Oracles: closed-form distances (sphere, capsule, cylinder), a brute-force convex hull of
the densely sampled cross-section (every profile), and dense sampling of the swept
primitives for the verdicts (a verdict of "clear" must hold at every sample).
"""

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from penfree.core.contact.solids import (SolidFrames, _frame, _local_closest, _support, full_directions,
                                         solid_separation, solid_verdict)
from penfree.errors import InputError

#: (name, profile): height, disc_bottom, round_bottom, disc_top, round_top
PROFILES = [
    ("sphere", (0.0, 0.0, 1.0, 0.0, 1.0)),
    ("capsule", (2.0, 0.0, 0.5, 0.0, 0.5)),
    ("capsule_1", (1.5, 0.0, 0.8, 0.0, 0.3)),
    ("cylinder", (2.0, 1.0, 0.0, 1.0, 0.0)),
    ("cone", (2.0, 1.0, 0.0, 0.0, 0.0)),
    ("frustum", (1.0, 0.4, 0.0, 1.2, 0.0)),
]


def _hull_2d(profile, samples=4000):
    h, a0, b0, a1, b1 = profile
    pts = []
    for z, a, b in ((-h / 2, a0, b0), (h / 2, a1, b1)):
        th = np.linspace(0, 2 * np.pi, samples, endpoint=False)
        for sx in (-a, a):
            pts.append(np.c_[sx + b * np.cos(th), z + b * np.sin(th)])
    P = np.vstack(pts)
    return P[ConvexHull(P).vertices]


def _polygon_signed_distance(poly, q):
    a, b = poly, np.roll(poly, -1, axis=0)
    ab = b - a
    t = np.clip(((q[:, None] - a) * ab).sum(-1) / (ab * ab).sum(-1), 0, 1)
    d = np.linalg.norm(q[:, None] - (a + t[..., None] * ab), axis=-1).min(axis=1)
    cross = ab[:, 0] * (q[:, None, 1] - a[:, 1]) - ab[:, 1] * (q[:, None, 0] - a[:, 0])
    inside = (cross >= 0).all(axis=1)  # ConvexHull vertices run anticlockwise
    return np.where(inside, -d, d)


def _rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q * np.sign(np.linalg.det(q))


def _similarity(rng, scale):
    """``(L, c)`` of a rotation times `scale` and a translation far from the origin."""
    return _rotation(rng) * scale, rng.normal(size=3) * 10.0 + 100.0


@pytest.mark.parametrize("name,profile", PROFILES)
@pytest.mark.parametrize("axis", [0, 2])
def test_the_local_signed_distance_matches_the_sampled_cross_section(name, profile, axis):
    rng = np.random.default_rng(1)
    frame = _frame(profile, np.eye(3), np.zeros(3), "t")
    y = rng.normal(size=(1000, 3)) * 1.5
    g, normal, q = _local_closest(frame, axis, y)
    u = np.hypot(y[:, (axis + 1) % 3], y[:, (axis + 2) % 3])
    # the sampled hull is inscribed: its arcs lie at most 1 - cos(pi / 1500) ~ 2.2e-6 inside
    expect = _polygon_signed_distance(_hull_2d(profile, samples=1500), np.c_[u, y[:, axis]])
    np.testing.assert_allclose(g, expect, atol=1e-5)
    out = g > 1e-9
    # the closest point lies on the surface, the normal is a unit vector along y - q
    np.testing.assert_allclose(np.linalg.norm(normal, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(y - q, axis=1)[out], g[out], rtol=1e-9, atol=1e-12)
    gq, _, _ = _local_closest(frame, axis, q[out])
    assert np.abs(gq).max() < 1e-9


@pytest.mark.parametrize("name,profile", PROFILES)
def test_the_support_function_bounds_the_solid_and_is_attained(name, profile):
    rng = np.random.default_rng(2)
    L = np.diag([1.0, 2.5, 0.7]) @ _rotation(rng)  # non-uniform scale: containment is affine
    c = np.array([3.0, -1.0, 2.0])
    frame = _frame(profile, L, c, "t")
    poly = _hull_2d(profile, samples=720)
    ang = np.linspace(0, 2 * np.pi, 360, endpoint=False)
    axis = 1
    pts = []
    for uu, zz in poly:
        ring = np.zeros((len(ang), 3))
        ring[:, 2], ring[:, 0] = uu * np.cos(ang), uu * np.sin(ang)
        ring[:, axis] = zz
        pts.append(ring)
    world = np.vstack(pts) @ L + c
    n = rng.normal(size=(200, 3))
    h, err = _support(frame, axis, n)
    best = (world @ n.T).max(axis=0)
    assert (best <= h + err).all()
    np.testing.assert_allclose(best, h, rtol=0, atol=2e-3 * np.linalg.norm(n, axis=1).max())


def _sample_path(P0, P1, steps=41):
    """Points of each primitive (K, k, 3) along its path: barycentric grid x time grid."""
    k = P0.shape[1]
    g = np.linspace(0, 1, 9)
    if k == 3:
        w = np.array([(a, b, 1 - a - b) for a in g for b in g if a + b <= 1 + 1e-12])
    elif k == 2:
        w = np.c_[g, 1 - g]
    else:
        w = np.ones((1, 1))
    t = np.linspace(0, 1, steps)[:, None, None, None]
    X = (1 - t) * P0[None] + t * P1[None]  # (steps, K, k, 3)
    return np.einsum("wk,skj->swj", w, X.reshape(-1, k, 3)).reshape(steps, len(P0), len(w), 3)


def _world_distance(profile, axis, L, c, scale, X):
    frame = _frame(profile, L, c, "t")
    g, _, _ = _local_closest(frame, axis, ((X.reshape(-1, 3) - c) @ np.linalg.inv(L)))
    return (g * scale).reshape(X.shape[:-1])


@pytest.mark.parametrize("name,profile", PROFILES)
@pytest.mark.parametrize("k", [3, 2, 1])
@pytest.mark.parametrize("thickness", [0.0, 0.05])
def test_a_clear_verdict_keeps_every_sampled_point_of_the_path_outside(name, profile, k, thickness):
    """Random primitives near the solid (many between it and a 2% shell, like a tessellation's),
    moving toward, along and into it; every primitive the verdict clears stays at least the
    thickness away at every sample, and the test is not vacuous: both verdicts occur."""
    rng = np.random.default_rng(3 + k)
    scale = 0.8
    L, c = _similarity(rng, scale)
    axis = 2
    frame = _frame(profile, L, c, "t")
    K = 400
    # start points just outside the solid: surface points pushed out along their normal
    y = rng.normal(size=(K, 3)) * 1.5
    g, normal, q = _local_closest(frame, axis, y)
    lift = rng.uniform(0.0, 0.04, K) + thickness / scale * rng.uniform(0.8, 1.5, K)
    base = q + (lift[:, None]) * normal
    size = rng.uniform(0.01, 0.3, K)
    P0 = (base[:, None] + size[:, None, None] * rng.normal(size=(K, k, 3)) * (k > 1)) @ L + c
    move = rng.normal(size=(K, 1, 3)) * rng.uniform(0.005, 0.2, (K, 1, 1)) + rng.normal(size=(K, k, 3)) * 0.01
    P1 = P0 + move
    x0, x1 = P0.reshape(-1, 3), P1.reshape(-1, 3)
    S = np.arange(K * k).reshape(K, k)
    solid = SolidFrames(axis, (profile, L, c), (profile, L, c))
    (start, path, _), = solid_verdict(x0, x1, [S], solid, thickness)[0]
    bad = np.zeros(K, bool)
    bad[start] = bad[path] = True
    d = _world_distance(profile, axis, L, c, scale, _sample_path(P0, P1)).min(axis=(0, 2))
    assert (d[~bad] >= thickness * (1 - 1e-9)).all()
    assert (~bad).sum() > K // 10 and bad.sum() > K // 10
    # the refusals are mostly real: most refused primitives do come within the thickness
    assert (d[bad] < thickness + 0.05).mean() > 0.5


@pytest.mark.parametrize("name,profile", PROFILES)
def test_a_primitive_resting_on_the_solid_is_not_a_false_alarm(name, profile):
    """Triangles tangent to the surface 1e-7 away (their closest point inside the face):
    the alternating projections find the gap, so the raw reading sees no start violation."""
    rng = np.random.default_rng(5)
    L, c = _similarity(rng, 1.3)
    frame = _frame(profile, L, c, "t")
    axis = 0
    y = rng.normal(size=(300, 3)) * 2
    _, normal, q = _local_closest(frame, axis, y)
    t1 = np.cross(normal, rng.normal(size=(300, 3)))
    t1 /= np.linalg.norm(t1, axis=1)[:, None]
    t2 = np.cross(normal, t1)
    base = q + 1e-7 / 1.3 * normal
    tri = base[:, None] + 0.02 * np.stack([t1, -t1 + t2, -t1 - t2], axis=1)
    P0 = tri @ L + c
    S = np.arange(900).reshape(300, 3)
    solid = SolidFrames(axis, (profile, L, c), (profile, L, c))
    d = _world_distance(profile, axis, L, c, 1.3, _sample_path(P0, P0, steps=1)).min(axis=(0, 2))
    clear = d > 5e-8
    (start, path, _), = solid_verdict(P0.reshape(-1, 3), P0.reshape(-1, 3), [S], solid, 0.0)[0]
    flagged = np.zeros(300, bool)
    flagged[start] = True
    assert clear.sum() > 200
    assert not flagged[clear].any()
    assert not len(path) or set(path) <= set(start)


def test_a_primitive_inside_the_solid_is_pre_existing_and_may_not_go_deeper():
    profile = (0.0, 0.0, 1.0, 0.0, 1.0)
    solid = SolidFrames(2, (profile, np.eye(3), np.zeros(3)), (profile, np.eye(3), np.zeros(3)))
    x0 = np.array([[0.0, 0, 0.99], [0.01, 0, 0.99], [0, 0.01, 0.99],  # inside
                   [0.0, 0, 1.0 + 1e-3], [0.01, 0, 1.0 + 1e-3], [0, 0.01, 1.0 + 1e-3]])  # within 0.01 outside
    S = np.array([[0, 1, 2], [3, 4, 5]])
    # the raw reading: both start violations at thickness 0.01
    (start, path, pre), = solid_verdict(x0, x0, [S], solid, 0.01)[0]
    assert list(start) == [0, 1] and list(pre) == []
    # the deform-result reading, not moving: one pre-existing, nothing violated
    (start, path, pre), = solid_verdict(x0, x0, [S], solid, 0.01, pre_existing=True)[0]
    assert list(start) == [] and list(path) == [] and list(pre) == [0]
    # moving outward: both may (the inside one comes out, the resting one rises)
    x1 = x0 + [0, 0, 0.02]
    (_, path, pre), = solid_verdict(x0, x1, [S], solid, 0.01, pre_existing=True)[0]
    assert list(path) == [] and list(pre) == [0]
    # sliding along the surface: the inside one keeps its depth along its direction, a sideways
    # slide that sinks it by 1e-3 is refused
    slide = x0 + [0.05, 0, 0]
    assert list(solid_verdict(x0, slide, [S[:1]], solid, 0.01, pre_existing=True)[0][0][1]) == []
    sink = x0 + [0.05, 0, -1e-3]
    assert list(solid_verdict(x0, sink, [S[:1]], solid, 0.01, pre_existing=True)[0][0][1]) == [0]
    # moving inward: the inside one goes deeper
    x3 = x0 - [0, 0, 0.02]
    (_, path, pre), = solid_verdict(x0, x3, [S], solid, 0.01, pre_existing=True)[0]
    assert list(path) == [0, 1] and list(pre) == [0]
    # the resting one may not touch the solid: down by 2e-3 puts it 1e-3 inside
    x2 = x0.copy()
    x2[3:] -= [0, 0, 2e-3]
    (_, path, _), = solid_verdict(x0, x2, [S], solid, 0.01, pre_existing=True)[0]
    assert list(path) == [1]


def test_a_moving_solid_is_judged_at_both_ends():
    """verify's kinematic solids: a sphere translated onto a resting point is a violation,
    one translated away is not (Minkowski interpolation: the translated sphere)."""
    profile = (0.0, 0.0, 1.0, 0.0, 1.0)
    x = np.array([[0.0, 0.0, 1.1]])
    S = np.array([[0]])
    towards = SolidFrames(2, (profile, np.eye(3), np.zeros(3)), (profile, np.eye(3), [0, 0, 0.2]))
    away = SolidFrames(2, (profile, np.eye(3), np.zeros(3)), (profile, np.eye(3), [0, 0, -0.2]))
    assert not towards.static
    assert list(solid_verdict(x, x, [S], towards, 0.0)[0][0][1]) == [0]
    assert list(solid_verdict(x, x, [S], away, 0.0)[0][0][1]) == []


def test_full_directions_point_from_the_solid_to_the_primitive_and_bound_the_distance():
    profile = (0.0, 0.0, 1.0, 0.0, 1.0)
    frame = _frame(profile, np.eye(3) * 2.0, np.array([5.0, 0, 0]), "t")
    P = np.array([[[5.0, 0, 3.0], [6.0, 0, 3.0], [5.0, 1.0, 3.0]]])  # 1 above the sphere of radius 2
    dirs, upper, touching = full_directions(frame, 2, P)
    assert not touching[0]
    # the first edge holds the closest point (a vertex) and the face is parallel to the tangent plane
    for n in (dirs[0], dirs[-1]):
        np.testing.assert_allclose(n[0] / np.linalg.norm(n[0]), [0, 0, 1], atol=1e-12)
    gaps = [(P[0] @ n[0]).min() - _support(frame, 2, n)[0][0] for n in dirs]
    assert all(g <= 1.0 * np.linalg.norm(n[0]) * (1 + 1e-12) for g, n in zip(gaps, dirs))  # never above the truth
    assert 1.0 <= upper[0] < 1.0 + 1e-8


def test_a_singular_or_non_finite_solid_is_refused():
    profile = (0.0, 0.0, 1.0, 0.0, 1.0)
    with pytest.raises(InputError, match="nonsingular"):
        SolidFrames(2, (profile, np.diag([1.0, 1.0, 0.0]), np.zeros(3)), (profile, np.eye(3), np.zeros(3)))
    with pytest.raises(InputError, match="finite"):
        SolidFrames(2, (profile, np.eye(3), [np.nan, 0, 0]), (profile, np.eye(3), np.zeros(3)))


def test_solid_separation_is_the_distance_of_vertices_and_of_faces_folded_into_them():
    """A sphere of radius 1: a vertex's bound is its distance; a big triangle over the
    sphere whose vertices are far passes its own (smaller) distance to its vertices."""
    from penfree.sequence import AnalyticShape

    ball = AnalyticShape("Sphere", 2, np.array([0.0, 0.0, 1.0, 0.0, 1.0]), np.vstack([np.eye(3), [0, 0, 0]]))
    x = np.array([[0.0, 0, 1.3], [3.0, 0, 1.1], [-1.5, 2.6, 1.1], [-1.5, -2.6, 1.1], [0, 0, 9.0]])
    F = np.array([[1, 2, 3]])
    E = np.array([[1, 2], [2, 3], [3, 1]])
    d = solid_separation(x, E, F, ball, radius=2.0)
    np.testing.assert_allclose(d[0], 0.3, rtol=1e-11)  # less its rounding bound
    np.testing.assert_allclose(d[1:4], 0.1, rtol=1e-9)  # the face's plane z = 1.1 is 0.1 from the sphere
    assert d[4] == 2.0  # beyond the radius: capped
    # never above the exact distance of the vertices
    assert (d <= np.linalg.norm(x, axis=1) - 1.0 + 1e-12).all()


def test_full_directions_prove_a_face_pierced_by_the_solid_touching():
    """A sphere poking through the middle of a big triangle whose edges all pass outside it:
    the foot of the sphere's top point proves the contact; a triangle 1e-3 above it is not."""
    profile = (0.0, 0.0, 1.0, 0.0, 1.0)
    frame = _frame(profile, np.eye(3), np.zeros(3), "t")
    tri = np.array([[3.0, 0, 0], [-1.5, 2.6, 0], [-1.5, -2.6, 0]])
    P = np.stack([tri + [0, 0, 0.9], tri + [0, 0, 1.001]])
    dirs, upper, touching = full_directions(frame, 2, P)
    assert touching.tolist() == [True, False]
    np.testing.assert_allclose(upper[1], 1e-3, rtol=1e-9)


def test_the_face_normal_of_a_face_cutting_into_the_solid_points_out_of_it():
    """Small triangles lying 0.01 inside a unit sphere's top, in random orientations within
    their plane: the first edge's nearest point lies in the face, so the direction from it
    to the centroid gives the normal no side; the searched face normal takes the side whose
    plane leaves the larger gap, +z (a gap of -0.01 against -1.99 below)."""
    rng = np.random.default_rng(4)
    frame = _frame((0.0, 0.0, 1.0, 0.0, 1.0), np.eye(3), np.zeros(3), "t")
    a = rng.uniform(0, 2 * np.pi, 200)[:, None] + np.array([0.0, 2.1, 4.2])
    size = rng.uniform(0.01, 0.1, (200, 1))
    P = np.stack([size * np.cos(a), size * np.sin(a), np.full((200, 3), 0.99)], axis=-1)
    P[::2] = P[::2, ::-1]  # both windings
    dirs, _, touching = full_directions(frame, 2, P)
    assert touching.all()
    face = dirs[3]
    assert (face[:, 2] > 0).all() and np.allclose(face[:, :2], 0.0, atol=1e-12 * np.abs(face[:, 2:]).max())

def test_faces_sliding_over_a_ball_pass_where_one_plane_for_the_whole_step_cannot():
    """Triangles resting 1e-5 above a unit sphere (beyond their sagitta), moved by the
    constant-velocity extrapolation of a rotation about the centre by 0.01-0.3 rad: every
    point moves outward along its tangent, so every path is clear (dense sampling checks
    it). One supporting plane for the whole step refused 130 of these 400 paths; the
    bisected path (`solid_kernels.PIECE_DEPTH`) passes them all."""
    rng = np.random.default_rng(0)
    profile = (0.0, 0.0, 1.0, 0.0, 1.0)
    solid = SolidFrames(2, (profile, np.eye(3), np.zeros(3)), (profile, np.eye(3), np.zeros(3)))
    K = 400
    c = rng.normal(size=(K, 3))
    c /= np.linalg.norm(c, axis=1)[:, None]
    a = np.cross(c, rng.normal(size=(K, 3)))
    a /= np.linalg.norm(a, axis=1)[:, None]
    b = np.cross(c, a)
    size = rng.uniform(0.01, 0.1, (K, 1, 1))
    ang = rng.uniform(0, 2 * np.pi, (K, 1)) + [0.0, 2.1, 4.2]
    tri = c[:, None] + size * (np.cos(ang)[..., None] * a[:, None] + np.sin(ang)[..., None] * b[:, None])
    tri /= np.linalg.norm(tri, axis=2)[..., None]
    tri *= 1 + rng.uniform(0.52, 0.7, (K, 1, 1)) * size ** 2 + 1e-5
    axis = rng.normal(size=(K, 3))
    axis /= np.linalg.norm(axis, axis=1)[:, None]
    theta = rng.uniform(0.01, 0.3, (K, 1, 1))
    # p R^T for the rotation about `axis` (Rodrigues), per triangle: d = p - p R^T is tangent and outward
    cross = np.cross(axis[:, None], tri)
    rotated_back = tri * np.cos(theta) - cross * np.sin(theta) + axis[:, None] * (
        np.einsum("kj,kvj->kv", axis, tri)[..., None] * (1 - np.cos(theta)))
    P0, P1 = tri, 2 * tri - rotated_back
    S = np.arange(3 * K).reshape(K, 3)
    d = np.linalg.norm(_sample_path(P0, P1), axis=-1) - 1.0
    assert d.min() > 0
    for thickness in (0.0, 5e-6):
        (start, path, _), = solid_verdict(P0.reshape(-1, 3), P1.reshape(-1, 3), [S], solid, thickness)[0]
        assert len(start) == 0 and len(path) == 0
    # The same faces riding a ball that translates by v over the step (a kinematic solid:
    # verify's reading of a recording with a moving collider, the blend of its frames being
    # the translated ball). Relative to the ball each path is the one above, so all are
    # clear; one plane for the whole step refused 130 of them here too.
    v = np.array([0.3, -0.2, 0.1])
    moving = SolidFrames(2, (profile, np.eye(3), np.zeros(3)), (profile, np.eye(3), v))
    t = np.linspace(0.0, 1.0, 41)[:, None, None, None]
    assert (np.linalg.norm(_sample_path(P0, P1 + v) - t * v, axis=-1) - 1.0).min() > 0  # the oracle, relative
    for thickness in (0.0, 5e-6):
        (start, path, _), = solid_verdict(P0.reshape(-1, 3), (P1 + v).reshape(-1, 3), [S], moving, thickness)[0]
        assert len(start) == 0 and len(path) == 0

def test_the_kernels_give_the_same_bits_serially_and_in_parallel():
    """`solid_kernels`' batch kernels: each primitive writes only its own slots, so the serial
    build and the parallel one (any thread count) agree bit for bit, verdicts and bounds."""
    from penfree.core.contact import solid_kernels as k

    rng = np.random.default_rng(11)
    profile = np.array(PROFILES[2][1])
    L, c = _similarity(rng, 0.8)
    frame0, frame1 = _frame(profile, L, c, "t0"), _frame(profile, L, c + 0.01, "t1")
    x0 = c + rng.normal(size=(3000, 3)) * 1.2
    x1 = x0 + rng.normal(size=(3000, 3)) * 0.05
    lo, hi = np.full(3, -np.inf), np.full(3, np.inf)
    for S in (rng.integers(0, 3000, (2500, 3)), rng.integers(0, 3000, (2500, 2)), np.arange(3000)[:, None]):
        for pre in (False, True):
            out = []
            for build in (k.verdict_kernel.serial, k.verdict_kernel.parallel):
                flags, lbs = np.zeros(len(S), np.int8), np.empty(len(S))
                build(x0, x1, S, frame0[4], frame1[4], False, 0, 0.02, pre, lo, hi, flags, lbs)
                out.append((flags, lbs))
            assert np.array_equal(out[0][0], out[1][0]) and np.array_equal(out[0][1], out[1][1])
            assert len(set(out[0][0])) >= 2  # both verdicts occur
        out = []
        for build in (k.separation_kernel.serial, k.separation_kernel.parallel):
            lbs = np.empty(len(S))
            build(x0, S, frame0[4], 0, 0.5, lo, hi, lbs)
            out.append(lbs)
        assert np.array_equal(out[0], out[1]) and 0 < (out[0] < 0.5).sum() < len(S)
