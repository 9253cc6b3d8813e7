"""Report building and writing: statistics read or computed, JSON round trip with stable keys, Markdown, plots."""

import json
import math
import os
import sys

import numpy as np
import pytest

from penfree.constants import DEFAULT_GAMMA
from penfree.core.trust.stats import compute_stats, stats_keys
from penfree.errors import InputError, OutputExistsError
from penfree.report.build import (
    REPORT_SCHEMA,
    load_report_json,
    make_file_report,
    open_result,
    select_steps,
    stored_stats,
    worst_steps,
    write_report,
)
from penfree.sequence import Sequence

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _far_bounds(x, *, edges=None, faces=None, thickness=0.0, gamma=DEFAULT_GAMMA, query_radius=None):
    # Stand-in for trust_region_bounds on scenes whose primitives are all farther apart
    # than r_q: every vertex gets gamma * (r_q - thickness) (SPEC section 7).
    return np.full(np.asarray(x).shape[0], gamma * max(0.0, query_radius - thickness))


def scene_arrays(T=6, n=6, seed=3):
    # Two 2-edge rods 10 apart (far beyond r_q), spinning slowly and drifting: the
    # translation map helps, and every non-adjacent pair is out of query range (so the
    # real bounds equal the stand-in's).
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 0.2, n // 2)
    base = np.concatenate([np.c_[s, 0 * s, 0 * s], np.c_[s, 0 * s + 10.0, 0 * s]])
    frames = []
    for t in range(T):
        a = 0.05 * t
        R = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
        frames.append(base @ R.T + 0.01 * t * np.array([1.0, 0.5, 0.0]) + 1e-4 * rng.normal(size=base.shape))
    m = n // 2
    edges = np.array([[i, i + 1] for i in range(m - 1)] + [[m + i, m + i + 1] for i in range(m - 1)])
    return Sequence(positions=np.stack(frames), edges=edges).validate()


def _translation_steps(seq):
    pos = seq.positions
    frames = np.arange(1, seq.n_frames)
    u = (pos[frames] - pos[frames - 1]).mean(axis=1)
    S = frames.size
    A = np.repeat(np.eye(3)[None], S, axis=0)
    return {
        "frame": frames, "A": A, "b": u, "deformed": pos[frames] + u[:, None, :],
        "model": np.array(["translation"] * S), "projection": np.array(["none"] * S),
        "certificate_margin": np.ones(S), "margin_required": np.zeros(S), "rank": np.zeros(S, dtype=np.int64),
        "time_fit_s": np.full(S, 1e-4),
    }


def write_tiny_result(path, with_stats=False, uncertified_frame=None):
    from penfree.formats.result import write_result

    seq = scene_arrays()
    steps = _translation_steps(seq)
    if uncertified_frame is not None:
        steps["certificate_margin"][steps["frame"] == uncertified_frame] = np.nan
    groups = None
    if with_stats:
        groups = {"stats": compute_stats(seq.positions, deformed=steps["deformed"], frames=steps["frame"],
                                         edges=seq.edges, bounds_fn=lambda x, r: _far_bounds(x, query_radius=r))}
    write_result(path, seq, steps, {"options": {"model": "translation", "projection": "none"}}, groups=groups)
    return path


def _report_entry(tmp_path, **kw):
    res = open_result(write_tiny_result(tmp_path / "r.h5", with_stats=True))
    return make_file_report(str(tmp_path / "r.h5"), res, ladder=False, **kw)


# ---------------------------------------------------------------- report entry


def test_stored_stats_are_used(tmp_path):
    res = open_result(write_tiny_result(tmp_path / "r.h5", with_stats=True))
    assert stored_stats(res) is not None
    assert stored_stats(res, replay=True) is None  # no replay keys in the file
    rep = make_file_report("r.h5", res, ladder=False)
    assert rep["stats_source"] == "file"
    sm = rep["summary"]
    assert sm["n_steps"] == 5 and sm["n_steps_next"] == 4
    # the translation removes the drift: closer to the next frame than doing nothing
    assert sm["deformed"]["residual_next_rms"] < sm["baseline"]["residual_next_rms"]
    assert rep["certificate"]["all_certified"] and rep["certificate"]["min_margin"] == 1.0


def test_stats_computed_when_missing(tmp_path):
    res = open_result(write_tiny_result(tmp_path / "r.h5"))
    rep = make_file_report("r.h5", res, ladder=False, replay=True)
    assert rep["stats_source"] == "computed"
    assert "replay_k_1pct" in rep["summary"]["projected"]
    assert set(stats_keys(True)) - {k for k in stats_keys(True) if k.startswith("r_hist")} <= set(rep["steps"])


def test_select_steps_subsets_steps_and_stats(tmp_path):
    res = open_result(write_tiny_result(tmp_path / "r.h5", with_stats=True))
    sub = select_steps(res, (2, 4))
    assert sub.steps["frame"].tolist() == [2, 3]
    assert sub.groups["stats"]["frame"].tolist() == [2, 3]
    assert sub.steps["deformed"].shape[0] == 2 and stored_stats(sub) is not None
    with pytest.raises(InputError, match="selects none"):
        select_steps(res, (50, None))


def test_open_result_rejects_a_raw_sequence(tmp_path):
    from penfree.formats import write_sequence

    p = tmp_path / "raw.h5"
    write_sequence(p, scene_arrays())
    with pytest.raises(InputError, match="not a penfree deform output"):
        open_result(p)
    with pytest.raises(InputError, match="no such file"):
        open_result(tmp_path / "missing.h5")


def test_worst_steps_order():
    st = {k: np.zeros(4) for k in stats_keys()}
    st["frame"] = np.array([1, 2, 3, 4])
    st["k_1pct_next_deformed"][:] = [2, 5, 5, np.nan]
    st["k_1pct_next_baseline"][:] = [2, 9, 6, np.nan]
    rows = worst_steps(st, n=3)
    # most deformed passes first; among equals the smaller gain (frame 3: 1 < frame 2: 4)
    assert [r["frame"] for r in rows] == [3, 2, 1]
    assert rows[0]["k_1pct_gain"] == 1.0 and rows[0]["target"] == "next"


# ---------------------------------------------------------------- write_report


TOP_KEYS = {"penfree_report", "penfree_version", "projected_formula", "options", "plots", "checks",
            "all_checks_passed", "files"}
FILE_KEYS = {"file", "name", "scene", "deform_options", "stats_source", "summary", "certificate", "worst_steps",
             "steps", "r_hist", "ladder"}
SUMMARY_KEYS = {"n_steps", "n_steps_next", "fit_ms_mean", "fit_ms_median", "hit_rate_gain_next", "hit_rate_gain_pred",
                "baseline", "deformed", "projected"}


def _strict_json(path):
    def bad(c):
        raise ValueError(f"non-standard JSON constant {c}")

    return json.loads(path.read_text(), parse_constant=bad)


def test_json_round_trip_keys_stable(tmp_path):
    rep = _report_entry(tmp_path)
    out = tmp_path / "rep"
    doc = write_report(out, [rep], options={"cd_share": 0.5}, plots=False)
    back = _strict_json(out / "report.json")
    assert back == doc
    assert set(back) == TOP_KEYS and back["penfree_report"] == REPORT_SCHEMA
    f = back["files"][0]
    assert set(f) == FILE_KEYS and set(f["summary"]) == SUMMARY_KEYS
    assert set(f["summary"]["projected"]) == {"label", "cd_share", "frame_ms", "fit_ms", "fit_ms_statistic", "target",
                                              "k_1pct", "k_any"}
    assert set(f["summary"]["projected"]["k_1pct"]) == {"k_baseline", "k_deformed", "frame_ms", "speedup"}
    assert f["summary"]["projected"]["label"] == "projected"
    assert f["steps"]["hit_rate_next_deformed"][-1] is None  # NaN written as null
    assert f["summary"]["projected"]["fit_ms"] == pytest.approx(0.1, rel=1e-12)
    assert load_report_json(out / "report.json") == back
    assert load_report_json(out) == back  # a report directory works as well
    md = (out / "report.md").read_text()
    assert "*projected*" in md and "f = 0.5" in md and "T_frame = 32 ms" in md
    assert "Plots disabled" in md and "r.h5" in md


def test_existing_output_needs_overwrite(tmp_path):
    rep = _report_entry(tmp_path)
    out = tmp_path / "rep"
    write_report(out, [rep], plots=False)
    (out / "marker").write_text("old")
    with pytest.raises(OutputExistsError):
        write_report(out, [rep], plots=False)
    assert (out / "marker").exists()
    with pytest.raises(InputError, match="marker.*did not write"):  # --overwrite: penfree's own files only
        write_report(out, [rep], overwrite=True, plots=False)
    assert (out / "marker").read_text() == "old"
    (out / "marker").unlink()
    write_report(out, [rep], overwrite=True, plots=False)
    assert sorted(os.listdir(out)) == ["report.json", "report.md"]


def test_load_report_json_rejects_other_json(tmp_path):
    p = tmp_path / "x.json"
    p.write_text('{"a": 1}')
    with pytest.raises(InputError, match="not a penfree report.json"):
        load_report_json(p)
    with pytest.raises(InputError, match="cannot read"):
        load_report_json(tmp_path / "none.json")


def test_plots_written_with_matplotlib(tmp_path):
    pytest.importorskip("matplotlib")
    res = open_result(write_tiny_result(tmp_path / "r.h5", with_stats=True))
    rep = make_file_report("r.h5", res, ladder=False)
    row = {"residual_pred_rms": 0.1, "k_1pct_next": 1.0, "k_any_next": 1.0, "hit_rate_next": 1.0,
           "certificate_margin_mean": 0.9, "certificate_margin_min": 0.9, "models_used": {"affine": 5}}
    rep["ladder"] = {"models": ["baseline", "affine"], "n_steps": 5, "n_steps_next": 4, "rows": [
        {**row, "model": "baseline", "fit_ms_mean": 0.0, "fit_ms_median": 0.0, "residual_next_rms": 1.0},
        {**row, "model": "affine", "fit_ms_mean": 0.1, "fit_ms_median": 0.1, "residual_next_rms": 0.2}]}
    out = tmp_path / "rep"
    doc = write_report(out, [rep, dict(rep)])
    assert doc["plots"]["status"] == "written"
    names = {"r_hit_rate.png", "r_cd_passes.png", "r_r_hist.png", "r_ladder.png"}
    assert set(doc["plots"]["per_file"][0]) == names
    assert set(doc["plots"]["per_file"][1]) == {n.replace("r_", "r-2_", 1) for n in names}
    for name in doc["plots"]["files"]:
        assert (out / name).read_bytes()[:8] == PNG_MAGIC
    assert "![r_hit_rate.png](r_hit_rate.png)" in (out / "report.md").read_text()


def test_plots_skipped_without_matplotlib(tmp_path, monkeypatch):
    for mod in [m for m in sys.modules if m == "matplotlib" or m.startswith("matplotlib.")]:
        monkeypatch.delitem(sys.modules, mod)
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    rep = _report_entry(tmp_path)
    out = tmp_path / "rep"
    doc = write_report(out, [rep])
    assert doc["plots"]["status"] == "skipped" and "matplotlib" in doc["plots"]["reason"]
    assert not list(out.glob("*.png"))
    assert "Plots skipped" in (out / "report.md").read_text()
    assert _strict_json(out / "report.json")["plots"]["status"] == "skipped"


# ---------------------------------------------------------------- unusable stored stats, forged plot lists


def _tamper_stats(path, key, value):
    import h5py

    with h5py.File(path, "a") as f:
        del f[f"stats/{key}"]
        if isinstance(value, str) and value == "group":
            f.create_group(f"stats/{key}")
        else:
            f[f"stats/{key}"] = value


@pytest.mark.parametrize("key,value,expect", [
    ("k_1pct_next_deformed", np.array([b"1", b"2", b"3", b"4", b"5"]), "stats/k_1pct_next_deformed must be numeric"),
    ("k_1pct_next_deformed", np.ones(4), "stats/k_1pct_next_deformed must be (5,); got (4,)"),
    ("hit_rate_pred_baseline", "group", "stats/hit_rate_pred_baseline is a group"),
    ("r_hist_next_deformed", np.ones(5), "stats/r_hist_next_deformed must be (5, "),
    ("frame", np.array([1, 2, 3, 4, 4]), "stats/frame differs from steps/frame"),
], ids=["text", "short", "group", "hist-1d", "other-frames"])
def test_unusable_stored_stats_are_recomputed_with_a_note(tmp_path, key, value, expect):
    good = open_result(write_tiny_result(tmp_path / "good.h5", with_stats=True))
    want = make_file_report("good.h5", good, ladder=False)
    p = write_tiny_result(tmp_path / "r.h5", with_stats=True)
    _tamper_stats(p, key, value)
    res = open_result(p)
    assert stored_stats(res) is None
    rep = make_file_report(str(p), res, ladder=False)
    assert rep["stats_source"] == "computed"
    assert expect in rep["stats_note"] and f"{p}:/stats/{key}" in rep["stats_note"]
    assert rep["summary"]["deformed"]["k_1pct_next"] == want["summary"]["deformed"]["k_1pct_next"]
    assert rep["summary"]["baseline"]["hit_rate_next"] == want["summary"]["baseline"]["hit_rate_next"]
    write_report(tmp_path / "rep", [rep], plots=False)
    assert "stored statistics ignored and recomputed" in (tmp_path / "rep" / "report.md").read_text()


def test_report_without_certificate_margin_is_refused(tmp_path):
    import h5py

    p = write_tiny_result(tmp_path / "nocert.h5")
    with h5py.File(p, "a") as f:
        del f["steps/certificate_margin"]
    with pytest.raises(InputError, match=rf"missing dataset steps/certificate_margin in {p}:/steps/certificate_margin"):
        open_result(p)


def test_forged_plot_list_owns_no_user_file(tmp_path):
    rep = _report_entry(tmp_path)
    out = tmp_path / "rep"
    write_report(out, [rep], plots=False)
    doc = json.loads((out / "report.json").read_text())
    doc["plots"]["files"] = ["holiday.png"]  # a list in the file never makes a user's file penfree's
    (out / "report.json").write_text(json.dumps(doc))
    (out / "holiday.png").write_bytes(PNG_MAGIC + b"mine")
    with pytest.raises(InputError, match="holiday.png.*did not write"):
        write_report(out, [rep], overwrite=True, plots=False)
    assert (out / "holiday.png").read_bytes() == PNG_MAGIC + b"mine"
    assert sorted(os.listdir(out)) == ["holiday.png", "report.json", "report.md"]


def test_plots_penfree_wrote_are_still_replaced(tmp_path):
    rep = _report_entry(tmp_path)
    out = tmp_path / "rep"
    write_report(out, [rep], plots=False)
    doc = json.loads((out / "report.json").read_text())
    doc["plots"]["files"] = ["r_hit_rate.png", "r-2_ladder.png"]  # as write_plots names them
    (out / "report.json").write_text(json.dumps(doc))
    for n in doc["plots"]["files"]:
        (out / n).write_bytes(PNG_MAGIC)
    write_report(out, [rep], overwrite=True, plots=False)
    assert sorted(os.listdir(out)) == ["report.json", "report.md"]


# ---------------------------------------------------------------- CI: statistics computed, not read


def test_stats_computed_for_checks_and_a_differing_group_noted(tmp_path):
    import h5py

    p = write_tiny_result(tmp_path / "r.h5", with_stats=True)
    honest = make_file_report("r.h5", open_result(p), ladder=False, use_stored_stats=False)
    assert honest["stats_source"] == "computed" and "stats_note" not in honest  # the same numbers: no note
    with h5py.File(p, "a") as f:
        f["stats/k_1pct_next_deformed"][...] = 1.0
    res = open_result(p)
    cached = make_file_report("r.h5", res, ladder=False)
    assert cached["stats_source"] == "file"
    rep = make_file_report("r.h5", res, ladder=False, use_stored_stats=False)
    assert rep["stats_source"] == "computed" and rep["summary"] == honest["summary"]
    assert rep["stats_note"].startswith("stored statistics differ from those computed from the positions")
    assert f"(k_1pct_next_deformed in {p}:/stats)" in rep["stats_note"]


def test_result_without_steps_is_refused(tmp_path):
    import h5py

    p = write_tiny_result(tmp_path / "r.h5")
    with h5py.File(p, "a") as f:
        for k in list(f["steps"]):
            data = f[f"steps/{k}"][()]
            del f[f"steps/{k}"]
            f[f"steps/{k}"] = data[:0]
    with pytest.raises(InputError, match=rf"{p} holds no steps to report \(steps/frame is empty in {p}:/steps/frame\)"):
        open_result(p)
