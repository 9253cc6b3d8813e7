"""verify_step / verify_affine_step / verify_sequence: named scenes, a dense-time
sampling oracle with exact distances, invariance, and the certificate fast path."""

from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from penfree.core.ccd_exact import exact_edge_edge, exact_vertex_face
from penfree.core.verify import verify_affine_step, verify_step
from penfree.errors import InputError
from test_ccd import exact_dist_sq  # exact Fraction distance at a rational time


def grid(n, z=0.0, shift=(0.0, 0.0)):
    """(n*n, 3) vertices and (2 (n-1)^2, 3) faces of a unit-spaced flat sheet."""
    ij = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1).reshape(-1, 2).astype(float)
    V = np.c_[ij + shift, np.full(len(ij), z)]
    F = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            F += [[a, a + n, a + 1], [a + 1, a + n, a + n + 1]]
    return V, np.array(F)


def two_sheets(n=4, gap=1.0):
    V0, F0 = grid(n, 0.0, (0.3, 0.3))
    V1, F1 = grid(n, gap)
    return np.r_[V0, V1], np.r_[F0, F1 + len(V0)]


def rods(k=3, n=4, spacing=1.0):
    """k parallel polylines of n vertices along x, stacked in z."""
    V = np.array([[i, 0.0, spacing * r] for r in range(k) for i in range(n)])
    E = np.array([[r * n + i, r * n + i + 1] for r in range(k) for i in range(n - 1)])
    return V, E


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
    n0 = 16
    assert all(f >= 18 for _, _, f, _ in vf)  # faces of the upper sheet (18 per sheet)
    assert r.min_separation == 0.0
    assert n0 == 16


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


# --- certificate fast path ------------------------------------------------------------------


def _affine(V, A, b):
    return V @ np.asarray(A).T + b


@pytest.mark.parametrize("thickness", [0.0, 0.05], ids=["zero", "thick"])
def test_affine_fast_path_agrees_with_ccd(thickness):
    V, F = two_sheets(n=4, gap=0.5)
    c, s = np.cos(0.3), np.sin(0.3)
    A = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]) @ np.diag([1.1, 0.9, 1.05])
    b = np.array([0.1, -0.2, 0.3])
    x_def = _affine(V, A, b)
    fast = verify_affine_step(V, x_def, A, b, faces=F, thickness=thickness)
    assert fast is not None and fast.ok and fast.method == "certificate"
    assert fast.min_separation >= thickness
    assert verify_step(V, x_def, faces=F, thickness=thickness).ok


def test_affine_fast_path_refuses_what_it_cannot_prove():
    V, F = two_sheets(n=4, gap=0.5)
    # 170 degree rotation with anisotropic stretch: det > 0, singular M(t) half-way
    c, s = np.cos(np.radians(170)), np.sin(np.radians(170))
    A = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]) @ np.diag([2.0, 0.5, 1.0])
    assert np.linalg.det(A) > 0
    x_def = _affine(V, A, np.zeros(3))
    assert verify_affine_step(V, x_def, A, np.zeros(3), faces=F) is None
    # and an x_def that is not A x + b (one vertex moved through the other sheet)
    A = np.eye(3)
    bad = V.copy()
    bad[5, 2] = 2.0
    assert verify_affine_step(V, bad, A, np.zeros(3), faces=F) is None
    assert not verify_step(V, bad, faces=F).ok
    # thickness larger than the gap: the start state violates, the fast path declines
    assert verify_affine_step(V, V, A, np.zeros(3), faces=F, thickness=0.6) is None


def test_verify_sequence_with_moving_obstacle():
    from penfree import Obstacle, Sequence
    from penfree.core.verify import verify_sequence

    V, F = grid(3, 1.0)
    floor = np.array([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0.0]])
    # the sheet stays put; the floor rises 0.6 per frame and reaches it between frames 1 and 2
    ob = Obstacle("floor", np.stack([floor + [0, 0, 0.6 * s] for s in range(3)]), faces=np.array([[0, 1, 2], [0, 2, 3]]))
    seq = Sequence(positions=np.stack([V] * 3), faces=F, obstacles=[ob], origin="mem").validate()
    calls = []
    rep = verify_sequence(seq, progress=lambda: calls.append(1))
    assert [s.ok for s in rep.steps] == [True, False] and len(calls) == 2
    kinds = {p[0] for p in rep.steps[1].result.pairs}
    assert kinds <= {"fv:floor", "ee:floor", "vf:floor"} and "vf:floor" in kinds
    assert all(0.6 < p[3] <= 2 / 3 for p in rep.steps[1].result.pairs)
    assert not rep.ok and rep.n_failed == 1
    only_first = verify_sequence(seq, frames=(0, 2))
    assert len(only_first.steps) == 1 and only_first.ok


def test_sequence_rechecks_start_intersections_after_a_failed_step():
    from penfree import Sequence
    from penfree.core.verify import verify_sequence

    V, F = two_sheets()
    seg = np.array([[1.5, 1.6, -1.0], [1.5, 1.6, 2.0]])  # pierces both sheets in every frame
    W = np.r_[V, seg]
    E = np.array([[len(V), len(V) + 1]])
    frames = np.stack([W + [0.01 * s, 0, 0] for s in range(3)])
    rep = verify_sequence(Sequence(positions=frames, faces=F, edges=E).validate())
    assert [s.result.n_start_violations for s in rep.steps] == [2, 2]
    clean = verify_sequence(Sequence(positions=np.stack([V + [0, 0, 0.1 * s] for s in range(4)]), faces=F).validate())
    assert clean.ok and len(clean.steps) == 3
