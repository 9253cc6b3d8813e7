"""fit_step: the guarantees (certified A, never worse than translation) and the result fields."""

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import penfree
from penfree.core.fit.certificate import certify
from penfree.core.fit.models import fit_model, fit_moments, residual_gain
from penfree.core.fit.step import StepResult, fit_step
from penfree.errors import InputError

from _geom import rot, prev_for


RNG_SEED = 3  # seed of the shared `rng` fixture (tests/conftest.py)


def check_result(r: StepResult, x_prev, x, margin):
    """Invariants every result must satisfy."""
    assert certify(r.A, margin)
    assert r.certificate_margin >= margin and certify(r.A, r.certificate_margin)
    assert np.array_equal(r.D, r.A - np.eye(3))
    np.testing.assert_allclose(r.b, r.u - r.D @ r.c, rtol=0, atol=1e-12 * (1 + np.abs(r.c).max()))
    assert r.x_def.dtype == x.dtype and r.x_def.shape == x.shape
    x64 = x.astype(np.float64)
    scale = np.abs(x64).max() + 1.0
    tol = (np.finfo(x.dtype).eps * 4) * scale
    np.testing.assert_allclose(r.x_def, x64 @ r.A.T + r.b, rtol=0, atol=tol * 10)
    # reported residuals: per-vertex distances of the stored x_def / of x to x_pred
    x_pred = 2 * x64 - x_prev.astype(np.float64)
    e_def = np.linalg.norm(r.x_def.astype(np.float64) - x_pred, axis=1)
    e_base = np.linalg.norm(x64 - x_pred, axis=1)
    atol = 8 * np.finfo(np.float64).eps * scale
    assert r.residual_pred_max == pytest.approx(e_def.max(), rel=1e-9, abs=atol)
    assert r.residual_pred_rms == pytest.approx(np.sqrt(np.mean(e_def**2)), rel=1e-9, abs=atol)
    assert r.baseline_pred_max == pytest.approx(e_base.max(), rel=1e-9, abs=atol)
    assert r.baseline_pred_rms == pytest.approx(np.sqrt(np.mean(e_base**2)), rel=1e-9, abs=atol)
    m = fit_moments(x_prev, x)
    assert residual_gain(m, r.D) <= 1e-12 * (m.qq + 1e-300)  # never worse than translation
    assert r.model in ("translation", "rigid", "similarity", "affine")
    assert r.projection in ("none", "svd", "sym")
    assert 0 <= r.rank <= 3 and r.time_fit_s > 0


def test_result_fields_and_api(rng):
    x = rng.standard_normal((100, 3))
    A = np.eye(3) + 0.02 * rng.standard_normal((3, 3))
    x_prev = prev_for(x, A, np.array([0.01, 0.02, 0.0]))
    r = penfree.fit_step(x_prev, x)
    check_result(r, x_prev, x, 0.0)
    assert (r.model, r.projection, r.rank, r.fallback) == ("affine", "none", 3, "")
    np.testing.assert_allclose(r.A, A, rtol=0, atol=1e-12)
    assert r.residual_pred_max < 1e-12 < r.baseline_pred_max
    d = np.linalg.norm(x - x_prev, axis=1)
    assert r.baseline_pred_rms == pytest.approx(np.sqrt(np.mean(d**2)), rel=1e-12)
    assert r.baseline_pred_max == pytest.approx(d.max(), rel=1e-12)


@pytest.mark.parametrize("margin", [0.0, 0.5])
def test_predicted_reflection_is_certified(rng, margin):
    x = rng.standard_normal((200, 3))
    mirror = np.diag([1.0, 1.0, -1.0])
    x_prev = prev_for(x, mirror, np.zeros(3))
    assert not certify(np.eye(3) + fit_model(fit_moments(x_prev, x), "affine")[1], 0.0)
    r = fit_step(x_prev, x, margin=margin)
    check_result(r, x_prev, x, margin)
    assert np.linalg.det(r.A) > 0
    assert r.residual_pred_rms <= r.baseline_pred_rms


def test_rotation_170_with_stretch(rng):
    x = rng.standard_normal((200, 3))
    A = rot([0, 0, 1], 170) @ np.diag([2.0, 0.5, 1.0])
    x_prev = prev_for(x, A, np.zeros(3))
    raw = np.eye(3) + fit_model(fit_moments(x_prev, x), "affine")[1]
    np.testing.assert_allclose(raw, A, rtol=0, atol=1e-12)
    assert np.linalg.det(raw) > 0 and not certify(raw)
    r = fit_step(x_prev, x)
    check_result(r, x_prev, x, 0.0)
    assert r.projection in ("svd", "sym")
    # projection "none" cannot certify the raw map: translation fallback
    r_none = fit_step(x_prev, x, projection="none")
    check_result(r_none, x_prev, x, 0.0)
    assert (r_none.model, r_none.fallback, r_none.model_fitted) == ("translation", "uncertified", "affine")
    assert np.array_equal(r_none.A, np.eye(3))


def test_evaluate_false_skips_summaries_only(rng):
    x = rng.standard_normal((100, 3))
    x_prev = prev_for(x, rot([0, 1, 0], 2), np.zeros(3))
    r, q = fit_step(x_prev, x), fit_step(x_prev, x, evaluate=False)
    assert np.array_equal(r.x_def, q.x_def) and np.array_equal(r.A, q.A)
    assert np.isnan(q.residual_pred_rms) and np.isnan(q.baseline_pred_max)


def test_zero_motion(rng):
    x = rng.standard_normal((50, 3)).astype(np.float32)
    r = fit_step(x.copy(), x)
    assert np.array_equal(r.x_def, x) and not r.D.any() and not r.u.any()
    assert r.residual_pred_max == 0.0 and r.baseline_pred_max == 0.0


def test_float32_in_float32_out_with_out_array(rng):
    x = rng.standard_normal((500, 3)).astype(np.float32)
    x_prev = prev_for(x.astype(np.float64), rot([1, 0, 0], 3), np.array([0.01, 0, 0])).astype(np.float32)
    out = np.empty_like(x)
    r = fit_step(x_prev, x, out=out)
    assert r.x_def is out and out.dtype == np.float32
    check_result(r, x_prev, x, 0.0)
    with pytest.raises(InputError, match="out must"):
        fit_step(x_prev, x, out=np.empty((500, 3)))


def test_far_from_origin_millimetre_motion(rng):
    n = 400
    P = rng.uniform(-0.5, 0.5, (n, 3))
    A = rot([0.2, 1, 0.3], 0.3) @ np.diag([1.001, 0.999, 1.0])
    b = np.array([1e-3, -2e-3, 5e-4])
    x = P + 1e6
    r = fit_step(prev_for(x, A, b), x)
    check_result(r, prev_for(x, A, b), x, 0.0)
    # Motion is ~mm; float64 at 1e6 resolves 1.2e-10: the displacement must
    # match the exact map's to that level (A x + b from uncentred values would not).
    exact = (x - 1e6) @ (A - np.eye(3)).T + (A - np.eye(3)) @ np.full(3, 1e6) + b
    np.testing.assert_allclose(r.x_def - x, exact, rtol=0, atol=2e-9)
    assert r.residual_pred_max < 2e-9


@pytest.mark.parametrize(
    "shape",
    ["collinear-rod", "planar-sheet", "single-vertex", "two-vertices"],
)
def test_rank_deficient_scenes(rng, shape):
    n = {"collinear-rod": 50, "planar-sheet": 60, "single-vertex": 1, "two-vertices": 2}[shape]
    x = rng.standard_normal((n, 3))
    if shape == "collinear-rod":
        x = np.outer(np.linspace(0, 1, n), [1.0, 1.0, 0.0])
    elif shape == "planar-sheet":
        x[:, 2] = 5.0
    x_prev = prev_for(x, rot([0, 0, 1], 4), np.array([0.0, 0.01, 0.0]))
    r = fit_step(x_prev, x)
    check_result(r, x_prev, x, 0.0)
    assert r.rank == {"collinear-rod": 1, "planar-sheet": 2, "single-vertex": 0, "two-vertices": 1}[shape]
    assert r.residual_pred_max < 1e-12


def test_noisy_cable_map_stays_near_identity(rng):
    n = 400
    s = np.linspace(0, 0.1, n)
    x = np.c_[s, 3e-7 * rng.standard_normal((n, 2))]
    x_prev = np.c_[s, 3e-7 * rng.standard_normal((n, 2))] @ rot([0, 0, 1], -0.5).T
    x_prev[:, 1] -= 2e-5 * np.sin(30 * np.pi * s)
    r = fit_step(x_prev, x)
    check_result(r, x_prev, x, 0.0)
    sv = np.linalg.svd(r.A, compute_uv=False)
    assert sv.min() > 0.99 and sv.max() < 1.01 and r.rank == 1
    assert r.residual_pred_rms <= r.baseline_pred_rms


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 40), scale=st.sampled_from([1e-3, 0.3, 3.0]),
       margin=st.sampled_from([0.0, 0.3, 0.9]), model=st.sampled_from(["affine", "rigid", "similarity", "auto"]),
       projection=st.sampled_from(["auto", "svd", "sym", "none"]))
def test_guarantees_on_arbitrary_data(seed, n, scale, margin, model, projection):
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((n, 3))
    # arbitrary targets: random affine maps far from identity plus noise
    A = np.eye(3) + scale * rng.standard_normal((3, 3))
    x_prev = prev_for(x, A, rng.standard_normal(3)) + 0.1 * scale * rng.standard_normal((n, 3))
    r = fit_step(x_prev, x, model=model, projection=projection, margin=margin)
    check_result(r, x_prev, x, margin)


def test_deterministic_across_thread_counts(rng, monkeypatch):
    from penfree import constants

    monkeypatch.setattr(constants, "FIT_BUILD", "parallel")  # force the parallel kernels
    x = rng.standard_normal((3000, 3)).astype(np.float32)
    x_prev = prev_for(x.astype(np.float64), rot([1, 2, 3], 2), np.array([0.0, 0.0, 0.01])).astype(np.float32)
    old = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        r1 = fit_step(x_prev, x)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        r2 = fit_step(x_prev, x)
    finally:
        numba.set_num_threads(old)
    assert np.array_equal(r1.x_def, r2.x_def) and np.array_equal(r1.A, r2.A) and np.array_equal(r1.b, r2.b)
    assert r1.residual_pred_rms == r2.residual_pred_rms


def test_weights_enter_the_fit(rng):
    x = rng.standard_normal((100, 3))
    x_prev = x.copy()
    x_prev[:50] -= 0.1  # half moves, half does not
    w = np.r_[np.ones(50), np.zeros(50)]
    r = fit_step(x_prev, x, weights=w, model="translation")
    np.testing.assert_allclose(r.u, 0.1, rtol=0, atol=1e-15)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(model="quadratic"), "model must be"),
        (dict(projection="clip"), "projection must be"),
        (dict(margin=1.0), "margin must be"),
        (dict(margin="wide"), "margin must be"),
        (dict(weights=-np.ones(4)), ">= 0"),
    ],
    ids=["model", "projection", "margin", "margin-not-a-number", "weights"],
)
def test_bad_arguments(kwargs, match):
    x = np.zeros((4, 3))
    with pytest.raises(InputError, match=match):
        fit_step(x, x, **kwargs)


def test_nonfinite_input_raises():
    x = np.zeros((4, 3))
    x_prev = x.copy()
    x_prev[2, 0] = np.inf
    with pytest.raises(InputError, match="x_prev must be finite"):
        fit_step(x_prev, x)


def test_two_frame_sequence(rng):
    # The smallest sequence (T = 2) has exactly one step.
    x0 = rng.standard_normal((30, 3))
    positions = np.stack([x0, x0 @ rot([1, 0, 0], 3).T + 0.01])
    r = fit_step(positions[0], positions[1])
    check_result(r, positions[0], positions[1], 0.0)
    assert r.rank == 3 and r.residual_pred_max < r.baseline_pred_max


def _scene(kind, rng, dtype):
    n = {"single": 1, "two": 2}.get(kind, 400)
    x = rng.standard_normal((n, 3))
    if kind == "collinear":
        x = np.outer(rng.standard_normal(n), rng.standard_normal(3))
    elif kind == "planar":
        x[:, 2] = 0.5 * x[:, 0] - x[:, 1]
    elif kind == "far":
        x += 1e4
    ang = {"half-turn": 178.0, "reflection": 0.0}.get(kind, 4.0)
    A = rot(rng.standard_normal(3), ang) @ (np.eye(3) + 0.02 * rng.standard_normal((3, 3)))
    if kind == "reflection":
        A = np.diag([1.0, 1.0, -0.2])
    x_prev = prev_for(x, A, 0.01 * rng.standard_normal(3))
    if kind == "noise":
        x_prev += 0.5 * rng.standard_normal((n, 3))  # the map fits worse than the translation
    return x_prev.astype(dtype), x.astype(dtype)


@pytest.mark.parametrize("dtype", [np.float64, np.float32], ids=["float64", "float32"])
@pytest.mark.parametrize("kind", ["generic", "collinear", "planar", "single", "two", "far", "half-turn",
                                  "reflection", "noise"])
def test_the_default_call_gives_the_general_paths_bits(kind, dtype):
    # fit_step's default call (affine, projection auto or none) takes a one-kernel path
    # (models.fit_affine_fast) when the fast test certifies the map; whichever path a
    # scene takes, the result is the general path's (`_fit_general` from `fit_moments`)
    # bit for bit, also where the map needs projecting or falls back.
    from penfree.core.fit.kernels import _offset_kernel
    from penfree.core.fit.step import _fit_general

    rng = np.random.default_rng(7)
    for margin in (0.0, 0.1, 0.9):
        for projection in ("auto", "none"):
            x_prev, x = _scene(kind, rng, dtype)
            r = fit_step(x_prev, x, margin=margin, projection=projection)
            m = fit_moments(x_prev, x)
            used, mode, A, D, u, bound, how, rank, fallback, fitted = _fit_general(m, "affine", projection, margin)
            assert (r.model, r.projection, r.certified_by, r.rank, r.fallback, r.model_fitted) == (
                used, mode, how, rank, fallback, fitted)
            for a, b in [(r.A, A), (r.D, D), (r.u, u), (r.c, m.c), (r.b, _offset_kernel(np.ascontiguousarray(D), u, m.c))]:
                assert np.array_equal(a, b)
            assert r.certificate_margin == bound or np.isnan(r.certificate_margin) and np.isnan(bound)
