"""``penfree convert``: every format pair it is meant for, overwrite rules, input safety, atomicity."""

import os

import numpy as np
import pytest

from penfree.formats import read_sequence, write_sequence
from penfree.sequence import Sequence


def _seq(dtype=np.float32):
    rng = np.random.default_rng(23)
    return Sequence(positions=rng.random((3, 5, 3)).astype(dtype), faces=np.array([[0, 1, 2], [2, 3, 4]]),
                    edges=np.array([[0, 4]]), thickness=0.05, dt=0.02, source="conv").validate()


def _snapshot(d):
    out = {}
    for root, _, files in os.walk(d):
        for n in files:
            p = os.path.join(root, n)
            out[os.path.relpath(p, d)] = (open(p, "rb").read(), os.stat(p).st_mtime_ns)
    return out


OUTPUTS = {
    "npz": ("out.npz", "out.npz"),
    "xdmf": ("out.xdmf", "out.xdmf"),
    "ply-pattern": ("mesh/A%08d.ply", "mesh/A%08d.ply"),
    "obj-dir": ("objs/frame_0000.obj", "objs/frame_%04d.obj"),
    "hdf5": ("again.h5", "again.h5"),
}


@pytest.mark.parametrize("dtype", [np.float32, np.float64], ids=["float32", "float64"])
@pytest.mark.parametrize("target", list(OUTPUTS))
def test_convert_and_back(cli, tmp_path, target, dtype):
    src = tmp_path / "in.h5"
    seq = _seq(dtype)
    write_sequence(src, seq)
    before = _snapshot(tmp_path)
    out, read_as = OUTPUTS[target]
    r = cli("convert", src, tmp_path / out)
    assert r.exit_code == 0, r.output
    assert "wrote" in r.stdout and "3 frames, 5 vertices" in r.stdout
    assert {k: v for k, v in _snapshot(tmp_path).items() if k in before} == before  # input untouched
    back = read_sequence(tmp_path / read_as)
    assert back.positions.dtype == dtype
    np.testing.assert_array_equal(back.positions, seq.positions)
    np.testing.assert_array_equal(back.faces, seq.faces)
    np.testing.assert_array_equal(back.edges, seq.edges)
    # and back to HDF5
    r = cli("convert", tmp_path / read_as, tmp_path / "back.h5")
    assert r.exit_code == 0, r.output
    np.testing.assert_array_equal(read_sequence(tmp_path / "back.h5").positions, seq.positions)
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".pf")]


def test_format_options(cli, tmp_path):
    src = tmp_path / "in.h5"
    write_sequence(src, _seq())
    (tmp_path / "in.h5").rename(tmp_path / "in.bin")
    r = cli("convert", tmp_path / "in.bin", tmp_path / "meshes", "--from-format", "hdf5", "--format", "meshseq")
    assert r.exit_code == 0, r.output
    assert sorted(os.listdir(tmp_path / "meshes")) == ["frame_0000.ply", "frame_0001.ply", "frame_0002.ply"]
    r = cli("convert", tmp_path / "in.bin", tmp_path / "x.dat")
    assert r.exit_code == 2 and "cannot tell the format of" in r.stderr and "x.dat" in r.stderr


def test_existing_output_needs_overwrite(cli, tmp_path):
    src, dst = tmp_path / "in.h5", tmp_path / "out.npz"
    write_sequence(src, _seq())
    dst.write_bytes(b"precious")
    r = cli("convert", src, dst)
    assert r.exit_code == 2 and "exists" in r.stderr and "--overwrite" in r.stderr
    assert dst.read_bytes() == b"precious"
    r = cli("convert", src, dst, "--overwrite")
    assert r.exit_code == 0, r.output
    assert read_sequence(dst).n_frames == 3


def test_existing_heavy_data_counts_as_output(cli, tmp_path):
    src = tmp_path / "in.h5"
    write_sequence(src, _seq())
    (tmp_path / "out.xdmf.h5").write_bytes(b"precious")
    r = cli("convert", src, tmp_path / "out.xdmf")
    assert r.exit_code == 2 and "out.xdmf.h5 exists" in r.stderr
    assert sorted(os.listdir(tmp_path)) == ["in.h5", "out.xdmf.h5"]


@pytest.mark.parametrize("out", ["in.h5", "./in.h5", "in.xdmf.h5"], ids=["same", "same-spelled-differently", "xdmf-heavy-data"])
def test_output_may_not_be_an_input(cli, tmp_path, out):
    src = tmp_path / "in.h5"
    write_sequence(src, _seq())
    write_sequence(tmp_path / "in.xdmf", _seq())
    inp = tmp_path / ("in.xdmf" if out == "in.xdmf.h5" else "in.h5")
    before = _snapshot(tmp_path)
    r = cli("convert", inp, str(tmp_path / out), "--overwrite")
    assert r.exit_code == 2 and "is also an input" in r.stderr
    assert _snapshot(tmp_path) == before


def test_failure_midway_leaves_no_file(cli, tmp_path, monkeypatch):
    import penfree.formats.hdf5 as hdf5

    src = tmp_path / "in.npz"
    write_sequence(src, _seq())
    real = hdf5.write_positions

    def boom(*a, **k):
        real(*a, **k)
        raise KeyboardInterrupt  # Ctrl-C after the positions were written

    monkeypatch.setattr(hdf5, "write_positions", boom)
    r = cli("convert", src, tmp_path / "out.h5")
    assert r.exit_code == 130 and "no output written" in r.stderr
    assert sorted(os.listdir(tmp_path)) == ["in.npz"]


def test_deformed_states_export(cli, tmp_path):
    # A deform result's deformed states become a sequence (one frame per step) that
    # ParaView can animate; a raw sequence is refused with exit 2 and nothing written.
    src = tmp_path / "in.h5"
    write_sequence(src, _seq(np.float64))
    res = tmp_path / "res.h5"
    assert cli("deform", src, "-o", res).exit_code == 0
    r = cli("convert", res, tmp_path / "def.xdmf", "--deformed")
    assert r.exit_code == 0, r.output
    from penfree.formats.result import read_result

    steps = read_result(res).steps
    back = read_sequence(tmp_path / "def.xdmf")
    np.testing.assert_array_equal(back.positions, steps["deformed"])
    np.testing.assert_array_equal(back.faces, _seq().faces)
    bad = cli("convert", src, tmp_path / "x.xdmf", "--deformed")
    assert bad.exit_code == 2 and not (tmp_path / "x.xdmf").exists()
    assert "in.h5" in bad.output


def _cloth(path):
    """A 16-vertex cloth, 6 frames (float64)."""
    g = np.stack(np.meshgrid(np.arange(4.0), np.arange(4.0)), -1).reshape(-1, 2)
    p0 = np.column_stack([g, np.zeros(16)])
    faces = [[i * 4 + j, i * 4 + j + 1, i * 4 + j + 5] for i in range(3) for j in range(3)]
    seq = Sequence(positions=np.stack([p0 + [0, 0, 0.1 * t] for t in range(6)]), faces=np.array(faces)).validate()
    write_sequence(path, seq)
    return seq


def test_meshio_heavy_data_is_an_input(cli, tmp_path, monkeypatch):
    import meshio

    monkeypatch.chdir(tmp_path)
    seq = _cloth(tmp_path / "a.h5")
    with meshio.xdmf.TimeSeriesWriter("sim.xdmf") as w:  # arrays in sim.h5 (meshio's default name)
        w.write_points_cells(seq.positions[0], [("triangle", seq.faces)])
        for s in range(seq.n_frames):
            w.write_data(float(s), point_data={"positions": seq.positions[s]})
    r = cli("convert", "sim.xdmf", "sim.h5", "--overwrite", expect=2)  # the contract checks nothing changed
    assert "sim.h5 is also an input" in r.stderr
    np.testing.assert_array_equal(read_sequence("sim.xdmf").positions, seq.positions)


@pytest.mark.parametrize("user_file", ["frame_0009.ply", "frame_9.ply"])
def test_overwrite_never_deletes_a_users_frame(cli, tmp_path, user_file):
    _cloth(tmp_path / "a.h5")
    (tmp_path / "userdir").mkdir()
    (tmp_path / "userdir" / user_file).write_text("mine")
    r = cli("convert", tmp_path / "a.h5", tmp_path / "userdir", "--format", "meshseq", "--overwrite", expect=2)
    assert user_file in r.stderr and "did not write" in r.stderr
    assert os.listdir(tmp_path / "userdir") == [user_file]
    assert (tmp_path / "userdir" / user_file).read_text() == "mine"


def test_overwrite_replaces_exactly_the_frames_it_writes(cli, tmp_path):
    seq = _cloth(tmp_path / "a.h5")
    cli("convert", tmp_path / "a.h5", tmp_path / "ply", "--format", "meshseq", expect=0)
    (tmp_path / "ply" / "notes.txt").write_text("mine")
    r = cli("convert", tmp_path / "a.h5", tmp_path / "ply", "--format", "meshseq", "--overwrite", expect=0)
    assert "notes.txt" not in str(r.changed) and (tmp_path / "ply" / "notes.txt").read_text() == "mine"
    assert sorted(os.listdir(tmp_path / "ply")) == [f"frame_{s:04d}.ply" for s in range(6)] + ["notes.txt"]
    np.testing.assert_array_equal(read_sequence(tmp_path / "ply" / "frame_%04d.ply").positions, seq.positions)


@pytest.mark.parametrize("out", ["ply2/frame_%02d.ply", "ply2", "ply2/", "ply2/out.h5", "ply2/sub/out.npz"],
                         ids=["other-pattern", "same-directory", "same-directory-slash", "file-inside", "deeper"])
def test_output_inside_an_input_directory_is_refused(cli, tmp_path, out):
    _cloth(tmp_path / "a.h5")
    cli("convert", tmp_path / "a.h5", tmp_path / "ply2", "--format", "meshseq", expect=0)
    args = ["--format", "meshseq"] if out.startswith("ply2") and "." not in out else []
    r = cli("convert", tmp_path / "ply2", str(tmp_path / out), "--overwrite", *args, expect=2)
    assert "ply2" in r.stderr and "input" in r.stderr
    assert read_sequence(tmp_path / "ply2").n_frames == 6


@pytest.mark.parametrize("name", ["d.h5", "d.npz", "d.xdmf"])
def test_file_output_that_is_a_directory(cli, tmp_path, name):
    _cloth(tmp_path / "a.h5")
    (tmp_path / name).mkdir()
    r = cli("convert", tmp_path / "a.h5", tmp_path / name, "--overwrite", expect=2)
    assert f"{name} is a directory" in r.stderr
    assert os.listdir(tmp_path / name) == []


def test_damaged_npz_member_exit_2(cli, tmp_path):
    import io
    import zipfile

    buf = io.BytesIO()
    np.save(buf, np.zeros((6, 16, 3)))
    with zipfile.ZipFile(tmp_path / "trunc_member.npz", "w") as z:
        z.writestr("positions.npy", buf.getvalue()[: len(buf.getvalue()) // 2])
    for args in (["info", tmp_path / "trunc_member.npz"], ["convert", tmp_path / "trunc_member.npz", tmp_path / "o.h5"]):
        r = cli(*args, expect=2)
        assert "trunc_member.npz:/positions" in r.stderr
