"""The CLI contract on the scale-out path (``--workers`` / ``--scheduler``, several inputs):
no foreign file deleted, ``-o`` a file for one input and a directory for several, bad
input or an unusable output directory one line and exit 2 with nothing written.

Scenes are a 16-vertex cloth; with 10 frames (9 steps) a file is split into frame
ranges on two workers, with 6 frames it is one task."""

import errno
import os
import tempfile

import h5py
import numpy as np
import pytest
from _scenes import grid_faces, sheet

from penfree.scaleout import plan


def cloth(path, T=6, nan_frame=None):
    """A 4 x 4 cloth drifting up and bending: (T, 16, 3) positions and its faces."""
    u, v = sheet(4)
    x = np.array([np.stack([u, v, 0.01 * t + 0.01 * t * u], axis=1) for t in range(T)])
    if nan_frame is not None:
        x[nan_frame, 2, 1] = np.nan
    with h5py.File(path, "w") as f:
        f["positions"] = x
        f["faces"] = grid_faces(4)
    return str(path)


def deformed(path):
    with h5py.File(path, "r") as f:
        return f["steps/deformed"][()], f["steps/frame"][()]


@pytest.mark.parametrize("T", [6, 10], ids=["whole-file-tasks", "split-into-ranges"])
def test_foreign_parts_directory_survives(cli, tmp_path, scheduler, T):
    a, b = cloth(tmp_path / "a.h5", T), cloth(tmp_path / "b.h5", T)
    assert any(t.lo is not None for t in plan([a, b], 2)) == (T == 10)
    out = tmp_path / "out"
    (out / ".a.parts").mkdir(parents=True)
    (out / ".a.parts" / "thesis.tex").write_text("precious")
    cli("deform", a, b, "-o", out, "--scheduler", scheduler, expect=0)
    assert (out / ".a.parts" / "thesis.tex").read_text() == "precious"
    assert sorted(os.listdir(out)) == [".a.parts", "a.h5", "b.h5"]
    assert sorted(os.listdir(out / ".a.parts")) == ["thesis.tex"]


@pytest.mark.parametrize("T", [6, 10], ids=["whole-file-task", "split-into-ranges"])
def test_one_input_with_workers_writes_the_named_file(cli, tmp_path, scheduler, T):
    a = cloth(tmp_path / "a.h5", T)
    assert any(t.lo is not None for t in plan([a], 2)) == (T == 10)
    cli("deform", a, "-o", tmp_path / "single.h5", "--scheduler", scheduler, expect=0)
    assert (tmp_path / "single.h5").is_file()
    cli("deform", a, "-o", tmp_path / "serial.h5", expect=0)
    for x, y in zip(deformed(tmp_path / "single.h5"), deformed(tmp_path / "serial.h5")):
        np.testing.assert_array_equal(x, y)


def test_one_input_with_workers_refuses_an_output_directory(cli, tmp_path, scheduler):
    a = cloth(tmp_path / "a.h5")
    (tmp_path / "outdir").mkdir()
    r = cli("deform", a, "-o", tmp_path / "outdir", "--scheduler", scheduler, expect=2)
    assert "is a directory" in r.stderr


@pytest.mark.parametrize("spec", ["dir", "glob"])
def test_several_inputs_refuse_a_result_file_name(cli, tmp_path, spec):
    d = tmp_path / "in"
    d.mkdir()
    cloth(d / "a.h5"), cloth(d / "b.h5")
    src = d if spec == "dir" else d / "*.h5"
    r = cli("deform", src, "-o", tmp_path / "x.h5", expect=2)  # before any cluster starts
    assert "-o" in r.stderr and "directory" in r.stderr and "x.h5" in r.stderr
    assert not (tmp_path / "x.h5").exists()


def test_bad_input_writes_nothing(cli, tmp_path, scheduler):
    a, bad = cloth(tmp_path / "a.h5", 10), cloth(tmp_path / "bad.h5", 10, nan_frame=3)
    r = cli("deform", a, bad, "-o", tmp_path / "out3", "--scheduler", scheduler, expect=2)
    assert "bad.h5" in r.stderr and "positions" in r.stderr and "frame 3" in r.stderr
    assert not (tmp_path / "out3").exists()


def test_bad_single_split_input_leaves_no_directory(cli, tmp_path, scheduler):
    bad = cloth(tmp_path / "bad.h5", 10, nan_frame=8)
    cli("deform", bad, "-o", tmp_path / "new" / "bad_def.h5", "--scheduler", scheduler, expect=2)
    assert not (tmp_path / "new").exists()


@pytest.mark.parametrize("command", ["deform", "verify"])
def test_bad_input_local_workers_one_line(cli_process, tmp_path, command):
    # A real process: worker logs go to the terminal, CliRunner would not see them.
    a, bad = cloth(tmp_path / "a.h5"), cloth(tmp_path / "bad.h5", nan_frame=3)
    args = ["-o", tmp_path / "out3"] if command == "deform" else []
    r = cli_process(command, a, bad, *args, "--workers", "1", expect=2)
    assert "bad.h5" in r.stderr and "frame 3" in r.stderr
    assert not (tmp_path / "out3").exists()


def test_output_below_a_file_is_one_line(cli, tmp_path, scheduler):
    a, b = cloth(tmp_path / "a.h5"), cloth(tmp_path / "b.h5")
    (tmp_path / "afile").write_text("x")
    r = cli("deform", a, b, "-o", tmp_path / "afile" / "sub", "--scheduler", scheduler, expect=2)
    assert "afile" in r.stderr
    assert (tmp_path / "afile").read_text() == "x"


def test_read_only_output_directory_is_one_line(cli, tmp_path, scheduler, monkeypatch):
    a, b = cloth(tmp_path / "a.h5"), cloth(tmp_path / "b.h5")
    ro = tmp_path / "ro"
    ro.mkdir()
    real = tempfile.mkdtemp

    def read_only(*args, dir=None, **kw):  # EROFS, as on a read-only mount (root ignores chmod)
        if dir is not None and os.path.realpath(dir).startswith(str(ro)):
            raise OSError(errno.EROFS, "Read-only file system", dir)
        return real(*args, dir=dir, **kw)

    monkeypatch.setattr(tempfile, "mkdtemp", read_only)
    r = cli("deform", a, b, "-o", ro, "--scheduler", scheduler, expect=2)
    assert "Read-only file system" in r.stderr and str(ro) in r.stderr
    assert not os.listdir(ro)


def test_verify_of_no_step_is_exit_2_as_serial(cli, tmp_path, scheduler):
    """With --scheduler, a --frames slice selecting no step said "0 step(s) checked ... all steps safe", exit 0."""
    a, b = cloth(tmp_path / "a.h5", 10), cloth(tmp_path / "b.h5", 10)
    serial = cli("verify", a, "--frames", "50:60", expect=2)
    one = cli("verify", a, "--frames", "50:60", "--scheduler", scheduler, expect=2)
    several = cli("verify", a, b, "--frames", "50:60", "--scheduler", scheduler, expect=2)
    for r in (serial, one, several):
        assert "--frames 50:60 selects no step of" in r.stderr and "a.h5" in r.stderr and "safe" not in r.output


@pytest.mark.parametrize("command,address", [("deform", "bogus"), ("verify", "tcp://"), ("report", "tcp://host:port")])
def test_malformed_scheduler_address_is_one_line(cli, cli_process, tmp_path, command, address):
    """A malformed address raised ValueError: ~74 lines of traceback and exit 1 ("a check failed").
    In a real process: a failed in-process Client can leave its event loop behind."""
    a = cloth(tmp_path / "a.h5")
    if command == "report":
        cli("deform", a, "-o", tmp_path / "a_def.h5", expect=0)
        a = tmp_path / "a_def.h5"
    args = {"deform": ["-o", tmp_path / "out.h5"], "verify": [], "report": ["-o", tmp_path / "rep"]}[command]
    r = cli_process(command, a, *args, "--scheduler", address, expect=2)
    assert f"--scheduler {address}: cannot connect" in r.stderr and len(r.stderr.strip().splitlines()) == 1
