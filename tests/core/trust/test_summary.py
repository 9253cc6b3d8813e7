"""The sequence summary and the projected frame time (SPEC section 7), on hand-built stats."""

import math

import numpy as np
import pytest

from penfree.core.trust.stats import stats_keys
from penfree.core.trust.summary import projected_frame_time, summarize
from penfree.errors import InputError


@pytest.mark.parametrize(
    "k_m, k_b, fit_ms, f, T, expect",
    [
        pytest.param(2.0, 4.0, 1.0, 0.5, 32.0, 32.0 * 0.75 + 1.0, id="half-the-passes"),
        pytest.param(3.0, 3.0, 0.0, 0.5, 32.0, 32.0, id="no-change"),
        pytest.param(1.0, 5.0, 2.0, 0.0, 10.0, 12.0, id="no-cd-share"),
        pytest.param(1.0, 4.0, 0.0, 1.0, 40.0, 10.0, id="all-cd"),
    ],
)
def test_projected_frame_time(k_m, k_b, fit_ms, f, T, expect):
    t, sp = projected_frame_time(k_m, k_b, fit_ms, cd_share=f, frame_ms=T)
    assert t == pytest.approx(expect, rel=1e-15, abs=0)
    assert sp == pytest.approx(T / expect, rel=1e-15, abs=0)


@pytest.mark.parametrize("kw", [{"cd_share": 1.5}, {"cd_share": -0.1}, {"frame_ms": 0.0}], ids=str)
def test_projected_frame_time_rejects_bad_assumptions(kw):
    with pytest.raises(InputError):
        projected_frame_time(1.0, 2.0, 0.0, **kw)


def test_projected_frame_time_nan_without_baseline():
    assert all(math.isnan(v) for v in projected_frame_time(1.0, math.nan))


def _fake_stats(S=3):
    st_ = {k: np.zeros(S) for k in stats_keys(False)}
    st_["frame"] = np.arange(1, S + 1)
    for t in ("next", "pred"):
        st_[f"k_1pct_{t}_baseline"][:] = [4, 2, 6][:S]
        st_[f"k_1pct_{t}_deformed"][:] = [2, 1, 3][:S]
        st_[f"k_any_{t}_baseline"][:] = 8
        st_[f"k_any_{t}_deformed"][:] = 4
        st_[f"hit_rate_{t}_baseline"][:] = 0.5
        st_[f"hit_rate_{t}_deformed"][:] = 0.8
        st_[f"residual_{t}_rms_baseline"][:] = [3.0, 4.0, 0.0][:S]
    for k in st_:
        if "_next_" in k:
            st_[k][-1] = np.nan
    return st_


def test_summarize_projection_from_means():
    st_ = _fake_stats()
    steps = {"time_fit_s": np.array([0.001, 0.003, 0.002])}
    sm = summarize(st_, steps, cd_share=0.5, frame_ms=32.0)
    assert sm["n_steps"] == 3 and sm["n_steps_next"] == 2
    assert sm["baseline"]["k_1pct_next"] == 3.0 and sm["deformed"]["k_1pct_next"] == 1.5
    assert sm["baseline"]["k_1pct_pred_total"] == 12.0
    assert sm["hit_rate_gain_next"] == pytest.approx(0.3, abs=1e-15)
    assert sm["fit_ms_mean"] == pytest.approx(2.0, rel=1e-12)
    assert sm["fit_ms_median"] == pytest.approx(2.0, rel=1e-12)
    p = sm["projected"]["k_1pct"]
    assert p["frame_ms"] == pytest.approx(32.0 * (0.5 + 0.5 * 1.5 / 3.0) + 2.0, rel=1e-14)
    assert p["speedup"] == pytest.approx(32.0 / p["frame_ms"], rel=1e-14)
    assert sm["projected"]["label"] == "projected"
    assert sm["projected"]["k_any"]["speedup"] == pytest.approx(32.0 / (32.0 * 0.75 + 2.0), rel=1e-14)
    # pooled RMS over the steps with a next frame: sqrt((9 + 16) / 2)
    assert sm["baseline"]["residual_next_rms"] == pytest.approx(math.sqrt(12.5), rel=1e-15)


def test_summarize_without_next_frames():
    st_ = _fake_stats(1)
    sm = summarize(st_, None)
    assert sm["n_steps_next"] == 0 and sm["fit_ms_mean"] == 0.0
    assert math.isnan(sm["projected"]["k_1pct"]["speedup"])
    assert sm["deformed"]["k_1pct_pred"] == 2.0


def test_summarize_fit_time_is_the_median():
    # a first step that paid JIT compilation must not dominate the projected frame time
    sm = summarize(_fake_stats(), {"time_fit_s": np.array([0.5, 0.001, 0.001])}, cd_share=0.5, frame_ms=32.0)
    assert sm["fit_ms_mean"] == pytest.approx(502.0 / 3, rel=1e-12)
    assert sm["projected"]["fit_ms"] == pytest.approx(1.0, rel=1e-12)
    assert sm["projected"]["fit_ms_statistic"] == "median"
    assert sm["projected"]["k_1pct"]["frame_ms"] == pytest.approx(32.0 * 0.75 + 1.0, rel=1e-12)
