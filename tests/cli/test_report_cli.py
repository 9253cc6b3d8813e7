"""``penfree report``: files written, exit codes of the CI checks, unusable input."""

import os
import json
import math

import numpy as np
import pytest

from penfree.constants import DEFAULT_GAMMA
from penfree.sequence import Sequence


def _result_file(path, uncertified=False):
    # Two 2-edge rods 10 apart (out of query range of each other), drifting and spinning
    # slowly, so every vertex gets the far-apart bound gamma (r_q - thickness); a translation map per step
    # (certified, margin 1).
    from penfree.formats.result import write_result

    s = np.linspace(0.0, 0.2, 3)  # 3 vertices a rod: no non-adjacent pair within a rod
    base = np.concatenate([np.c_[s, 0 * s, 0 * s], np.c_[s, 0 * s + 10.0, 0 * s]])
    frames = []
    for t in range(6):
        a = 0.05 * t
        R = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
        frames.append(base @ R.T + 0.01 * t * np.array([1.0, 0.5, 0.0]))
    edges = np.array([[0, 1], [1, 2], [3, 4], [4, 5]])
    seq = Sequence(positions=np.stack(frames), edges=edges).validate()
    pos, fr = seq.positions, np.arange(1, 6)
    u = (pos[fr] - pos[fr - 1]).mean(axis=1)
    margin = np.ones(5)
    if uncertified:
        margin[2] = np.nan
    steps = {"frame": fr, "A": np.repeat(np.eye(3)[None], 5, axis=0), "b": u, "deformed": pos[fr] + u[:, None],
             "model": np.array(["translation"] * 5), "projection": np.array(["none"] * 5),
             "certificate_margin": margin, "margin_required": np.zeros(5), "rank": np.zeros(5, dtype=np.int64),
             "time_fit_s": np.full(5, 2e-4)}
    write_result(path, seq, steps, {"options": {"model": "translation", "projection": "auto"}})
    return str(path)


@pytest.fixture
def result(tmp_path):
    return _result_file(tmp_path / "res.h5")


def test_report_written(cli, result, tmp_path):
    out = tmp_path / "rep"
    r = cli("report", result, "-o", out, "--no-ladder", "--frame-ms", "16", "--cd-share", "0.4")
    assert r.exit_code == 0, r.output
    doc = json.loads((out / "report.json").read_text())
    assert doc["options"]["frame_ms"] == 16.0 and doc["options"]["cd_share"] == 0.4
    p = doc["files"][0]["summary"]["projected"]
    assert (p["frame_ms"], p["cd_share"], p["label"]) == (16.0, 0.4, "projected")
    assert doc["files"][0]["stats_source"] == "computed" and doc["files"][0]["ladder"] is None
    assert (out / "report.md").exists()
    assert "projected speedup" in r.output


def test_json_on_stdout_and_frames(cli, result, tmp_path):
    r = cli("report", result, "-o", tmp_path / "rep", "--no-ladder", "--no-plots", "--frames", "2:4", "--json")
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    assert doc["files"][0]["steps"]["frame"] == [2, 3]
    assert doc["plots"]["status"] == "disabled"


def test_ladder_and_replay(cli, result, tmp_path):
    r = cli("report", result, "-o", tmp_path / "rep", "--replay", "--no-plots", "--json")
    assert r.exit_code == 0, r.output
    f = json.loads(r.output)["files"][0]
    assert [row["model"] for row in f["ladder"]["rows"]] == ["baseline", "translation", "rigid", "similarity",
                                                              "affine", "auto", "x_pred"]
    assert 0.0 <= f["ladder"]["auto_best_rate"] <= 1.0
    assert "replay_k_1pct" in f["summary"]["projected"]


@pytest.mark.parametrize(
    "opts, code",
    [
        pytest.param(["--min-speedup", "0.5"], 0, id="speedup-pass"),
        pytest.param(["--min-speedup", "1000"], 1, id="speedup-fail"),
        pytest.param(["--min-hit-rate-gain", "-100"], 0, id="gain-pass"),
        pytest.param(["--min-hit-rate-gain", "101"], 1, id="gain-fail"),
        pytest.param(["--fail-if-uncertified"], 0, id="certified"),
    ],
)
def test_threshold_exit_codes(cli, result, tmp_path, opts, code):
    out = tmp_path / "rep"
    r = cli("report", result, "-o", out, "--no-ladder", "--no-plots", *opts)
    assert r.exit_code == code, r.output
    assert (out / "report.json").exists()  # written whether the checks pass or not
    doc = json.loads((out / "report.json").read_text())
    assert doc["all_checks_passed"] is (code == 0)
    if code:
        assert "check(s) failed" in r.output


def test_uncertified_fails(cli, tmp_path):
    f = _result_file(tmp_path / "u.h5", uncertified=True)
    r = cli("report", f, "-o", tmp_path / "rep", "--no-ladder", "--no-plots", "--fail-if-uncertified")
    assert r.exit_code == 1 and "certified" in r.output and "frames [3]" in r.output


def test_regression_against_baseline(cli, result, tmp_path):
    r = cli("report", result, "-o", tmp_path / "base", "--no-ladder", "--no-plots")
    assert r.exit_code == 0, r.output
    base = tmp_path / "base" / "report.json"
    # the same file against itself: no regression (fit time comes from the file)
    r = cli("report", result, "-o", tmp_path / "same", "--no-ladder", "--no-plots", "--baseline", base, "--max-regression", "0")
    assert r.exit_code == 0, r.output
    # a baseline that needed half the CD passes: the current file regressed
    doc = json.loads(base.read_text())
    doc["files"][0]["summary"]["deformed"]["k_1pct_next"] /= 2
    better = tmp_path / "better.json"
    better.write_text(json.dumps(doc))
    r = cli("report", result, "-o", tmp_path / "new", "--no-ladder", "--no-plots", "--baseline", better,
            "--max-regression", "5")
    assert r.exit_code == 1, r.output
    assert "regression:deformed.k_1pct_next" in r.output
    checks = json.loads((tmp_path / "new" / "report.json").read_text())["checks"]
    assert [c["passed"] for c in checks] == [False, True, True]


@pytest.mark.parametrize(
    "make, args, match",
    [
        pytest.param("raw", [], "not a penfree deform output", id="raw-sequence"),
        pytest.param("missing", [], "no such file", id="missing-file"),
        pytest.param("text", [], "not a penfree deform output", id="not-hdf5"),
        pytest.param("ok", ["--baseline", "nope.json"], "go together", id="baseline-without-max"),
        pytest.param("ok", ["--baseline", "nope.json", "--max-regression", "5"], "cannot read", id="bad-baseline"),
        pytest.param("ok", ["--frames", "90:"], "selects none", id="empty-frames"),
    ],
)
def test_unusable_input_exit_2(cli, tmp_path, make, args, match):
    from penfree.formats import write_sequence

    f = tmp_path / "in.h5"
    if make == "raw":
        write_sequence(f, Sequence(positions=np.zeros((3, 2, 3)) + np.arange(3)[:, None, None]).validate())
    elif make == "text":
        f.write_text("hello")
    elif make == "ok":
        _result_file(f)
    out = tmp_path / "rep"
    r = cli("report", f, "-o", out, "--no-ladder", *[tmp_path / a if a.endswith(".json") else a for a in args])
    assert r.exit_code == 2, r.output
    assert match in r.output and "Traceback" not in r.output
    assert len(r.output.strip().splitlines()) == 1
    assert not out.exists()


def test_existing_output_not_replaced(cli, result, tmp_path):
    out = tmp_path / "rep"
    out.mkdir()
    (out / "keep").write_text("x")
    r = cli("report", result, "-o", out, "--no-ladder", "--no-plots")
    assert r.exit_code == 2 and "--overwrite" in r.output
    assert (out / "keep").exists()
    r = cli("report", result, "-o", out, "--no-ladder", "--no-plots", "--overwrite")  # --overwrite: the named output only
    assert r.exit_code == 2 and "did not write" in r.output and (out / "keep").read_text() == "x"
    (out / "keep").unlink()
    assert cli("report", result, "-o", out, "--no-ladder", "--no-plots").exit_code == 2  # exists, even empty
    assert cli("report", result, "-o", out, "--no-ladder", "--overwrite").exit_code == 0  # an empty directory
    r = cli("report", result, "-o", out, "--no-ladder", "--overwrite")  # a report penfree wrote, plots included
    assert r.exit_code == 0 and {"report.json", "report.md"} <= set(os.listdir(out))


def test_click_rejects_bad_assumptions(cli, result, tmp_path):
    r = cli("report", result, "-o", tmp_path / "rep", "--cd-share", "1.5")
    assert r.exit_code == 2


def test_two_frames_no_next_frame(cli, tmp_path):
    # One step and no next frame: next figures are null, projections n/a, and a
    # speedup threshold cannot be met (a check that cannot be evaluated fails).
    from penfree.formats.result import write_result

    x0 = np.array([[0.0, 0, 0], [0.1, 0, 0], [0.2, 0, 0]])
    seq = Sequence(positions=np.stack([x0, x0 + [0.01, 0, 0]]), edges=np.array([[0, 1], [1, 2]])).validate()
    steps = {"frame": np.array([1]), "A": np.eye(3)[None], "b": np.array([[0.01, 0, 0]]),
             "deformed": seq.positions[1:] + [0.01, 0, 0], "model": np.array(["translation"]),
             "projection": np.array(["none"]), "certificate_margin": np.ones(1), "time_fit_s": np.full(1, 1e-4)}
    f = tmp_path / "two.h5"
    write_result(f, seq, steps, {})
    out = tmp_path / "rep"
    r = cli("report", f, "-o", out, "--no-ladder", "--min-speedup", "0.1")
    assert r.exit_code == 1, r.output
    doc = json.loads((out / "report.json").read_text())
    fr = doc["files"][0]
    assert fr["summary"]["n_steps_next"] == 0 and fr["summary"]["projected"]["k_1pct"]["speedup"] is None
    assert fr["worst_steps"][0]["target"] == "pred"
    assert fr["summary"]["deformed"]["hit_rate_pred"] == 1.0  # deformed exactly onto x_pred
    assert doc["checks"][0]["message"] == "no step with a next frame"
    assert "n/a" in (out / "report.md").read_text()


# ---------------------------------------------------------------- failed swaps, symlinks, damaged results


def test_overwrite_whose_rename_fails_exits_2_and_keeps_old(cli, result, tmp_path, monkeypatch):
    # As on a mount point: the existing report directory cannot be renamed aside.
    import errno

    out = tmp_path / "rep"
    assert cli("report", result, "-o", out, "--no-ladder", "--no-plots").exit_code == 0
    before = {n: (out / n).read_bytes() for n in os.listdir(out)}
    real = os.rename

    def busy(src, dst, *a, **k):
        if os.fspath(src) == str(out):
            raise OSError(errno.EBUSY, "Device or resource busy", os.fspath(src))
        return real(src, dst, *a, **k)

    monkeypatch.setattr(os, "rename", busy)
    r = cli("report", result, "-o", out, "--no-ladder", "--no-plots", "--overwrite", "--frame-ms", "16")
    assert r.exit_code == 2 and "Device or resource busy" in r.stderr and str(out) in r.stderr
    assert {n: (out / n).read_bytes() for n in os.listdir(out)} == before  # the old report, intact
    assert sorted(os.listdir(tmp_path)) == ["rep", "res.h5"]  # no .pf*.tmp / .pf*.old


@pytest.mark.parametrize("spelling", ["", "/"], ids=["link", "link-slash"])
def test_symlinked_report_dir_is_refused(cli, result, tmp_path, spelling):
    real = tmp_path / "real"
    assert cli("report", result, "-o", real, "--no-ladder", "--no-plots").exit_code == 0
    os.symlink("real", tmp_path / "link")
    target = str(tmp_path / "link") + spelling  # (pathlib would drop a trailing separator)
    r = cli("report", result, "-o", target, "--no-ladder", "--no-plots", "--overwrite")
    assert r.exit_code == 2 and "exists and is not a directory" in r.stderr
    assert os.path.islink(tmp_path / "link") and sorted(os.listdir(tmp_path)) == ["link", "real", "res.h5"]


def _tampered(path, change):
    import h5py

    _result_file(path)
    with h5py.File(path, "a") as f:
        change(f)
    return path


def _truncated_result(path):
    _result_file(path)
    data = open(path, "rb").read()
    with open(path, "wb") as fh:
        fh.write(data[: len(data) * 2 // 3])
    return path


@pytest.mark.parametrize("make, match", [
    (lambda p: _tampered(p, lambda f: f.__delitem__("steps/certificate_margin")),
     "missing dataset steps/certificate_margin in {p}:/steps/certificate_margin"),
    (_truncated_result, "{p} is a truncated or damaged HDF5 file"),
    (lambda p: _tampered(p, lambda f: f["steps/b"].__setitem__((1, 0), np.nan)),
     "(frame 2) holds NaN or Inf in {p}:/steps/b"),
    (lambda p: _tampered(p, lambda f: f["steps/frame"].__setitem__(1, 1)),
     "strictly increasing; found 1 then 1 in {p}:/steps/frame"),
], ids=["no-certificate-margin", "truncated", "nan-in-b", "frames-repeat"])
def test_damaged_result_exit_2_names_file_and_dataset(cli, tmp_path, make, match):
    p = str(make(tmp_path / "bad.h5"))
    out = tmp_path / "rep"
    r = cli("report", p, "-o", out, "--no-ladder", "--no-plots")
    assert r.exit_code == 2 and match.format(p=p) in r.stderr, r.output
    assert not out.exists()
