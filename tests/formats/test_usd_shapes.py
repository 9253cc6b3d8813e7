"""Conservative tessellation of USD's analytic colliders: the mesh contains the shape."""

import numpy as np
import pytest

from penfree.formats import _usd_shapes as shapes


def _outward_planes(V, F, inside):
    """Unit normals n and offsets d of each face plane, oriented so that `inside` has n.x < d."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1)[:, None]
    d = np.einsum("ij,ij->i", n, a)
    flip = n @ inside > d
    n[flip], d[flip] = -n[flip], -d[flip]
    return n, d


def _sphere_points(rng, k=20000):
    p = rng.normal(size=(k, 3))
    return p / np.linalg.norm(p, axis=1)[:, None]


@pytest.mark.parametrize("radius", [1e-3, 0.5, 7.0], ids=["tiny", "half", "large"])
def test_sphere_face_planes_clear_the_radius(radius):
    rng = np.random.default_rng(0)
    V, F = shapes.sphere(radius)
    assert (shapes.face_plane_distances(V, F) >= radius).all()
    n, d = _outward_planes(V, F, np.zeros(3))
    # Oracle: the support of the ball in each face direction is the radius.
    assert (d >= radius).all()
    pts = radius * _sphere_points(rng)
    assert ((pts @ n.T) <= d).all()
    # Conservative but tight: vertices lie within 3% of the radius.
    assert np.linalg.norm(V, axis=1).max() <= 1.03 * radius


@pytest.mark.parametrize("axis", ["X", "Y", "Z"])
def test_capsule_hull_contains_both_end_balls(axis):
    rng = np.random.default_rng(1)
    r, h = 0.3, 1.2
    V, F = shapes.capsule(r, h, axis)
    k = "XYZ".index(axis)
    ends = np.zeros((2, 3))
    ends[:, k] = [0.5 * h, -0.5 * h]
    n, d = _outward_planes(V, F, np.zeros(3))
    # The capsule is the hull of the two end balls: each face half-space must hold both.
    assert ((d[None, :] - ends @ n.T) >= r).all()
    # Sampled surface points: sphere caps and the cylinder between.
    s = _sphere_points(rng)
    t = rng.uniform(-0.5 * h, 0.5 * h, size=len(s))
    axial = np.zeros((len(s), 3))
    axial[:, k] = t
    ring = s.copy()
    ring[:, k] = 0
    ring /= np.linalg.norm(ring, axis=1)[:, None]
    pts = np.vstack([r * s + ends[0], r * s + ends[1], axial + r * ring])
    assert ((pts @ n.T) <= d).all()


def test_cube_is_exact():
    V, F = shapes.cube(2.0)
    assert np.array_equal(np.sort(np.unique(V)), [-1.0, 1.0]) and len(V) == 8 and len(F) == 12
    n, d = _outward_planes(V, F, np.zeros(3))
    assert np.allclose(d, 1.0, rtol=0, atol=1e-15)
    # Every face is a half of one of the six cube faces: 6 planes, 2 triangles each.
    assert len(np.unique(np.round(n, 12), axis=0)) == 6


def test_a_triangle_starting_inside_the_sphere_s_tessellation_stays_outside_the_sphere():
    """A 0.2 mm triangle 0.5 mm, then 0.2 mm above a Sphere collider of radius 3 cm, under
    a vertex of its icosphere (which lies 0.54 mm above the sphere): the triangle is inside
    the tessellation, outside the shape. The constant-velocity prediction puts it 0.1 mm
    inside the sphere. Safe against the tessellation (no face of it is crossed) is not
    safe against the shape here; the obstacle's exact solid (`AnalyticShape`) keeps the
    triangle out (before it, `deform` wrote the step 0.1 mm into the sphere)."""
    from penfree.core.pipeline.deform import deform_sequence
    from penfree.sequence import AnalyticShape, Obstacle, Sequence

    R = 0.03
    V, F = shapes.sphere(R)
    n = V[np.argmax(V[:, 2])] / np.linalg.norm(V[np.argmax(V[:, 2])])  # under an icosphere vertex
    a = np.cross(n, [1.0, 0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    tri = n * R + 1e-4 * np.array([a, -a + b, -a - b])
    frames = np.array([tri + n * 5e-4, tri + n * 2e-4, tri - n * 1e-4])
    ball = AnalyticShape("Sphere", 2, np.array([0.0, 0.0, R, 0.0, R]), np.vstack([np.eye(3), np.zeros(3)]))
    seq = Sequence(positions=frames, faces=np.array([[0, 1, 2]]),
                   obstacles=[Obstacle("ball", positions=V, faces=F, shape=ball)]).validate()
    out = deform_sequence(seq, model="affine", thickness=0.0).steps
    k = list(out["frame"]).index(1)  # the step that starts outside the sphere
    assert np.linalg.norm(frames[1], axis=1).min() > R
    assert np.linalg.norm(np.asarray(out["deformed"][k], float), axis=1).min() >= R
