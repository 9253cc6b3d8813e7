"""verify_step: named scenes, a dense-time sampling oracle with exact distances, invariance."""

from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from penfree.core.contact.ccd_exact import exact_edge_edge, exact_vertex_face
from penfree.core.verify.path import verify_step
from penfree.errors import InputError

from _geom import grid, rods, two_sheets
from oracles import exact_dist_sq  # exact Fraction distance at a rational time


# --- named scenes -----------------------------------------------------------------------


def test_cloth_rigid_motion_is_safe():
    V, F = two_sheets()
    r = verify_step(V, V + [0.5, -0.25, 3.0], faces=F)
    assert r.ok and r.start_ok and r.n_violations == 0 and r.pairs == []
    assert r.min_separation == 0.0  # thickness 0: pairs the broad phase skipped have no quantitative bound
    assert r.n_candidates > 0


def test_vertex_pushed_through_other_sheet_names_the_pair():
    V, F = two_sheets()
    V1 = V.copy()
    v = 5  # interior vertex of the lower sheet, at (1.3, 1.3, 0)
    V1[v, 2] = 2.0  # goes through the upper sheet at z = 1, halfway
    r = verify_step(V, V1, faces=F)
    assert not r.ok and r.start_ok
    kinds = {p[0] for p in r.pairs}
    assert "vf" in kinds
    vf = [p for p in r.pairs if p[0] == "vf"]
    assert vf[0][1] == v and 0.49 < vf[0][3] <= 0.5
    n_lower = len(grid(4)[0])  # vertices of the lower sheet come first (16)
    assert v < n_lower
    assert all(f >= 18 for _, _, f, _ in vf)  # faces of the upper sheet (18 per sheet)
    assert all((F[f] >= n_lower).all() for _, _, f, _ in vf)  # ... whose corners are all upper-sheet
    assert r.min_separation == 0.0


def test_rod_through_rod():
    V, E = rods(k=2, n=5)
    V1 = V.copy()
    V1[5:10, 2] = -1.0  # the upper rod passes through the lower one (parallel, at t = 1/2)
    r = verify_step(V, V1, edges=E)
    assert not r.ok and r.n_violations >= 4
    assert all(p[0] == "ee" and p[1] < 4 <= p[2] and 0.49 < p[3] <= 0.5 for p in r.pairs)
    near = V1.copy()
    near[5:10, 1] = 0.25  # sliding sideways: misses by 0.125 at t = 1/2
    miss = verify_step(V, near, edges=E)
    assert miss.ok and miss.min_separation == 0.0  # a bound above the true gap would be false
    assert r.pairs == sorted(r.pairs, key=lambda p: p[3])


@pytest.mark.parametrize("thickness,ok", [(0.0, True), (0.9, True), (1.0, False), (1.5, False)],
                         ids=["zero", "below-gap", "equal-gap", "above-gap"])
def test_thickness_on_static_rods(thickness, ok):
    V, E = rods(k=2, n=3, spacing=1.0)
    r = verify_step(V, V, edges=E, thickness=thickness)
    assert r.ok == ok
    assert r.start_ok == ok  # static: a thickness violation is a property of the start state
    if ok:
        assert r.min_separation >= thickness


def test_start_state_intersection_is_reported():
    V, F = two_sheets()
    seg = np.array([[1.5, 1.6, -1.0], [1.5, 1.6, 2.0]])  # a rod piercing both sheets
    W = np.r_[V, seg]
    E = np.array([[len(V), len(V) + 1]])
    r = verify_step(W, W, faces=F, edges=E)
    assert not r.ok and not r.start_ok and r.n_violations == 0
    assert r.n_start_violations == 2
    assert {k for k, _, _ in r.start_violations} == {"ef"}
    assert all(r.edges[i].tolist() == E[0].tolist() for _, i, _ in r.start_violations)


def test_obstacles():
    V, F = grid(4, 1.0)
    floor_V = np.array([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0.0]])
    floor_F = np.array([[0, 1, 2], [0, 2, 3]])
    obstacle = [(floor_V, floor_V, floor_F, None)]
    safe = verify_step(V, V - [0, 0, 0.5], faces=F, obstacles=obstacle, obstacle_names=["floor"])
    assert safe.ok
    hit = verify_step(V, V - [0, 0, 2.0], faces=F, obstacles=obstacle, obstacle_names=["floor"])
    assert not hit.ok and {p[0] for p in hit.pairs} >= {"vf:floor"}
    assert min(p[3] for p in hit.pairs) <= 0.5
    # the floor rising into a static rod, as an obstacle moving linearly
    Vr, Er = rods(k=1, n=4)
    rising = [(floor_V - [0, 0, 1], floor_V + [0, 0, 1], floor_F, None)]
    r = verify_step(Vr, Vr, edges=Er, obstacles=rising)
    assert not r.ok and {p[0] for p in r.pairs} <= {"vf:0", "ee:0", "fv:0"} and r.pairs
    with pytest.raises(InputError, match="faces or edges"):
        verify_step(Vr, Vr, edges=Er, obstacles=[(floor_V, floor_V, None, None)])


def test_points_only_and_validation():
    V = np.zeros((3, 3))
    r = verify_step(V, V)
    assert r.ok and r.n_candidates == 0 and r.min_separation == 0.0  # never +inf
    with pytest.raises(InputError, match="thickness"):
        verify_step(V, V, thickness=-1.0)
    with pytest.raises(InputError):
        verify_step(V, V[:2], edges=[[0, 1]])
    with pytest.raises(InputError):
        verify_step(V, V, edges=[[0, 5]])


# --- dense sampling oracle ---------------------------------------------------------------


def _all_pairs_violate(kind, X0, X1, idx_pairs, thickness):
    samples = [Fraction(k, 8) for k in range(9)]
    th2 = Fraction(thickness) ** 2
    bad = []
    for ij, rows in idx_pairs:
        a, b = X0[rows], X1[rows]
        if any(exact_dist_sq(kind, a, b, t) <= th2 for t in samples):
            bad.append(ij)
    return bad


@pytest.mark.parametrize("seed", [0, 1])
def test_random_rods_against_sampling(seed):
    rng = np.random.default_rng(seed)
    k, n = 4, 4
    V0 = rng.uniform(-1, 1, size=(k * n, 3)) * [2, 2, 2]
    E = np.array([[r * n + i, r * n + i + 1] for r in range(k) for i in range(n - 1)])
    V1 = V0 + rng.normal(scale=0.6, size=V0.shape)
    for thickness in (0.0, 0.1):
        r = verify_step(V0, V1, edges=E, thickness=thickness, max_pairs=1000)
        pairs = [((i, j), np.r_[E[i], E[j]]) for i in range(len(E)) for j in range(i + 1, len(E))
                 if not set(E[i]) & set(E[j])]
        sampled = _all_pairs_violate("ee", V0, V1, pairs, thickness)
        reported = {(p[1], p[2]) for p in r.pairs}
        assert set(sampled) <= reported, (thickness, set(sampled) - reported)
        if thickness == 0.0:  # exact CCD + complete broad phase: reported == touching pairs
            truth = {ij for ij, rows in pairs if exact_edge_edge(V0[rows], V1[rows])}
            assert reported == truth
        else:
            assert sampled  # the scene does exercise contacts
        assert r.n_violations == len(reported)


def test_random_cloth_against_sampling_and_exact():
    rng = np.random.default_rng(5)
    V, F = two_sheets(n=3, gap=0.4)
    V1 = V + rng.normal(scale=0.3, size=V.shape)
    E = verify_step(V, V, faces=F).edges
    vf = [(("vf", v, f), np.r_[v, F[f]]) for v in range(len(V)) for f in range(len(F)) if v not in F[f]]
    ee = [(("ee", i, j), np.r_[E[i], E[j]]) for i in range(len(E)) for j in range(i + 1, len(E))
          if not set(E[i]) & set(E[j])]
    # thickness 0: the reported set is exactly the set of pairs that touch (exact CCD, complete broad phase)
    r = verify_step(V, V1, faces=F, max_pairs=10_000)
    truth = {key for key, rows in vf if exact_vertex_face(V[rows], V1[rows])}
    truth |= {key for key, rows in ee if exact_edge_edge(V[rows], V1[rows])}
    assert truth and {p[:3] for p in r.pairs} == truth
    # thickness > 0: every pair sampled within thickness is reported
    h = 0.05
    r = verify_step(V, V1, faces=F, thickness=h, max_pairs=10_000)
    sampled = _all_pairs_violate("vf", V, V1, vf, h) + _all_pairs_violate("ee", V, V1, ee, h)
    reported = {p[:3] for p in r.pairs} | set(r.start_violations)
    assert sampled and set(sampled) <= reported


# --- invariance ---------------------------------------------------------------------------


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), shift=st.integers(-64, 64))
def test_verdict_invariant_under_relabelling_and_translation(seed, shift):
    rng = np.random.default_rng(seed)
    V0 = rng.integers(-3, 4, size=(12, 3)).astype(float)
    V1 = rng.integers(-3, 4, size=(12, 3)).astype(float)
    E = np.array([[0, 1], [2, 3], [4, 5], [6, 7], [8, 9], [10, 11], [1, 2]])
    ref = verify_step(V0, V1, edges=E)
    perm = rng.permutation(12)
    inv = np.argsort(perm)
    eperm = rng.permutation(len(E))
    E2 = inv[E[eperm]][:, ::-1]  # new vertex labels, edge order and orientation
    r = verify_step(V0[perm] + shift, V1[perm] + shift, edges=E2)  # integer shift: exact
    assert (r.ok, r.start_ok, r.n_violations, r.n_start_violations) == (ref.ok, ref.start_ok, ref.n_violations, ref.n_start_violations)
    back = {tuple(sorted((int(eperm[i]), int(eperm[j])))) for _, i, j, _ in r.pairs}
    assert back == {tuple(sorted((i, j))) for _, i, j, _ in ref.pairs}


@pytest.mark.parametrize("share", [0.0, 0.02, 0.5, 1.0])
@pytest.mark.parametrize("width", [2, 3])
def test_all_kept_rows_against_numpy(rng, share, width):
    # The kept-primitive filter of the gate's near-pair query: the rows all of whose
    # vertices are kept, as numpy's keep[T].all(axis=1) gives them.
    from penfree.core.verify.path import _all_kept

    T = rng.integers(0, 500, size=(2000, width))
    keep = rng.random(500) < share
    np.testing.assert_array_equal(_all_kept(keep, T), keep[T].all(axis=1))
    assert _all_kept(keep, T[:0]).shape == (0,)
