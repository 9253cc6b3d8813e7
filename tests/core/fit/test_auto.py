"""Collision-aware model choice: the predictor is never optimistic, the choice rule is
the documented one, every chosen map is certified."""

import numba
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from penfree import constants as K
from penfree.core.fit import models as _fit
from penfree.core.fit.certificate import certify
from penfree.core.fit.projection import project_sym
from penfree.core.fit.auto import (
    Candidate, candidate_maps, choose, predict_map_passes, predict_passes, predicted_bounds, select_step,
    sigma_min_lower_bound,
)
from penfree.core.fit.auto_kernels import predict_kernel
from penfree.core.trust.stats import ratio_stats
from penfree.core.trust.bounds import scene_arrays, per_vertex_separation, trust_region_bounds
from penfree.errors import InputError


def rod_scene(rng, n_rods=4, n_per=12):
    """Parallel wavy rods along x, 0.3 apart in y."""
    V, E = [], []
    for r in range(n_rods):
        t = np.linspace(0, 1, n_per)
        pts = np.stack([t, 0.3 * r + 0.03 * np.sin(6 * t + r), 0.02 * rng.standard_normal(n_per)], axis=1)
        base = r * n_per
        V.append(pts)
        E += [[base + i, base + i + 1] for i in range(n_per - 1)]
    return np.concatenate(V), np.array(E), None


def cloth_scene(rng, n=8):
    g = np.linspace(0, 1, n)
    X, Y = np.meshgrid(g, g, indexing="ij")
    V = np.stack([X.ravel(), Y.ravel(), 0.05 * np.sin(5 * X.ravel()) + 0.01 * rng.standard_normal(n * n)], axis=1)
    F = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, i * n + j + 1, (i + 1) * n + j + 1
            F += [[a, b, c], [b, d, c]]
    return V, None, np.array(F)


def random_certified_D(rng, scale):
    D = scale * rng.standard_normal((3, 3))
    D = project_sym(D, 0.0)
    A = np.eye(3) + D
    assert certify(A, 0.0)
    return A - np.eye(3)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), kind=st.sampled_from(["rods", "cloth"]),
       scale=st.sampled_from([0.01, 0.1, 0.4]), thickness=st.sampled_from([0.0, 0.01, 0.05]))
def test_predicted_bound_never_exceeds_recomputed_bound(seed, kind, scale, thickness):
    rng = np.random.default_rng(seed)
    V, E, F = rod_scene(rng) if kind == "rods" else cloth_scene(rng)
    D = random_certified_D(rng, scale)
    u = 0.05 * rng.standard_normal(3)
    c = V.mean(axis=0)
    x_def = V + (V - c) @ D.T + u
    r_q = thickness + 0.2
    _, E_, F_ = scene_arrays(V, E, F)
    d_start = per_vertex_separation(np.ascontiguousarray(V), E_, F_, r_q)
    b_hat = predicted_bounds(d_start, sigma_min_lower_bound(np.eye(3) + D), r_q, thickness)
    b_def = trust_region_bounds(x_def, edges=E, faces=F, thickness=thickness, query_radius=r_q)
    assert np.all(b_hat <= b_def), float(np.max(b_hat - b_def))


@pytest.mark.parametrize("A", [
    np.diag([0.5, 1.0, 2.0]),
    np.array([[1.0, 0.3, 0.0], [0.0, 0.2, 0.0], [0.0, 0.0, 1.0]]),
    np.eye(3),
], ids=["diagonal", "shear-compress", "identity"])
def test_sigma_lower_bound_against_svd(A):
    s = np.linalg.svd(A, compute_uv=False)[-1]
    lb = sigma_min_lower_bound(A)
    assert lb <= s
    assert lb >= s - 1e-12


def test_predict_passes_matches_ratio_stats():
    rng = np.random.default_rng(3)
    x = rng.random((500, 3))
    y = x + 0.05 * rng.standard_normal((500, 3))
    b = rng.random(500) * 0.05
    b[:7] = 0.0
    p, r = predict_passes(x, y, b), ratio_stats(x, y, b)
    for key in ("hit_rate", "k_1pct", "k_any", "n_blocked"):
        assert p[key] == r[key], key
    assert p["r_q99"] == r["r_q99"]


def _cand(name, k, q99):
    c = Candidate(name, np.eye(3), np.zeros((3, 3)), np.zeros(3), 0, "none", 1.0, 1.0)
    c.predicted = {"k_1pct": k, "r_q99": q99}
    return c


@pytest.mark.parametrize("table, expected", [
    ([("none", 3, 2.5), ("translation", 2, 1.9), ("affine", 2, 1.2)], 2),    # equal K, clearly lower q99
    ([("none", 3, 2.5), ("translation", 2, 1.9), ("affine", 2, 1.89)], 1),   # near tie -> simpler
    ([("none", 2, 1.5), ("translation", 3, 2.1), ("affine", 4, 3.5)], 0),    # nothing beats doing nothing
    ([("none", 2, 1.5), ("translation", 2, 1.6), ("affine", 1, 0.9)], 2),    # fewer passes wins
    ([("none", 1, 1e-16), ("translation", 1, 0.0)], 0),                      # rounding noise is no signal
], ids=["lower-q99", "near-tie-simpler", "fallback-none", "fewer-passes", "rounding-tie"])
def test_choose_rule(table, expected):
    assert choose([_cand(*row) for row in table]) == expected


def test_zero_motion_chooses_doing_nothing():
    rng = np.random.default_rng(0)
    V, E, F = rod_scene(rng)
    _, E_, F_ = scene_arrays(V, E, F)
    d = per_vertex_separation(V, E_, F_, 0.1)
    r, table = select_step(V, V, d, r_q=0.1)
    assert r.model == "none"
    np.testing.assert_array_equal(r.x_def, V)


def test_pure_translation_chooses_translation():
    # The translation reaches x_pred exactly; doing nothing leaves r = 0.2 / b >> 1.
    rng = np.random.default_rng(1)
    V, E, F = rod_scene(rng)
    x_prev = V - np.array([0.2, 0.0, 0.0])
    r_q = 0.2
    _, E_, F_ = scene_arrays(V, E, F)
    d = per_vertex_separation(V, E_, F_, r_q)
    r, table = select_step(x_prev, V, d, r_q=r_q)
    assert r.model == "translation"
    assert table[0]["k_1pct"] > 1 and table[1]["k_1pct"] == 1
    np.testing.assert_allclose(r.x_def, V + [0.2, 0, 0], rtol=0, atol=1e-12)


def test_compression_is_not_chosen_when_it_shrinks_the_bounds():
    # Two rods 0.3 apart; the prediction squeezes the gap five-fold (affine) and every
    # vertex also jitters by 0.01. The affine map reaches the squeeze, but its predicted
    # bounds shrink five-fold and the jitter is left: more predicted passes than doing
    # nothing, so the choice must avoid it. (The global sigma scaling is pessimistic
    # here: the nearest gaps run along the rods, which the squeeze does not compress.)
    rng = np.random.default_rng(2)
    V, E, _ = rod_scene(rng, n_rods=2, n_per=40)
    c = V.mean(axis=0)
    x_pred = c + (V - c) @ np.diag([1.0, 0.2, 1.0]).T + 0.01 * rng.standard_normal(V.shape)
    x_prev = 2 * V - x_pred
    r_q = float(np.linalg.norm(x_pred - V, axis=1).max())
    _, E_, F_ = scene_arrays(V, E, None)
    d = per_vertex_separation(V, E_, F_, r_q)
    r, table = select_step(x_prev, V, d, r_q=r_q)
    rows = {t["name"]: t for t in table}
    assert rows["affine"]["k_1pct"] > rows["none"]["k_1pct"]
    assert r.model != "affine"
    assert rows[r.model]["k_1pct"] <= min(rows["none"]["k_1pct"], rows["rigid"]["k_1pct"])

    def actual_k(x_s):
        b = trust_region_bounds(x_s, edges=E, thickness=0.0, query_radius=r_q)
        return ratio_stats(x_s, x_pred, b)["k_1pct"]

    m = _fit.fit_moments(x_prev, V)
    aff = next(cd for cd in candidate_maps(m) if cd.name == "affine")
    x_aff, _ = _fit.apply_map(V, aff.D, aff.u, m.c)
    # never optimistic: the recomputed passes are at most the predicted ones
    assert actual_k(r.x_def) <= rows[r.model]["k_1pct"]
    assert actual_k(x_aff) <= rows["affine"]["k_1pct"]


@pytest.mark.parametrize("margin", [0.0, 0.3, 0.9], ids=["m0", "m0.3", "m0.9"])
def test_every_candidate_and_choice_is_certified(margin):
    rng = np.random.default_rng(5)
    V, E, F = cloth_scene(rng)
    # A 170-degree rotation with an anisotropic stretch predicted: the raw affine fit
    # is not certifiable; every candidate offered must still pass the exact test.
    th = np.deg2rad(170.0)
    R = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    A_pred = R @ np.diag([1.5, 0.6, 1.0])
    x_pred = V @ A_pred.T
    x_prev = 2 * V - x_pred
    m = _fit.fit_moments(x_prev, V)
    for cand in candidate_maps(m, margin):
        assert certify(cand.A, margin), cand.name
        np.testing.assert_array_equal(cand.D, cand.A - np.eye(3))
    r_q = float(np.linalg.norm(x_pred - V, axis=1).max())
    _, E_, F_ = scene_arrays(V, E, F)
    d = per_vertex_separation(V, E_, F_, r_q)
    r, _ = select_step(x_prev, V, d, r_q=r_q, margin=margin)
    assert certify(r.A, margin)
    np.testing.assert_allclose(r.x_def, V @ r.A.T + r.b, rtol=0, atol=1e-12)


# --- the fused predictor against apply_map + predict_passes -------------------


def _scene_step(kind, dtype, offset, seed):
    """A small step with a non-affine prediction, some still vertices and some zero gaps."""
    rng = np.random.default_rng(seed)
    V, E, F = rod_scene(rng, n_rods=6, n_per=40) if kind == "rods" else cloth_scene(rng, n=24)
    V = V + offset
    c = V.mean(axis=0)
    th = 0.05
    R = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    x_pred = c + (V - c) @ (R @ np.diag([1.02, 0.97, 1.0])).T + 0.004 + 0.003 * rng.standard_normal(V.shape)
    x_pred[:5] = V[:5]  # vertices that do not move: r = 0 whatever their bound
    x = V.astype(dtype)
    x_prev = (2 * V - x_pred).astype(dtype)
    r_q = 0.01 + float(np.linalg.norm(x_pred - V, axis=1).max())
    _, E_, F_ = scene_arrays(V, E, F)
    d = per_vertex_separation(np.ascontiguousarray(V), E_, F_, r_q)
    d[5:7] = 0.0  # blocked: must move but have no room (under 1% of the vertices)
    return x_prev, x, d, r_q


#: The thickness of the fused-prediction tests; `_scene_step`'s vertex 7 rests just above it.
_THICKNESS = 0.01


@pytest.mark.parametrize("dtype", [np.float64, np.float32], ids=["float64", "float32"])
@pytest.mark.parametrize("kind, offset", [("rods", 0.0), ("cloth", 0.0), ("cloth", 1e3)],
                         ids=["rods", "cloth", "far-from-origin"])
def test_fused_prediction_matches_apply_then_predict(kind, offset, dtype):
    x_prev, x, d, r_q = _scene_step(kind, dtype, offset, seed=11)
    thickness = _THICKNESS
    d[7] = thickness * (1.0 + 1e-9)  # a positive start bound that a shrinking map's sigma takes to 0
    m = _fit.fit_moments(x_prev, x)
    x_pred = 2.0 * x.astype(np.float64) - x_prev.astype(np.float64)
    eps = np.finfo(dtype).eps
    r_buf = np.empty(len(x))
    cands = candidate_maps(m)
    assert len(cands) >= 8
    for cand in cands:
        x_def, _ = _fit.apply_map(x, cand.D, cand.u, m.c)
        nothing = cand.name == "none"
        # Doing nothing: the start bounds exactly, zero bounds blocked (left out).
        # Any map: lower bounds; a zero start bound is blocked as for doing nothing, a
        # positive one that the map's sigma takes to 0 gives r = inf (counted).
        sigma = 1.0 / (1.0 - K.PREDICT_SLACK_REL) if nothing else cand.sigma_lb
        b = predicted_bounds(d, sigma, r_q, thickness)
        b0 = K.DEFAULT_GAMMA * np.maximum(0.0, np.minimum(r_q, d) - thickness)
        ref = predict_passes(x_def, x_pred, b, b_start=None if nothing else b0)
        got = predict_map_passes(x_prev, x, cand.D, cand.u, m.c, d, cand.sigma_lb, r_q, thickness)
        s = 1.0 if nothing else cand.sigma_lb * (1.0 - K.PREDICT_SLACK_REL)
        counts = predict_kernel(x_prev, x, cand.D, cand.u, m.c, d, s, r_q, thickness, K.DEFAULT_GAMMA, r_buf)
        assert counts == (round(ref["hit_rate"] * len(x)), ref["n_blocked"])
        assert list(got) == list(ref)
        for key in ("hit_rate", "n_blocked", "k_1pct", "k_any"):
            assert got[key] == ref[key], (cand.name, key)
        assert ref["n_blocked"] == 2  # vertices 5 and 6, for every candidate
        # Per vertex: x_def may differ from apply_map's in its last bit (apply_map fuses
        # multiply-adds; a float32 store can then round the other way), so r may differ
        # by one unit of x_def's dtype at the largest coordinate, divided by the bound.
        dist = np.linalg.norm(x_pred - x_def.astype(np.float64), axis=1)
        zero_b = (dist > 0) & ~(b > 0)
        blocked = zero_b & ~(b0 > 0)
        r_ref = np.where(blocked, -np.inf, np.where(zero_b, np.inf,
                         np.where(dist > 0, dist / np.where(b > 0, b, 1.0), 0.0)))
        tol = np.where(b > 0, 2.0 * np.sqrt(3.0) * eps * np.abs(x_def).max() / np.where(b > 0, b, 1.0), 0.0)
        assert np.array_equal(r_buf == -np.inf, blocked) and np.array_equal(r_buf == np.inf, zero_b & ~blocked)
        assert np.flatnonzero(blocked).tolist() == [5, 6]
        # Vertex 7 counts as r = inf exactly for the maps whose sigma may shrink its gap.
        assert (got["k_any"] == K.K_UNBOUNDED) == (not nothing and s * d[7] <= thickness)
        ok = ~zero_b
        assert np.all(np.abs(r_buf[ok] - r_ref[ok]) <= tol[ok]), cand.name
        tol_q = tol[ok].max()
        np.testing.assert_allclose(got["r_q99"], ref["r_q99"], rtol=0, atol=tol_q)
        np.testing.assert_allclose(got["r_max"], ref["r_max"], rtol=0, atol=tol_q)


def test_fused_prediction_exact_for_doing_nothing():
    # D = 0, u = 0 reproduces x bit for bit, so the fused predictor equals the numpy one.
    x_prev, x, d, r_q = _scene_step("rods", np.float64, 0.0, seed=12)
    x_pred = 2.0 * x - x_prev
    b = K.DEFAULT_GAMMA * np.maximum(0.0, np.minimum(r_q, d))  # the start bounds, thickness 0
    got = predict_map_passes(x_prev, x, np.zeros((3, 3)), np.zeros(3), np.zeros(3), d, 1.0, r_q)
    assert got == predict_passes(x, x_pred, b)
    assert got["n_blocked"] == 2


def test_all_blocked_prediction():
    x_prev, x, d, r_q = _scene_step("rods", np.float64, 0.0, seed=13)
    x_prev = x - 0.01  # everything moves
    got = predict_map_passes(x_prev, x, np.zeros((3, 3)), np.zeros(3), np.zeros(3), np.zeros(len(x)), 1.0, r_q)
    assert got == predict_passes(x, 2.0 * x - x_prev, np.zeros(len(x)))
    assert got["n_blocked"] == len(x) and got["k_1pct"] == 1 and got["hit_rate"] == 0.0


def test_select_step_deterministic_across_thread_counts(monkeypatch):
    from penfree import constants

    monkeypatch.setattr(constants, "FIT_BUILD", "parallel")  # force the parallel kernels
    x_prev, x, d, r_q = _scene_step("cloth", np.float32, 0.0, seed=14)
    old = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        r1, t1 = select_step(x_prev, x, d, r_q=r_q, thickness=0.01)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        r2, t2 = select_step(x_prev, x, d, r_q=r_q, thickness=0.01)
    finally:
        numba.set_num_threads(old)
    assert t1 == t2
    assert np.array_equal(r1.x_def, r2.x_def) and np.array_equal(r1.A, r2.A)


def test_select_step_checks_d_start():
    x_prev, x, d, r_q = _scene_step("rods", np.float64, 0.0, seed=15)
    with pytest.raises(InputError, match="d_start must be"):
        select_step(x_prev, x, d[:-1], r_q=r_q)


@pytest.mark.parametrize("change, match", [
    (dict(x_prev=np.zeros((5, 3))), "x_prev must have the same N"),
    (dict(d_start=np.ones(5)), "d_start must be"),
    (dict(D=np.zeros((2, 3))), "D, u, c must be"),
    (dict(c=np.zeros(2)), "D, u, c must be"),
    (dict(r_buf=np.empty(5)), "r_buf must be"),
    (dict(r_buf=np.empty(10, dtype=np.float32)), "r_buf must be"),
], ids=["x_prev-N", "d_start-N", "D-shape", "c-shape", "r_buf-N", "r_buf-dtype"])
def test_predict_map_passes_checks_its_arrays(change, match):
    # The kernel indexes without bounds checks: every size it relies on is validated.
    x = np.random.default_rng(16).random((10, 3))
    args = dict(x_prev=x - 0.01, x=x, D=np.zeros((3, 3)), u=np.zeros(3), c=np.zeros(3), d_start=np.ones(10),
                sigma=1.0, r_q=1.0)
    args.update(change)
    with pytest.raises(InputError, match=match):
        predict_map_passes(**args)


def test_zero_predicted_bound_is_not_left_out():
    # Vertices that rest at the thickness (gap barely above it, as after an OGC
    # truncation) have tiny positive bounds. A map that may shrink gaps predicts 0 for
    # them; leaving them out of K (as blocked) would be optimistic, since the
    # recomputed bound is tiny and positive and its ratio huge. They must count as
    # r = inf, so that any map moving them loses to doing nothing.
    rng = np.random.default_rng(21)
    n = 400
    x = rng.uniform(-1, 1, (n, 3))
    x_prev = x - 0.01 * np.array([1.0, 0.5, 0.0]) - 0.001 * rng.standard_normal((n, 3))
    thickness, r_q = 0.05, 0.2
    d = np.full(n, r_q)
    stuck = np.arange(20)  # 5 %: they do not move in the prediction and sit at the thickness
    d[stuck] = thickness * (1.0 + 1e-9)
    x_prev[stuck] = x[stuck]
    squeeze = np.diag([0.99, 1.0, 1.0]) - np.eye(3)
    got = predict_map_passes(x_prev, x, squeeze, np.zeros(3), x.mean(0), d, 0.99, r_q, thickness)
    assert got["n_blocked"] == 0 and got["k_1pct"] == K.K_UNBOUNDED and np.isinf(got["r_q99"])
    # Doing nothing keeps the exact start bounds: the stuck vertices do not move (r = 0).
    none = predict_map_passes(x_prev, x, np.zeros((3, 3)), np.zeros(3), np.zeros(3), d, 1.0, r_q, thickness)
    assert none["k_1pct"] < K.K_UNBOUNDED and none["n_blocked"] == 0
    # And the choice: every candidate moves the stuck vertices, so nothing wins.
    res, table = select_step(x_prev, x, d, r_q=r_q, thickness=thickness)
    assert res.model == "none"
    # (A map that expands, like the similarity here, keeps a tiny positive bound: finite
    # but huge.)
    assert all(row["k_1pct"] > 1000 for row in table if row["name"] != "none"), table
    assert any(row["k_1pct"] == K.K_UNBOUNDED for row in table)


def _numpy_upper(r, rank):
    p = np.partition(r, rank)
    return float(p[rank]), float(p[rank:].max())


@pytest.mark.parametrize("n", [1, 2, 3, 17, 1000, 4097, 70000])
def test_upper_quantile_equals_numpy_partition(rng, n):
    # Ties, infinities (blocked -inf, unbounded +inf), sorted and reversed orders, and
    # ranks from 0 to n - 1: the same floats as numpy's partition.
    from penfree.core.fit.auto_kernels import upper_quantile

    cases = {
        "random": rng.random(n),
        "ties": rng.integers(0, 4, n).astype(np.float64),
        "blocked": np.where(rng.random(n) < 0.3, -np.inf, rng.exponential(size=n)),
        "unbounded": np.where(rng.random(n) < 0.02, np.inf, rng.random(n)),
        "sorted": np.sort(rng.random(n)),
        "reversed": np.sort(rng.random(n))[::-1].copy(),
        "zeros": np.zeros(n),
        "heavy-tail": rng.pareto(0.5, n),
    }
    ranks = sorted({0, n // 2, (99 * (n - 1) + 99) // 100, n - 2, n - 1} - {-1})
    for name, r in cases.items():
        for rank in ranks:
            got = upper_quantile(r.copy(), rank)
            assert got == _numpy_upper(r, rank), (name, rank)


def test_upper_quantile_takes_numpy_for_nan_and_missed_thresholds(rng):
    from penfree.core.fit import auto_kernels

    r = rng.random(50000)
    r[123] = np.nan  # numpy sorts NaN last: the percentile is a number, the maximum NaN
    got = auto_kernels.upper_quantile(r.copy(), 49000)
    want = _numpy_upper(r, 49000)
    assert got[0] == want[0] and np.isnan(got[1]) and np.isnan(want[1])
    # The thresholded selection itself declines rather than guess.
    assert not auto_kernels._upper_select(r, 49000)[2]
    assert not auto_kernels._upper_select(np.zeros(50000), 49000)[2]  # all at the threshold
    assert auto_kernels._upper_select(rng.random(50000), 49500)[2]


def test_a_zero_start_bound_is_left_out_for_every_candidate():
    # A recording with a few pre-existing crossings (or vertices resting inside the
    # thickness): 5% of the vertices have a zero start bound. They are stuck whatever
    # the map, so they are left out of K for every candidate as for doing nothing;
    # counting them as r = inf made every moving candidate's K_1pct unbounded, and
    # `auto` then never moved such a recording.
    rng = np.random.default_rng(22)
    n = 400
    x = rng.uniform(-1, 1, (n, 3))
    v = np.array([0.01, 0.005, 0.0])
    x_prev = x - v - 1e-4 * rng.standard_normal((n, 3))
    thickness, r_q = 0.05, 0.06  # bounds 0.0045: doing nothing needs 3 passes
    d = np.full(n, r_q)
    stuck = np.arange(0, n, 20)  # 5 %
    d[stuck[::2]] = 0.0  # crossing
    d[stuck[1::2]] = 0.5 * thickness  # inside the thickness
    none = predict_map_passes(x_prev, x, np.zeros((3, 3)), np.zeros(3), np.zeros(3), d, 1.0, r_q, thickness)
    shift = predict_map_passes(x_prev, x, np.zeros((3, 3)), v, np.zeros(3), d, 1.0, r_q, thickness)
    assert none["n_blocked"] == shift["n_blocked"] == len(stuck)
    assert shift["k_1pct"] < none["k_1pct"] < K.K_UNBOUNDED
    # The numpy reading agrees: blocked where the start bound is 0, whatever the map.
    b0 = K.DEFAULT_GAMMA * np.maximum(0.0, np.minimum(r_q, d) - thickness)
    ref = predict_passes(x + v, 2.0 * x - x_prev, b0 * (1.0 - K.PREDICT_SLACK_REL), b_start=b0)
    assert ref["n_blocked"] == len(stuck) and ref["k_1pct"] == shift["k_1pct"]
    res, table = select_step(x_prev, x, d, r_q=r_q, thickness=thickness)
    assert res.model != "none"
    assert np.allclose(res.x_def - x, v, atol=2e-3)
