"""Trust-region bounds (SPEC section 7) against a brute-force numpy oracle over
ALL primitive pairs with the same definition, plus invariances."""

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from penfree.core.contact.distance import edge_edge_distance, point_triangle_distance
from penfree.core.topology import edges_from_faces
from penfree.core.trust.bounds import min_separation, trust_region_bounds
from penfree.errors import InputError

GAMMA = 0.45
#: Bounds computed along different paths (relabelled, rigidly moved) agree to
#: rounding of the distances: 1e-12 of the scene extent.
ATOL_EXTENT = 1e-12


RNG_SEED = 3  # seed of the shared `rng` fixture (tests/conftest.py)


def crumpled_cloth(n, rng):
    u = np.linspace(0.0, 1.0, n)
    X, Y = np.meshgrid(u, u, indexing="ij")
    # fold the sheet over itself at x = 0.5 (layers 0.008 .. 0.038 apart) so
    # that non-adjacent parts come close
    fold = X > 0.5
    X = np.where(fold, 1.0 - X, X)
    Z = 0.15 * np.sin(5 * X) * np.cos(4 * Y) + np.where(fold, 0.008 + 0.03 * Y, 0.0)
    V = np.stack([X, Y, Z], -1).reshape(-1, 3)
    V += rng.normal(scale=0.2 / n, size=V.shape)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return V, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def rod_bundle(n_rods, n_per, rng):
    t = np.linspace(0.0, 1.0, n_per)
    Vs, Es = [], []
    for r in range(n_rods):
        c = rng.uniform(0, 0.15, 2)
        ph = rng.uniform(0, 2 * np.pi)
        Vs.append(np.stack([c[0] + 0.05 * np.cos(7 * t + ph), c[1] + 0.05 * np.sin(7 * t + ph), t], 1))
        Es.append(np.stack([np.arange(n_per - 1), np.arange(1, n_per)], 1) + r * n_per)
    return np.concatenate(Vs), np.concatenate(Es)


def oracle(x, edges=None, faces=None, thickness=0.0, gamma=GAMMA, r_q=None):
    """All pairs, no broad phase: the SPEC definition written out."""
    n = len(x)
    if r_q is None:
        r_q = thickness + 0.1 * np.linalg.norm(np.ptp(x, axis=0))
    d = np.full(n, np.inf)
    if faces is not None:
        F = np.asarray(faces)
        E = edges_from_faces(F)
        v, f = np.meshgrid(np.arange(n), np.arange(len(F)), indexing="ij")  # every vertex meets the faces
        v, f = v.ravel(), f.ravel()
        keep = np.all(F[f] != v[:, None], axis=1)
        v, f = v[keep], f[keep]
        dist = point_triangle_distance(x[v], x[F[f, 0]], x[F[f, 1]], x[F[f, 2]])
        np.minimum.at(d, v, dist)
        for c in range(3):
            np.minimum.at(d, F[f, c], dist)
    else:
        E = np.asarray(edges)
    i, j = np.triu_indices(len(E), 1)
    keep = np.all(E[i][:, :, None] != E[j][:, None, :], axis=(1, 2))
    i, j = i[keep], j[keep]
    dist = edge_edge_distance(x[E[i, 0]], x[E[i, 1]], x[E[j, 0]], x[E[j, 1]])
    for c in range(2):
        np.minimum.at(d, E[i, c], dist)
        np.minimum.at(d, E[j, c], dist)
    d = np.minimum(d, r_q)
    return gamma * np.maximum(0.0, d - thickness)


def _assert_close(b, want, x):
    ext = float(np.ptp(x, axis=0).max())
    np.testing.assert_allclose(b, want, rtol=0, atol=ATOL_EXTENT * ext)


RADII = {"small-radius": 0.02, "medium-radius": 0.1, "default-radius": None}
THICK = {"no-thickness": 0.0, "thick": 0.012}


@pytest.mark.parametrize("r_q", list(RADII.values()), ids=list(RADII))
@pytest.mark.parametrize("thickness", list(THICK.values()), ids=list(THICK))
def test_rods_match_oracle(rng, r_q, thickness):
    x, E = rod_bundle(6, 25, rng)
    b = trust_region_bounds(x, edges=E, thickness=thickness, query_radius=r_q)
    want = oracle(x, edges=E, thickness=thickness, r_q=r_q)
    _assert_close(b, want, x)
    assert b.dtype == np.float64 and b.shape == (len(x),) and np.all(b >= 0.0)
    # the scene is not trivial: bounds vary, some are capped by the radius
    assert len(np.unique(b)) > 10


@pytest.mark.parametrize("r_q", list(RADII.values()), ids=list(RADII))
@pytest.mark.parametrize("thickness", list(THICK.values()), ids=list(THICK))
def test_cloth_matches_oracle(rng, r_q, thickness):
    x, F = crumpled_cloth(11, rng)
    b = trust_region_bounds(x, faces=F, thickness=thickness, query_radius=r_q)
    want = oracle(x, faces=F, thickness=thickness, r_q=r_q)
    _assert_close(b, want, x)
    assert np.all(b >= 0.0) and len(np.unique(b)) > 10


def test_thickness_above_some_gaps_gives_zero_not_negative(rng):
    x, F = crumpled_cloth(11, rng)
    d = trust_region_bounds(x, faces=F, gamma=1.0, query_radius=0.2)  # gamma 1: b = d
    thickness = float(np.quantile(d, 0.3))
    b = trust_region_bounds(x, faces=F, thickness=thickness, query_radius=0.2)
    assert np.any(b == 0.0) and np.any(b > 0.0) and np.all(b >= 0.0)
    _assert_close(b, oracle(x, faces=F, thickness=thickness, r_q=0.2), x)


def test_far_and_unreferenced_vertices_get_the_radius(rng):
    x, E = rod_bundle(3, 10, rng)
    far = np.array([[50.0, 50.0, 50.0], [51.0, 50.0, 50.0], [0.05, 0.05, 0.5]])
    x = np.concatenate([x, far])
    n = len(x)
    E = np.concatenate([E, [[n - 3, n - 2]]])  # a far edge; vertex n-1 is in no primitive
    b = trust_region_bounds(x, edges=E, thickness=0.01, query_radius=0.3)
    assert b[n - 3] == b[n - 2] == b[n - 1] == pytest.approx(GAMMA * (0.3 - 0.01), rel=1e-15)
    # default radius: thickness + 0.1 * bounding-box diagonal
    r_default = 0.01 + 0.1 * np.linalg.norm(np.ptp(x, axis=0))
    b = trust_region_bounds(x, edges=E, thickness=0.01)
    assert b[n - 1] == pytest.approx(GAMMA * (r_default - 0.01), rel=1e-15)


@pytest.mark.parametrize("thickness", list(THICK.values()), ids=list(THICK))
def test_free_vertices_near_cloth_match_oracle(rng, thickness):
    """Vertices in no primitive (particles) among cloth meet its faces: their own bound
    and those of the faces near them shrink (they kept the radius, ipctk did not: a
    particle could move into the cloth undetected)."""
    x, F = crumpled_cloth(11, rng)
    free = x[rng.choice(len(x), 12, replace=False)] + rng.normal(scale=0.01, size=(12, 3))
    x = np.concatenate([x, free])
    b = trust_region_bounds(x, faces=F, thickness=thickness, query_radius=0.1)
    want = oracle(x, faces=F, thickness=thickness, r_q=0.1)
    _assert_close(b, want, x)
    assert (b[-12:] < GAMMA * (0.1 - thickness)).all()


def test_particles_over_a_mesh_obstacle(rng):
    """A scene without primitives over a mesh floor: each particle's bound is its height."""
    from penfree.sequence import Obstacle

    x = np.c_[rng.uniform(-1, 1, (20, 2)), rng.uniform(0.01, 0.2, 20)]
    floor = Obstacle("floor", positions=np.array([[-5, -5, 0], [5, -5, 0], [0, 5, 0.0]]), faces=[[0, 1, 2]])
    b = trust_region_bounds(x, query_radius=0.5, obstacles=[floor])
    np.testing.assert_allclose(b, GAMMA * x[:, 2], rtol=1e-12)


def test_no_primitives_and_zero_radius():
    x = np.random.default_rng(0).normal(size=(5, 3))
    np.testing.assert_array_equal(trust_region_bounds(x, query_radius=0.5), np.full(5, GAMMA * 0.5))
    V, E = rod_bundle(2, 5, np.random.default_rng(1))
    np.testing.assert_array_equal(trust_region_bounds(V, edges=E, query_radius=0.0), np.zeros(10))


def test_relabelling(rng):
    x, F = crumpled_cloth(9, rng)
    perm = rng.permutation(len(x))
    inv = np.argsort(perm)  # new vertex k is old vertex perm[k]
    b = trust_region_bounds(x, faces=F, thickness=0.005, query_radius=0.15)
    b_perm = trust_region_bounds(x[perm], faces=inv[F], thickness=0.005, query_radius=0.15)
    _assert_close(b_perm, b[perm], x)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), shift=st.floats(-100, 100))
def test_rigid_motion_invariance(seed, shift):
    rng = np.random.default_rng(seed)
    x, E = rod_bundle(4, 12, rng)
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    y = x @ Q.T + shift
    b = trust_region_bounds(x, edges=E, thickness=0.003, query_radius=0.08)
    b_moved = trust_region_bounds(y, edges=E, thickness=0.003, query_radius=0.08)
    # rounding of the moved coordinates: ~1e-16 * (|shift| + extent) per distance
    np.testing.assert_allclose(b_moved, b, rtol=0, atol=1e-12 * (abs(shift) + 1.0))


def test_thread_count_independent(rng):
    x, F = crumpled_cloth(12, rng)
    n0 = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        b1 = trust_region_bounds(x, faces=F, query_radius=0.1)
    finally:
        numba.set_num_threads(n0)
    np.testing.assert_array_equal(trust_region_bounds(x, faces=F, query_radius=0.1), b1)


def test_min_separation(rng):
    x, F = crumpled_cloth(10, rng)
    d_all = oracle(x, faces=F, gamma=1.0, r_q=np.inf)
    assert min_separation(x, F=F, radius=1.0) == pytest.approx(d_all.min(), rel=1e-12)
    assert min_separation(x, F=F, radius=0.5 * d_all.min()) == 0.5 * d_all.min()
    xr, E = rod_bundle(4, 15, rng)
    d_rod = oracle(xr, edges=E, gamma=1.0, r_q=np.inf)
    assert min_separation(xr, E=E, radius=1.0) == pytest.approx(d_rod.min(), rel=1e-12)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(edges=[[0, 5]]), r"edges indices must lie in \[0, 4\)"),
        (dict(faces=[[0, 1]]), r"faces must be \(M, 3\)"),
        (dict(thickness=-1.0), "thickness must be finite and >= 0"),
        (dict(query_radius=np.nan), "query_radius must be finite"),
    ],
    ids=["edge-index", "face-shape", "negative-thickness", "nan-radius"],
)
def test_input_errors(kwargs, match):
    with pytest.raises(InputError, match=match):
        trust_region_bounds(np.zeros((4, 3)), **kwargs)
