"""CI checks: certificate summary, thresholds, regression against a baseline report."""

import numpy as np
import pytest

from penfree.report.checks import certificate_summary, run_checks


def test_certificate_summary():
    steps = {"frame": np.array([1, 2, 3]), "certificate_margin": np.array([0.3, np.nan, 0.05]),
             "margin_required": np.array([0.1, 0.1, 0.1]), "model": np.array(["affine"] * 3),
             "projection": np.array(["none", "sym", "sym"])}
    c = certificate_summary(steps)
    assert (c["all_certified"], c["n_uncertified"], c["uncertified_frames"]) == (False, 2, [2, 3])
    assert c["min_margin"] == 0.05 and c["projections"] == {"none": 1, "sym": 2}


def _rep(name="a.h5", speedup=1.2, gain=0.1, k=2.0, hit=0.8, n_uncert=0):
    return {"name": name, "summary": {"hit_rate_gain_next": gain,
                                      "deformed": {"k_1pct_next": k, "hit_rate_next": hit},
                                      "projected": {"k_1pct": {"speedup": speedup}}},
            "certificate": {"all_certified": n_uncert == 0, "n_uncertified": n_uncert,
                            "uncertified_frames": list(range(n_uncert))}}


@pytest.mark.parametrize(
    "kw, rep_kw, passed",
    [
        pytest.param({"min_speedup": 1.1}, {}, [True], id="speedup-pass"),
        pytest.param({"min_speedup": 1.3}, {}, [False], id="speedup-fail"),
        pytest.param({"min_speedup": 1.0}, {"speedup": float("nan")}, [False], id="speedup-missing"),
        pytest.param({"min_hit_rate_gain": 10.0}, {}, [True], id="gain-10-points-pass"),
        pytest.param({"min_hit_rate_gain": 10.5}, {}, [False], id="gain-fail"),
        pytest.param({"fail_if_uncertified": True}, {"n_uncert": 2}, [False], id="uncertified"),
        pytest.param({"fail_if_uncertified": True}, {}, [True], id="certified"),
    ],
)
def test_threshold_checks(kw, rep_kw, passed):
    checks = run_checks([_rep(**rep_kw)], **kw)
    assert [c["passed"] for c in checks] == passed


def test_regression_checks():
    base = {"files": [_rep(name="a.h5")]}
    same = run_checks([_rep()], baseline=base, max_regression=0.0)
    assert len(same) == 3 and all(c["passed"] for c in same)
    # K_1pct 2 -> 2.1 is a 5 % regression; speedup 1.2 -> 1.17 is 2.5 %
    worse = run_checks([_rep(k=2.1, speedup=1.17)], baseline=base, max_regression=3.0)
    by = {c["name"]: c["passed"] for c in worse}
    assert by == {"regression:deformed.k_1pct_next": False, "regression:projected.k_1pct.speedup": True,
                  "regression:deformed.hit_rate_next": True}
    better = run_checks([_rep(k=1.0, speedup=2.0, hit=0.99)], baseline=base, max_regression=0.0)
    assert all(c["passed"] for c in better)
    # a single file on each side is matched whatever its name; two are matched by name
    assert all(c["passed"] for c in run_checks([_rep(name="b.h5")], baseline=base, max_regression=0.0))
    two = run_checks([_rep(name="b.h5"), _rep(name="a.h5")], baseline=base, max_regression=0.0)
    assert [c["passed"] for c in two if c["file"] == "b.h5"] == [False]
