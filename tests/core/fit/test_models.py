"""Fit: moments and models against lstsq / exact-Fraction oracles, rank and noise handling."""

from fractions import Fraction

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from penfree.core.fit import models as F
from penfree.errors import InputError

from _geom import rot, prev_for


RNG_SEED = 7  # seed of the shared `rng` fixture (tests/conftest.py)


def lstsq_fit(x_prev, x, w=None):
    """Oracle: weighted lstsq of d = x - x_prev on the homogeneous N x 4 system [x, 1]."""
    x = x.astype(np.float64)
    d = x - x_prev.astype(np.float64)
    H = np.c_[x, np.ones(len(x))]
    s = np.ones(len(x)) if w is None else np.sqrt(w)
    coef = np.linalg.lstsq(H * s[:, None], d * s[:, None], rcond=None)[0]
    D = coef[:3].T
    wn = np.ones(len(x)) if w is None else w
    return D, (wn @ d) / wn.sum()


def fit(x_prev, x, w=None, model="affine", slope_tol=None):
    m = F.fit_moments(x_prev, x, w)
    used, D, u, r = F.fit_model(m, model, slope_tol)
    return m, D, u, r


# --- moments --------------------------------------------------------------------------


def exact_moments(x_prev, x, w):
    xf = [[Fraction(float(v)) for v in row] for row in x]
    df = [[Fraction(float(a)) - Fraction(float(b)) for a, b in zip(r1, r0)] for r1, r0 in zip(x, x_prev)]
    wf = [Fraction(float(v)) for v in w]
    W = sum(wf)
    c = [sum(wi * xi[k] for wi, xi in zip(wf, xf)) / W for k in range(3)]
    u = [sum(wi * di[k] for wi, di in zip(wf, df)) / W for k in range(3)]
    P = [[xi[k] - c[k] for k in range(3)] for xi in xf]
    Q = [[di[k] - u[k] for k in range(3)] for di in df]
    C = [[sum(wi * p[a] * p[b] for wi, p in zip(wf, P)) for b in range(3)] for a in range(3)]
    G = [[sum(wi * q[a] * p[b] for wi, p, q in zip(wf, P, Q)) for b in range(3)] for a in range(3)]
    return c, u, C, G


def _rel(a, exact):
    """Largest exact error of float array `a` against Fractions, relative to the largest exact entry."""
    ex = np.ravel(np.array(exact, dtype=object))
    err = max(abs(Fraction(float(v)) - e) for v, e in zip(np.ravel(a), ex))
    return float(err / max(abs(e) for e in ex))


@pytest.mark.parametrize("offset", [0.0, 1e6], ids=["at-origin", "far-from-origin"])
def test_moments_match_exact_fractions(rng, offset):
    n = 60
    x = offset + rng.standard_normal((n, 3))
    M = 0.1 * rng.standard_normal((3, 3))  # millimetre motion: translation, strain, noise
    x_prev = x - 1e-3 * (1.0 + (x - offset) @ M.T + 0.1 * rng.standard_normal((n, 3)))
    w = rng.uniform(0.0, 2.0, n)
    m = F.fit_moments(x_prev, x, w)
    c, u, C, G = exact_moments(x_prev, x, w)
    assert _rel(m.c, c) <= 4 * np.finfo(float).eps
    assert _rel(m.u, u) <= 1e-12
    assert _rel(m.C, C) <= 1e-12
    assert _rel(m.G, G) <= 1e-12


def test_far_from_origin_naive_moments_would_lose_digits(rng):
    # The oracle test above is not vacuous: uncentred raw second moments lose
    # ~12 digits at a 1e6 offset, centring afterwards cannot recover them.
    x = 1e6 + rng.standard_normal((60, 3))
    c = x.mean(axis=0)
    C_raw = x.T @ x - 60 * np.outer(c, c)
    C_ok = F.fit_moments(x, x).C
    assert np.abs(C_raw - C_ok).max() / np.abs(C_ok).max() > 1e-6


def test_far_from_origin_fit_no_digits_lost(rng):
    n = 200
    P = rng.standard_normal((n, 3))
    A = np.eye(3) + 1e-3 * rng.standard_normal((3, 3))
    b = np.array([1e-3, -2e-3, 5e-4])
    x0 = P + 1e6
    _, D0, u0, _ = fit(prev_for(P, A, b), P)
    _, D, u, r = fit(prev_for(x0, A, b), x0)
    # Exact affine data: D from the far copy matches the true map to what the
    # input rounding (1e6 * eps ~ 1e-10 on mm motion) allows, and the origin copy.
    assert r == 3
    np.testing.assert_allclose(D, A - np.eye(3), rtol=0, atol=1e-9)
    np.testing.assert_allclose(D0, A - np.eye(3), rtol=0, atol=1e-13)


# --- models on exact data -----------------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(4, 60), weighted=st.booleans())
def test_random_affine_map_is_recovered(seed, n, weighted):
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((n, 3)) * rng.uniform(0.1, 10)
    A = np.eye(3) + 0.2 * rng.standard_normal((3, 3))
    b = rng.standard_normal(3)
    w = rng.uniform(0.1, 2.0, n) if weighted else None
    m, D, u, r = fit(prev_for(x, A, b), x, w)
    if np.linalg.eigvalsh(m.C)[0] < 1e-6 * np.linalg.eigvalsh(m.C)[-1]:
        return  # nearly degenerate draw; rank cases are tested separately
    assert r == 3
    scale = np.abs(A - np.eye(3)).max() + 1.0
    np.testing.assert_allclose(D, A - np.eye(3), rtol=0, atol=1e-10 * scale)
    u_tol = 1e-10 * (np.abs(b).max() + scale * np.abs(x).max())
    np.testing.assert_allclose(u, (A - np.eye(3)) @ m.c + b, rtol=0, atol=u_tol)


@pytest.mark.parametrize("weighted", [False, True], ids=["unweighted", "weighted"])
def test_affine_matches_lstsq(rng, weighted):
    n = 300
    x = rng.standard_normal((n, 3))
    A = np.eye(3) + 0.05 * rng.standard_normal((3, 3))
    x_prev = prev_for(x, A, np.array([0.01, 0.0, -0.02])) + 1e-3 * rng.standard_normal((n, 3))
    w = rng.uniform(0.0, 3.0, n) if weighted else None
    if weighted:
        w[:10] = 0.0  # zero weights are allowed
    _, D, u, r = fit(x_prev, x, w)
    D_ls, u_ls = lstsq_fit(x_prev, x, w)
    assert r == 3
    np.testing.assert_allclose(D, D_ls, rtol=0, atol=1e-12)
    np.testing.assert_allclose(u, u_ls, rtol=0, atol=1e-14)


def test_noise_cutoff_disabled_equals_lstsq_on_pure_noise(rng):
    # Pure noise: plain least squares (slope_tol=inf) still equals lstsq, while
    # the default cut-off refuses to fit slopes the data does not determine.
    x = rng.standard_normal((40, 3))
    x_prev = x - rng.standard_normal((40, 3))
    _, D, _, r = fit(x_prev, x, slope_tol=np.inf)
    np.testing.assert_allclose(D, lstsq_fit(x_prev, x)[0], rtol=0, atol=1e-12)
    assert r == 3
    _, D_def, _, r_def = fit(x_prev, x)
    assert r_def == 0 and not D_def.any()


@pytest.mark.parametrize("model", ["rigid", "similarity", "affine"])
@pytest.mark.parametrize("shape", ["cloud", "planar-sheet", "collinear-rod"])
def test_every_model_recovers_rigid_motion(rng, model, shape):
    n = 50
    x = rng.standard_normal((n, 3))
    if shape == "planar-sheet":
        x[:, 2] = 0.0
    elif shape == "collinear-rod":
        x = np.outer(np.linspace(-1, 1, n), [1.0, 2.0, 0.5]) + [3.0, 0.0, 1.0]
    axis = [0.3, -0.2, 1.0] if shape != "collinear-rod" else np.cross([1.0, 2.0, 0.5], [0.0, 0.0, 1.0])
    R = rot(axis, 7.0)
    b = np.array([0.1, -0.05, 0.02])
    m, D, u, r = fit(prev_for(x, R, b), x, model=model)
    assert r == {"cloud": 3, "planar-sheet": 2, "collinear-rod": 1}[shape]
    if model == "affine" and shape != "cloud":
        # Rank-deficient affine: D is the rotation on the spanned directions
        # and acts as 0 on the others.
        span = {"planar-sheet": np.eye(3)[:, :2], "collinear-rod": np.array([[1.0, 2.0, 0.5]]).T}[shape]
        null = np.linalg.svd(span.T)[2][span.shape[1]:].T
        np.testing.assert_allclose(D @ span, (R - np.eye(3)) @ span, rtol=0, atol=1e-12)
        np.testing.assert_allclose(D @ null, 0.0, rtol=0, atol=1e-12)
    else:
        # Rigid/similarity: full R on a sheet; on the rod the rotation axis is
        # perpendicular to it, so the minimal rotation is R itself.
        np.testing.assert_allclose(D, R - np.eye(3), rtol=0, atol=1e-12)
    np.testing.assert_allclose(u, (R - np.eye(3)) @ m.c + b, rtol=0, atol=1e-12)
    assert F.weighted_rms(m, D) < 1e-12


def test_rigid_rod_spin_is_minimal(rng):
    # A rod that spins about itself and tilts: the spin is unobserved, so the
    # rigid fit is the minimal rotation, identity about the axis normal to both.
    e = np.array([0.0, 0.0, 1.0])
    x = np.outer(np.linspace(0, 1, 30), e)
    R = rot([1.0, 0.0, 0.0], 10) @ rot(e, 40)
    _, D, _, r = fit(prev_for(x, R, np.zeros(3)), x, model="rigid")
    Rf = D + np.eye(3)
    assert r == 1
    np.testing.assert_allclose(Rf @ e, R @ e, rtol=0, atol=1e-12)
    np.testing.assert_allclose(Rf @ [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], rtol=0, atol=1e-12)
    assert np.linalg.det(Rf) == pytest.approx(1.0, abs=1e-12)


def test_similarity_recovers_scale(rng):
    x = rng.standard_normal((40, 3))
    A = 1.03 * rot([1, 2, 3], 4)
    m, D, _, _ = fit(prev_for(x, A, np.zeros(3)), x, model="similarity")
    np.testing.assert_allclose(D + np.eye(3), A, rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "make, rank",
    [
        (lambda x: x[:1], 0),
        (lambda x: x[:2], 1),
        (lambda x: x[:3], 2),
    ],
    ids=["single-vertex", "two-vertices", "three-vertices"],
)
def test_small_sets(rng, make, rank):
    x = make(rng.standard_normal((5, 3)))
    x_prev = x - rng.standard_normal(3) * 0.1
    m, D, u, r = fit(x_prev, x)
    assert r == rank
    np.testing.assert_allclose(u, x[0] - x_prev[0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(D, 0.0, rtol=0, atol=1e-14)  # pure translation data


def test_zero_motion_gives_zero_map(rng):
    x = rng.standard_normal((100, 3))
    m, D, u, r = fit(x.copy(), x)
    assert not D.any() and not u.any()
    out, stats = F.apply_map(x, D, u, m.c, x_prev=x)
    assert np.array_equal(out, x)
    assert stats["residual_pred_max"] == 0.0


def test_float32_input_is_fitted_in_float64(rng):
    x = rng.standard_normal((200, 3)).astype(np.float32)
    x_prev = (x - 1e-3 * (1 + x @ np.diag([0.1, 0.2, 0.3]))).astype(np.float32)
    m32 = F.fit_moments(x_prev, x)
    m64 = F.fit_moments(x_prev.astype(np.float64), x.astype(np.float64))
    np.testing.assert_array_equal(m32.C, m64.C)  # exact upcast: identical sums
    np.testing.assert_array_equal(m32.G, m64.G)
    assert m32.input_eps == np.finfo(np.float32).eps
    out, _ = F.apply_map(x, np.zeros((3, 3)), m32.u, m32.c)
    assert out.dtype == np.float32


def test_float32_precision_is_a_noise_floor(rng):
    # A float32 plate 1e3 from the origin, 1e-5 thick: its thickness is a few
    # float32 ulps (6e-5), so that direction must not be fitted.
    n = 200
    x = np.c_[rng.uniform(-1, 1, (n, 2)), 1e-5 * rng.standard_normal(n)] + 1e3
    x_prev = x - 1e-3 * np.c_[x[:, :1] - 1e3, np.zeros((n, 2))]
    r32 = fit(x_prev.astype(np.float32), x.astype(np.float32))[3]
    r64 = fit(x_prev, x)[3]
    assert r32 == 2 and r64 == 3


# --- the noise-aware cut-off -----------------------------------------------------------


def noisy_cable(rng, n=400, jitter=3e-7, length=1.0):
    """A hanging cable along x swinging about z, bending slightly, with sub-micron lateral jitter."""
    s = np.linspace(0.0, length, n)
    base = np.c_[s, np.zeros(n), np.zeros(n)]
    x = base + np.c_[np.zeros(n), jitter * rng.standard_normal((n, 2))]
    x_prev = base + np.c_[np.zeros(n), jitter * rng.standard_normal((n, 2))]
    R = rot([0, 0, 1], 0.5)
    bend = 2e-4 * length * np.c_[np.zeros(n), np.sin(3 * np.pi * s / length), np.cos(2 * np.pi * s / length)]
    x_prev = x_prev @ np.linalg.inv(R).T - bend
    return x_prev, x


@pytest.mark.parametrize("jitter, length", [(1e-6, 1.0), (3e-7, 0.1), (1e-7, 0.03)],
                         ids=["1m-jitter-1um", "10cm-jitter-0.3um", "3cm-jitter-0.1um"])
def test_noisy_cable_no_blowup(rng, jitter, length):
    x_prev, x = noisy_cable(rng, jitter=jitter, length=length)
    m, D_plain, _, r_plain = fit(x_prev, x, slope_tol=np.inf)
    # Hard case indeed: a machine-precision cut-off keeps the jitter directions
    # and turns the noise into a D of order 1 or more.
    assert r_plain == 3 and np.abs(D_plain).max() > 1  # the true swing is 0.0087
    _, D, _, r = fit(x_prev, x)
    assert r == 1
    s = np.linalg.svd(np.eye(3) + D, compute_uv=False)
    assert s.min() > 0.99 and s.max() < 1.01
    assert F.residual_gain(m, D) <= 0.0  # not worse than doing the translation


def test_validation_errors():
    x = np.zeros((4, 3))
    with pytest.raises(InputError, match="must be \\(N, 3\\)"):
        F.fit_moments(x, np.zeros((4, 2)))
    with pytest.raises(InputError, match="same N"):
        F.fit_moments(np.zeros((3, 3)), x)
    bad = x.copy()
    bad[1, 1] = np.nan
    with pytest.raises(InputError, match="finite"):
        F.fit_moments(bad, x)
    with pytest.raises(InputError, match=">= 0"):
        F.fit_moments(x, x, np.array([1.0, -1.0, 1.0, 1.0]))
    with pytest.raises(InputError, match="positive sum"):
        F.fit_moments(x, x, np.zeros(4))
    with pytest.raises(InputError, match="model must be"):
        F.fit_model(F.fit_moments(x, x), "quadratic")


def test_auto_model_picks_cheapest_adequate(rng):
    x = rng.standard_normal((80, 3))
    cases = {
        "translation": np.eye(3),
        "rigid": rot([1, 0, 1], 5),
        "similarity": 1.05 * rot([1, 0, 1], 5),
        "affine": np.diag([1.05, 0.97, 1.0]),
    }
    for name, A in cases.items():
        used, D, _, _ = F.fit_model(F.fit_moments(prev_for(x, A, np.array([0.1, 0, 0])), x), "auto")
        assert used == name


def _run(x_prev, x, w):
    m = F.fit_moments(x_prev, x, w)
    out, stats = F.apply_map(x, m.G * 1e-3, m.u, m.c, x_prev=x_prev)
    return m, out, stats


@pytest.mark.parametrize("weighted", [True, False])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_deterministic_across_thread_counts_and_builds(rng, monkeypatch, weighted, dtype):
    # Bitwise identical results for 1 and 2 threads with the parallel build
    # forced (threshold 0), and identical to the serial build small N uses
    # (weighted and unweighted builds of the moment kernel, both input dtypes).
    x = rng.standard_normal((5000, 3)) + 100.0
    x_prev = (x - 1e-2 * rng.standard_normal((5000, 3))).astype(dtype)
    x = x.astype(dtype)
    w = rng.uniform(0, 1, 5000) if weighted else None
    old = numba.get_num_threads()
    runs = []
    try:
        monkeypatch.setattr(F.K, "FIT_BUILD", "parallel")
        for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(threads)
            runs.append(_run(x_prev, x, w))
        monkeypatch.setattr(F.K, "FIT_BUILD", "serial")
        runs.append(_run(x_prev, x, w))
    finally:
        numba.set_num_threads(old)
    (m1, o1, s1) = runs[0]
    for m2, o2, s2 in runs[1:]:
        for a, b in [(m1.C, m2.C), (m1.G, m2.G), (m1.c, m2.c), (m1.u, m2.u), (o1, o2)]:
            assert np.array_equal(a, b)
        assert m1.qq == m2.qq and s1 == s2


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), model=st.sampled_from(["rigid", "similarity", "affine"]))
def test_relabelling_invariance_and_rotation_equivariance(seed, model):
    # Permuting vertices does not change the map; rotating the whole scene
    # (both frames) by Rg conjugates it: D' = Rg D Rg^T, u' = Rg u.
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((50, 3))
    A = rot(rng.standard_normal(3), 6) @ (np.eye(3) + 0.03 * rng.standard_normal((3, 3)))
    x_prev = prev_for(x, A, rng.standard_normal(3) * 0.1) + 1e-4 * rng.standard_normal((50, 3))
    _, D, u, r = fit(x_prev, x, model=model)
    perm = rng.permutation(50)
    _, Dp, up, rp = fit(x_prev[perm], x[perm], model=model)
    np.testing.assert_allclose(Dp, D, rtol=0, atol=1e-12)
    np.testing.assert_allclose(up, u, rtol=0, atol=1e-12)
    Rg = rot(rng.standard_normal(3), float(rng.uniform(0, 180)))
    _, Dr, ur, rr = fit(x_prev @ Rg.T, x @ Rg.T, model=model)
    assert rp == r == rr
    np.testing.assert_allclose(Dr, Rg @ D @ Rg.T, rtol=0, atol=1e-11)
    np.testing.assert_allclose(ur, Rg @ u, rtol=0, atol=1e-12)


@pytest.mark.parametrize("build", ["serial", "parallel"])
@pytest.mark.parametrize("dtype", [np.float64, np.float32], ids=["float64", "float32"])
def test_apply_map_residuals_against_numpy(rng, monkeypatch, dtype, build):
    # The residual summaries (maxima taken on the bit patterns) against numpy on the
    # stored x_def, including vertices that do not move (residual exactly 0).
    monkeypatch.setattr(F.K, "FIT_BUILD", build)
    x = (rng.standard_normal((3001, 3)) + 50.0).astype(dtype)
    x_prev = (x - 1e-2 * rng.standard_normal((3001, 3))).astype(dtype)
    x_prev[:7] = x[:7]
    D = 1e-3 * rng.standard_normal((3, 3))
    u, c = 1e-3 * rng.standard_normal(3), x.astype(np.float64).mean(axis=0)
    out, stats = F.apply_map(x, D, u, c, x_prev=x_prev)
    x64, xp64 = x.astype(np.float64), x_prev.astype(np.float64)
    x_def = x64 + (x64 - c) @ D.T + u
    np.testing.assert_allclose(out, x_def.astype(dtype), rtol=np.finfo(dtype).eps, atol=0)
    d = x64 - xp64
    e_def = np.linalg.norm(d - (out.astype(np.float64) - x64), axis=1)
    e_base = np.linalg.norm(d, axis=1)
    # Only the summation order differs (fused multiply-adds, vectorised partial sums).
    for key, ref in [("residual_pred_rms", np.sqrt(np.mean(e_def**2))), ("residual_pred_max", e_def.max()),
                     ("baseline_pred_rms", np.sqrt(np.mean(e_base**2))), ("baseline_pred_max", e_base.max())]:
        np.testing.assert_allclose(stats[key], ref, rtol=1e-13, atol=0, err_msg=key)


@pytest.mark.parametrize("build", ["serial", "parallel"])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf], ids=["nan", "inf", "-inf"])
def test_apply_map_nonfinite_poisons_the_summaries(rng, monkeypatch, bad, build):
    monkeypatch.setattr(F.K, "FIT_BUILD", build)
    x = rng.standard_normal((500, 3))
    x_prev = x - 1e-2
    x_prev[123, 1] = bad
    _, stats = F.apply_map(x, np.zeros((3, 3)), np.full(3, 1e-2), x.mean(axis=0), x_prev=x_prev)
    for key in ("residual_pred_max", "baseline_pred_max", "residual_pred_rms", "baseline_pred_rms"):
        assert not np.isfinite(stats[key]), key


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_unweighted_moments_equal_unit_weights(rng, dtype):
    # The unweighted kernel (no weight loads or multiplies) against the weighted one
    # with every weight 1: the same sums up to the order of the additions.
    x = (rng.standard_normal((3000, 3)) + 10.0).astype(dtype)
    x_prev = (x - 1e-2 * rng.standard_normal((3000, 3))).astype(dtype)
    a, b = F.fit_moments(x_prev, x), F.fit_moments(x_prev, x, np.ones(3000))
    for name in ("W", "c", "u", "C", "G", "qq", "n_eff", "coord_scale"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-12, atol=1e-12, err_msg=name)


@pytest.mark.parametrize("scale", [1e2, 1e4, 1e6, 1e-6], ids=["x1e2", "x1e4", "x1e6", "x1e-6"])
def test_large_exact_scale_change_is_recovered_like_lstsq(scale):
    """x_pred = s x exactly: the residual is rounding only, never noise; rank 1 and a miss of 5.6e5 at 1e6 before."""
    x = np.random.default_rng(5).random((12, 3)) - 0.5
    x_prev = 2 * x - scale * x
    _, D, u, r = fit(x_prev, x)
    D_ls, u_ls = lstsq_fit(x_prev, x)
    assert r == 3
    np.testing.assert_allclose(D, D_ls, rtol=0, atol=1e-9 * scale + 1e-12)
    np.testing.assert_allclose(D, (scale - 1.0) * np.eye(3), rtol=0, atol=1e-9 * scale + 1e-12)


@pytest.mark.parametrize("factor", [5e-324, 1e-200, 3.7, 1e200], ids=["subnormal", "tiny", "plain", "huge"])
def test_weights_only_count_by_their_ratios(rng, factor):
    """Weights of 1e-200 divided by zero (sum of squares underflowed); 1e200 blamed the positions."""
    x = rng.random((40, 3))
    x_prev = x - 0.01 + 1e-3 * rng.random((40, 3))
    w = np.full(40, factor)
    w[:5] = 0.0
    ref = np.where(w > 0, 1.0, 0.0)
    m, D, u, r = fit(x_prev, x, w)
    m1, D1, u1, r1 = fit(x_prev, x, ref)
    assert r == r1 == 3 and m.n_eff == pytest.approx(35.0, rel=1e-14) and m1.n_eff == 35.0
    np.testing.assert_allclose(D, D1, rtol=0, atol=1e-13)
    np.testing.assert_allclose(u, u1, rtol=0, atol=1e-15)


@pytest.mark.parametrize("bad", [np.ones(4, dtype=complex), np.array(["1"] * 4), np.array([1, None, 1, 1])],
                         ids=["complex", "strings", "objects"])
def test_weights_must_be_real_numbers(bad):
    x = np.eye(4, 3)
    with pytest.raises(InputError, match="weights must be real numbers"):
        F.fit_moments(x - 0.1, x, bad)
