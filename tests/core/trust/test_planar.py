"""Planar ("Divide and Truncate") and isotropic filters against ipctk.ogc.TrustRegion."""

from __future__ import annotations

import numpy as np
import pytest

from penfree.core.trust.planar import (
    KIND_EDGE_EDGE, KIND_VERTEX_FACE, candidate_stencils, isotropic_filter, planar_filter, stencil_coefficients,
)
from penfree.core.trust.bounds import scene_arrays, trust_region_bounds

ipctk = pytest.importorskip("ipctk", reason="ipctk (penfree[ogc]) is the oracle of these tests; make test installs it")


def _grid(rng, n=9, layers=2, gap=0.06):
    u, w = np.meshgrid(np.linspace(0, 0.4, n), np.linspace(0, 0.4, n), indexing="ij")
    V, F = [], []
    for k in range(layers):
        V.append(np.column_stack([u.ravel(), w.ravel(), np.full(n * n, k * gap)]))
        q = np.arange(n * n).reshape(n, n)[:-1, :-1].ravel() + k * n * n
        F += [np.column_stack([q, q + n, q + 1]), np.column_stack([q + 1, q + n, q + n + 1])]
    V = np.concatenate(V) + rng.normal(0, 0.01, (layers * n * n, 3))
    return V, None, np.concatenate(F)


def _rods(rng, n_rods=8, per=12):
    t = np.linspace(0, 0.5, per)
    V = np.concatenate([np.column_stack([t, np.full(per, 0.05 * k), 0.02 * np.sin(9 * t + k)])
                        for k in range(n_rods)]) + rng.normal(0, 0.01, (n_rods * per, 3))
    E = np.concatenate([np.column_stack([np.arange(per - 1), np.arange(1, per)]) + k * per for k in range(n_rods)])
    return V, E, None


def _client(V, E, F, R, thickness=0.0):
    _, E_, F_ = scene_arrays(V, E, F)
    mesh = ipctk.CollisionMesh(np.asfortranarray(V), np.asfortranarray(E_.astype(np.int32)),
                               np.asfortranarray(F_.astype(np.int32)))
    tr = ipctk.ogc.TrustRegion(0.01)
    tr.trust_region_inflation_radius = R
    tr.update(mesh, np.asfortranarray(V), ipctk.NormalCollisions(), thickness)
    return mesh, tr, E_, F_


def _ipctk_stencils(mesh, tr):
    st = [c.vertex_ids(mesh.edges, mesh.faces) for c in tr.candidates.ee_candidates]
    kd = [KIND_EDGE_EDGE] * len(st)
    st += [c.vertex_ids(mesh.edges, mesh.faces) for c in tr.candidates.fv_candidates]
    kd += [KIND_VERTEX_FACE] * (len(st) - len(kd))
    return np.array(st, dtype=np.int64).reshape(-1, 4), np.array(kd, dtype=np.int64)


SCENES = {"cloth-layers": _grid, "rods": _rods}


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("scene", sorted(SCENES))
@pytest.mark.parametrize("moved", [False, True], ids=["at-centres", "moved-since-update"])
def test_planar_matches_ipctk(scene, seed, moved):
    """Same truncated displacements as planar_filter_step, to 1e-9 relative."""
    rng = np.random.default_rng(seed)
    V, E, F = SCENES[scene](rng)
    R = 0.08
    mesh, tr, E_, F_ = _client(V, E, F, R)
    x = V + (rng.normal(0, 0.005, V.shape) if moved else 0.0)
    dx = rng.normal(0, 0.03, V.shape)
    ref = np.array(dx, order="F")
    tr.planar_filter_step(mesh, np.asfortranarray(x), ref)
    scale = np.abs(ref).max()
    # with ipctk's own candidates
    st, kd = _ipctk_stencils(mesh, tr)
    out, n_trunc = planar_filter(x, dx, V, R, st, kd)
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-9 * scale)
    assert n_trunc == int(np.count_nonzero(np.any(ref != dx, axis=1)))
    # with penfree's own broad phase (a superset within the same radius)
    st2, kd2 = candidate_stencils(V, E_, F_, R)
    out2, _ = planar_filter(x, dx, V, R, st2, kd2)
    np.testing.assert_allclose(out2, ref, rtol=0, atol=1e-9 * scale)
    assert n_trunc > 0  # the scenes are tight enough for the planes to matter


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("scene", sorted(SCENES))
def test_isotropic_matches_ipctk(scene, seed):
    rng = np.random.default_rng(seed)
    V, E, F = SCENES[scene](rng)
    R, thickness = 0.08, 0.002
    mesh, tr, E_, F_ = _client(V, E, F, R, thickness)
    radii = 0.45 * trust_region_bounds(V, edges=E_, faces=F_, thickness=thickness, query_radius=R) / 0.45
    np.testing.assert_allclose(radii, tr.trust_region_radii, rtol=1e-12, atol=1e-15)
    dx = rng.normal(0, 0.03, V.shape)
    ref = np.array(dx, order="F")
    tr.filter_step(mesh, np.asfortranarray(V), ref)
    out, _ = isotropic_filter(V, dx, V, radii)
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-12)


def test_stencil_coefficients_match_ipctk():
    """Closest-point coefficients of both stencil kinds against ipctk's own."""
    rng = np.random.default_rng(5)
    V, E, F = _grid(rng)
    mesh, tr, _, _ = _client(V, E, F, 0.08)
    for cands, kind in ((tr.candidates.ee_candidates, KIND_EDGE_EDGE),
                        (tr.candidates.fv_candidates, KIND_VERTEX_FACE)):
        for c in list(cands)[:200]:
            P = V[c.vertex_ids(mesh.edges, mesh.faces)]
            coef = np.zeros(4)
            stencil_coefficients(P, kind, coef)
            dv, ref = c.compute_distance_vector_with_coefficients(P.ravel())
            np.testing.assert_allclose(coef @ P, dv, rtol=0, atol=1e-12)
            np.testing.assert_allclose(coef, ref, rtol=0, atol=1e-9)


@pytest.mark.parametrize("case", ["parallel-approach", "tangential-slide"])
def test_planar_named_cases(case):
    """Two parallel segments 0.1 apart: approaching stops at 0.9 x the way to the
    mid-plane; sliding along the plane is not truncated at all."""
    x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 0.1, 0], [1, 0.1, 0]])
    st, kd = np.array([[0, 1, 2, 3]]), np.array([KIND_EDGE_EDGE])
    if case == "parallel-approach":
        dx = np.array([[0, 0.1, 0], [0, 0.1, 0], [0, -0.1, 0], [0, -0.1, 0]])
        out, n = planar_filter(x, dx, x, 1.0, st, kd)
        np.testing.assert_allclose(out[:, 1], 0.9 * np.array([0.05, 0.05, -0.05, -0.05]), atol=1e-15)
        assert n == 4
    else:
        dx = np.array([[0.3, 0, 0.2]] * 4)
        out, n = planar_filter(x, dx, x, 1.0, st, kd)
        np.testing.assert_array_equal(out, dx)
        assert n == 0


def test_near_parallel_stacked_layers_regression():
    """The falling stack (samples/falling_stack.h5) before the landing, frames 0 -> 1.

    Neighbouring edges of one cloth layer (53-69 and 54-70) are parallel to
    a c - b^2 ~ 6.5e-7 a c. Their closest points, solved in the dot-product form,
    were off by 1.6e-10; the closest-point direction then tilted out of the layer
    by 1.3e-13, the layer's straight fall crossed it (|dx . n| = 1.6e-15 > the
    parallel cut 1e-15) and 9 vertices were truncated to ~3% of their move, where
    planar_filter_step truncates none. Now the same filtered step as ipctk."""
    from _samples import load_sample

    data = load_sample("falling_stack")
    P = data["positions"].astype(np.float64)
    _, E, F = scene_arrays(P[0], None, data["faces"])
    x, dx = P[1], P[1] - P[0]  # the warm-start move toward x_pred = 2 x - x_prev
    R = max(2.0 * float(data["attrs"]["contact_radius"]), float(np.linalg.norm(dx, axis=1).max()))
    mesh, tr, E_, F_ = _client(x, None, F, R, thickness=float(data["attrs"]["thickness"]))
    ref = np.array(dx, order="F")
    tr.planar_filter_step(mesh, np.asfortranarray(x), ref)
    st, kd = candidate_stencils(x, E_, F_, R + float(data["attrs"]["thickness"]))
    out, n = planar_filter(x, dx, x, R, st, kd)
    assert n == int(np.count_nonzero(np.any(ref != dx, axis=1))) == 0
    np.testing.assert_array_equal(out, ref)
    # the named pair: its closest-point direction stays in the layer's plane
    coef = np.zeros(4)
    stencil_coefficients(x[[53, 69, 54, 70]], KIND_EDGE_EDGE, coef)
    dv = coef @ x[[53, 69, 54, 70]]
    assert abs(dv[2]) <= 1e-14 * np.linalg.norm(dv)  # was 1.3e-13


@pytest.mark.parametrize("tri", [[[0.2, 0.2, 0.1]] * 2 + [[0.6, 0.3, 0.1]], [[0, 0, 0.1], [0.5, 0, 0.1], [1, 0, 0.1]],
                                 [[0.3, 0.3, 0.1]] * 3], ids=["two-coincident", "collinear", "a-point"])
def test_degenerate_triangle_stencils_are_their_nearest_edge(tri):
    """A triangle without area: the vertex-face coefficients are those of the nearest
    point on its edges (the type classification divided by the normal's length: a
    ZeroDivisionError made `predeform(truncation="planar")` raise SystemError)."""
    from penfree import predeform

    p = np.array([0.4, -0.3, 0.5])
    P = np.vstack([p, tri])
    coef = np.zeros(4)
    stencil_coefficients(P, KIND_VERTEX_FACE, coef)
    # brute force: the nearest of many points on the three edges
    s = np.linspace(0, 1, 100001)[:, None]
    pts = np.concatenate([P[a] + s * (P[b] - P[a]) for a, b in ((1, 2), (2, 3), (3, 1))])
    np.testing.assert_allclose(np.linalg.norm(coef @ P), np.linalg.norm(pts - p, axis=1).min(), rtol=0, atol=1e-6)
    assert coef[0] == 1.0 and np.isclose(coef[1:].sum(), -1.0) and (coef[1:] <= 0).all()
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0], *tri])
    r = predeform(x + [0.03, -0.02, 0.05], x, faces=[[0, 1, 2], [3, 4, 5]], thickness=0.01, contact_radius=0.05,
                  truncation="planar")
    assert np.isfinite(r.x_def).all()


def test_a_segment_end_falling_onto_a_face_is_truncated_like_ipctk():
    """A free segment's endpoint 0.01 above a triangle falls 0.05: ipctk stops it above
    the face. The own planar client paired faces only with the faces' vertices, so a
    segment's vertex met no face and went through (to z = -0.04)."""
    from penfree.core.trust.client import make_client

    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, 0.01], [0.2, 0.2, 0.5]])
    F = np.array([[0, 1, 2]])
    _, E, _ = scene_arrays(x, np.array([[3, 4]]), F)
    dx = np.zeros_like(x)
    dx[3:, 2] = -0.05
    z = {}
    for kind in ("own", "ipctk"):
        c = make_client(kind, x, E, F, 0.01, 0.0, "planar")
        c.set_radius(0.06)
        c.update(x.copy())
        z[kind] = x[3, 2] + c.filter(x, dx)[0][3, 2]
    assert 0.0 < z["own"] < 0.01 and z["own"] == pytest.approx(z["ipctk"], abs=1e-12)


def _outside_cases(rng, n):
    """Vertices moved off their trust-region centres (as after an unhindered move of a
    vertex whose radius is 0), some with radius 0, and displacements some of which are
    exactly perpendicular to the offset (ipctk's b = 0: the line misses the ball)."""
    V = rng.uniform(0, 1, (n, 3))
    off = np.zeros((n, 3))
    off[np.arange(n), rng.integers(0, 3, n)] = rng.choice([-1.0, 1.0], n) * rng.uniform(0.02, 0.2, n)
    radii = np.where(rng.random(n) < 0.5, 0.0, rng.uniform(0.01, 0.1, n))
    dx = rng.normal(0, 0.05, (n, 3))
    perp = rng.random(n) < 0.4  # zero the offset's axis: dx . (x - c) == 0 exactly
    dx[perp] *= (off[perp] == 0.0)
    return V, V + off, dx, radii


@pytest.mark.parametrize("seed", range(3))
def test_a_vertex_outside_its_ball_is_filtered_like_ipctk(seed):
    """ipctk's formula takes the square root of a negative discriminant (the line from
    a vertex outside its ball misses the ball): NaN, and its ``beta < 1`` test leaves
    the vertex unhindered; the planar fallback's ``std::min`` keeps the planar ratio.
    Clamping the discriminant at 0 gave -inf ratios (NaN positions, on which the own
    client's next pass crashed) and negative ones."""
    from penfree.core.trust.planar import ball_ratio

    rng = np.random.default_rng(seed)
    n = 400
    V, x, dx, radii = _outside_cases(rng, n)
    E = np.arange(n).reshape(-1, 2)
    mesh, tr, E_, F_ = _client(V, E, None, 0.05)
    tr.trust_region_radii = radii
    # near a zero discriminant the root is ill-conditioned and its rounding decides ipctk's answer: leave those out
    rel = x - V
    a, b = np.einsum("ij,ij->i", dx, dx), 2 * np.einsum("ij,ij->i", dx, rel)
    c = np.einsum("ij,ij->i", rel, rel) - radii ** 2
    clear = np.abs(b * b - 4 * a * c) > 1e-6 * (b * b + np.abs(4 * a * c))
    ref = np.array(dx, order="F")
    tr.filter_step(mesh, np.asfortranarray(x), ref)
    out, _ = isotropic_filter(x, dx, V, radii)
    assert np.isfinite(out).all()
    assert np.isnan(ball_ratio(x, dx, V, radii)[clear & (b == 0) & (c > 0)]).all()
    np.testing.assert_allclose(out[clear], ref[clear], rtol=0, atol=1e-12)
    assert (np.any(ref != dx, axis=1)[clear]).sum() > 0 and (np.all(ref == dx, axis=1) & clear & (b == 0)).sum() > 0
    # planar: vertices farther than the inflation radius from their centres, with candidates
    R = 0.05
    st, kd = _ipctk_stencils(mesh, tr)
    assert st.shape[0] > 0
    ref = np.array(dx, order="F")
    tr.planar_filter_step(mesh, np.asfortranarray(x), ref)
    out, _ = planar_filter(x, dx, V, R, st, kd)
    assert np.isfinite(out).all()
    rel2 = np.einsum("ij,ij->i", rel, rel) - R * R
    clear = np.abs(b * b - 4 * a * rel2) > 1e-6 * (b * b + np.abs(4 * a * rel2))
    assert (clear & (b == 0) & (rel2 > 0)).sum() > 0  # lines that miss the inflation ball are among them
    # a planar ratio near ipctk's cut (t < 1e-10 is no crossing), from a pair of random segments nearly
    # touching, follows the plane's last bits: leave those out
    for got in (out, ref):
        clear &= ~(np.linalg.norm(got, axis=1) < 1e-6 * np.linalg.norm(dx, axis=1))
    np.testing.assert_allclose(out[clear], ref[clear], rtol=0, atol=1e-9 * np.abs(ref).max())  # as the planar test
