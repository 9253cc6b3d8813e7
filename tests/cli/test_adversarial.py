"""Regression tests of issue 9: the adversarial pass over the five commands.

One named test (or parametrised case) per finding. Every command runs through the
`cli` fixture (tests/cli/conftest.py), which asserts the file contract on each
call: no traceback, one stderr line on exit 2, nothing changed but the named
output. The tests below add the exit code and the truth of what is printed.
Finding 6 (zero-motion steps) belongs to issue 10.
"""

import json
import os
import re
import subprocess
import sys

import h5py
import numpy as np
import pytest

from penfree.core.fit.certificate import certify_map
from penfree.formats import write_sequence
from penfree.formats.atomic import atomic_file
from penfree.errors import OutputExistsError
from penfree.sequence import SCALE_MAX, SCALE_MIN, Obstacle, Sequence


def grid(n=8, T=6, scale=1.0, thickness=0.001, **kw):
    """An n x n sheet (spacing 1/(n-1)) in gentle rigid motion; thickness 0.001."""
    g = np.linspace(0.0, 1.0, n)
    X, Y = np.meshgrid(g, g, indexing="ij")
    base = np.stack([X, Y, 0 * X], axis=-1).reshape(-1, 3)
    frames = []
    for t in range(T):
        a = 0.02 * t
        R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        frames.append(base @ R.T + 0.01 * t * np.array([1.0, 0.5, 0.2]))
    F = []
    for i in range(n - 1):
        for j in range(n - 1):
            p, q, r, s = i * n + j, (i + 1) * n + j, i * n + j + 1, (i + 1) * n + j + 1
            F += [[p, q, r], [q, s, r]]
    return Sequence(positions=np.array(frames) * scale, faces=np.array(F), thickness=thickness * scale, **kw)


def rods(T=4):
    x = np.linspace(0.0, 1.0, 5)
    V = np.concatenate([np.c_[x, 0 * x, 0 * x], np.c_[x, 0 * x + 0.5, 0 * x]])
    E = np.array([[r * 5 + i, r * 5 + i + 1] for r in range(2) for i in range(4)])
    return Sequence(positions=np.stack([V + [0.0, 0.0, 0.05 * s] for s in range(T)]), edges=E)


def _write(path, seq):
    write_sequence(str(path), seq.validate())
    return path


@pytest.fixture
def result(cli, tmp_path):
    """A deform result (with stored stats) of grid()."""
    src = _write(tmp_path / "data" / "in.h5", grid())
    out = tmp_path / "data" / "res.h5"
    cli("deform", src, "-o", out, "--stats", expect=0)
    return out


def _replace(path, name, data):
    with h5py.File(path, "r+") as f:
        del f[name]
        f[name] = data


# ---------------------------------------------------------------- 1. data loss

def test_f1_report_overwrite_into_the_input_folder_is_refused(cli, tmp_path, result):
    (tmp_path / "data" / "notes.txt").write_text("mine")
    r = cli("report", result, "-o", tmp_path / "data", "--overwrite", "--no-ladder", "--no-plots", expect=2)
    assert "contains the input" in r.stderr


def test_f1_report_overwrite_into_the_working_directory_is_refused(cli, tmp_path, result, monkeypatch):
    monkeypatch.chdir(tmp_path / "data")
    r = cli("report", "res.h5", "-o", ".", "--overwrite", "--no-ladder", "--no-plots", expect=2)
    assert "penfree: error:" in r.stderr


def test_f1_report_overwrite_keeps_foreign_files(cli, tmp_path, result):
    rep = tmp_path / "rep"
    rep.mkdir()
    (rep / "thesis.tex").write_text("mine")
    r = cli("report", result, "-o", rep, "--overwrite", "--no-ladder", "--no-plots", expect=2)
    assert "thesis.tex" in r.stderr and "did not write" in r.stderr


# ---------------------------------------------------------- 2. inputs by other names

@pytest.fixture
def plyseq(tmp_path):
    write_sequence(str(tmp_path / "seq" / "frame_%04d.ply"), grid(n=4, T=3, thickness=0.0).validate())
    return tmp_path / "seq"


@pytest.mark.parametrize("args", [
    ["seq/frame_%04d.ply", "seq/", "--format", "meshseq"],
    ["seq/", "seq/frame_%04d.ply"],
    ["seq/frame_%04d.ply", "seq/../seq/frame_%04d.ply"],
], ids=["pattern-to-dir", "dir-to-pattern", "pattern-respelled"])
def test_f2_convert_onto_its_own_frames_is_refused(cli, tmp_path, plyseq, monkeypatch, args):
    monkeypatch.chdir(tmp_path)
    r = cli("convert", *args, "--overwrite", expect=2)
    assert "is also an input" in r.stderr


def test_f2_quads_respelled_pattern_is_refused(cli, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "seq").mkdir()
    for s in range(3):
        (tmp_path / "seq" / f"q{s}.obj").write_text(
            f"v 0 0 {s}\nv 1 0 {s}\nv 1 1 {s}\nv 0 1 {s}\nf 1 2 3 4\n")
    cli("convert", "seq/q%d.obj", "seq/q%01d.obj", "--overwrite", expect=2)


def test_f2_deform_output_onto_a_frame_file_is_refused(cli, tmp_path, plyseq, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cli("deform", "seq/frame_%04d.ply", "-o", "seq/frame_0001.ply", "--overwrite", expect=2)


# ------------------------------------------------------ 3. "all steps safe" about nothing

@pytest.mark.parametrize("frames", ["100:200", "5:2", "3:4"])
def test_f3_verify_slice_without_steps_on_a_sequence(cli, tmp_path, frames):
    src = _write(tmp_path / "in.h5", grid())
    r = cli("verify", src, "--frames", frames, expect=2)
    assert "selects no step" in r.stderr and "safe" not in r.output


@pytest.mark.parametrize("frames", ["100:200", "5:2"])
def test_f3_verify_slice_without_steps_on_a_result(cli, result, frames):
    r = cli("verify", result, "--frames", frames, expect=2)
    assert "selects no step" in r.stderr


# -------------------------------------------------------- 4. report trusts stored claims

@pytest.mark.parametrize("tamper", ["reflection", "nan"])
def test_f4_report_reruns_the_certificate(cli, tmp_path, result, tamper):
    with h5py.File(result, "r") as f:
        A = f["steps/A"][()]
    A[2] = np.diag([1.0, 1.0, -1.0]) if tamper == "reflection" else np.nan
    assert not certify_map(A[2])
    _replace(result, "steps/A", A)
    r = cli("report", result, "-o", tmp_path / "rep", "--no-ladder", "--no-plots", "--fail-if-uncertified",
            "--json", expect=1)
    cert = json.loads(r.stdout)["files"][0]["certificate"]
    assert not cert["all_certified"] and 3 in cert["uncertified_frames"]
    cli("verify", result, expect=1 if tamper == "reflection" else 2)


def test_f4_report_refuses_string_maps(cli, tmp_path, result):
    _replace(result, "steps/A", np.array([["x"] * 3] * 3 * 5, dtype=object).reshape(5, 3, 3).astype("S1"))
    r = cli("report", result, "-o", tmp_path / "rep", "--no-ladder", "--no-plots", "--fail-if-uncertified", expect=2)
    assert "steps/A" in r.stderr


def test_f4_report_accepts_the_untampered_result(cli, tmp_path, result):
    r = cli("report", result, "-o", tmp_path / "rep", "--no-ladder", "--no-plots", "--json")
    assert r.exit_code in (0, 1)
    with h5py.File(result, "r") as f:
        A, m = f["steps/A"][()], f["steps/margin_required"][()]
    rechecked = [bool(certify_map(a, mm)) if mm < 1 else bool(np.array_equal(a, np.eye(3))) for a, mm in zip(A, m)]
    cert = json.loads(r.stdout)["files"][0]["certificate"]
    assert cert["n_uncertified"] >= rechecked.count(False)


# ------------------------------------------------------ 7. two writers of one new output

OTHER_WRITER = """
import sys
from penfree.formats.atomic import atomic_file
with atomic_file(sys.argv[1]) as tmp:
    open(tmp, "w").write("other, faster")
"""


def test_f7_second_writer_of_a_new_output_gets_output_exists(tmp_path):
    target = tmp_path / "out.h5"
    with pytest.raises(OutputExistsError, match="exists"):
        with atomic_file(target) as tmp1:
            open(tmp1, "w").write("this one, slower")
            # another process creates the same new output while this one writes
            subprocess.run([sys.executable, "-c", OTHER_WRITER, str(target)], check=True)
    assert target.read_text() == "other, faster"  # never silently replaced
    assert sorted(os.listdir(tmp_path)) == ["out.h5"]


def test_f7_concurrent_deform_gets_output_exists(cli_process, tmp_path):
    src = _write(tmp_path / "in.h5", grid(n=4, T=3))
    other = _write(tmp_path / "other.h5", grid(n=4, T=4))
    out = tmp_path / "out.h5"
    hook = ("import subprocess, sys\n"
            f"subprocess.run([sys.executable, '-m', 'penfree', 'deform', {str(other)!r}, '-o', {str(out)!r}], check=True)")
    r = cli_process("deform", src, "-o", out, during_write=hook, expect=2, concurrent=True)
    assert "exists" in r.stderr
    with h5py.File(out, "r") as f:  # the other writer's result, complete
        assert f["positions"].shape[0] == 4


# ------------------------------------------------------------ 8. convert drops data

@pytest.mark.parametrize("out", ["m/r_%03d.stl", "m/r_%03d.off"])
def test_f8_rods_to_formats_without_lines_are_refused(cli, tmp_path, out):
    src = _write(tmp_path / "rods.h5", rods())
    r = cli("convert", src, tmp_path / out, expect=2)
    assert "cannot hold the edges" in r.stderr


def test_f8_obstacles_to_mesh_files_are_refused(cli, tmp_path):
    seq = grid(n=4, T=3)
    seq.obstacles.append(Obstacle("floor", np.array([[0, 0, -1], [1, 0, -1], [0, 1, -1.0]]), faces=np.array([[0, 1, 2]])))
    src = _write(tmp_path / "in.h5", seq)
    r = cli("convert", src, tmp_path / "m" / "f_%03d.ply", expect=2)
    assert "obstacles (floor)" in r.stderr


# ------------------------------------------------------------ 9. tracebacks

def _h5_with(path, seq=None, **extra):
    _write(path, seq or grid(n=4, T=3))
    with h5py.File(path, "r+") as f:
        for k, v in extra.items():
            if k.startswith("@"):
                f.attrs[k[1:]] = v
            elif v is None:
                f.create_group(k)
            else:
                f[k] = v
    return path


def _npz(path, **arrays):
    seq = grid(n=4, T=3)
    np.savez(path, positions=seq.positions, faces=seq.faces, **arrays)
    return path


def _xdmf(path, edit):
    write_sequence(str(path), grid(n=4, T=3).validate())
    text = path.read_text()
    m = re.search(r'Name="penfree" Value="([^"]*)"', text)
    import html

    info = json.loads(html.unescape(m.group(1)))
    edit(info)
    new = html.escape(json.dumps(info), quote=True)
    path.write_text(text[:m.start(1)] + new + text[m.end(1):])
    return path


def _xdmf_string_weights(path):
    seq = grid(n=4, T=3)
    seq.weights = np.ones(seq.positions.shape[1])
    write_sequence(str(path), seq.validate())
    with h5py.File(str(path) + ".h5", "r+") as f:
        del f["main/weights"]
        f["main/weights"] = np.array(["a"] * seq.positions.shape[1], dtype="S1")
    return path


TRACEBACK_CASES = {
    "thickness-nan": (lambda p: _h5_with(p / "in.h5"), ["deform", "{in}", "-o", "{out}", "--thickness", "nan"]),
    "thickness-inf": (lambda p: _h5_with(p / "in.h5"), ["deform", "{in}", "-o", "{out}", "--thickness", "inf"]),
    "weights-1e-320": (lambda p: _h5_with(p / "in.h5", weights=np.full(16, 1e-320)), ["deform", "{in}", "-o", "{out}"]),
    "weights-group": (lambda p: _h5_with(p / "in.h5", w=None), ["deform", "{in}", "-o", "{out}", "--weights", "w"]),
    "weights-strings": (lambda p: _h5_with(p / "in.h5", w=np.array(["a"] * 16, dtype="S1")),
                        ["deform", "{in}", "-o", "{out}", "--weights", "w"]),
    "npz-attrs-list": (lambda p: _npz(p / "in.npz", attrs_json=np.str_("[1, 2]")), ["info", "{in}"]),
    "npz-string-weights": (lambda p: _npz(p / "in.npz", weights=np.array(["a"] * 16)), ["info", "{in}"]),
    "xdmf-attrs-list": (lambda p: _xdmf(p / "in.xdmf", lambda i: i.update(attrs=[1, 2])), ["info", "{in}"]),
    "xdmf-dt-string": (lambda p: _xdmf(p / "in.xdmf", lambda i: i.update(dt="soon")), ["info", "{in}"]),
    "xdmf-string-weights": (lambda p: _xdmf_string_weights(p / "in.xdmf"), ["info", "{in}"]),
    "h5-json-attr": (lambda p: _h5_with(p / "in.h5", **{"@note": "json:{not json"}), ["info", "{in}"]),
    "h5-json-thickness": (lambda p: _h5_with(p / "in.h5", **{"@thickness": "json:["}), ["verify", "{in}"]),
    "trailing-slash": (lambda p: _h5_with(p / "in.h5"), ["deform", "{in}", "-o", "{dir}/out/"]),
}


@pytest.mark.parametrize("case", sorted(TRACEBACK_CASES))
def test_f9_unusable_input_is_one_line(cli, tmp_path, case):
    make, args = TRACEBACK_CASES[case]
    src = make(tmp_path)
    args = [a.format(**{"in": src, "out": tmp_path / "out.h5", "dir": tmp_path}) for a in args]
    r = cli(*args, expect=2)
    assert "penfree: error:" in r.stderr


@pytest.mark.parametrize("name,bad", [("steps/A", "strings"), ("steps/certificate_margin", "strings")])
def test_f9_string_per_step_datasets(cli, result, name, bad):
    with h5py.File(result, "r") as f:
        shape = f[name].shape
    _replace(result, name, np.full(shape, b"x", dtype="S1"))
    r = cli("verify", result, expect=2)
    assert name in r.stderr


@pytest.mark.parametrize("content", ['{"penfree_report": 1, "files": "x"}',
                                     '{"penfree_report": 1, "files": [{"name": "res.h5", "summary": '
                                     '{"deformed": {"k_1pct_next": "fast"}}}]}', "{not json"])
def test_f9_malformed_baseline(cli, tmp_path, result, content):
    base = tmp_path / "base.json"
    base.write_text(content)
    cli("report", result, "-o", tmp_path / "rep", "--baseline", base, "--max-regression", "5", "--no-ladder",
        "--no-plots", expect=2)


# ------------------------------------------------------------ 10. a false printed bound

def _two_sheets(gap, n=4, T=3):
    a = grid(n=n, T=T, thickness=0.0)
    pos = a.positions
    both = np.concatenate([pos, pos + [0.0, 0.0, gap]], axis=1)
    N = pos.shape[1]
    return Sequence(positions=both, faces=np.concatenate([a.faces, a.faces + N]))


def _printed_bounds(text):
    return [float(x) for x in re.findall(r"min separation >= ([0-9.e+-]+)", text)]


@pytest.mark.parametrize("gap,thickness", [(0.01, 0.009), (0.0064, 0.001)], ids=["triangles-0.01", "sheets-0.0064"])
def test_f10_printed_separation_is_a_true_lower_bound(cli, tmp_path, gap, thickness):
    seq = _two_sheets(gap, n=2 if gap == 0.01 else 8)
    seq.thickness = thickness
    src = _write(tmp_path / "in.h5", seq)
    r = cli("verify", src, expect=0)
    bounds = _printed_bounds(r.stdout)
    assert bounds and "inf" not in r.stdout
    assert max(bounds) <= gap  # rigid motion: the sheets stay exactly `gap` apart
    res = tmp_path / "res.h5"
    cli("deform", src, "-o", res, expect=0)
    r = cli("verify", res, "--mode", "ccd", expect=0)
    assert max(_printed_bounds(r.stdout)) <= gap * (1 + 1e-6)
    r = cli("verify", res, "--json", expect=0)
    assert all(s["min_separation"] is not None and s["min_separation"] <= gap * (1 + 1e-6)
               for s in json.loads(r.stdout)["steps"])


# ------------------------------------------------------------ 11. convert writes what penfree rejects

def test_f11_negative_dt_is_refused(cli, tmp_path):
    src = _npz(tmp_path / "in.npz", dt=np.float64(-0.01))
    r = cli("convert", src, tmp_path / "out.h5", expect=2)
    assert "dt" in r.stderr


def test_f11_empty_obstacle_name_is_refused(cli, tmp_path):
    src = _npz(tmp_path / "in.npz", **{"obstacles//positions": np.zeros((3, 3)),
                                       "obstacles//faces": np.array([[0, 1, 2]])})
    r = cli("convert", src, tmp_path / "out.h5", expect=2)
    assert "obstacle names" in r.stderr


# ------------------------------------------------------------ 12. extreme magnitudes

@pytest.mark.parametrize("scale", [1e-300, 1e-120, 1e120, 1e300])
@pytest.mark.parametrize("command", ["info", "verify"])
def test_f12_out_of_range_scenes_are_refused_with_the_range(cli, tmp_path, scale, command):
    src = tmp_path / "in.h5"
    with h5py.File(src, "w") as f:  # written raw: penfree's writer refuses such scenes
        seq = grid()
        f["positions"] = seq.positions * scale
        f["faces"] = seq.faces
        f.attrs["thickness"] = 0.001 * scale if scale < 1 else 0.0
    r = cli(command, src, expect=2)
    assert f"[{SCALE_MIN:g}, {SCALE_MAX:g}]" in r.stderr and "Warning" not in r.output


@pytest.mark.parametrize("scale", [1e-90, 1e90])
def test_f12_in_range_scenes_verify(cli, tmp_path, scale):
    src = _write(tmp_path / "in.h5", grid(scale=scale))
    r = cli("verify", src, expect=0)
    assert "Warning" not in r.output


# ------------------------------------------------------------ 13. wrong diagnosis

def test_f13_overflowing_weights_are_blamed_on_the_weights(cli, tmp_path):
    src = _h5_with(tmp_path / "in.h5", weights=np.full(16, 1e308))
    r = cli("deform", src, "-o", tmp_path / "out.h5", expect=2)
    assert "weights" in r.stderr and "positions" not in r.stderr and "Warning" not in r.output


def test_f13_unreadable_file_is_not_called_not_hdf5(cli, tmp_path, monkeypatch):
    import penfree.formats.hdf5 as hdf5

    src = _write(tmp_path / "in.h5", grid())
    real_open = open

    def denied(path, *a, **k):
        if os.fspath(path) == str(src):
            raise PermissionError(13, "Permission denied", str(src))
        return real_open(path, *a, **k)

    monkeypatch.setattr(hdf5, "open", denied, raising=False)
    r = cli("info", src, expect=2)
    assert "Permission denied" in r.stderr and "not an HDF5" not in r.stderr


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root reads any file")
def test_f13_unreadable_file_by_permissions(cli, tmp_path):
    src = _write(tmp_path / "in.h5", grid())
    os.chmod(src, 0)
    r = cli("info", src, expect=2)
    assert "not an HDF5" not in r.stderr


def test_f13_group_in_place_of_obstacle_positions_is_named(cli, tmp_path):
    src = _write(tmp_path / "in.h5", grid(n=4, T=3))
    with h5py.File(src, "r+") as f:
        f.create_group("obstacles/floor/positions")
        f["obstacles/floor/faces"] = np.array([[0, 1, 2]])
    r = cli("info", src, expect=2)
    assert "obstacles/floor/positions" in r.stderr and "group" in r.stderr


# ------------------------------------------------------------ 14. option errors

@pytest.mark.parametrize("args", [
    ["deform", "{in}", "-o", "{out}", "--margin", "1.0"],
    ["deform", "{in}", "-o", "{out}", "--threads", "0"],
    ["deform", "{in}", "-o", "{dir}"],
    ["report", "{dir}", "-o", "{dir}/rep"],
    ["verify", "{in}", "--no-such-option"],
    ["info"],
    ["deform", "{in}", "-o", "{out}", "--margin", "nan"],
    ["report", "{in}", "-o", "{dir}/rep", "--cd-share", "nan"],
    ["report", "{in}", "-o", "{dir}/rep", "--min-speedup", "inf"],
], ids=["margin", "threads", "output-is-dir", "input-is-dir", "unknown-option", "missing-argument", "margin-nan",
        "cd-share-nan", "min-speedup-inf"])
def test_f14_option_errors_are_one_line(cli, tmp_path, args):
    src = _write(tmp_path / "in.h5", grid(n=4, T=3))
    args = [a.format(**{"in": src, "out": tmp_path / "out.h5", "dir": tmp_path}) for a in args]
    r = cli(*args, expect=2)
    assert "Usage:" not in r.output


# ------------------------------------------------------------ 15. long output names

def test_f15_a_249_byte_output_name_is_written(cli, tmp_path):
    src = _write(tmp_path / "in.h5", grid(n=4, T=3))
    name = "o" * 246 + ".h5"
    assert len(name.encode()) == 249
    cli("deform", src, "-o", tmp_path / name, expect=0)
    assert (tmp_path / name).is_file()
    cli("convert", src, tmp_path / ("x" * 244 + ".xdmf"), expect=0)  # + its .xdmf.h5: 252 bytes


# ------------------------------------------------------------ 5. signals

KILL = "import os, signal; os.kill(os.getpid(), signal.{})"


@pytest.mark.parametrize("sig,code", [("SIGINT", 130), ("SIGTERM", 143)])
@pytest.mark.parametrize("phase", ["before_read", "during_write"])
def test_f5_signals_leave_nothing_and_one_line(cli_process, tmp_path, sig, code, phase):
    src = _write(tmp_path / "in.h5", grid(n=4, T=3))
    r = cli_process("deform", src, "-o", tmp_path / "out.h5", **{phase: KILL.format(sig)}, expect=code)
    assert "no output written" in r.stderr
    assert sorted(os.listdir(tmp_path)) == ["in.h5"]


@pytest.mark.parametrize("args", [["convert", "{in}", "{dir}/out.xdmf"], ["convert", "{in}", "{dir}/m/f_%03d.obj"],
                                  ["convert", "{in}", "{dir}/new/deeper/out.xdmf"],
                                  ["deform", "{in}", "-o", "{dir}/new/deeper/out.h5"],
                                  ["report", "{res}", "-o", "{dir}/rep", "--no-ladder", "--no-plots"]],
                         ids=["xdmf", "meshseq", "xdmf-new-dirs", "deform-new-dirs", "report"])
def test_f5_sigterm_while_writing_other_outputs(cli_process, tmp_path, result, args):
    src = tmp_path / "data" / "in.h5"
    args = [a.format(**{"in": src, "dir": tmp_path, "res": result}) for a in args]
    cli_process(*args, during_write=KILL.format("SIGTERM"), expect=143)


# ------------------------------------------------------------ the promises, in --help and the README

@pytest.mark.parametrize("command", ["deform", "convert", "report"])
def test_overwrite_help_says_what_the_readme_promises(cli, command):
    from penfree.cli.options import FILE_PROMISES

    readme = open(os.path.join(os.path.dirname(__file__), "..", "..", "README.md"), encoding="utf-8").read()
    section = readme.split("### What penfree promises about your files", 1)[1].split("\n\n", 2)[1]
    assert " ".join(section.split()) == FILE_PROMISES
    r = cli(command, "--help", expect=0)
    assert " ".join(FILE_PROMISES.split()) in " ".join(r.stdout.split())


def _two_objects():
    a = grid(n=4, T=4, thickness=0.0)
    b = grid(n=4, T=4, thickness=0.0)
    pos_b = b.positions + np.array([0.0, 0.0, 0.5])
    pos_b[:, :, 0] -= 0.02 * np.arange(4)[:, None]
    return Sequence(positions=np.concatenate([a.positions, pos_b], axis=1),
                    faces=np.concatenate([a.faces, b.faces + 16]))


@pytest.mark.parametrize("tamper", [None, "reflection", "missing"])
def test_f4_report_rechecks_per_component_maps(cli, tmp_path, tamper):
    src = _write(tmp_path / "in.h5", _two_objects())
    res = tmp_path / "res.h5"
    cli("deform", src, "-o", res, "--model", "per-component", expect=0)
    with h5py.File(res, "r+") as f:
        assert np.isnan(f["steps/A"][()]).all()
        if tamper == "reflection":
            comp = f["component_maps/A"][()]
            comp[1, 0] = np.diag([1.0, -1.0, 1.0])
            _replace_in(f, "component_maps/A", comp)
        elif tamper == "missing":
            del f["component_maps/A"]
    r = cli("report", res, "-o", tmp_path / "rep", "--no-ladder", "--no-plots", "--fail-if-uncertified", "--json")
    cert = json.loads(r.stdout)["files"][0]["certificate"]
    if tamper is None:
        assert r.exit_code == 0 and cert["all_certified"]
    else:
        assert r.exit_code == 1 and not cert["all_certified"]


def _replace_in(f, name, data):
    del f[name]
    f[name] = data
