"""Neighbour lists reused across frames against fresh queries (the oracle): on every
step of the bundled samples the listed pairs are a superset of the pairs within the
query radius (brute-force distances over fresh box candidates) and the per-vertex
separations equal `per_vertex_separation` bit for bit; results do not depend on the
thread count or on whether a list was reused, rebuilt or bypassed."""

from pathlib import Path

import numba
import numpy as np
import pytest

from penfree.core.contact import broad_phase as bp
from penfree.core.contact import neighbours as nbm
from penfree.core.contact.broad_phase import edge_edge_candidates, vertex_face_candidates
from penfree.core.contact.distance import edge_edge_distance, point_triangle_distance
from penfree.core.contact.neighbours import NeighbourList, affine_residual
from penfree.core.trust.stats import query_radius
from penfree.core.topology import referenced_vertices
from penfree.core.trust.bounds import per_vertex_separation, scene_arrays
from penfree.formats import read_sequence

from _geom import rot

SAMPLES = Path(__file__).resolve().parents[3] / "samples"
SAMPLE_FILES = sorted(p.name for p in SAMPLES.glob("*.h5"))


def pairs_within(x, E, F, r):
    """Oracle: every non-adjacent ee / vf pair within distance r (fresh boxes + exact distances)."""
    infl = 0.5 * r * (1 + 1e-9)
    out = {}
    ee = edge_edge_candidates(x, x, E, infl) if len(E) > 1 else np.zeros((0, 2), np.int64)
    d = edge_edge_distance(x[E[ee[:, 0], 0]], x[E[ee[:, 0], 1]], x[E[ee[:, 1], 0]], x[E[ee[:, 1], 1]])
    out["ee"] = ee[d <= r]
    if len(F):
        used = np.flatnonzero(referenced_vertices(x.shape[0], F, E))
        vf = vertex_face_candidates(x, x, F, infl, used)
        d = point_triangle_distance(x[vf[:, 0]], x[F[vf[:, 1], 0]], x[F[vf[:, 1], 1]], x[F[vf[:, 1], 2]])
        out["vf"] = vf[d <= r]
    else:
        out["vf"] = np.zeros((0, 2), np.int64)
    return out


def missing_pairs(truth, listed):
    """Rows of `truth` (K, 2) not among the rows of `listed`."""
    m = max(int(truth.max(initial=0)), int(listed.max(initial=0))) + 1
    t, l = truth[:, 0] * m + truth[:, 1], np.sort(listed[:, 0] * m + listed[:, 1])
    k = np.minimum(np.searchsorted(l, t), max(len(l) - 1, 0))
    found = l[k] == t if len(l) else np.zeros(len(t), bool)
    return truth[~found]


@pytest.mark.parametrize("name", SAMPLE_FILES)
def test_superset_and_exact_on_every_sample_step(name):
    seq = read_sequence(SAMPLES / name)
    pos = np.asarray(seq.positions, dtype=np.float64)
    _, E, F = scene_arrays(pos[0], seq.edges, seq.faces)
    steps = range(1, pos.shape[0])
    radii = [query_radius(pos[s], 2 * pos[s] - pos[s - 1], seq.thickness) for s in steps]
    # A fixed skin forces lists (the automatic choice bypasses them on these fast scenes).
    nl = NeighbourList(E, F, skin=1.0 * max(radii))
    for s, r in zip(steps, radii):
        x = np.ascontiguousarray(pos[s])
        listed = nl.pairs(x, r)
        truth = pairs_within(x, E, F, r)
        for kind in ("ee", "vf"):
            missing = missing_pairs(truth[kind], listed[kind])
            assert not len(missing), f"{name} step {s}: {kind} pairs within r not listed: {missing[:5].tolist()}"
        np.testing.assert_array_equal(nl.separations(x, r), per_vertex_separation(x, E, F, r))
    assert nl.info["reused"] > 0 and nl.info["builds"] < len(radii)


@pytest.mark.parametrize("name", ["cloth.h5", "rods.h5", "twisting_cloth.h5", "falling_stack.h5"])
def test_coverage_holds_every_pair_within_it(name):
    # One list built at frame 1: at each later frame, every pair within its `coverage`
    # is listed (brute-force oracle), and the reach of that radius fits the list.
    seq = read_sequence(SAMPLES / name)
    pos = np.asarray(seq.positions, dtype=np.float64)
    _, E, F = scene_arrays(pos[0], seq.edges, seq.faces)
    r = query_radius(pos[1], 2 * pos[1] - pos[0], seq.thickness)
    nl = NeighbourList(E, F, skin=0.5 * r)
    nl.ensure(np.ascontiguousarray(pos[1]), r, need_list=True)
    covered = 0
    for s in range(1, min(pos.shape[0], 8)):
        x = np.ascontiguousarray(pos[s])
        cover = nl.coverage(x)
        if cover <= 0:
            continue
        covered += 1
        assert nl.reach(x, cover, nl.x_b) <= nl.r_b
        truth = pairs_within(x, E, F, cover)
        for kind, P in (("ee", nl.P_ee), ("vf", nl.P_vf)):
            assert not len(missing_pairs(truth[kind], P)), f"{name} frame {s}: {kind}"
    assert covered >= 2
    assert NeighbourList(E, F).coverage(pos[1]) == -np.inf  # no list yet


@pytest.mark.parametrize("name", ["cloth.h5", "rods.h5", "twisting_cloth.h5"])
def test_automatic_skin_is_exact(name):
    """Whatever the cost model decides (build, reuse, fresh), the answer is the fresh one."""
    seq = read_sequence(SAMPLES / name)
    pos = np.asarray(seq.positions, dtype=np.float64)[:16]
    _, E, F = scene_arrays(pos[0], seq.edges, seq.faces)
    nl = NeighbourList(E, F)
    for s in range(1, pos.shape[0]):
        x = pos[s]
        r = query_radius(x, 2 * x - pos[s - 1], seq.thickness)
        x_def = x + 0.3 * (x - pos[s - 1])  # a second state per step, as report visits x_def
        for y in (x, x_def):
            np.testing.assert_array_equal(nl.separations(y, r), per_vertex_separation(np.ascontiguousarray(y), E, F, r))
    info = nl.info
    assert info["queries"] == info["builds"] + info["reused"] + info["fresh"]


def sheet(n, rng):
    u = np.linspace(0.0, 1.0, n)
    X, Y = np.meshgrid(u, u, indexing="ij")
    Z = 0.2 * np.sin(3 * X) * np.cos(2 * Y)
    V = np.stack([X, Y, Z], -1).reshape(-1, 3) + rng.normal(scale=0.05 / n, size=(n * n, 3))
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    # fold: a second layer 0.01 above, so that non-adjacent pairs come close
    V2 = V + [0.003, 0.002, 0.01]
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return np.concatenate([V, V2]), np.concatenate([F, F + n * n])


def test_affine_bound_keeps_the_list_through_large_rigid_motion():
    """rotating-far-from-origin: every vertex moves far (identity bound fails every step),
    the affine residual is tiny, so one build serves all steps, exactly."""
    rng = np.random.default_rng(5)
    V, F = sheet(12, rng)
    V = V + 1e3
    _, E, F = scene_arrays(V, None, F)
    r = 0.02
    nl = NeighbourList(E, F, skin=0.2 * r)
    c = V.mean(axis=0)
    for k in range(8):
        A = rot([1, 2, 3], 20.0 * k) @ np.diag([1.0, 1.0 + 1e-4 * k, 1.0])
        x = np.ascontiguousarray((V - c) @ A.T + c + [0.5 * k, 0, 0])
        assert k == 0 or nl.reach(x, r, nl.x_b) < r + 2.0 * np.abs(x - nl.x_b).max()
        np.testing.assert_array_equal(nl.separations(x, r), per_vertex_separation(x, E, F, r))
    assert nl.info["builds"] == 1 and nl.info["reused"] == 7


@pytest.mark.parametrize("case", ["planar-sheet", "collinear-rod", "three-points"])
def test_affine_residual_declines_degenerate_data(case):
    rng = np.random.default_rng(1)
    if case == "planar-sheet":
        x = np.c_[rng.uniform(size=(50, 2)), np.zeros(50)]
    elif case == "collinear-rod":
        x = np.outer(np.linspace(0, 1, 20), [1.0, 2.0, 3.0])
    else:
        x = rng.uniform(size=(3, 3))
    assert affine_residual(x, x + 0.1) is None


def test_affine_residual_bounds_the_true_residual():
    rng = np.random.default_rng(2)
    x_b = rng.uniform(-1, 1, size=(500, 3)) + 50.0
    A = rot([0, 1, 1], 30.0) @ np.diag([1.1, 0.9, 1.0])
    x = x_b @ A.T + [3.0, -1.0, 2.0] + rng.normal(scale=1e-3, size=x_b.shape)
    s_min, eps = affine_residual(x_b, x)
    # any affine map gives a residual no smaller than the least-squares one's max
    X = np.c_[x_b, np.ones(len(x_b))]
    coef, *_ = np.linalg.lstsq(X, x, rcond=None)
    res = np.linalg.norm(x - X @ coef, axis=1).max()
    assert eps >= res * (1 - 1e-6) and eps < 10 * res
    sv = np.linalg.svd(coef[:3].T, compute_uv=False)
    assert 0 < s_min <= sv[2] * (1 + 1e-9)


@pytest.fixture
def force_parallel(monkeypatch):
    """Run the dual-build kernels' parallel builds even on small inputs."""
    for k in (nbm._ee_sq, nbm._vf_sq, nbm._listed_min, bp._fill_chunks, bp._gather_chunks, bp._min_rows, bp._defer_rows,
              bp._defer_dense, bp._grid_count, bp._grid_fill, bp._boxes, bp._corners, bp._cell_ranges_k):
        monkeypatch.setattr(k, "min_work", 0)
    monkeypatch.setattr(bp, "use_parallel", lambda work, min_work=0: numba.get_num_threads() > 1)
    yield
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)


@pytest.mark.parametrize("compact", [False, True], ids=["scan", "compacted-scan"])
def test_identical_for_one_and_two_threads(force_parallel, monkeypatch, compact):
    """Broad phase (grid build chunked per thread, plain or compacted row scan), per-vertex
    separations and listed queries: the same bits on 1 and 2 threads."""
    monkeypatch.setattr(bp, "_COMPACT_MIN_ROWS", 0)
    monkeypatch.setattr(bp, "_COMPACT_HIT_RATE", 1.01 if compact else 0.0)
    monkeypatch.setattr(bp, "_COMPACT_MISSES", 0)
    rng = np.random.default_rng(3)
    V, F = sheet(30, rng)
    _, E, F = scene_arrays(V, None, F)
    out = {}
    for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
        numba.set_num_threads(threads)
        nl = NeighbourList(E, F, skin=0.01)
        out[threads] = (nl.separations(V, 0.02), nl.pairs(V, 0.02), per_vertex_separation(V, E, F, 0.02),
                        edge_edge_candidates(V, V, E, 0.01), bp.min_pair_sq(V, E, E, 0.01, True))
    a, b = out.values()
    assert a[4] == b[4]
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[2], b[2])
    np.testing.assert_array_equal(a[3], b[3])
    for kind in ("ee", "vf", "ef"):
        np.testing.assert_array_equal(a[1][kind], b[1][kind])
    np.testing.assert_array_equal(a[0], a[2])


@pytest.mark.parametrize("chunk_pairs, max_chunks", [(1, 10**9), (10**9, 1)], ids=["one-pair-chunks", "one-chunk"])
def test_listed_fold_claims_chunks_with_the_same_bits(force_parallel, monkeypatch, chunk_pairs, max_chunks):
    # A listed query's workers claim chunks of the listed pairs as they go: any chunking,
    # 1 or 2 threads, the same bits as a fresh query.
    monkeypatch.setattr(nbm, "_LISTED_CHUNK_PAIRS", chunk_pairs)
    monkeypatch.setattr(nbm, "_LISTED_CHUNKS", max_chunks)
    V, F = sheet(20, np.random.default_rng(4))
    _, E, F = scene_arrays(V, None, F)
    want = per_vertex_separation(V, E, F, 0.03)
    for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
        numba.set_num_threads(threads)
        nl = NeighbourList(E, F, skin=0.01)
        nl.pairs(V, 0.03)  # built: the next query is answered from the list
        np.testing.assert_array_equal(nl.listed_separations(V, 0.03), want)


@pytest.mark.parametrize("case", ["nan", "wrong-n", "negative-radius"])
def test_bad_queries_raise_input_error(case):
    from penfree import NeighbourList as Public
    from penfree.errors import InputError

    x = np.zeros((4, 3)) + np.arange(4.0)[:, None]
    nl = Public.for_scene(x, edges=[[0, 1], [2, 3]])
    bad = {"nan": (np.full((4, 3), np.nan), 1.0), "wrong-n": (np.zeros((5, 3)), 1.0),
           "negative-radius": (x, -1.0)}[case]
    with pytest.raises(InputError):
        nl.separations(*bad)
    with pytest.raises(InputError):
        nl.pairs(*bad)
