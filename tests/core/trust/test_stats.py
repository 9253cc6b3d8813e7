"""Trust-region statistics (SPEC section 7) against hand-built cases and oracles."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from penfree.constants import DEFAULT_GAMMA
from penfree.core.trust.stats import (
    StepBounds,
    QUANTILES,
    R_HIST_EDGES,
    compute_stats,
    query_radius,
    ratio_stats,
    replay_passes,
    residual_summary,
    stats_keys,
)
from penfree.errors import InputError

# ---------------------------------------------------------------- brute-force oracle
# The same definition as SPEC section 7, over ALL pairs, in plain numpy/Python.


def _pe_dist(p, a, b):
    ab = b - a
    L = ab @ ab
    t = 0.0 if L == 0 else min(1.0, max(0.0, (p - a) @ ab / L))
    return float(np.linalg.norm(p - (a + t * ab)))


def _ee_dist(a0, a1, b0, b1):
    # Minimum of a convex quadratic over [0,1]^2: at the interior critical point or on
    # the boundary (one parameter clamped -> a point-segment distance).
    cands = [_pe_dist(a0, b0, b1), _pe_dist(a1, b0, b1), _pe_dist(b0, a0, a1), _pe_dist(b1, a0, a1)]
    u, v, w = a1 - a0, b1 - b0, a0 - b0
    A, B, C, D, E = u @ u, u @ v, v @ v, u @ w, v @ w
    den = A * C - B * B
    if den > 1e-14 * A * C:
        s = (B * E - C * D) / den
        t = (A * E - B * D) / den
        if 0 < s < 1 and 0 < t < 1:
            cands.append(float(np.linalg.norm(w + s * u - t * v)))
    return min(cands)


def _pt_dist(p, t0, t1, t2):
    n = np.cross(t1 - t0, t2 - t0)
    nn = n @ n
    cands = [_pe_dist(p, t0, t1), _pe_dist(p, t1, t2), _pe_dist(p, t2, t0)]
    if nn > 0:
        q = p - ((p - t0) @ n) / nn * n
        # barycentric inside test on the projection
        c0 = np.cross(t1 - t0, q - t0) @ n
        c1 = np.cross(t2 - t1, q - t1) @ n
        c2 = np.cross(t0 - t2, q - t2) @ n
        if c0 >= 0 and c1 >= 0 and c2 >= 0:
            cands.append(float(np.linalg.norm(p - q)))
    return min(cands)


def _edges_of(faces):
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0)


def brute_bounds(x, *, edges=None, faces=None, thickness=0.0, gamma=DEFAULT_GAMMA, query_radius=1.0):
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[0]
    d = np.full(n, float(query_radius))
    if faces is not None and len(faces):
        edges = _edges_of(np.asarray(faces))
        for f in faces:
            for v in range(n):
                if v in f:
                    continue
                dist = _pt_dist(x[v], *x[f])
                d[v] = min(d[v], dist)
                for w in f:
                    d[w] = min(d[w], dist)
    if edges is not None:
        for i, ea in enumerate(edges):
            for eb in edges[i + 1:]:
                if set(ea) & set(eb):
                    continue
                dist = _ee_dist(*x[ea], *x[eb])
                for w in (*ea, *eb):
                    d[w] = min(d[w], dist)
    return gamma * np.maximum(0.0, d - thickness)


# ---------------------------------------------------------------- ratio_stats


def test_hand_built_mixed_case():
    # r = 1 exactly (hit), 1.5, 2.5, one blocked (b = 0, must move), one still with b = 0.
    x = np.zeros((5, 3))
    y = np.array([[0.5, 0, 0], [0.75, 0, 0], [0, 2.5, 0], [0, 0, 1.0], [0, 0, 0]])
    b = np.array([0.5, 0.5, 1.0, 0.0, 0.0])
    s = ratio_stats(x, y, b)
    assert s["hit_rate"] == 2 / 5
    assert s["n_blocked"] == 1
    assert s["k_any"] == 3
    # kept r sorted: [0, 1, 1.5, 2.5]; "higher" index ceil(q * 3 / 100)
    assert (s["r_q50"], s["r_q90"], s["r_q99"], s["r_max"]) == (1.5, 2.5, 2.5, 2.5)
    assert s["k_1pct"] == 3
    assert s["r_hist"].sum() == 5
    assert s["r_hist"][-1] == 1  # the blocked vertex sits in the last (inf) bin
    assert s["r_hist"][0] == 1  # r = 0


@pytest.mark.parametrize(
    "n_ones, outliers, k_any, k_1pct",
    [
        pytest.param(99, [10.0], 10, 10, id="one-in-100-is-1pct"),
        pytest.param(100, [10.0], 10, 1, id="one-in-101-below-1pct"),
        pytest.param(198, [5.0, 10.0], 10, 5, id="two-in-200"),
        pytest.param(197, [3.2, 5.0, 10.0], 10, 5, id="three-in-200"),
    ],
)
def test_k_1pct_against_the_count_rule(n_ones, outliers, k_any, k_1pct):
    r = np.array([0.5] * n_ones + outliers)
    x = np.zeros((r.size, 3))
    y = np.zeros_like(x)
    y[:, 0] = r  # b = 1 so |y - x| / b = r exactly
    s = ratio_stats(x, y, np.ones(r.size))
    assert (s["k_any"], s["k_1pct"]) == (k_any, k_1pct)
    # the rule itself: fewer than 1% exceed K_1pct, and not for K_1pct - 1
    assert 100 * np.count_nonzero(r > k_1pct) < r.size
    if k_1pct > 1:
        assert 100 * np.count_nonzero(r > k_1pct - 1) >= r.size


@pytest.mark.parametrize("b_value", [0.0, 1.0], ids=["zero-bounds", "unit-bounds"])
def test_zero_motion(b_value):
    x = np.random.default_rng(1).normal(size=(7, 3))
    s = ratio_stats(x, x.copy(), np.full(7, b_value))
    assert s["hit_rate"] == 1.0 and s["n_blocked"] == 0
    assert s["k_any"] == 1 and s["k_1pct"] == 1
    assert s["r_max"] == 0.0


def test_all_blocked():
    x = np.zeros((3, 3))
    s = ratio_stats(x, x + 1.0, np.zeros(3))
    assert s["hit_rate"] == 0.0 and s["n_blocked"] == 3
    assert s["k_any"] == 1 and s["k_1pct"] == 1
    assert math.isnan(s["r_q99"]) and math.isnan(s["r_max"])


def test_ratio_stats_rejects_mismatched_shapes():
    with pytest.raises(InputError, match="ratio_stats"):
        ratio_stats(np.zeros((3, 3)), np.zeros((3, 3)), np.zeros(4))


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 400), seed=st.integers(0, 2**32 - 1))
def test_quantiles_match_numpy_higher(n, seed):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 3))
    y = x + rng.normal(size=(n, 3)) * rng.uniform(0, 3, size=(n, 1))
    b = rng.uniform(0.1, 1.0, size=n)
    s = ratio_stats(x, y, b)
    r = np.linalg.norm(y - x, axis=1) / b
    for q in QUANTILES:
        assert s[f"r_q{q}"] == np.percentile(r, q, method="higher")
    assert s["k_1pct"] == max(1, math.ceil(np.percentile(r, 99, method="higher")))
    assert s["k_any"] == max(1, math.ceil(r.max()))
    assert s["hit_rate"] == np.count_nonzero(r <= 1) / n
    # K_1pct is the smallest K with fewer than 1% of the vertices beyond K passes
    ks = [k for k in range(1, s["k_any"] + 1) if 100 * np.count_nonzero(r > k) < n]
    assert s["k_1pct"] == ks[0]
    assert s["r_hist"].sum() == n and s["r_hist"].size == R_HIST_EDGES.size - 1


# ---------------------------------------------------------------- replay


def test_replay_with_fixed_bounds_equals_static():
    rng = np.random.default_rng(7)
    x = rng.normal(size=(150, 3))
    y = x + rng.normal(size=(150, 3))
    b = rng.uniform(0.1, 0.6, size=150)
    b[3] = 0.0  # one blocked vertex
    s = ratio_stats(x, y, b)
    rp = replay_passes(x, y, lambda z: b, cap=100)
    assert (rp["k_any"], rp["k_1pct"], rp["capped"]) == (s["k_any"], s["k_1pct"], False)
    assert rp["n_blocked"] == 1


def test_replay_hand_built_growing_bounds():
    # One vertex from 0 to 10 along x; the bound at position p is 1 + p:
    # pass 1: b=1 -> 1; pass 2: b=2 -> 3; pass 3: b=4 -> 7; pass 4: b=8 >= 3 left -> done.
    x = np.zeros((1, 3))
    y = np.array([[10.0, 0, 0]])
    calls = []

    def bounds(z):
        calls.append(z[0, 0])
        return 1.0 + z[:, 0]

    rp = replay_passes(x, y, bounds, cap=64)
    assert rp == {"k_any": 4, "k_1pct": 4, "capped": False, "n_blocked": 0}
    np.testing.assert_allclose(calls, [0.0, 1.0, 3.0, 7.0], rtol=0, atol=1e-15)
    assert ratio_stats(x, y, bounds(x))["k_any"] == 10  # the static estimate


def test_replay_cap_and_first_bounds_reused():
    x = np.zeros((2, 3))
    y = np.array([[100.0, 0, 0], [0, 0, 0]])
    calls = []

    def bounds(z):
        calls.append(1)
        return np.ones(2)

    rp = replay_passes(x, y, bounds, cap=5, b0=np.ones(2))
    assert rp["capped"] and rp["k_any"] == 5
    assert len(calls) == 4  # pass 1 used b0


@pytest.mark.parametrize("n, k_1pct", [(100, 3), (101, 1)], ids=["1-of-100", "1-of-101"])
def test_replay_1pct_rule(n, k_1pct):
    x = np.zeros((n, 3))
    y = np.zeros((n, 3))
    y[:, 0] = 0.5
    y[0, 0] = 2.5  # needs 3 passes at b = 1
    rp = replay_passes(x, y, lambda z: np.ones(n))
    assert (rp["k_any"], rp["k_1pct"]) == (3, k_1pct)


# ---------------------------------------------------------------- projected time


# ---------------------------------------------------------------- compute_stats


def _rod_scene(rng, T=4, n=12):
    # Two parallel polylines 0.3 apart, drifting and wobbling.
    s = np.linspace(0, 1, n // 2)
    base = np.concatenate([np.c_[s, np.zeros_like(s), np.zeros_like(s)],
                           np.c_[s, np.full_like(s, 0.3), np.zeros_like(s)]])
    pos = np.stack([base + 0.02 * t * np.array([1.0, 0.2, 0.0]) + 0.01 * rng.normal(size=base.shape)
                    for t in range(T)])
    m = n // 2
    edges = np.array([[i, i + 1] for i in range(m - 1)] + [[m + i, m + i + 1] for i in range(m - 1)])
    return pos, edges


RNG_SEED = 20261121  # seed of the shared `rng` fixture (tests/conftest.py)


def test_compute_stats_against_direct_computation(rng):
    pos, edges = _rod_scene(rng)
    T = pos.shape[0]
    frames = np.arange(1, T)
    # a "deformed" state: the next frame for step 1 (perfect), x itself for the others
    deformed = pos[frames].copy()
    deformed[0] = pos[2]
    thickness, contact_radius = 0.01, 0.02

    def oracle(x, r_q):
        return brute_bounds(x, edges=edges, thickness=thickness, query_radius=r_q)

    st_ = compute_stats(pos, deformed=deformed, frames=frames, edges=edges, thickness=thickness, bounds_fn=oracle,
                        contact_radius=contact_radius)
    assert set(st_) == set(stats_keys(False))
    assert st_["frame"].tolist() == frames.tolist()
    for i, f in enumerate(frames):
        x, x_pred = pos[f], 2 * pos[f] - pos[f - 1]
        r_q = query_radius(x, x_pred, contact_radius)
        assert st_["query_radius"][i] == r_q  # the contact radius sizes the query, never the thickness
        assert r_q == pytest.approx(contact_radius + np.linalg.norm(pos[f] - pos[f - 1], axis=1).max(), rel=1e-15)
        for s, x_s in (("baseline", x), ("deformed", deformed[i])):
            b = oracle(x_s, r_q)
            targets = {"pred": x_pred, **({"next": pos[f + 1]} if f + 1 < T else {})}
            for t, y in targets.items():
                ref = ratio_stats(x_s, y, b)
                for k in ("hit_rate", "k_any", "k_1pct", "n_blocked", "r_q50", "r_max"):
                    assert st_[f"{k}_{t}_{s}"][i] == ref[k], (k, t, s, i)
                d = np.linalg.norm(x_s - y, axis=1)
                assert st_[f"residual_{t}_rms_{s}"][i] == pytest.approx(np.sqrt(np.mean(d**2)), rel=1e-14)
    # step 1 was deformed onto the next frame exactly
    assert st_["hit_rate_next_deformed"][0] == 1.0 and st_["residual_next_max_deformed"][0] == 0.0
    # steps where x_def = x give identical baseline and deformed figures
    assert st_["k_any_pred_deformed"][1] == st_["k_any_pred_baseline"][1]
    # the last frame has no next frame: NaN for every next figure
    last = T - 2
    for k in st_:
        if "_next_" in k:
            assert np.all(np.isnan(st_[k][last])), k
        if "_pred_" in k:
            assert np.all(np.isfinite(st_[k])), k


def test_compute_stats_from_result_like_object(rng):
    pos, edges = _rod_scene(rng, T=3)

    class Seq:
        positions, faces, thickness, contact_radius, obstacles = pos, None, 0.0, 0.0, ()

    Seq.edges = edges

    class Result:
        sequence = Seq
        steps = {"frame": np.array([1, 2]), "deformed": pos[[1, 2]].astype(np.float32)}

    seen = []
    st_ = compute_stats(Result, bounds_fn=lambda x, r: brute_bounds(x, edges=edges, query_radius=r),
                        replay=True, progress=lambda: seen.append(1))
    assert len(seen) == 2
    assert set(st_) == set(stats_keys(True))
    # x_def = x (up to float32 rounding of the stored deformed state)
    np.testing.assert_allclose(st_["residual_pred_rms_deformed"], st_["residual_pred_rms_baseline"], rtol=1e-6)
    assert np.all(st_["replay_k_any_pred_baseline"] >= 1)
    assert np.all(st_["replay_k_1pct_pred_baseline"] <= st_["replay_k_any_pred_baseline"])


def test_compute_stats_zero_motion_needs_no_bounds():
    pos = np.zeros((3, 4, 3))

    def boom(x, r_q):  # r_q = 0: the bounds are all 0 by definition, no query
        raise AssertionError("bounds_fn called with r_q = 0")

    st_ = compute_stats(pos, deformed=pos[1:], frames=[1, 2], bounds_fn=boom)
    assert st_["hit_rate_pred_baseline"].tolist() == [1.0, 1.0]
    assert st_["k_any_next_deformed"][0] == 1.0


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"deformed": np.zeros((2, 5, 3)), "frames": [1, 2]}, "deformed must be"),
        ({"deformed": np.zeros((2, 4, 3)), "frames": [0, 1]}, "step frames"),
        ({}, "needs a deform result"),
    ],
    ids=["wrong-N", "frame-0", "no-deformed"],
)
def test_compute_stats_rejects_bad_input(kw, match):
    with pytest.raises(InputError, match=match):
        compute_stats(np.zeros((3, 4, 3)), bounds_fn=lambda x, r: np.ones(4), **kw)


def _cloth_scene(rng, T=4, m=4):
    # A small wavy m x m sheet, drifting and flapping.
    u, v = np.meshgrid(np.linspace(0, 1, m), np.linspace(0, 1, m))
    base = np.c_[u.ravel(), v.ravel(), 0.1 * np.sin(3 * u.ravel())]
    pos = np.stack([base + 0.03 * t * np.array([0.5, 0.0, 1.0]) + 0.01 * rng.normal(size=base.shape)
                    for t in range(T)])
    q = np.arange(m * m).reshape(m, m)
    faces = np.concatenate([np.c_[q[:-1, :-1].ravel(), q[1:, :-1].ravel(), q[:-1, 1:].ravel()],
                            np.c_[q[1:, 1:].ravel(), q[:-1, 1:].ravel(), q[1:, :-1].ravel()]])
    return pos, faces


@pytest.mark.parametrize("kind", ["rods", "cloth"])
def test_compute_stats_default_bounds_match_oracle(rng, kind):
    if kind == "rods":
        pos, topo = _rod_scene(rng)
        kw = {"edges": topo}
    else:
        pos, topo = _cloth_scene(rng)
        kw = {"faces": topo}
    frames = np.arange(1, pos.shape[0])
    deformed = pos[frames] + 0.001
    a = compute_stats(pos, deformed=deformed, frames=frames, thickness=0.01, **kw)
    b = compute_stats(pos, deformed=deformed, frames=frames, thickness=0.01,
                      bounds_fn=lambda x, r: brute_bounds(x, thickness=0.01, query_radius=r, **kw), **kw)
    for k in a:
        np.testing.assert_allclose(a[k], b[k], rtol=1e-9, atol=0, err_msg=k)


@pytest.mark.parametrize("kind", ["rods", "cloth"])
def test_compute_stats_step_lists_equal_fresh_queries_bit_for_bit(rng, kind):
    # The default (one StepBounds list per step, at the reach of the last answers; the
    # replay states fresh) against fresh trust_region_bounds at every state.
    from penfree.core.trust.bounds import trust_region_bounds

    pos, topo = _rod_scene(rng, T=6, n=40) if kind == "rods" else _cloth_scene(rng, T=6, m=9)
    kw = {"edges": topo} if kind == "rods" else {"faces": topo}
    frames = np.arange(1, pos.shape[0])
    c = pos[frames].mean(axis=1, keepdims=True)
    deformed = 0.98 * (pos[frames] - c) + c + 0.3 * (pos[frames] - pos[frames - 1])
    a = compute_stats(pos, deformed=deformed, frames=frames, thickness=0.01, replay=True, **kw)
    b = compute_stats(pos, deformed=deformed, frames=frames, thickness=0.01, replay=True,
                      bounds_fn=lambda x, r: trust_region_bounds(x, thickness=0.01, query_radius=r, **kw), **kw)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_brute_bounds_oracle_hand_case():
    # Two parallel unit segments 0.5 apart plus a triangle-free far vertex: d = 0.5 for
    # the segments' vertices, r_q for the isolated vertex 3 (on no edge).
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 0.5, 0], [9, 9, 9], [1, 0.5, 0]], dtype=float)
    b = brute_bounds(x, edges=np.array([[0, 1], [2, 4]]), thickness=0.1, query_radius=2.0)
    np.testing.assert_allclose(b, DEFAULT_GAMMA * np.array([0.4, 0.4, 0.4, 1.9, 0.4]), rtol=1e-15, atol=0)


def test_compute_stats_positions_keyword_and_relabelling(rng):
    # The deform command calls compute_stats(positions=..., frames=..., deformed=...);
    # a vertex relabelling changes no figure.
    pos, edges = _rod_scene(rng)
    frames = np.arange(1, pos.shape[0])
    deformed = pos[frames] + 0.002

    def run(p, e, d):
        return compute_stats(positions=p, deformed=d, frames=frames, edges=e, thickness=0.005,
                             bounds_fn=lambda x, r: brute_bounds(x, edges=e, thickness=0.005, query_radius=r))

    perm = rng.permutation(pos.shape[1])
    inv = np.argsort(perm)
    a = run(pos, edges, deformed)
    b = run(pos[:, perm], inv[edges], deformed[:, perm])
    for k in a:
        np.testing.assert_allclose(a[k], b[k], rtol=1e-12, atol=0, err_msg=k)


@pytest.mark.parametrize("kind", ["rods", "cloth"])
@pytest.mark.parametrize("shuffled", [False, True], ids=["own-labels", "shuffled-relabelled"])
def test_step_bounds_answer_affine_images_from_the_list_bit_for_bit(rng, monkeypatch, kind, shuffled):
    # One neighbour list per step (built at the start x): the affine images of x (the
    # ladder's maps, a result's x_def) come from it, any other state (the prediction)
    # from a fresh query; every answer is trust_region_bounds' bit for bit. Shuffled:
    # the labels of a remesher, the lists and queries run on the scene's relabelling
    # (forced here on a small scene), the same bits in the caller's labels.
    from penfree.core.contact import locality
    from penfree.core.trust.bounds import trust_region_bounds

    pos, topo = _rod_scene(rng, n=40) if kind == "rods" else _cloth_scene(rng, m=9)
    if shuffled:
        monkeypatch.setattr(locality, "GAP_MIN", -1)
        monkeypatch.setattr(locality, "GAP_SHARE", 0.0)
        perm = rng.permutation(pos.shape[1])  # new vertex k is old vertex perm[k]
        inv = np.empty_like(perm)
        inv[perm] = np.arange(perm.size)
        pos, topo = np.ascontiguousarray(pos[:, perm]), np.ascontiguousarray(inv[topo][rng.permutation(len(topo))])
    kw = {"edges": topo} if kind == "rods" else {"faces": topo}
    sb = StepBounds.for_scene(pos[0], kw.get("edges"), kw.get("faces"), 0.01, DEFAULT_GAMMA)
    x, x_prev = pos[2].astype(np.float64), pos[1].astype(np.float64)
    r_q = 0.01 + float(np.linalg.norm(x - x_prev, axis=1).max()) + 0.05
    c, th = x.mean(axis=0), 0.4
    R = np.array([[np.cos(th), -np.sin(th), 0.0], [np.sin(th), np.cos(th), 0.0], [0.0, 0.0, 1.0]])
    states = {
        "start": (x, "listed"),
        "rotated": ((x - c) @ R.T + c + [0.3, -0.2, 0.1], "listed"),
        "sheared": (x @ np.array([[1.0, 0.02, 0.0], [0.0, 1.0, 0.01], [0.0, 0.0, 1.0]]).T, "listed"),
        # sigma_min 0.5: beyond the skin; listed below r_q and completed, or fresh
        "shrunk by half": (0.5 * (x - c) + c, None),
        "prediction": (2.0 * x - x_prev + 0.02 * rng.normal(size=x.shape), "fresh"),
    }
    sb.begin_step(x, r_q)
    for name, (z, how) in states.items():
        before = dict(sb.info)
        got = sb(z, r_q)
        ref = trust_region_bounds(z, thickness=0.01, gamma=DEFAULT_GAMMA, query_radius=r_q, **kw)
        np.testing.assert_array_equal(got, ref, err_msg=name)
        assert how is None or sb.info[how] == before[how] + 1, name
        assert (ref < DEFAULT_GAMMA * (r_q - 0.01)).any(), name  # some pair within reach
    assert sb.info["builds"] == 1
    # without begin_step, or with r_q = 0, every query is fresh and still exact
    sb2 = StepBounds.for_scene(pos[0], kw.get("edges"), kw.get("faces"), 0.01, DEFAULT_GAMMA)
    np.testing.assert_array_equal(sb2(x, r_q), trust_region_bounds(x, thickness=0.01, query_radius=r_q, **kw))
    assert sb2.info == {"listed": 0, "fresh": 1, "builds": 0, "completed": 0, "relabelled": shuffled}
    assert sb.info["relabelled"] == shuffled


@pytest.mark.parametrize("kind", ["rods", "cloth"])
@pytest.mark.parametrize("reach_rel", [None, 0.5, 0.85, 1.05], ids=["remembered", "half", "below", "above"])
def test_step_bounds_at_a_reach_bit_for_bit(rng, monkeypatch, kind, reach_rel):
    # The list of a later step is built at the reach of the last answers (below r_q); a
    # state it covers only up to `cover` < r_q is answered from it and its vertices at the
    # cap completed at r_q (every vertex, with COMPLETE_MAX 1, at the smaller reaches).
    from penfree.core.contact import proximity
    from penfree.core.trust.bounds import trust_region_bounds

    monkeypatch.setattr(proximity, "COMPLETE_MAX", 1.0)
    pos, topo = _rod_scene(rng, n=40) if kind == "rods" else _cloth_scene(rng, m=9)
    kw = {"edges": topo} if kind == "rods" else {"faces": topo}
    sb = StepBounds.for_scene(pos[0], kw.get("edges"), kw.get("faces"), 0.01, DEFAULT_GAMMA)
    x, x_prev = pos[2].astype(np.float64), pos[1].astype(np.float64)
    r_q = 0.01 + float(np.linalg.norm(x - x_prev, axis=1).max()) + 0.3
    c = x.mean(axis=0)
    th = 0.3
    R = np.array([[np.cos(th), -np.sin(th), 0.0], [np.sin(th), np.cos(th), 0.0], [0.0, 0.0, 1.0]])
    states = [x, (x - c) @ R.T + c, 0.97 * (x - c) + c, 2.0 * x - x_prev]
    for step in range(2):
        sb.begin_step(x, r_q)
        if step == 1:
            assert sb.nl.r_b < r_q  # built at the reach
        for z in states:
            ref = trust_region_bounds(z, thickness=0.01, gamma=DEFAULT_GAMMA, query_radius=r_q, **kw)
            np.testing.assert_array_equal(sb(z, r_q), ref)
        if step == 0 and reach_rel is not None:
            d = proximity.per_vertex_separation(x, sb.E, sb.F, r_q)
            sb.query.reach = reach_rel * float(d.max())  # the list's cover: 1.1 times this
    assert sb.info["listed"] >= 5
    if reach_rel is not None and reach_rel < 1.0:
        assert sb.info["completed"] > 0


@pytest.mark.parametrize("da, db", [(np.float64, np.float64), (np.float32, np.float64), (np.float32, np.float32)])
@pytest.mark.parametrize("offset", [0.0, 1e4])
@pytest.mark.parametrize("n", [1, 7, 64, 1000])
def test_residual_summary_against_numpy(rng, da, db, offset, n):
    # The numpy oracle: per-vertex distances in float64, rms of them and their max. The
    # max is the same float (sqrt is monotone and both square and sum x, y, z in order).
    a = (rng.normal(size=(n, 3)) + offset).astype(da)
    b = (a.astype(np.float64) + 1e-3 * rng.normal(size=(n, 3))).astype(db)
    d = np.linalg.norm(a.astype(np.float64) - b.astype(np.float64), axis=1)
    rms, top = residual_summary(a, b)
    assert top == d.max()
    assert rms == pytest.approx(math.sqrt(np.mean(d * d)), rel=1e-13)


def test_residual_summary_zero_motion_nan_and_bad_shapes(rng):
    a = rng.normal(size=(50, 3))
    assert residual_summary(a, a) == (0.0, 0.0)
    b = a.copy()
    b[17, 1] = np.nan
    assert all(math.isnan(v) for v in residual_summary(a, b))
    b[17, 1] = np.inf
    assert residual_summary(a, b) == (math.inf, math.inf)
    with pytest.raises(InputError, match="one shape"):
        residual_summary(a, a[:-1])
    with pytest.raises(InputError, match="at least one"):
        residual_summary(a[:0], a[:0])


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("offset", [0.0, 1e5])
@pytest.mark.parametrize("n", [0, 1, 33, 5000])
def test_query_radius_bit_for_bit_against_numpy(rng, dtype, offset, n):
    # r_q sizes every query of a step: its bits must be numpy's contact + max |x_pred - x|.
    x = (rng.normal(size=(n, 3)) + offset).astype(dtype)
    x_pred = 2.0 * x.astype(np.float64) - (x + 1e-3 * rng.normal(size=(n, 3))).astype(dtype)
    d = np.linalg.norm(x_pred - x.astype(np.float64), axis=1)
    want = 0.0125 + (float(d.max()) if n else 0.0)
    assert query_radius(x, x_pred, 0.0125) == want
    if n:
        x_pred[n // 2, 0] = np.nan
        assert math.isnan(query_radius(x, x_pred, 0.0125))
    with pytest.raises(InputError, match="one shape"):
        query_radius(x, x_pred[:, :2], 0.0)
