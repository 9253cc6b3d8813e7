"""A stored report.json as a CI baseline: validation, entry matching, what differs."""

import copy
import json

import pytest
from _report_docs import set_in_entry

from penfree._version import __version__
from penfree.errors import InputError
from penfree.constants import BASELINE_K_MAX
from penfree.report.baseline import baseline_warnings, match_baseline, read_baseline
from penfree.report.build import REPORT_SCHEMA
from penfree.report.checks import run_checks


def _entry(file="out/r.h5", k=2.0, speedup=1.2, hit=0.8, cd_share=0.5):
    return {"file": file, "name": file.rsplit("/", 1)[-1],
            "scene": {"kind": "segments", "n_vertices": 6, "n_frames": 6, "dtype": "float64"},
            "deform_options": {"input": "in.h5"},
            "summary": {"hit_rate_gain_next": 0.1, "deformed": {"k_1pct_next": k, "hit_rate_next": hit},
                        "projected": {"cd_share": cd_share, "k_1pct": {"speedup": speedup}}},
            "certificate": {"all_certified": True, "n_uncertified": 0, "uncertified_frames": []}}


def _doc(*entries):
    return {"penfree_report": REPORT_SCHEMA, "penfree_version": __version__,
            "options": {"cd_share": 0.5, "frame_ms": 32.0, "frames": None, "gamma": 0.45},
            "files": list(entries) or [_entry()]}


def _write(tmp_path, doc=None, raw=None):
    p = tmp_path / "base.json"
    p.write_text(raw if raw is not None else json.dumps(doc))
    return p


def test_a_report_json_reads_back(tmp_path):
    assert read_baseline(_write(tmp_path, _doc()), REPORT_SCHEMA)["files"][0]["name"] == "r.h5"


@pytest.mark.parametrize("dotted, value, expect", [
    ("summary", KeyError, "files[0].summary must be an object; got nothing (missing)"),
    ("summary.deformed", KeyError, "files[0].summary.deformed must be an object; got nothing (missing)"),
    ("summary.deformed", 5, "files[0].summary.deformed must be an object; got 5"),
    ("summary.projected.k_1pct", 3, "files[0].summary.projected.k_1pct must be an object; got 3"),
    ("summary.deformed.k_1pct_next", KeyError, "files[0].summary.deformed.k_1pct_next must be null or a mean "
                                               "CD-pass count in [1, 2^53]; got nothing (missing)"),
    ("summary.deformed.k_1pct_next", "12", 'k_1pct_next must be null or a mean CD-pass count in [1, 2^53]; got "12"'),
    ("summary.deformed.k_1pct_next", True, "k_1pct_next must be null or a mean CD-pass count in [1, 2^53]; got true"),
    ("summary.deformed.k_1pct_next", 1e300, "got 1e+300"),
    ("summary.deformed.k_1pct_next", 0.5, "got 0.5"),
    ("summary.deformed.k_1pct_next", 2 * BASELINE_K_MAX, "in [1, 2^53]"),
    ("summary.projected.k_1pct.speedup", -5, "speedup must be null or a projected speedup in (0, 2]"),
    ("summary.projected.k_1pct.speedup", 0, "speedup must be null or a projected speedup in (0, 2]"),
    ("summary.projected.k_1pct.speedup", 50, "(1 / (1 - f), f = 0.5); got 50"),
    ("summary.deformed.hit_rate_next", -3.0, "hit_rate_next must be null or a hit rate in [0, 1]; got -3.0"),
    ("summary.deformed.hit_rate_next", 7.0, "hit_rate_next must be null or a hit rate in [0, 1]; got 7.0"),
    ("summary.projected.cd_share", 1.5, "files[0].summary.projected.cd_share must be a number in [0, 1]"),
    ("name", 5, "files[0].name must be a non-empty string; got 5"),
    ("file", KeyError, "files[0].file must be a non-empty string; got nothing (missing)"),
], ids=["no-summary", "no-deformed", "deformed-number", "k-block-number", "k-missing", "k-string", "k-bool",
        "k-1e300", "k-below-1", "k-beyond-2^53", "speedup-negative", "speedup-zero", "speedup-beyond-1/(1-f)",
        "hit-negative", "hit-above-1", "cd-share", "name-int", "file-missing"])
def test_malformed_baseline_is_an_input_error_naming_file_and_key(tmp_path, dotted, value, expect):
    doc = _doc()
    set_in_entry(doc, dotted, value)
    p = _write(tmp_path, doc)
    with pytest.raises(InputError) as exc:
        read_baseline(p, REPORT_SCHEMA)
    msg = str(exc.value)
    assert msg.startswith(f"baseline {p}: ") and expect in msg and "\n" not in msg


@pytest.mark.parametrize("const", ["NaN", "Infinity", "-Infinity", "1e400"])
def test_non_finite_numbers_are_refused(tmp_path, const):
    raw = json.dumps(_doc()).replace('"speedup": 1.2', f'"speedup": {const}')
    assert const in raw
    with pytest.raises(InputError, match=r"files\[0\]\.summary\.projected\.k_1pct\.speedup is .*strict JSON"):
        read_baseline(_write(tmp_path, raw=raw), REPORT_SCHEMA)


@pytest.mark.parametrize("change, expect", [
    (lambda d: d.update(files=[]), "files must be a non-empty list of objects"),
    (lambda d: d.update(files={}), "files must be a non-empty list of objects"),
    (lambda d: d.pop("penfree_version"), "penfree_version must be a string"),
    (lambda d: d.update(options=[]), "options must be an object"),
    (lambda d: d.update(penfree_report=True), "is not a penfree report.json"),
], ids=["no-files", "files-dict", "no-version", "options-list", "schema-bool"])
def test_malformed_top_level_is_an_input_error(tmp_path, change, expect):
    doc = _doc()
    change(doc)
    with pytest.raises(InputError, match=expect):
        read_baseline(_write(tmp_path, doc), REPORT_SCHEMA)


def _rep(file, **kw):
    e = _entry(file, **kw)
    return {k: e[k] for k in ("file", "name", "scene", "deform_options", "summary", "certificate")}


def test_null_baseline_value_fails_the_check_instead_of_passing():
    doc = _doc()
    doc["files"][0]["summary"]["deformed"]["k_1pct_next"] = None  # how a report writes "no next frame"
    checks = run_checks([_rep("out/r.h5")], baseline=doc, max_regression=5.0)
    by = {c["name"]: c for c in checks}
    assert not by["regression:deformed.k_1pct_next"]["passed"]
    assert "no baseline value" in by["regression:deformed.k_1pct_next"]["message"]
    now_missing = run_checks([_rep("out/r.h5", speedup=None)], baseline=_doc(), max_regression=5.0)
    assert [c["passed"] for c in now_missing] == [True, False, True]


def test_baseline_matched_by_path_not_by_first_base_name():
    # B/r.h5 regressed by 50 %; A/r.h5's entry (listed first) must not stand in for it
    base = _doc(_entry("A/r.h5", k=2.0), _entry("B/r.h5", k=1.0))
    checks = run_checks([_rep("A/r.h5", k=2.0), _rep("B/r.h5", k=1.5)], baseline=base, max_regression=5.0)
    k = [c for c in checks if c["name"] == "regression:deformed.k_1pct_next"]
    assert [(c["file"], c["passed"]) for c in k] == [("A/r.h5", True), ("B/r.h5", False)]
    assert "+50% regression" in k[1]["message"]
    assert match_baseline(["./B/r.h5", "A//r.h5"], base, "b.json") == [(1, "path"), (0, "path")]


def test_base_name_match_only_when_unambiguous():
    base = _doc(_entry("A/r.h5"), _entry("B/r.h5"), _entry("C/s.h5"))
    assert match_baseline(["new/s.h5", "A/r.h5"], base, "b.json") == [(2, "name"), (0, "path")]
    # A/r.h5's entry belongs to the input A/r.h5: the name leaves only B/r.h5 for X/r.h5
    assert match_baseline(["X/r.h5", "A/r.h5"], base, "b.json") == [(1, "name"), (0, "path")]
    assert match_baseline(["X/t.h5", "A/r.h5"], base, "b.json") == [None, (0, "path")]
    with pytest.raises(InputError, match=r"X/r\.h5 matches no entry by path and two by base name r\.h5: "
                                         r"A/r\.h5 and B/r\.h5"):
        match_baseline(["X/r.h5", "new/s.h5"], base, "b.json")
    with pytest.raises(InputError, match=r"both X/s\.h5 and Y/s\.h5 match the entry C/s\.h5 by base name only"):
        match_baseline(["X/s.h5", "Y/s.h5"], base, "b.json")
    with pytest.raises(InputError, match=r"holds two entries for A/r\.h5: files\[0\] and files\[1\]"):
        match_baseline(["A/r.h5", "B/r.h5"], _doc(_entry("A/r.h5"), _entry("./A/r.h5")), "b.json")
    # one file on each side is compared whatever its name (and warned about)
    assert match_baseline(["other/x.h5"], _doc(_entry("A/r.h5")), "b.json") == [(0, "single")]


def test_same_base_names_are_told_apart_in_checks():
    from penfree.report.checks import entry_labels

    reps = [_rep("A/r.h5"), _rep("B/r.h5"), _rep("C/s.h5")]
    assert entry_labels(reps) == ["A/r.h5", "B/r.h5", "s.h5"]
    checks = run_checks(reps, min_speedup=1.0)
    assert [c["file"] for c in checks] == ["A/r.h5", "B/r.h5", "s.h5"]


def test_warnings_name_what_differs():
    base = copy.deepcopy(_doc(_entry("x/other.h5")))
    base["penfree_version"] = "0.0.1-other"
    base["options"]["cd_share"] = 0.9
    base["files"][0]["deform_options"]["input"] = "elsewhere.h5"
    base["files"][0]["scene"]["n_vertices"] = 7
    rep = _rep("out/r.h5")
    options = {"cd_share": 0.5, "frame_ms": 32.0, "frames": None, "gamma": 0.45}
    lines = baseline_warnings(base, "b.json", options, [rep], match_baseline(["out/r.h5"], base, "b.json"))
    assert len(lines) == 2 and all("\n" not in line for line in lines)
    assert f"penfree_version 0.0.1-other (now {__version__})" in lines[0] and "cd_share 0.9 (now 0.5)" in lines[0]
    assert ("file x/other.h5 (now out/r.h5)" in lines[1] and "deform input elsewhere.h5 (now in.h5)" in lines[1]
            and "scene n_vertices 7 (now 6)" in lines[1])
    same = _doc(_entry("out/r.h5"))
    assert baseline_warnings(same, "b.json", options, [rep], match_baseline(["out/r.h5"], same, "b.json")) == []
