"""``penfree report``: files written, exit codes of the CI checks, unusable input."""

import json
import math
import os

import h5py
import numpy as np
import pytest
from _report_docs import set_in_entry

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


# ---------------------------------------------------------------- CI checks that must not pass falsely


def _moved_vertex(f):
    d = f["steps/deformed"][()]
    d[2, 1, 0] += 1e-4  # far below the vertex spacing (0.1), far above the rounding
    f["steps/deformed"][...] = d


def _map_off_2pct(f):
    A = f["steps/A"][()]
    A[2] = A[2] @ np.diag([1.02, 0.98, 1.01])  # still a certified map, not the applied one
    f["steps/A"][...] = A


def _mirrored(f):
    x = f["positions"][3]
    c = x.mean(axis=0)
    d = f["steps/deformed"][()]
    d[2] = c + (x - c) * [1.0, 1.0, -1.0]  # penetrating path; steps/A still the certified translation
    f["steps/deformed"][...] = d


@pytest.mark.parametrize("change", [_moved_vertex, _map_off_2pct, _mirrored], ids=["moved-vertex", "map-off-2pct",
                                                                                   "mirrored"])
def test_fail_if_uncertified_checks_deformed_is_the_maps_image(cli, tmp_path, change):
    p = _tampered(tmp_path / "forged.h5", change)
    r = cli("report", p, "-o", tmp_path / "rep", "--no-ladder", "--no-plots", "--fail-if-uncertified")
    assert r.exit_code == 1, r.output
    assert "certified: NOT ALL" in r.output and "frames [3]" in r.output
    assert "steps/deformed is not the image A x + b of the stored map at 1 step(s), frames [3]" in r.output
    cert = json.loads((tmp_path / "rep" / "report.json").read_text())["files"][0]["certificate"]
    assert (cert["n_uncertified"], cert["not_applied_frames"]) == (1, [3])


def _baseline_of(cli, result, tmp_path, edit=None, raw=None):
    assert cli("report", result, "-o", tmp_path / "base", "--no-ladder", "--no-plots").exit_code == 0
    doc = json.loads((tmp_path / "base" / "report.json").read_text())
    if edit is not None:
        edit(doc)
    p = tmp_path / "baseline.json"
    p.write_text(raw(json.dumps(doc)) if raw is not None else json.dumps(doc))
    return p


def _set_summary(path, value):
    return lambda doc: set_in_entry(doc, f"summary.{path}", value)


@pytest.mark.parametrize("edit, raw, expect", [
    (_set_summary("deformed", 5), None, "files[0].summary.deformed must be an object; got 5"),
    (_set_summary("deformed.k_1pct_next", KeyError), None, "files[0].summary.deformed.k_1pct_next must be"),
    (lambda d: d["files"][0].pop("summary"), None, "files[0].summary must be an object"),
    (None, lambda s: s.replace('"speedup": ', '"speedup": NaN, "was": ', 1),
     "files[0].summary.projected.k_1pct.speedup is NaN"),
    (_set_summary("projected.k_1pct.speedup", -5), None, "speedup must be null or a projected speedup in (0, 2]"),
    (_set_summary("deformed.hit_rate_next", -3), None, "hit_rate_next must be null or a hit rate in [0, 1]"),
    (_set_summary("deformed.k_1pct_next", 1e300), None, "k_1pct_next must be null or a mean CD-pass count"),
], ids=["block-number", "key-missing", "no-summary", "nan", "speedup-negative", "hit-rate-negative", "k-1e300"])
def test_baseline_that_cannot_be_compared_exits_2(cli, result, tmp_path, edit, raw, expect):
    base = _baseline_of(cli, result, tmp_path, edit, raw)
    out = tmp_path / "new"
    r = cli("report", result, "-o", out, "--no-ladder", "--no-plots", "--baseline", base, "--max-regression", "5")
    assert r.exit_code == 2 and f"baseline {base}: " in r.stderr and expect in r.stderr, r.output
    assert not out.exists()


def test_null_baseline_values_fail_the_regression_checks(cli, result, tmp_path):
    def nulls(doc):
        sm = doc["files"][0]["summary"]
        sm["deformed"]["k_1pct_next"] = sm["deformed"]["hit_rate_next"] = None
        sm["projected"]["k_1pct"]["speedup"] = None
    base = _baseline_of(cli, result, tmp_path, nulls)
    r = cli("report", result, "-o", tmp_path / "new", "--no-ladder", "--no-plots", "--baseline", base,
            "--max-regression", "5")
    assert r.exit_code == 1 and r.output.count("no baseline value") == 3, r.output
    assert "not compared" not in r.output


def test_same_base_name_is_matched_by_path(cli, tmp_path):
    # The audit's reproducer: B/r.h5 regressed; A/r.h5's baseline entry must not stand in for it.
    (tmp_path / "A").mkdir()
    (tmp_path / "B").mkdir()
    a, b = _result_file(tmp_path / "A" / "r.h5"), _result_file(tmp_path / "B" / "r.h5")
    assert cli("report", a, b, "-o", tmp_path / "base", "--no-ladder", "--no-plots").exit_code == 0
    doc = json.loads((tmp_path / "base" / "report.json").read_text())
    assert doc["files"][1]["file"] == b
    doc["files"][1]["summary"]["deformed"]["k_1pct_next"] /= 2  # B needed half the passes then
    base = tmp_path / "base.json"
    base.write_text(json.dumps(doc))
    r = cli("report", a, b, "-o", tmp_path / "new", "--no-ladder", "--no-plots", "--baseline", base,
            "--max-regression", "5")
    assert r.exit_code == 1, r.output
    failed = [c for c in json.loads((tmp_path / "new" / "report.json").read_text())["checks"] if not c["passed"]]
    assert [(c["name"], c["file"]) for c in failed] == [("regression:deformed.k_1pct_next", b)]
    md = (tmp_path / "new" / "report.md").read_text()
    assert f"## {a}\n" in md and f"## {b}\n" in md


def test_ambiguous_base_name_match_exits_2(cli, tmp_path):
    for d in ("A", "B", "C"):
        (tmp_path / d).mkdir()
        _result_file(tmp_path / d / "r.h5")
    a, b, c = (str(tmp_path / d / "r.h5") for d in ("A", "B", "C"))
    assert cli("report", a, b, "-o", tmp_path / "base", "--no-ladder", "--no-plots").exit_code == 0
    out = tmp_path / "new"
    r = cli("report", c, a, "-o", out, "--no-ladder", "--no-plots", "--baseline", tmp_path / "base",
            "--max-regression", "5")
    # A/r.h5's entry is A's by path: C/r.h5 may take B's by base name, the only one left
    assert r.exit_code == 0, r.output
    r = cli("report", c, "-o", tmp_path / "new2", "--no-ladder", "--no-plots", "--baseline", tmp_path / "base",
            "--max-regression", "5")
    assert r.exit_code == 2 and f"{c} matches no entry by path and two by base name r.h5: {a} and {b}" in r.stderr
    assert not (tmp_path / "new2").exists()


def test_baseline_from_another_run_is_warned_about(cli, result, tmp_path):
    def other(doc):
        doc["penfree_version"] = "0.0.1-other"
        doc["options"]["cd_share"] = 0.9
        doc["files"][0]["file"] = "x/something_else.h5"
    base = _baseline_of(cli, result, tmp_path, other)
    r = cli("report", result, "-o", tmp_path / "new", "--no-ladder", "--no-plots", "--baseline", base,
            "--max-regression", "5")
    assert r.exit_code == 0, r.output
    lines = r.stderr.splitlines()
    assert len(lines) == 2 and all(line.startswith("penfree: warning: baseline ") for line in lines)
    assert "penfree_version 0.0.1-other" in lines[0] and "option cd_share 0.9 (now 0.5)" in lines[0]
    assert f"file x/something_else.h5 (now {result})" in lines[1]


def _forged_stats(path):
    import h5py

    from penfree.core.trust.stats import compute_stats
    from penfree.report.build import open_result

    _result_file(path)
    stats = compute_stats(open_result(path))
    with h5py.File(path, "a") as f:
        for k, v in stats.items():
            f[f"stats/{k}"] = v
        for k in ("k_1pct_next_deformed", "k_any_next_deformed", "hit_rate_next_deformed"):
            f[f"stats/{k}"][:4] = 1.0  # forged: one CD pass, every vertex a hit
    return str(path)


def test_ci_checks_compute_statistics_instead_of_trusting_stats(cli, tmp_path):
    p = _forged_stats(tmp_path / "forged.h5")
    r = cli("report", p, "-o", tmp_path / "cache", "--no-ladder", "--no-plots", "--json")
    assert json.loads(r.output)["files"][0]["stats_source"] == "file"  # no check: the group is a cache
    out = tmp_path / "rep"
    r = cli("report", p, "-o", out, "--no-ladder", "--no-plots", "--min-speedup", "1.3")
    assert r.exit_code == 1 and "projected speedup 1.19" in r.output, r.output  # forged: 1.49
    f = json.loads((out / "report.json").read_text())["files"][0]
    assert f["stats_source"] == "computed"
    assert "stored statistics differ from those computed" in f["stats_note"]
    assert sum(line.startswith("Note: stored statistics differ") for line in (out / "report.md").read_text()
               .splitlines()) == 1


def test_threshold_message_shows_the_difference(cli, result, tmp_path):
    # f = 0.45 gives a speedup of 1.167883...: at 3 decimals "1.168", above a minimum of 1.16789
    # that it fails ("projected speedup 1.168 (minimum 1.16789)" read as a pass)
    opts = ["--no-ladder", "--no-plots", "--cd-share", "0.45"]
    r = cli("report", result, "-o", tmp_path / "rep", *opts, "--json")
    v = json.loads(r.output)["files"][0]["summary"]["projected"]["k_1pct"]["speedup"]
    limit = math.ceil(v * 1e5) / 1e5
    assert v < limit < float(f"{v:.3f}")
    r = cli("report", result, "-o", tmp_path / "rep2", *opts, "--min-speedup", str(limit))
    assert r.exit_code == 1
    msg = json.loads((tmp_path / "rep2" / "report.json").read_text())["checks"][0]["message"]
    shown, minimum = msg.removeprefix("projected speedup ").removesuffix(")").split(" (minimum ")
    assert float(shown) < float(minimum) and float(minimum) == limit, msg
    assert len(shown.replace(".", "")) >= 6 and f"{msg}" in r.output


def test_zero_step_result_exits_2(cli, tmp_path):
    from penfree.formats.result import write_result

    x0 = np.array([[0.0, 0, 0], [0.1, 0, 0], [0.2, 0, 0]])
    seq = Sequence(positions=np.stack([x0, x0 + [0.01, 0, 0]]), edges=np.array([[0, 1], [1, 2]])).validate()
    steps = {"frame": np.zeros(0, dtype=np.int64), "A": np.zeros((0, 3, 3)), "b": np.zeros((0, 3)),
             "deformed": np.zeros((0, 3, 3)), "model": np.array([], dtype=str),
             "projection": np.array([], dtype=str), "certificate_margin": np.zeros(0)}
    f = tmp_path / "empty.h5"
    write_result(f, seq, steps, {})
    out = tmp_path / "rep"
    r = cli("report", f, "-o", out, "--no-ladder", "--fail-if-uncertified")
    assert r.exit_code == 2 and f"{f} holds no steps to report" in r.stderr, r.output
    assert "certified" not in r.stdout and not out.exists()


def test_help_shows_no_empty_range(cli):
    r = cli("report", "--help")
    assert r.exit_code == 0 and "None" not in r.output
    assert "--min-speedup X" in r.output and "--min-hit-rate-gain POINTS" in r.output


@pytest.mark.parametrize("opt", [["--truncation", "planar"], ["--radius", "own"], ["--dhat", "0.1"],
                                 ["--every", "2"]], ids=["truncation", "radius", "dhat", "every"])
def test_client_options_without_client_exit_2(cli, result, tmp_path, opt):
    out = tmp_path / "rep"
    r = cli("report", result, "-o", out, "--no-ladder", *opt)
    assert r.exit_code == 2 and f"{opt[0]} applies only to the real-client replay" in r.stderr, r.output
    assert not out.exists()


def _forged_through_the_ground(f):
    # step 3: A = I and b one unit into the ground half-space, deformed its exact image
    s = int(f["steps/frame"][3])
    n = f["obstacles/ground/normal"][()]
    b = -n / np.linalg.norm(n)
    f["steps/A"][3], f["steps/b"][3] = np.eye(3), b
    f["steps/deformed"][3] = (f["positions"][s].astype(np.float64) + b).astype(f["steps/deformed"].dtype)


def _forged_components_into_each_other(f):
    # step 3: component 0's map a translation onto component 1 (certified), deformed its exact image
    from penfree.core.pipeline.components import component_labels

    s = int(f["steps/frame"][3])
    x = f["positions"][s].astype(np.float64)
    lab = component_labels(x.shape[0], None, f["faces"][()], f["components"][()])
    A, b = f["component_maps/A"][3], f["component_maps/b"][3]
    A[0], b[0] = np.eye(3), x[lab == 1].mean(axis=0) - x[lab == 0].mean(axis=0)
    f["component_maps/A"][3], f["component_maps/b"][3] = A, b
    f["steps/deformed"][3] = (np.einsum("nij,nj->ni", A[lab], x) + b[lab]).astype(f["steps/deformed"].dtype)


@pytest.mark.parametrize("sample, model, forge", [
    ("cloth_drape_box", "affine", _forged_through_the_ground),
    ("carried_stack", "per-component", _forged_components_into_each_other),
], ids=["through-the-ground", "components-into-each-other"])
def test_fail_if_uncertified_runs_verify_on_every_path(cli, tmp_path, sample, model, forge):
    """A certificate proves one map's path free of new intersections within the scene; a
    translation through the ground, or two components' certified maps moving them into each
    other, with deformed their exact images, were "certified: all" (exit 0). With
    --fail-if-uncertified a step now also needs verify's check of its path; the genuine
    result still passes."""
    import shutil

    from _samples import SAMPLES

    genuine = tmp_path / "genuine.h5"
    assert cli("deform", SAMPLES / f"{sample}.h5", "-o", genuine, "--model", model, "--frames", "0:8").exit_code == 0
    r = cli("report", genuine, "-o", tmp_path / "rep0", "--no-ladder", "--no-plots", "--fail-if-uncertified")
    assert r.exit_code == 0, r.output
    cert = json.loads((tmp_path / "rep0" / "report.json").read_text())["files"][0]["certificate"]
    assert cert["path_checked"] and cert["n_path_failed"] == 0
    forged = tmp_path / "forged.h5"
    shutil.copy(genuine, forged)
    with h5py.File(forged, "r+") as f:
        frame = int(f["steps/frame"][3])
        forge(f)
    r = cli("report", forged, "-o", tmp_path / "rep", "--no-ladder", "--no-plots", "--fail-if-uncertified")
    assert r.exit_code == 1, r.output
    assert f"verify's check of the path fails at 1 step(s), frames [{frame}]" in r.output, r.output
    assert cli("verify", forged).exit_code == 1
