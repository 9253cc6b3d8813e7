"""Broad phase against its O(n^2) numpy oracle (sets must be equal), on small
rod and cloth scenes, static and swept, with inflation, fast-moving
primitives, coincident boxes, sparse (hashed) and dense grids."""

import numpy as np
import pytest
from numba import njit
from hypothesis import given, settings
from hypothesis import strategies as st

from penfree.core.contact import broad_phase as bp
from penfree.core.contact.broad_phase import (
    edge_edge_candidates,
    edge_edge_candidates_between,
    vertex_face_candidates,
    vertex_face_candidates_between,
)
from penfree.core.parallel import work_counter
from penfree.core.topology import edges_from_faces
from penfree.errors import InputError

from oracles import (
    edge_edge_candidates_between_brute,
    edge_edge_candidates_brute,
    vertex_face_candidates_between_brute,
    vertex_face_candidates_brute,
)


RNG_SEED = 7  # seed of the shared `rng` fixture (tests/conftest.py)


def cloth(n, rng, amp=0.2):
    """n x n sheet, wavy and jittered, two triangles per quad."""
    u = np.linspace(0.0, 1.0, n)
    X, Y = np.meshgrid(u, u, indexing="ij")
    Z = amp * np.sin(3 * np.pi * X) * np.cos(2 * np.pi * Y)
    V = np.stack([X, Y, Z], -1).reshape(-1, 3) + rng.normal(scale=0.1 / n, size=(n * n, 3))
    idx = np.arange(n * n).reshape(n, n)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return V, F


def rods(n_rods, n_per, rng):
    """Wiggly polylines in a bundle, crossing each other."""
    t = np.linspace(0.0, 1.0, n_per)
    Vs, Es = [], []
    for r in range(n_rods):
        c = rng.uniform(0, 0.2, 2)
        ph = rng.uniform(0, 2 * np.pi)
        Vs.append(np.stack([c[0] + 0.05 * np.cos(9 * t + ph), c[1] + 0.05 * np.sin(9 * t + ph), t], 1))
        Es.append(np.stack([np.arange(n_per - 1), np.arange(1, n_per)], 1) + r * n_per)
    return np.concatenate(Vs), np.concatenate(Es)


def _fast_movers(V, rng, k=3, scale=0.7):
    V1 = V + rng.normal(scale=0.004, size=V.shape)
    idx = rng.choice(V.shape[0], k, replace=False)
    V1[idx] += rng.normal(scale=scale, size=(k, 3))
    return V1


def _assert_valid(pairs, self_query):
    assert pairs.dtype == np.int64 and pairs.ndim == 2 and pairs.shape[1] == 2
    if len(pairs):
        order = np.lexsort((pairs[:, 1], pairs[:, 0]))
        assert np.array_equal(order, np.arange(len(pairs))), "rows not sorted"
        assert len(np.unique(pairs, axis=0)) == len(pairs), "duplicate rows"
        if self_query:
            assert np.all(pairs[:, 0] < pairs[:, 1])


MOTIONS = ["static", "swept", "fast-moving"]


def _motion(kind, V, rng):
    if kind == "static":
        return V.copy()
    if kind == "swept":
        return V + rng.normal(scale=0.01, size=V.shape)
    return _fast_movers(V, rng)


@pytest.mark.parametrize("inflation", [0.0, 0.003, 0.05], ids=["no-inflation", "small", "large"])
@pytest.mark.parametrize("motion", MOTIONS)
def test_rods_edge_edge(rng, motion, inflation):
    V, E = rods(12, 40, rng)
    V1 = _motion(motion, V, rng)
    got = edge_edge_candidates(V, V1, E, inflation)
    want = edge_edge_candidates_brute(V, V1, E, inflation)
    _assert_valid(got, True)
    assert len(want) > 0
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("inflation", [0.0, 0.01], ids=["no-inflation", "inflated"])
@pytest.mark.parametrize("motion", MOTIONS)
def test_cloth(rng, motion, inflation):
    V, F = cloth(18, rng)
    E = edges_from_faces(F)
    V1 = _motion(motion, V, rng)
    ee = edge_edge_candidates(V, V1, E, inflation)
    vf = vertex_face_candidates(V, V1, F, inflation)
    _assert_valid(ee, True)
    _assert_valid(vf, False)
    np.testing.assert_array_equal(ee, edge_edge_candidates_brute(V, V1, E, inflation))
    np.testing.assert_array_equal(vf, vertex_face_candidates_brute(V, V1, F, inflation))
    assert len(ee) > 0 and len(vf) > 0


def test_big_boxes_take_the_brute_force_path(rng):
    # A handful of vertices jumping across the scene: their boxes cover many
    # cells, stay out of the grid, are tested against every box, and every
    # pair must still be found exactly once.
    V, E = rods(10, 60, rng)
    V1 = _fast_movers(V, rng, k=4, scale=2.0)
    lo, hi = bp._box_arrays(V, V1, E, 0.0)
    plan = bp._Plan(lo, hi, E, lo, hi, E, True)
    assert plan.bigB.size > 0 and (~plan.smallA).sum() > 0
    np.testing.assert_array_equal(plan.pairs(), edge_edge_candidates_brute(V, V1, E))


def test_sparse_scene_uses_hashed_grid(rng):
    # Two clusters 1e4 apart: a dense cell table would be huge, so the
    # hashed table is used; results must not change.
    V, E = rods(6, 30, rng)
    V = np.concatenate([V, V + 1e4])
    E = np.concatenate([E, E + len(V) // 2])
    lo, hi = bp._box_arrays(V, V, E, 0.01)
    plan = bp._Plan(lo, hi, E, lo, hi, E, True)
    assert plan.bits >= 0  # hashed, not dense
    np.testing.assert_array_equal(plan.pairs(), edge_edge_candidates_brute(V, V, E, 0.01))


def test_coincident_boxes(rng):
    # Every vertex at the same point: all boxes are identical and of zero
    # extent; every non-adjacent pair overlaps.
    V = np.zeros((30, 3)) + 0.5
    E = np.stack([np.arange(29), np.arange(1, 30)], 1)
    F = np.stack([np.arange(28), np.arange(1, 29), np.arange(2, 30)], 1)
    ee = edge_edge_candidates(V, V, E)
    assert len(ee) == 29 * 28 // 2 - 28  # all pairs minus the 28 adjacent ones
    np.testing.assert_array_equal(ee, edge_edge_candidates_brute(V, V, E))
    np.testing.assert_array_equal(vertex_face_candidates(V, V, F), vertex_face_candidates_brute(V, V, F))
    # duplicated geometry under different vertex indices is not adjacent
    V2 = np.concatenate([V, V])
    E2 = np.concatenate([E, E + 30])
    assert len(edge_edge_candidates(V2, V2, E2)) == 58 * 57 // 2 - 56


def test_touching_boxes_count():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [1.0, 0, 0], [2, 0, 0], [2.0 + 1e-12, 0, 0], [3, 0, 0]])
    E = np.array([[0, 1], [2, 3], [4, 5]])
    np.testing.assert_array_equal(edge_edge_candidates(V, V, E), [[0, 1]])
    # an inflation of half the gap closes it
    assert [1, 2] in edge_edge_candidates(V, V, E, 1e-12).tolist()


def test_adjacency_rule():
    # Edges 0-1 and 1-2 overlap but share vertex 1; a face never pairs with its own vertices.
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0.3, 0.0, 0]])
    assert edge_edge_candidates(V, V, [[0, 1], [1, 2], [2, 0]]).shape == (0, 2)
    np.testing.assert_array_equal(vertex_face_candidates(V, V, [[0, 1, 2]]), [[3, 0]])
    np.testing.assert_array_equal(
        edge_edge_candidates_between(V, V, [[0, 1]], [[1, 2], [2, 3], [0, 1]]), [[0, 1]]
    )


@pytest.mark.parametrize("ka, kb", [(2, 2), (1, 3), (1, 2), (2, 3), (3, 3), (1, 1)])
def test_adjacent_matches_a_set_oracle(rng, ka, kb):
    # `_adjacent` writes out the widths that occur (edge-edge, vertex-face) branch-free
    # and loops over the others: every width must say whether two rows share an index.
    TA = rng.integers(0, 6, (300, ka))
    TB = rng.integers(0, 6, (300, kb))
    for i in range(300):
        want = bool(set(TA[i]) & set(TB[i]))
        assert bp._adjacent(TA, i, TB, i) == want and bp._adjacent.py_func(TA, i, TB, i) == want


def test_between_sets(rng):
    V, F = cloth(12, rng)
    Vo, Fo = cloth(8, rng)
    Vo = Vo * 0.7 + [0.1, 0.1, 0.05]
    n = len(V)
    Vall = np.concatenate([V, Vo])
    Fo = Fo + n
    V1 = _motion("fast-moving", Vall, rng)
    EA, EB = edges_from_faces(F), edges_from_faces(Fo)
    got = edge_edge_candidates_between(Vall, V1, EA, EB, 0.01)
    assert len(got) > 0
    np.testing.assert_array_equal(got, edge_edge_candidates_between_brute(Vall, V1, EA, EB, 0.01))
    cloth_v = np.arange(n)
    got = vertex_face_candidates_between(Vall, V1, cloth_v, Fo, 0.01)
    assert len(got) > 0 and np.all(got[:, 0] < n)
    np.testing.assert_array_equal(got, vertex_face_candidates_between_brute(Vall, V1, cloth_v, Fo, 0.01))
    obst_v = np.arange(n, len(Vall))[::-1]  # unsorted on purpose: output is still sorted
    got = vertex_face_candidates_between(Vall, V1, obst_v, F, 0.01)
    _assert_valid(got, False)
    np.testing.assert_array_equal(got, vertex_face_candidates_between_brute(Vall, V1, obst_v, F, 0.01))


def test_vertex_subset(rng):
    V, F = cloth(10, rng)
    sub = rng.choice(len(V), 30, replace=False)
    got = vertex_face_candidates(V, V, F, 0.02, vertices=sub)
    full = vertex_face_candidates(V, V, F, 0.02)
    np.testing.assert_array_equal(got, full[np.isin(full[:, 0], sub)])


def test_empty_inputs():
    V = np.zeros((4, 3))
    assert edge_edge_candidates(V, V, np.zeros((0, 2), int)).shape == (0, 2)
    assert vertex_face_candidates(V, V, None).shape == (0, 2)
    assert vertex_face_candidates(V, V, [[0, 1, 2]], vertices=[]).shape == (0, 2)


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda V: edge_edge_candidates(V, V[:3], [[0, 1]]), "V_t1 must have the shape"),
        (lambda V: edge_edge_candidates(V, V, [[0, 9]]), r"E indices must lie in \[0, 4\)"),
        (lambda V: edge_edge_candidates(V, V, [[0, 1]], -1.0), "inflation must be"),
        (lambda V: vertex_face_candidates(V, V, [[0, 1]]), r"F must be \(M, 3\)"),
        (lambda V: vertex_face_candidates(V, V, [[0, 1, 2]], vertices=[7]), "vertices must lie"),
        (lambda V: edge_edge_candidates(V[:, :2], V[:, :2], [[0, 1]]), r"V_t0 must be \(N, 3\)"),
    ],
    ids=["shape-mismatch", "index-range", "negative-inflation", "face-width", "vertex-range", "2d"],
)
def test_input_errors(call, match):
    with pytest.raises(InputError, match=match):
        call(np.zeros((4, 3)))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 60), spread=st.floats(0.01, 3.0),
       inflation=st.floats(0.0, 0.2))
def test_random_soup_matches_brute(seed, n, spread, inflation):
    rng = np.random.default_rng(seed)
    V = rng.uniform(0, spread, (n, 3))
    V1 = V + rng.normal(scale=0.1 * spread, size=V.shape)
    E = rng.integers(0, n, (2 * n, 2))
    F = rng.integers(0, n, (n, 3))
    np.testing.assert_array_equal(edge_edge_candidates(V, V1, E, inflation),
                                  edge_edge_candidates_brute(V, V1, E, inflation))
    np.testing.assert_array_equal(vertex_face_candidates(V, V1, F, inflation),
                                  vertex_face_candidates_brute(V, V1, F, inflation))


def test_overflowing_chunks_are_refilled(rng, monkeypatch):
    # The one-pass enumeration sizes each chunk's buffer from a sample of rows; with no
    # slack every chunk holding a pair runs out and is refilled at exact offsets.
    V, F = cloth(40, rng)
    E = edges_from_faces(F)
    V1 = _motion("swept", V, rng)
    expect = edge_edge_candidates_brute(V, V1, E, 0.01)
    assert len(E) > 4 * bp._PAIR_CHUNK_MIN_ROWS  # several chunks
    monkeypatch.setattr(bp, "_CAP_SLACK", 0.0)
    monkeypatch.setattr(bp, "_CAP_PAD", 0)
    np.testing.assert_array_equal(edge_edge_candidates(V, V1, E, 0.01), expect)
    monkeypatch.setattr(bp, "_CAP_PAD", 3)  # some chunks fit, some overflow
    np.testing.assert_array_equal(edge_edge_candidates(V, V1, E, 0.01), expect)
    np.testing.assert_array_equal(vertex_face_candidates(V, V1, F, 0.01),
                                  vertex_face_candidates_brute(V, V1, F, 0.01))


def _min_pair_sq_brute(V, TA, TB, inflation, self_query):
    from oracles import _brute, _np_boxes, ee_sq, pt_sq

    loA, hiA = _np_boxes(V, V, TA, inflation)
    loB, hiB = _np_boxes(V, V, TB, inflation)
    from fractions import Fraction

    X = [[Fraction(float(c)) for c in row] for row in V]
    best = np.inf
    for i, j in _brute(loA, hiA, TA, loB, hiB, TB, self_query):
        if TA.shape[1] == 2:
            d = ee_sq(*(X[v] for v in TA[i]), *(X[v] for v in TB[j]))
        else:
            d = pt_sq(X[TA[i, 0]], *(X[v] for v in TB[j]))
        best = min(best, float(d))
    return best


@pytest.mark.parametrize("inflation", [0.0, 0.004, 0.02])
def test_min_pair_sq_matches_brute(rng, inflation):
    # The smallest distance over the pairs whose inflated boxes overlap (the
    # certificate path's "anything within g?") against the O(n^2) oracle in exact
    # arithmetic: equal up to the distance kernels' rounding; inf with no pair.
    V, F = cloth(12, rng)
    E = edges_from_faces(F)
    Q = np.arange(len(V), dtype=np.int64)[:, None]
    for TA, TB, sq in ((E, E, True), (Q, F, False)):
        got = bp.min_pair_sq(V, TA, TB, inflation, sq)
        want = _min_pair_sq_brute(V, TA, TB, inflation, sq)
        if np.isinf(want):
            assert np.isinf(got)
        else:
            assert abs(got - want) <= 1e-12 * max(want, 1e-12)
    far = np.array([[0.0, 0, 0], [1, 0, 0], [0, 5, 0], [1, 5, 0]])
    assert np.isinf(bp.min_pair_sq(far, np.array([[0, 1], [2, 3]]), np.array([[0, 1], [2, 3]]), 0.1, True))


def _scene(kind, rng):
    if kind == "rods":
        V, E = rods(8, 40, rng)
        return V, E, np.zeros((0, 3), dtype=np.int64)
    V, F = cloth(14, rng)
    if kind == "folded-cloth":  # a second layer just above the first: many near pairs
        V = np.concatenate([V, V + [0.0, 0.0, 0.01]])
        F = np.concatenate([F, F + len(V) // 2])
    if kind == "far-from-origin":
        V = V + 1e5
    if kind == "touching":  # coincident copies: distance-0 pairs
        V = np.concatenate([V, V])
        F = np.concatenate([F, F + len(V) // 2])
    return V, edges_from_faces(F), F


def _fold(V, TA, TB, inflation, self_query, mode, init, prune):
    lo_a, hi_a = bp._box_arrays(V, V, TA, inflation)
    lo_b, hi_b = (lo_a, hi_a) if self_query else bp._box_arrays(V, V, TB, inflation)
    plan = bp._Plan(lo_a, hi_a, TA, lo_b, hi_b, TB, self_query, inflation)
    if not prune:
        plan.gap_off = -np.inf  # every box bound 0: no pair skipped
    partial = np.full((4, len(V)) if mode == bp.MODE_MIN else (4, 1), init)
    plan.min_sq_into(V, partial, mode)
    return partial.min(axis=0)


@pytest.mark.parametrize("kind", ["rods", "cloth", "folded-cloth", "far-from-origin", "touching"])
@pytest.mark.parametrize("inflation", [0.0, 0.004, 0.03])
def test_min_folds_skip_pairs_without_changing_a_bit(rng, kind, inflation):
    # The folds skip a pair whose box bound proves it cannot lower any minimum it
    # touches: per-vertex and global minima equal those of the fold that evaluates
    # every pair, bit for bit, from inf and from a cap (as `per_vertex_separation` starts).
    V, E, F = _scene(kind, rng)
    Q = np.arange(len(V), dtype=np.int64)[:, None]
    sets = [(E, E, True)] + ([(Q, F, False)] if len(F) else [])
    cap = (2.0 * inflation) ** 2
    for TA, TB, sq in sets:
        for mode in (bp.MODE_MIN, bp.MODE_GLOBAL_MIN):
            for init in (np.inf, cap):
                want = _fold(V, TA, TB, inflation, sq, mode, init, prune=False)
                got = _fold(V, TA, TB, inflation, sq, mode, init, prune=True)
                np.testing.assert_array_equal(got.view(np.uint64), want.view(np.uint64))


def test_box_bound_is_below_every_pair_distance(rng):
    # The bound the folds prune with never exceeds the pair's computed distance
    # (times the pruning factor), on every overlapping pair of varied scenes.
    from penfree.core.contact.distance import edge_edge_distance

    for kind in ("rods", "cloth", "far-from-origin"):
        V, E, _ = _scene(kind, rng)
        for inflation in (0.002, 0.02):
            lo, hi = bp._box_arrays(V, V, E, inflation)
            plan = bp._Plan(lo, hi, E, lo, hi, E, True, inflation)
            P = plan.pairs()
            i, j = P[:, 0], P[:, 1]
            g = np.maximum(np.maximum(lo[j] - hi[i], lo[i] - hi[j]) + plan.gap_off, 0.0)
            lb_sq = (g * g).sum(axis=1)
            d = edge_edge_distance(V[E[i, 0]], V[E[i, 1]], V[E[j, 0]], V[E[j, 1]])
            assert np.all(lb_sq * bp._PRUNE_REL <= d * d), kind
            assert np.any(lb_sq > 0.0)  # the bound is not trivially 0


@pytest.mark.parametrize("offset", [0.0, 1e6], ids=["near-origin", "far-from-origin"])
def test_each_pair_found_once_from_lower_corner_cells(rng, offset):
    # Each grid box is stored once, in its lower corner's cell; rows scan the reach below
    # their cells (a self query only the cells after its own): every overlapping pair
    # exactly once, on dense and hashed grids, near and far from the origin (where cell
    # arithmetic rounds most).
    V, F = cloth(16, rng)
    V = V + offset
    E = edges_from_faces(F)
    V1 = _motion("swept", V, rng)
    for VV in (V1, np.concatenate([V1, V1 + 1e4])):
        EE = E if len(VV) == len(V) else np.concatenate([E, E + len(V)])
        FF = F if len(VV) == len(V) else np.concatenate([F, F + len(V)])
        V0 = V if len(VV) == len(V) else np.concatenate([V, V + 1e4])
        np.testing.assert_array_equal(edge_edge_candidates(V0, VV, EE, 0.01),
                                      edge_edge_candidates_brute(V0, VV, EE, 0.01))
        np.testing.assert_array_equal(vertex_face_candidates(V0, VV, FF, 0.01),
                                      vertex_face_candidates_brute(V0, VV, FF, 0.01))
        # the min fold of a self query (each pair from the row whose cell comes first)
        pairs = edge_edge_candidates_brute(VV, VV, EE, 0.01)
        assert len(pairs) > 0
        want = min(bp._pair_sq(VV, EE, i, EE, j) for i, j in pairs)
        assert bp.min_pair_sq(VV, EE, EE, 0.01, True) == want


@pytest.mark.parametrize("kind", ["rods", "cloth", "folded-cloth", "far-from-origin", "touching"])
@pytest.mark.parametrize("inflation", [0.0, 0.004, 0.03])
def test_min_fold_cells_split_along_the_runs(rng, kind, inflation, monkeypatch):
    # The min folds' plans (listing=False) cut each cell along x, the runs of a dense
    # table, into `_RUN_SPLIT` (rows scan more layers along x), and keep whole cells on a
    # hashed table. Either way the per-vertex minima are those of the brute-force
    # oracle's pairs bit for bit, and the listed pairs are the oracle's.
    V, E, F = _scene(kind, rng)
    Q = np.arange(len(V), dtype=np.int64)[:, None]
    sets = [(E, E, True, edge_edge_candidates_brute(V, V, E, inflation))]
    if len(F):
        sets.append((Q, F, False, vertex_face_candidates_brute(V, V, F, inflation)))
    assert bp._RUN_SPLIT > 1
    dense = []
    for TA, TB, sq, pairs in sets:
        want = np.full(len(V), np.inf)
        for i, j in pairs:
            d2 = bp._pair_sq(V, TA, i, TB, j)
            k = np.concatenate([TA[i], TB[j]])
            want[k] = np.minimum(want[k], d2)
        lo_a, hi_a = bp._box_arrays(V, V, TA, inflation)
        lo_b, hi_b = (lo_a, hi_a) if sq else bp._box_arrays(V, V, TB, inflation)
        for split in (bp._RUN_SPLIT, 1):
            monkeypatch.setattr(bp, "_RUN_SPLIT", split)
            plan = bp._Plan(lo_a, hi_a, TA, lo_b, hi_b, TB, sq, inflation, listing=False)
            if split > 1:  # cubes cut along x on a dense table, whole on a hashed one
                dense.append(plan.bits < 0)
                assert (plan.h[0] < plan.h[1]) == (plan.bits < 0) and plan.h[1] == plan.h[2]
            part = np.full((3, len(V)), np.inf)
            plan.min_sq_into(V, part)
            np.testing.assert_array_equal(part.min(axis=0).view(np.uint64), want.view(np.uint64))
            np.testing.assert_array_equal(plan.pairs(), pairs)
    assert all(dense) or kind == "rods"  # the sheets' tables are dense: the split is exercised


@pytest.mark.parametrize("long_share", [4, 400], ids=["many-long", "few-long"])
def test_reach_covers_boxes_spanning_several_cells(long_share, monkeypatch):
    # Segments of two lengths: with a long one in every 4, too many to brute-force, the
    # rows scan two cell layers below their own (reach 2); with one in 400 they stay out
    # of the grid (reach 1). Every pair is found once either way, for the listed pairs
    # (rows i < j), the vertex-face pairs and the folds. (Whole cells: the split along
    # x has its own test above.)
    monkeypatch.setattr(bp, "_RUN_SPLIT", 1)
    rng = np.random.default_rng(5)
    n = 3000
    P = rng.uniform(0, 1, size=(n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    L = np.where(np.arange(n) % long_share == 0, 0.1, 0.025)
    V = np.concatenate([P, P + d * L[:, None]])
    E = np.stack([np.arange(n), np.arange(n) + n], 1).astype(np.int64)
    lo, hi = bp._box_arrays(V, V, E, 0.0)
    plan = bp._Plan(lo, hi, E, lo, hi, E, True, listing=False)  # the min folds' layout
    assert (plan.reach.max(), plan.bigB.size > 0) == ((2, False) if long_share == 4 else (1, True))
    np.testing.assert_array_equal(plan.pairs(), edge_edge_candidates_brute(V, V, E))
    np.testing.assert_array_equal(bp.edge_edge_candidates(V, V, E), edge_edge_candidates_brute(V, V, E))
    part = np.full((3, len(V)), np.inf)
    plan.min_sq_into(V, part)
    want = np.full(len(V), np.inf)
    for i, j in edge_edge_candidates_brute(V, V, E):
        d2 = bp._pair_sq(V, E, i, E, j)
        want[E[[i, j]].ravel()] = np.minimum(want[E[[i, j]].ravel()], d2)
    np.testing.assert_array_equal(part.min(axis=0), want)
    assert bp.min_pair_sq(V, E, E, 0.0, True) == want.min()
    F = np.stack([E[:, 0], E[:, 1], E[::-1, 0]], 1)  # long and short triangles
    np.testing.assert_array_equal(vertex_face_candidates(V, V, F), vertex_face_candidates_brute(V, V, F))


def _grid_oracle(clo, chi, small, dims, bits, covering):
    # One entry per small box and cell it covers (`covering`), or per small box in the
    # cell of its lower corner; boxes in id order, stably sorted by bucket.
    rows = []
    for j in range(clo.shape[0]):
        if not small[j]:
            continue
        top = chi[j] if covering else clo[j]
        for z in range(clo[j, 2], top[2] + 1):
            for y in range(clo[j, 1], top[1] + 1):
                for x in range(clo[j, 0], top[0] + 1):
                    key = int(x + dims[0] * (y + dims[1] * z))
                    rows.append((int(bp._bucket(key, bits)), key, j))
    b, key, ids = (np.array(c, dtype=np.int64) for c in zip(*rows))
    order = np.argsort(b, kind="stable")
    return b[order], key[order], ids[order]


@pytest.mark.parametrize("max_reach", [1, bp._MAX_REACH, bp._SPLIT_MAX_REACH, 7])
def test_cell_ranges_match_a_numpy_oracle(rng, max_reach):
    # The cell ranges and their statistics (per-chunk histograms in the kernel) against
    # numpy: the largest cell per axis; for every r >= 1, the boxes spanning more than r
    # cells beyond their first along some axis, and the others' largest span per axis.
    # Boxes of many spans, some far beyond the largest reach, and one far corner.
    lo = rng.uniform(0.0, 1.0, (3000, 3))
    hi = lo + rng.uniform(0.0, 1.0, (3000, 3)) ** 4 * rng.choice([0.05, 0.5], (3000, 1))
    hi[7] = 3.0
    origin, h = lo.min(axis=0), np.array([0.01, 0.02, 0.013])
    clo, chi = np.empty(lo.shape, np.int64), np.empty(lo.shape, np.int64)
    top, reach, n_over = bp._cell_ranges(lo, hi, origin, h, clo, chi, max_reach)
    np.testing.assert_array_equal(clo, np.floor((lo - origin) / h).astype(np.int64))
    np.testing.assert_array_equal(chi, np.floor((hi - origin) / h).astype(np.int64))
    np.testing.assert_array_equal(top, chi.max(axis=0))
    span = chi - clo
    assert reach.shape == (max_reach + 1, 3) and n_over.shape == (max_reach + 1,)
    for r in range(1, max_reach + 1):
        over = span.max(axis=1) > r
        assert n_over[r] == np.count_nonzero(over) and 0 < n_over[r] < len(lo)
        np.testing.assert_array_equal(reach[r], span[~over].max(axis=0))


@pytest.mark.parametrize("listing", [True, False], ids=["covering", "lower-corner"])
@pytest.mark.parametrize("sparse", [False, True], ids=["dense", "hashed"])
@pytest.mark.parametrize("chunks", [1, 2, 3, 7])
def test_grid_build_is_one_serial_pass_for_any_chunking(rng, sparse, chunks, listing):
    # The parallel counting sort (counted by chunks of boxes, filled by ranges of
    # buckets, as many of each as `chunks`) must lay out the entries as one serial pass
    # in id order: ids ascending within a bucket, each with its own box. A
    # listed self query's grid covers cells (reach 0, big boxes cover > _BIG_CELLS cells);
    # the min folds' grid stores each box at its lower corner (big boxes span more cells
    # than the reach's cap, the reach is the others' largest span).
    V, E = rods(8, 40, rng)
    if sparse:
        V = np.concatenate([V, V + 1e4])
        E = np.concatenate([E, E + len(V) // 2])
    V1 = _fast_movers(V, rng, k=3, scale=0.5 if not listing else 2.0)  # a few big boxes stay out of the grid
    lo, hi = bp._box_arrays(V, V1, E, 0.01)
    plan = bp._Plan(lo, hi, E, lo, hi, E, True, listing=listing)
    assert (plan.bits >= 0) == sparse and (~plan.smallA).any()
    np.testing.assert_array_equal(plan.bigB, np.flatnonzero(~plan.smallA))
    span = plan.chiA - plan.cloA
    if listing:
        cells = np.prod(span + 1, axis=1)
        assert cells[plan.smallA].max() <= bp._BIG_CELLS < cells[~plan.smallA].min()
        assert not plan.reach.any()
    else:
        s = span.max(axis=1)
        cap = bp._SPLIT_MAX_REACH if plan.h[0] < plan.h[1] else bp._MAX_REACH  # cells cut along the runs
        assert s[plan.smallA].max() < s[~plan.smallA].min() and s[plan.smallA].max() <= cap
        np.testing.assert_array_equal(plan.reach, span[plan.smallA].max(axis=0))
    nb = plan.boff.size - 1
    lo, hi = plan.loB, plan.hiB  # the boxes with their axes in the grid key's order
    got = bp._build_grid(plan.cloA, plan.chiA, plan.smallA, listing, plan.dims, plan.bits, nb, lo, hi, chunks=chunks)
    boff, cmax, ent_key, ent_id, ent_box, ent_clo = got
    b, key, ids = _grid_oracle(plan.cloA, plan.chiA, plan.smallA, plan.dims, plan.bits, listing)
    np.testing.assert_array_equal(boff, np.searchsorted(b, np.arange(nb + 1)))
    np.testing.assert_array_equal(ent_id, ids)
    np.testing.assert_array_equal(ent_box, np.hstack([lo, hi])[ids])  # one box per row
    np.testing.assert_array_equal(ent_clo, plan.cloA[ids] if listing else np.zeros((0, 3)))
    if sparse:
        np.testing.assert_array_equal(ent_key, key)
    if sparse:
        assert cmax.size == 0
    else:  # each cell's largest upper x (-inf when empty; a covering grid's unused, all -inf)
        want = np.full(nb, -np.inf)
        if not listing:
            np.maximum.at(want, b, hi[ids, 0])
        np.testing.assert_array_equal(cmax, want)
    for name, arr in zip(("boff", "cmax", "ent_key", "ent_id", "ent_box", "ent_clo"), got):
        np.testing.assert_array_equal(getattr(plan, name), arr)


@pytest.mark.parametrize("kind", ["rods", "folded-cloth", "touching"])
@pytest.mark.parametrize("hashed", [False, True])
def test_compacted_scan_finds_the_same_pairs_and_minima(rng, kind, hashed):
    # The row scan either tests each entry and branches, or compacts a bucket's box
    # hits first (chosen per plan from a sample of rows, only above a few thousand
    # rows): both must give the same pairs, edge-face pairs and minima, bit for bit.
    V, E, F = _scene(kind, rng)
    if hashed:  # a far copy: sparse, hashed table (buckets mixing cells)
        V = np.concatenate([V, V + 1e4])
        F = np.concatenate([F, F + len(V) // 2]) if len(F) else F
        E = np.concatenate([E, E + len(V) // 2])
    Q = np.arange(len(V), dtype=np.int64)[:, None]
    sets = [(E, E, True)] + ([(Q, F, False), (E, F, False)] if len(F) else [])
    for TA, TB, sq in sets:
        lo_a, hi_a = bp._box_arrays(V, V, TA, 0.01)
        lo_b, hi_b = (lo_a, hi_a) if sq else bp._box_arrays(V, V, TB, 0.01)
        out = []
        for compact in (False, True):
            plan = bp._Plan(lo_a, hi_a, TA, lo_b, hi_b, TB, sq, 0.01)
            assert (plan.bits >= 0) == hashed
            plan.compact = compact
            part = np.full((4, len(V)), np.inf)
            plan.min_sq_into(V, part)
            ef = plan.edge_face_pairs(V) if TA.shape[1] == 2 and TB.shape[1] == 3 else None
            out.append((plan.pairs(), part.min(axis=0), ef))
        np.testing.assert_array_equal(out[0][0], out[1][0])
        np.testing.assert_array_equal(out[0][1], out[1][1])
        if out[0][2] is not None:
            np.testing.assert_array_equal(out[0][2], out[1][2])
        assert len(out[0][0]) > 0
    # and the brute force agrees with both (edge pairs)
    np.testing.assert_array_equal(out[1][0] if not len(F) else bp.edge_edge_candidates(V, V, E, 0.01),
                                  edge_edge_candidates_brute(V, V, E, 0.01))


def _bundle(k=20, per=16, spacing=0.25):
    # k x k straight rods along z, unit segments, `spacing` apart: thin boxes in cubic
    # cells sized by the segments' length, so few entries of a bucket hit (like a yarn).
    gx, gy = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    base = np.stack([gx.ravel(), gy.ravel()], -1) * spacing
    z = np.arange(per, dtype=float)
    V = np.concatenate([np.column_stack([np.full(per, bx), np.full(per, by), z]) for bx, by in base])
    E = np.array([[r * per + i, r * per + i + 1] for r in range(k * k) for i in range(per - 1)], dtype=np.int64)
    return V, E


def test_plan_chooses_the_compacted_scan_where_few_entries_hit(rng):
    # A bundle of thin rods (~4% of the scanned entries hit): compacted; wavy rods
    # (~38%): not; a sheet's min fold (~19%, but ~30 entries a row that miss, fewer
    # than _COMPACT_MISSES): not. Either way the pairs are the brute force's. Plans
    # below _COMPACT_MIN_ROWS rows never compact.
    V, F = cloth(70, rng)
    cases = [(*_bundle(), 0.2, True, True), (*rods(40, 120, rng), 0.001, False, True),
             (V, edges_from_faces(F), 0.004, False, False)]
    for V, E, inflation, compact, listing in cases:
        lo, hi = bp._box_arrays(V, V, E, inflation)
        assert len(E) >= bp._COMPACT_MIN_ROWS
        plan = bp._Plan(lo, hi, E, lo, hi, E, True, inflation, listing=listing)
        assert plan.compact is compact
        if not listing:  # few hits, but few entries scanned a row: the plain scan
            rows = np.arange(0, len(E), len(E) // bp._SAMPLE_ROWS)
            scanned, hits = bp._hit_rate(rows, True, plan.loA, plan.hiA, plan.cloA, plan.chiA, plan.smallA, plan.dims,
                                         plan.bits, plan.reach, plan.boff, plan.ent_id, plan.ent_box)
            assert hits < bp._COMPACT_HIT_RATE * scanned and scanned - hits < bp._COMPACT_MISSES * len(rows)
            continue
        pairs = plan.pairs()
        assert len(pairs) > 0
        np.testing.assert_array_equal(pairs, edge_edge_candidates_brute(V, V, E, inflation))
    small = bp._Plan(lo[:100], hi[:100], E[:100], lo[:100], hi[:100], E[:100], True)
    assert small.compact is False



def test_grid_entries_store_int32_ids_and_refuse_more_boxes():
    # int32 entry ids (cells per axis are capped at 2^20, keys fit int64); a grid of
    # 2^31 boxes or more is refused instead of wrapping the ids.
    V, E = rods(4, 10, np.random.default_rng(0))
    lo, hi = bp._box_arrays(V, V, E, 0.01)
    plan = bp._Plan(lo, hi, E, lo, hi, E, True, 0.01)
    assert plan.ent_id.dtype == np.int32 and np.all(plan.dims <= bp._MAX_DIM)
    bp._check_box_count((1 << 31) - 1)
    with pytest.raises(InputError, match="at most 2\\^31 - 1 boxes; got 2147483648"):
        bp._check_box_count(1 << 31)


def _start_scene(kind, rng):
    """(x, E, F, vertices) for the certificate path's start pass."""
    V, E, F = _scene("cloth" if kind == "free-vertex-outside" else kind, rng)
    if kind == "free-vertex-outside":  # a vertex in no face, beyond every face's box
        V = np.concatenate([V, [[-3.0, 0.5, 0.0]]])
    return np.ascontiguousarray(V), E, np.ascontiguousarray(F, dtype=np.int64), np.arange(len(V), dtype=np.int64)


@pytest.mark.parametrize("inflation", [0.0, 1e-3, 0.02])
@pytest.mark.parametrize("kind", ["cloth", "folded-cloth", "far-from-origin", "free-vertex-outside"])
def test_start_pass_is_the_three_queries(rng, kind, inflation):
    # Two grids for the edge-face candidates and the two folds: the candidates hold
    # `edge_face_candidates`' (the boxes are inflated, so maybe more) and every pair
    # they add has overlapping inflated boxes; the minimum is the two folds' float.
    x, E, F, Q = _start_scene(kind, rng)
    cand, d2 = bp.start_pass(x, E, F, Q, inflation)
    _assert_valid(cand, False)
    want = bp.edge_face_candidates(x, E, F)
    assert set(map(tuple, want.tolist())) <= set(map(tuple, cand.tolist()))
    if inflation == 0.0:
        np.testing.assert_array_equal(cand, want)
    lo_e, hi_e = x[E].min(1) - inflation, x[E].max(1) + inflation
    lo_f, hi_f = x[F].min(1) - inflation, x[F].max(1) + inflation
    k, f = cand[:, 0], cand[:, 1]
    assert np.all((lo_e[k] <= hi_f[f]) & (lo_f[f] <= hi_e[k]))
    ee = bp.min_pair_sq(x, E, E, inflation, True)
    vf = bp.min_pair_sq(x, Q[:, None], F, inflation, False)
    # The fused pass (a triangle mesh) evaluates an edge pair smaller id first, the
    # edge-edge fold in its cell order: the same minimum up to the kernels' rounding.
    assert bp._start_owners(E, F, Q, len(x))[3] == (kind != "free-vertex-outside")
    assert abs(d2 - min(ee, vf)) <= 1e-12 * min(ee, vf)
    if kind == "folded-cloth" and inflation == 0.02:  # the layers 0.01 apart: both folds see them
        assert max(ee, vf) < 0.011 ** 2


def _separate_start_pass(monkeypatch, x, E, F, Q, inflation, cap_sq=np.inf):
    """`start_pass` through its separate folds (as for a mesh that is not all triangles)."""
    owners = bp._start_owners
    with monkeypatch.context() as m:
        m.setattr(bp, "_start_owners", lambda *a: owners(*a)[:3] + (False,))
        return bp.start_pass(x, E, F, Q, inflation, cap_sq=cap_sq)


def _big_triangle_scene(rng):
    """A flat sheet and one triangle whose edges' boxes hold all of it: rows with more
    box hits than the fused pass's scratch (`_ROW_HITS`), big boxes on both sides."""
    V, F = cloth(24, rng, amp=0.0)
    n = len(V)
    V = np.concatenate([V, [[-0.05, -0.05, -0.1], [1.05, 1.05, 0.1], [1.05, -0.05, 0.0]]])
    F = np.concatenate([F, [[n, n + 1, n + 2]]])
    assert len(F) > 2 * bp._ROW_HITS
    return np.ascontiguousarray(V), edges_from_faces(F), F.astype(np.int64), np.arange(len(V), dtype=np.int64)


@pytest.mark.parametrize("refill", [False, True], ids=["fits", "refilled"])
@pytest.mark.parametrize("kind", ["cloth", "folded-cloth", "far-from-origin", "big-triangle"])
def test_fused_start_pass_is_the_separate_one(rng, monkeypatch, kind, refill):
    # One pass over the edge-face box hits (adjacent ones too) folds the edge-edge and
    # vertex-face minima: the same candidates as the separate pass, the same minimum up
    # to the kernels' rounding, the same bits on 1 and 2 threads, in many chunks, with
    # every chunk's buffer overflowing and refilled (a refill folds again).
    import numba

    x, E, F, Q = _big_triangle_scene(rng) if kind == "big-triangle" else _start_scene(kind, rng)
    assert bp._start_owners(E, F, Q, len(x))[3]
    monkeypatch.setattr(bp, "_PAIR_CHUNK_MIN_ROWS", 16)
    monkeypatch.setattr(bp._start_chunks, "min_work", 0)
    if refill:
        monkeypatch.setattr(bp, "_CAP_SLACK", 0.0)
        monkeypatch.setattr(bp, "_CAP_PAD", 0)
    for inflation in (0.0, 0.01):
        want_cand, want_d2 = _separate_start_pass(monkeypatch, x, E, F, Q, inflation)
        old = numba.get_num_threads()
        try:
            numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
            cand, d2 = bp.start_pass(x, E, F, Q, inflation)
            numba.set_num_threads(1)
            cand1, d21 = bp.start_pass(x, E, F, Q, inflation)
        finally:
            numba.set_num_threads(old)
        np.testing.assert_array_equal(cand, want_cand)
        assert abs(d2 - want_d2) <= 1e-12 * want_d2
        np.testing.assert_array_equal(cand1, cand)
        assert d21 == d2
        if kind == "big-triangle":  # the triangle crosses the sheet
            assert len(cand) > 0


@pytest.mark.parametrize("refill", [False, True], ids=["fits", "refilled"])
def test_pair_passes_give_the_same_bits_for_any_claiming_workers(rng, monkeypatch, refill):
    # The listing passes' workers claim chunks by ranges (`parallel.range_counter`):
    # 1, 2, 3 or 7 workers (more than the chunks of some passes), on 1 and 2 threads, every
    # chunk's buffer fitting or refilled, give the same candidates as the brute force and
    # the same fused start pass (candidates and minimum) bit for bit.
    import numba

    from penfree.core import parallel

    x, E, F, Q = _start_scene("folded-cloth", rng)
    x1 = _motion("swept", x, rng)
    monkeypatch.setattr(bp, "_PAIR_CHUNK_MIN_ROWS", 16)
    monkeypatch.setattr(bp._fill_chunks, "min_work", 0)
    monkeypatch.setattr(bp._start_chunks, "min_work", 0)
    if refill:
        monkeypatch.setattr(bp, "_CAP_SLACK", 0.0)
        monkeypatch.setattr(bp, "_CAP_PAD", 0)
    want_ee = edge_edge_candidates_brute(x, x1, E, 0.01)
    want_vf = vertex_face_candidates_brute(x, x1, F, 0.01)
    assert len(want_ee) and len(want_vf)
    start = None
    old = numba.get_num_threads()
    try:
        for workers in (1, 2, 3, 7):
            monkeypatch.setattr(bp, "range_counter", lambda n, w=workers: parallel.range_counter(n, workers=w))
            for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
                numba.set_num_threads(threads)
                np.testing.assert_array_equal(edge_edge_candidates(x, x1, E, 0.01), want_ee)
                np.testing.assert_array_equal(vertex_face_candidates(x, x1, F, 0.01), want_vf)
                cand, d2 = bp.start_pass(x, E, F, Q, 0.01)
                if start is None:
                    start = cand, d2
                np.testing.assert_array_equal(cand, start[0])
                assert d2 == start[1]
    finally:
        numba.set_num_threads(old)


@pytest.mark.parametrize("inflation", [0.0, 0.004, 0.03])
@pytest.mark.parametrize("kind", ["cloth", "folded-cloth", "vertex-subset"])
def test_fused_start_pass_minimum_is_exact(rng, kind, inflation):
    # Against the O(n^2) oracle in exact arithmetic over the pairs whose inflated boxes
    # overlap: edge pairs sharing no vertex, and the listed vertices against the faces.
    V, F = cloth(8, rng)
    if kind == "folded-cloth":
        V = np.concatenate([V, V + [0.0, 0.0, 0.005]])
        F = np.concatenate([F, F + len(V) // 2])
    V, F = np.ascontiguousarray(V), F.astype(np.int64)
    E = edges_from_faces(F)
    Q = np.arange(len(V), dtype=np.int64)
    if kind == "vertex-subset":
        Q = Q[::3]
    face_edges, owner_face, owner_edge, ok = bp._start_owners(E, F, Q, len(V))
    assert ok
    want_ee = _min_pair_sq_brute(V, E, E, inflation, True)
    want_vf = _min_pair_sq_brute(V, Q[:, None], F, inflation, False)
    _, d2 = bp.start_pass(V, E, F, Q, inflation)
    # Each fold alone: with no owner edge (no owner face) the walk folds only the
    # edge-edge (vertex-face) pairs.
    lo_e, hi_e = bp._box_arrays(V, V, E, inflation)
    lo_f, hi_f = bp._box_arrays(V, V, F, inflation)
    plan = bp._Plan(lo_e, hi_e, E, lo_f, hi_f, F, False, inflation)
    none_e, none_f = np.full_like(owner_edge, -1), np.full_like(owner_face, -1)
    _, ee = plan.start_pairs(V, (face_edges, owner_face, none_e), lo_e, hi_e, lo_f, hi_f, inflation)
    _, vf = plan.start_pairs(V, (face_edges, none_f, owner_edge), lo_e, hi_e, lo_f, hi_f, inflation)
    for got, want in ((d2, min(want_ee, want_vf)), (ee, want_ee), (vf, want_vf)):
        if np.isinf(want):
            assert np.isinf(got)
        else:
            assert abs(got - want) <= 1e-12 * max(want, 1e-300)
    if inflation > 0:
        assert np.isfinite(want_ee) and np.isfinite(want_vf)


@pytest.mark.parametrize("kind", ["cloth", "folded-cloth", "far-from-origin", "free-vertex-outside"])
def test_capped_start_pass_is_the_minimum_or_the_cap(rng, monkeypatch, kind):
    # A cap lets the folds skip the pairs provably above their minimum so far, which
    # starts at the cap (projection gaps in the fused pass, box gaps in the separate
    # folds): the result is min(cap, the uncapped minimum) bit for bit and the
    # candidates are unchanged, on both paths; caps far below the minimum (as the
    # certificate path's), at it, just above it and above it.
    x, E, F, Q = _start_scene(kind, rng)
    for inflation in (0.0, 1e-3):
        for separate in (False, True):
            def start(cap_sq):
                if separate:
                    return _separate_start_pass(monkeypatch, x, E, F, Q, inflation, cap_sq)
                return bp.start_pass(x, E, F, Q, inflation, cap_sq=cap_sq)

            cand, d2 = start(np.inf)
            assert 0.0 < d2 < np.inf
            for cap in (0.0, 1e-12, 0.25 * d2, d2, np.nextafter(d2, np.inf), 4.0 * d2):
                got_cand, got = start(cap)
                np.testing.assert_array_equal(got_cand, cand)
                assert got == min(cap, d2), (separate, inflation, cap)


def test_start_owners_of_a_triangle_mesh_and_what_falls_back(rng):
    # Each face's edge rows, an edge's first face, a vertex's first edge (numpy oracle);
    # not ok (the separate folds run) for an edge in no face, a listed vertex in no
    # edge, or E not sorted as `scene_edges` makes it.
    V, F = cloth(6, rng)
    F = np.concatenate([F, [[3, 3, 9]]]).astype(np.int64)  # a degenerate face: one edge twice
    E = edges_from_faces(F)
    n = len(V)
    Q = np.arange(n, dtype=np.int64)
    face_edges, owner_face, owner_edge, ok = bp._start_owners(E, F, Q, n)
    assert ok
    row = {tuple(e): r for r, e in enumerate(E.tolist())}
    for f, tri in enumerate(F.tolist()):
        for c in range(3):
            a, b = tri[c], tri[(c + 1) % 3]
            assert face_edges[f, c] == (-1 if a == b else row[(min(a, b), max(a, b))])
    for r in range(len(E)):
        assert owner_face[r] == min(f for f in range(len(F)) if r in face_edges[f])
    for v in range(n):
        assert owner_edge[v] == np.flatnonzero((E == v).any(1))[0]
    rod = np.array([[n, n + 1]])  # an edge of no face (a rod beside the cloth)
    assert not bp._start_owners(np.concatenate([E, rod]), F, np.arange(n + 2), n + 2)[3]
    assert not bp._start_owners(E, F, np.arange(n + 1), n + 1)[3]  # vertex n in no edge
    assert bp._start_owners(E, F, Q, n + 1)[3]  # ... unless it is not listed
    assert not bp._start_owners(E[::-1].copy(), F, Q, n)[3]
    assert not bp._start_owners(E[:, ::-1].copy(), F, Q, n)[3]


def test_start_pass_without_faces_or_with_one_edge(rng):
    V, E = rods(4, 10, rng)
    none = np.zeros((0, 3), dtype=np.int64)
    cand, d2 = bp.start_pass(V, E, none, np.arange(len(V)), 0.01)
    assert cand.shape == (0, 2) and d2 == bp.min_pair_sq(V, E, E, 0.01, True)
    cand, d2 = bp.start_pass(V, E[:1], none, np.arange(len(V)), 0.01)
    assert cand.shape == (0, 2) and np.isinf(d2)


@pytest.mark.parametrize("sparse", [False, True], ids=["dense", "hashed"])
def test_plan_with_rows_finds_a_fresh_plans_pairs(rng, sparse):
    # Rows of another set against a built grid: the same pairs as a fresh plan over
    # the same boxes; rows leaving the grid's cells get no plan (keys would alias).
    x, E, F, Q = _start_scene("cloth", rng)
    if sparse:  # a second sheet far away: a hashed table
        x, E, F = np.concatenate([x, x + 50.0]), np.concatenate([E, E + len(x)]), np.concatenate([F, F + len(x)])
        Q = np.arange(len(x), dtype=np.int64)
    loF, hiF = bp._box_arrays(x, x, F, 0.01)
    loE, hiE = bp._box_arrays(x, x, E, 0.0)
    plan = bp._Plan(loE, hiE, E, loF, hiF, F, False)
    TV = Q[:, None]
    loV, hiV = bp._box_arrays(x, x, TV, 0.01)
    shared = plan.with_rows(loV, hiV, TV, 0.01)
    assert shared is not None and shared.boff is plan.boff and (plan.bits >= 0) == sparse
    np.testing.assert_array_equal(shared.pairs(), bp._Plan(loV, hiV, TV, loF, hiF, F, False, 0.01).pairs())
    np.testing.assert_array_equal(shared.pairs(), vertex_face_candidates(x, x, F, 0.01))
    for shift in ([-5.0, 0, 0], [0, 0, 5.0]):  # below the origin, beyond the last cell
        assert plan.with_rows(loV + shift, hiV + shift, TV, 0.01) is None
    assert bp._Plan(loE, hiE, E, loE, hiE, E, True).with_rows(loV, hiV, TV, 0.0) is None  # self query


#: Column orders that put the test rods' own axis (z in `rods`) at x, y or z.
_ROD_AXIS_AT = {0: [2, 0, 1], 1: [0, 2, 1], 2: [0, 1, 2]}


@pytest.mark.parametrize("axis", [0, 1, 2], ids=["rods-along-x", "rods-along-y", "rods-along-z"])
@pytest.mark.parametrize("listing", [True, False], ids=["covering", "lower-corner"])
def test_key_axis_order_follows_the_rods_and_changes_no_pair(rng, axis, listing, monkeypatch):
    # Consecutive segments of a rod change cells along the rod: the plan's key takes that
    # axis first whichever it is (boxes in id order fill nearby buckets). The pairs are the
    # brute-force oracle's and the minima the oracle pairs' bit for bit, the same as with
    # the natural order.
    V, E = rods(10, 50, rng)
    V = np.ascontiguousarray(V[:, _ROD_AXIS_AT[axis]])
    V1 = V + rng.normal(scale=0.002, size=V.shape)
    lo, hi = bp._box_arrays(V, V1, E, 0.004)
    want_pairs = edge_edge_candidates_brute(V, V1, E, 0.004)
    want = np.full(len(V), np.inf)
    for i, j in want_pairs:
        want[E[[i, j]].ravel()] = np.minimum(want[E[[i, j]].ravel()], bp._pair_sq(V, E, i, E, j))
    for ordered in (True, False):
        monkeypatch.setattr(bp, "_AXIS_ORDER", ordered)
        plan = bp._Plan(lo, hi, E, lo, hi, E, True, 0.004, listing=listing)
        first = 0 if plan.perm is None else plan.perm[0]
        assert first == (axis if ordered else 0)
        np.testing.assert_array_equal(plan.pairs(), want_pairs)
        part = np.full((3, len(V)), np.inf)
        plan.min_sq_into(V, part)
        np.testing.assert_array_equal(part.min(axis=0).view(np.uint64), want.view(np.uint64))
    np.testing.assert_array_equal(lo, bp._box_arrays(V, V1, E, 0.004)[0])  # the caller's boxes untouched


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_rows_of_another_set_follow_the_grids_axis_order(rng, axis):
    # A sheet whose faces run along `axis` in id order: the faces' grid puts that axis
    # first, and rows of vertices queried against it (`with_rows`) are permuted the same
    # way: their pairs are the oracle's, and the grid's edge-face pairs the public query's.
    x, E, F, Q = _start_scene("cloth", rng)
    x = np.ascontiguousarray(x[:, [[1, 0, 2], [0, 1, 2], [0, 2, 1]][axis]])  # the rows run along y
    loF, hiF = bp._box_arrays(x, x, F, 0.01)
    loE, hiE = bp._box_arrays(x, x, E, 0.0)
    plan = bp._Plan(loE, hiE, E, loF, hiF, F, False)
    assert plan.perm is not None and plan.perm[0] == axis
    TV = Q[:, None]
    loV, hiV = bp._box_arrays(x, x, TV, 0.01)
    shared = plan.with_rows(loV, hiV, TV, 0.01)
    np.testing.assert_array_equal(shared.pairs(), vertex_face_candidates_brute(x, x, F, 0.01))
    np.testing.assert_array_equal(plan.edge_face_pairs(x), bp.edge_face_candidates(x, E, F))


def test_pairs_overlapping_is_the_queries_box_test():
    """`pairs_overlapping` of every pair against a brute-force box test in numpy, and of
    a query's own pairs (all kept); boxes touching exactly count as overlapping."""
    rng = np.random.default_rng(21)
    V = np.round(rng.random((60, 3)), 2)  # a coarse lattice: many exactly touching boxes
    E = np.array([[i, i + 1] for i in range(0, 60, 2)], dtype=np.int64)
    F = np.array([[i, i + 1, i + 2] for i in range(0, 57, 3)], dtype=np.int64)
    Q = np.arange(60, dtype=np.int64)[:, None]
    for TA, TB, infl in ((E, E, 0.05), (Q, F, 0.0), (Q, F, 0.02)):
        P = np.array([(i, j) for i in range(TA.shape[0]) for j in range(TB.shape[0])], dtype=np.int64)
        lo = lambda T: V[T].min(axis=1) - infl  # noqa: E731
        hi = lambda T: V[T].max(axis=1) + infl  # noqa: E731
        want = ((lo(TA)[P[:, 0]] <= hi(TB)[P[:, 1]]) & (lo(TB)[P[:, 1]] <= hi(TA)[P[:, 0]])).all(axis=1)
        np.testing.assert_array_equal(bp.pairs_overlapping(V, TA, TB, P, infl), want)
        assert want.any() and not want.all()
    pairs = edge_edge_candidates(V, V, E, 0.05)
    assert pairs.shape[0] and bp.pairs_overlapping(V, E, E, pairs, 0.05).all()



def _cluster(rng, n, kind):
    """`n` disjoint short edges (kind "ee") or triangles ("vf") in a ball of radius 0.05,
    and their vertices: at an inflation of 0.1 every pair's boxes overlap."""
    k = 2 if kind == "ee" else 3
    c = rng.uniform(-0.05, 0.05, size=(n, 1, 3))
    V = (c + rng.normal(scale=0.01, size=(n, k, 3))).reshape(-1, 3)
    return np.ascontiguousarray(V), np.arange(n * k, dtype=np.int64).reshape(n, k)


@njit
def _brute_minima(V, TA, TB, self_query, init):
    # Every non-adjacent pair (j > i in a self query) through the scalar kernels.
    out = np.full(V.shape[0], init)
    for i in range(TA.shape[0]):
        for j in range(i + 1 if self_query else 0, TB.shape[0]):
            if bp._adjacent(TA, i, TB, j):
                continue
            d = bp._pair_sq(V, TA, i, TB, j)
            for v in TA[i]:
                out[v] = min(out[v], d)
            for v in TB[j]:
                out[v] = min(out[v], d)
    return out


def _with_spanning(V, T, k, rng):
    """`T` plus `k` primitives of `T`'s width whose vertices lie far apart across the
    bounding box of `V` (new vertices appended): boxes too big for a fold's grid."""
    lo, hi = V.min(axis=0), V.max(axis=0)
    W = rng.uniform(lo, hi, size=(k * T.shape[1], 3))
    W[::T.shape[1]] = lo + 0.05 * (hi - lo) * rng.uniform(size=(k, 3))  # a corner to the far side
    new = len(V) + np.arange(k * T.shape[1], dtype=np.int64).reshape(k, T.shape[1])
    return np.concatenate([V, W]), np.concatenate([T, new])


def test_deferred_kernels_are_one_source_with_their_own_row_visits():
    # `_defer_rows` and `_defer_dense` compile one source (`_deferred_py`), each build with
    # its own row visit frozen in (`_with_visit`): the generic visit for any grid, the
    # dense one where `_Plan.min_sq_into` picks it. Both give the same bits (the test
    # below), so only this tells a swapped or shared visit from the right one.
    for kernel, visit in ((bp._defer_rows, bp._visit_row), (bp._defer_dense, bp._visit_dense)):
        for build in (kernel.serial, kernel.parallel):
            assert build.py_func.__code__ is bp._deferred_py.__code__
            assert build.py_func.__globals__["_DEFERRED_VISIT"] is visit
    assert "_DEFERRED_VISIT" not in vars(bp)  # no module-wide default to fall back on


@pytest.mark.parametrize("kind", ["rods", "folded-cloth"])
@pytest.mark.parametrize("compact", [False, True])
def test_dense_deferred_fold_gives_the_generic_folds_bits(rng, kind, compact):
    # `_defer_dense`, the deferred fold with its own row visit for dense lower-corner
    # grids (`_visit_dense`, picked by `_Plan.min_sq_into`), against the generic deferred
    # fold (`_defer_rows`), the fold that evaluates each pair at once (`_min_rows`) and
    # brute force, bit for bit: with and without compaction, one and two workers, the
    # folds' own list and a list of 8 (rows visited again). Primitives spanning the scene
    # are too big for the grid: rows against every box, partners of every small row.
    V, E, F = _scene(kind, rng)
    V, E = _with_spanning(V, E, 3, rng)
    sets = [(E, E, True)]
    if len(F):
        V, F = _with_spanning(V, F, 3, rng)
        sets.append((np.arange(len(V), dtype=np.int64)[:, None], F, False))
    for TA, TB, self_query in sets:
        lo_a, hi_a = bp._box_arrays(V, V, TA, 0.01)
        lo_b, hi_b = (lo_a, hi_a) if self_query else bp._box_arrays(V, V, TB, 0.01)
        plan = bp._Plan(lo_a, hi_a, TA, lo_b, hi_b, TB, self_query, 0.01, listing=False)
        assert plan.bits < 0 and plan.ent_clo.shape[0] == 0  # dense, lower-corner: `_defer_dense`'s grid
        assert len(plan.bigB) > 0 and (self_query or plan.smallA.all())
        plan.compact = compact
        # from a cap below the boxes' reach (every pair that lowers a minimum overlaps: the
        # brute force's minima), and from inf (the direct fold's: farther pairs may be skipped)
        for init in (1e-4, np.inf):
            direct = np.full((2, len(V)), init)
            bp._min_rows(len(TA), *plan._args(), V, direct, bp.MODE_MIN, 4, work_counter())
            want = _brute_minima(V, TA, TB, self_query, init) if init < np.inf else direct.min(axis=0)
            outs = [direct]
            for kernel in (bp._defer_rows, bp._defer_dense):
                for workers, cap, flush in ((1, bp._DEFER_CAP, bp._DEFER_FLUSH), (2, bp._DEFER_CAP, bp._DEFER_FLUSH),
                                            (2, 8, 4)):
                    outs.append(np.full((workers, len(V)), init))
                    kernel(len(TA), *plan._args(), V, outs[-1], 7, work_counter(), cap, flush)
            outs.append(np.full((2, len(V)), init))
            plan.min_sq_into(V, outs[-1])  # the folds' own call: `_defer_dense`
            assert np.any(want < init)
            for got in outs:
                np.testing.assert_array_equal(got.min(axis=0).view(np.uint64), want.view(np.uint64))


@pytest.mark.parametrize("kind", ["ee", "vf"])
@pytest.mark.parametrize("cap, flush", [(512, 256), (8, 4), (3, 3), (1, 1)])
def test_deferred_fold_rows_beyond_its_list(rng, kind, cap, flush):
    # MODE_MIN folds of edge-edge and vertex-face pairs list each row's pairs and evaluate
    # them in batches (`_defer_rows`, branch-free kernels). A cluster of 600 primitives
    # whose boxes all overlap gives rows of 0 to 599 pairs; small lists make every path
    # run: rows that do not fit in the room left (visited again after the list is
    # emptied) and rows beyond the whole list (a list of their own). The minima are those
    # of the fold that evaluates each pair at once (`_min_rows`) and of the brute-force
    # pairs, bit for bit, from inf and from a cap, on one and two workers.
    V, T = _cluster(rng, 600, kind)
    if kind == "ee":
        TA = TB = T
        self_query = True
    else:
        TA, TB, self_query = np.arange(len(V), dtype=np.int64)[:, None], T, False
    lo_a, hi_a = bp._box_arrays(V, V, TA, 0.1)
    lo_b, hi_b = (lo_a, hi_a) if self_query else bp._box_arrays(V, V, TB, 0.1)
    plan = bp._Plan(lo_a, hi_a, TA, lo_b, hi_b, TB, self_query, 0.1, listing=False)
    for init in (np.inf, 0.05):
        want = _brute_minima(V, TA, TB, self_query, init)
        direct = np.full((2, len(V)), init)
        bp._min_rows(len(TA), *plan._args(), V, direct, bp.MODE_MIN, 4, work_counter())
        outs = [direct]
        for workers in (1, 2):
            deferred = np.full((workers, len(V)), init)
            bp._defer_rows(len(TA), *plan._args(), V, deferred, 7, work_counter(), cap, flush)
            outs.append(deferred)
        if (cap, flush) == (bp._DEFER_CAP, bp._DEFER_FLUSH):
            outs.append(np.full((2, len(V)), init))
            plan.min_sq_into(V, outs[-1])  # the folds' own call
        for got in outs:
            np.testing.assert_array_equal(got.min(axis=0).view(np.uint64), want.view(np.uint64))
