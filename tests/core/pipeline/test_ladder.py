"""Model ladder: speed against error (re-fit every step with every model)."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from penfree.core.pipeline.ladder import LADDER_FIGURES, LADDER_MODELS, LADDER_NAMES, model_ladder


def _affine_motion(rng, T=5, n=30):
    # x_t = x0 + t (G x0 + g): constant velocity, so x_pred = x_next exactly and the
    # displacement is an affine function of x_t; the affine model must be exact.
    x0 = rng.normal(size=(n, 3))
    G = 0.02 * rng.normal(size=(3, 3))
    g = np.array([0.05, -0.01, 0.02])
    return np.stack([x0 + t * (x0 @ G.T + g) for t in range(T)])


def _lstsq_fit(x_prev, x, *, weights=None, model="affine", projection="auto", margin=0.0):
    # Oracle stand-in for fit_step: translation = mean displacement, affine = lstsq.
    x = np.asarray(x, dtype=np.float64)
    d = x - np.asarray(x_prev, dtype=np.float64)
    if model == "translation":
        x_def = x + d.mean(axis=0)
    else:
        H = np.c_[x, np.ones(len(x))]
        coef = np.linalg.lstsq(H, d, rcond=None)[0]
        x_def = x + H @ coef
    return SimpleNamespace(x_def=x_def, model="affine" if model == "auto" else model, certificate_margin=0.5)


def _far_bounds(x, r_q):
    # points far apart: every vertex gets the cap 0.45 * r_q (thickness 0)
    return np.full(x.shape[0], 0.45 * r_q)


RNG_SEED = 5  # seed of the shared `rng` fixture (tests/conftest.py)


def test_ladder_with_oracle_fit(rng):
    pos = _affine_motion(rng)
    frames = np.arange(1, pos.shape[0])
    calls = []

    def fit(*a, **kw):
        calls.append(kw["model"])
        return _lstsq_fit(*a, **kw)

    seen = []
    lad = model_ladder(pos, frames, models=("translation", "affine"), bounds_fn=_far_bounds, fit_fn=fit,
                       progress=lambda: seen.append(1))
    assert lad["models"] == ["baseline", "translation", "affine", "x_pred"]
    assert (lad["n_steps"], lad["n_steps_next"]) == (4, 3) and len(seen) == 4
    assert math.isnan(lad["auto_best_rate"])  # no auto in this ladder
    # warm-up (LADDER_WARMUP_CALLS per model), then one call per model and step
    assert calls[:4] == ["translation"] * 2 + ["affine"] * 2 and len(calls) == 4 + 2 * 4
    rows = {r["model"]: r for r in lad["rows"]}
    # baseline residual to x_pred = RMS of the per-step displacement
    d = np.linalg.norm(pos[1] - pos[0], axis=1)
    assert rows["baseline"]["residual_pred_rms"] == pytest.approx(math.sqrt(np.mean(d**2)), rel=1e-12)
    assert rows["baseline"]["fit_ms_mean"] == 0.0 and rows["baseline"]["fit_ms_median"] == 0.0
    assert math.isnan(rows["baseline"]["certificate_margin_min"])
    # the affine model is exact on affine constant-velocity motion
    assert rows["affine"]["residual_next_rms"] < 1e-12 and rows["affine"]["residual_pred_rms"] < 1e-12
    assert rows["affine"]["hit_rate_next"] == 1.0 and rows["affine"]["k_1pct_next"] == 1.0
    assert rows["translation"]["residual_next_rms"] > 1e3 * rows["affine"]["residual_next_rms"]
    assert rows["baseline"]["k_any_next"] >= rows["translation"]["k_any_next"] >= 1
    assert rows["affine"]["models_used"] == {"affine": 4}
    assert rows["affine"]["certificate_margin_mean"] == 0.5
    # the x_pred ceiling is the prediction itself: zero residual to x_pred
    assert rows["x_pred"]["residual_pred_rms"] == 0.0
    assert rows["x_pred"]["residual_next_rms"] == pytest.approx(rows["affine"]["residual_next_rms"], abs=1e-12)
    for m in lad["models"]:
        assert set(lad["steps"][m]) == set(LADDER_FIGURES) | set(LADDER_NAMES)
        assert np.isnan(lad["steps"][m]["k_1pct_next"][-1])  # the last step has no next frame
    # the per-step names behind models_used ("" where no fit ran)
    assert lad["steps"]["affine"]["model_used"].tolist() == ["affine"] * 4
    assert lad["steps"]["baseline"]["model_used"].tolist() == [""] * 4


def test_margin_one_means_translation(rng):
    pos = _affine_motion(rng, T=3)
    used = []

    def fit(*a, **kw):
        used.append((kw["model"], kw["margin"]))
        return _lstsq_fit(*a, **kw)

    model_ladder(pos, [1, 2], models=("affine",), margins=[0.2, 1.0], bounds_fn=_far_bounds, fit_fn=fit)
    assert used == [("affine", 0.0), ("affine", 0.0), ("affine", 0.2), ("translation", 0.0)]


def test_ladder_with_fit_step(rng):
    pos = _affine_motion(rng)
    frames = np.arange(1, pos.shape[0])
    lad = model_ladder(pos, frames, bounds_fn=_far_bounds)
    assert lad["models"] == ["baseline", *LADDER_MODELS, "x_pred"]
    rows = {r["model"]: r for r in lad["rows"]}
    scale = rows["baseline"]["residual_next_rms"]
    assert rows["affine"]["residual_next_rms"] <= 1e-9 * scale
    assert rows["translation"]["residual_next_rms"] <= scale * (1 + 1e-12)
    for m in LADDER_MODELS:
        assert rows[m]["certificate_margin_min"] >= 0.0  # every applied map is certified
        assert rows[m]["residual_pred_rms"] <= rows["baseline"]["residual_pred_rms"] * (1 + 1e-12)


def test_ladder_of_step_ranges_joined_equals_the_whole(rng):
    """`ladder_steps` of consecutive frame ranges (each with only the frames its steps read),
    joined in step order, summarise to the whole ladder: every row, count and rate (the fit
    wall times aside), `models_used` and `auto_best_rate` from the per-step figures alone."""
    from penfree.core.pipeline.ladder import concat_ladder_steps, ladder_steps, ladder_summary

    pos = _affine_motion(rng, T=9)
    pos[5:] += 0.01 * rng.normal(size=pos[5:].shape)  # not exactly affine: the models differ
    frames = np.arange(1, 9)
    kw = dict(models=("translation", "affine", "auto"), bounds_fn=_far_bounds, fit_fn=_lstsq_fit)
    whole = model_ladder(pos, frames, **kw)
    parts = [ladder_steps(pos[lo - 1:min(hi + 1, 9)], frames[(frames >= lo) & (frames < hi)] - (lo - 1), **kw)
             for lo, hi in ((1, 4), (4, 7), (7, 9))]
    joined = ladder_summary(concat_ladder_steps(parts))
    assert (joined["n_steps"], joined["n_steps_next"]) == (whole["n_steps"], whole["n_steps_next"]) == (8, 7)
    assert joined["auto_best_rate"] == whole["auto_best_rate"]
    for a, b in zip(joined["rows"], whole["rows"]):
        a, b = dict(a), dict(b)
        for k in ("fit_ms_mean", "fit_ms_median"):
            a.pop(k), b.pop(k)
        assert sorted(a) == sorted(b)
        for k in a:  # bit for bit, NaN equal to NaN
            assert a[k] == b[k] or (isinstance(a[k], float) and math.isnan(a[k]) and math.isnan(b[k])), (k, a, b)
