"""Numbered mesh-file sequences: ways to name them, PLY/OBJ/VTU round trips, OBJ polylines, refusals."""

import os

import numpy as np
import pytest

from penfree.errors import FormatError, InputError, OutputExistsError
from penfree.formats import read_sequence, write_sequence
from penfree.formats import meshseq
from penfree.formats.meshseq import frame_files, output_pattern
from penfree.formats.obj import read_obj
from penfree.sequence import Sequence


RNG_SEED = 3  # seed of the shared `rng` fixture (tests/conftest.py)


def _seq(rng, dtype=np.float64, T=3, faces=True, edges=True):
    return Sequence(
        positions=rng.standard_normal((T, 5, 3)).astype(dtype),
        faces=np.array([[0, 1, 2], [1, 3, 2]]) if faces else None,
        edges=np.array([[3, 4], [4, 0]]) if edges else None,
    ).validate()


@pytest.mark.parametrize("ext", ["ply", "obj", "vtu"])
@pytest.mark.parametrize("dtype", [np.float32, np.float64], ids=["float32", "float64"])
def test_round_trip(tmp_path, rng, ext, dtype):
    seq = _seq(rng, dtype)
    pattern = str(tmp_path / "out" / f"A%08d.{ext}")
    write_sequence(pattern, seq)
    assert sorted(os.listdir(tmp_path / "out")) == [f"A{s:08d}.{ext}" for s in range(3)]
    back = read_sequence(pattern)
    assert back.positions.dtype == dtype
    np.testing.assert_array_equal(back.positions, seq.positions)
    np.testing.assert_array_equal(back.faces, seq.faces)
    np.testing.assert_array_equal(back.edges, seq.edges)


@pytest.mark.parametrize("ext", ["ply", "obj", "vtu", "vtk"])
def test_points_only(tmp_path, rng, ext):
    seq = _seq(rng, faces=False, edges=False)
    write_sequence(str(tmp_path / f"p_%02d.{ext}"), seq)
    back = read_sequence(str(tmp_path / f"p_%02d.{ext}"))
    assert back.kind == "points"
    np.testing.assert_array_equal(back.positions, seq.positions)


def test_ways_to_name_a_sequence(tmp_path, rng):
    seq = _seq(rng, T=12)
    d = tmp_path / "frames"
    write_sequence(str(d) + os.sep, seq)  # a directory -> frame_%04d.ply
    expected = [str(d / f"frame_{s:04d}.ply") for s in range(12)]
    assert frame_files(str(d)) == expected
    assert frame_files(str(d / "frame_%04d.ply")) == expected
    assert frame_files(str(d / "frame_*.ply")) == expected
    assert frame_files(str(d / "frame_0005.ply")) == expected  # siblings of one numbered file
    for path in (str(d), str(d / "frame_*.ply"), str(d / "frame_0000.ply")):
        np.testing.assert_array_equal(read_sequence(path).positions, seq.positions)


def test_numeric_not_lexicographic_order(tmp_path, rng):
    seq = _seq(rng, T=11, faces=False)
    for s in range(11):  # unpadded numbers: frame_10 sorts after frame_9
        meshseq._write_mesh(str(tmp_path / f"frame_{s}.obj"), seq.positions[s], seq.edges, None)
    back = read_sequence(str(tmp_path / "frame_*.obj"))
    np.testing.assert_array_equal(back.positions, seq.positions)
    np.testing.assert_array_equal(read_sequence(str(tmp_path / "frame_%d.obj")).positions, seq.positions)


@pytest.mark.parametrize("path,pattern", [
    ("out/", "out/frame_%04d.ply"),
    ("out/cloth.obj", "out/cloth_%04d.obj"),
    ("out/frame_0001.vtu", "out/frame_%04d.vtu"),
    ("out/B%06d.ply", "out/B%06d.ply"),
], ids=["directory", "plain-name", "numbered-name", "pattern"])
def test_output_pattern(path, pattern):
    assert output_pattern(path.replace("/", os.sep)) == pattern.replace("/", os.sep)


OBJ_HANDWRITTEN = """# exported by a rod simulator
o rod
v 0 0 0
v 1 0 0
v 2 0 0 1.0
v 3 0 0
vt 0 0
l 1 2 3
l -2 -1
f 1/1/1 2/1/1 3/1/1 4/1/1
"""


def test_obj_polylines_quads_and_relative_indices(tmp_path):
    p = tmp_path / "rod_0001.obj"
    p.write_text(OBJ_HANDWRITTEN)
    pts, edges, faces = read_obj(str(p))
    assert pts.dtype == np.float64 and pts.shape == (4, 3)
    assert edges.tolist() == [[0, 1], [1, 2], [2, 3]]  # polyline 1-2-3 and relative "l -2 -1"
    assert faces.tolist() == [[0, 1, 2], [0, 2, 3]]  # quad as a fan
    q = tmp_path / "rod_0002.obj"
    q.write_text(OBJ_HANDWRITTEN.replace("v 3 0 0", "v 3 1 0"))
    seq = read_sequence(str(p))
    assert seq.n_frames == 2 and seq.kind == "triangles"
    np.testing.assert_array_equal(seq.positions[1, 3], [3, 1, 0])


@pytest.mark.parametrize("text,expect", [
    ("v 0 0\n", "expected 'v x y z'"),
    ("v 0 0 0\nl 1 x\n", "bad vertex index 'x' on line 2"),
    ("v 0 0 0\nl 0 1\n", "vertex index 0 on line 2"),
    ("# nothing\n", "holds no vertices"),
    ("v 0 0 0\nv 1 0 0\nl -3 -1\n", r"vertex index -3 on line 3 .* points before the first vertex; expected -1 \.\. -2"),
], ids=["short-vertex", "text-index", "zero-index", "empty", "relative-before-first"])
def test_obj_refusals(tmp_path, text, expect):
    p = tmp_path / "f_1.obj"
    p.write_text(text)
    with pytest.raises(FormatError, match=expect):
        read_obj(str(p))


def test_vertex_count_mismatch_names_first_bad_file(tmp_path, rng):
    seq = _seq(rng, T=4)
    write_sequence(str(tmp_path / "f_%02d.obj"), seq)
    (tmp_path / "f_02.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(InputError, match=r"frame 2 has 3 vertices.*f_02\.obj"):
        read_sequence(str(tmp_path / "f_%02d.obj"))


def test_topology_mismatch_names_first_bad_file(tmp_path, rng):
    seq = _seq(rng, T=3)
    write_sequence(str(tmp_path / "f_%02d.ply"), seq)
    other = Sequence(positions=seq.positions, faces=np.array([[0, 1, 2], [1, 3, 4]]), edges=seq.edges).validate()
    meshseq._write_mesh(str(tmp_path / "f_01.ply"), other.positions[1], other.edges, other.faces)
    with pytest.raises(InputError, match=r"frame 1 has a different topology.*f_01\.ply"):
        read_sequence(str(tmp_path / "f_%02d.ply"))


def test_unreadable_mesh_file_is_named_and_silent(tmp_path, rng, capsys):
    write_sequence(str(tmp_path / "f_%02d.ply"), _seq(rng))
    (tmp_path / "f_01.ply").write_text("garbage")
    with pytest.raises(FormatError, match=r"cannot read mesh file .*f_01\.ply"):
        read_sequence(str(tmp_path / "f_00.ply"))
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""  # meshio's console chatter is swallowed


@pytest.mark.parametrize("make,expect", [
    (lambda d: (d / "a_0001.ply").write_text(""), "a sequence needs at least 2 frames"),
    (lambda d: [(d / n).write_text("") for n in ("a_1.ply", "a_2.ply", "b_1.obj", "b_2.obj")],
     "holds several numbered series"),
    (lambda d: (d / "notes.txt").write_text(""), "holds no numbered mesh files"),
], ids=["one-file", "two-series", "no-mesh"])
def test_directory_refusals(tmp_path, make, expect):
    make(tmp_path)
    with pytest.raises(InputError, match=expect):
        read_sequence(str(tmp_path), format="meshseq")


def test_existing_frames_need_overwrite(tmp_path, rng):
    pattern = str(tmp_path / "f_%04d.obj")
    write_sequence(pattern, _seq(rng, T=3))
    (tmp_path / "keep.txt").write_text("mine")
    with pytest.raises(OutputExistsError):
        write_sequence(pattern, _seq(rng, T=3))
    assert len(os.listdir(tmp_path)) == 4
    again = _seq(rng, T=3)
    write_sequence(pattern, again, overwrite=True)
    assert sorted(os.listdir(tmp_path)) == ["f_0000.obj", "f_0001.obj", "f_0002.obj", "keep.txt"]
    np.testing.assert_array_equal(read_sequence(pattern).positions, again.positions)


@pytest.mark.parametrize("extra", ["f_0004.obj", "f_9.obj", "f_00001.obj"],
                         ids=["longer-earlier-run", "unpadded", "other-padding"])
def test_overwrite_never_removes_frames_it_does_not_write(tmp_path, rng, extra):
    # A frame file this write does not replace could be anyone's (penfree cannot tell), and
    # leaving it would make the series read back with an extra frame: refuse, remove nothing.
    pattern = str(tmp_path / "f_%04d.obj")
    first = _seq(rng, T=3)
    write_sequence(pattern, first)
    (tmp_path / extra).write_text("mine")
    before = {n: (tmp_path / n).read_bytes() for n in os.listdir(tmp_path)}
    for overwrite in (True, False):
        with pytest.raises(InputError) as err:
            write_sequence(pattern, _seq(rng, T=3), overwrite=overwrite)
        assert extra in str(err.value) and "did not write" in str(err.value)
        assert {n: (tmp_path / n).read_bytes() for n in os.listdir(tmp_path)} == before


@pytest.mark.parametrize("fresh", [True, False], ids=["new-directory", "existing-directory"])
def test_failure_midway_leaves_nothing(tmp_path, rng, monkeypatch, fresh):
    out = tmp_path / "out"
    if not fresh:
        out.mkdir()
    real, calls = meshseq._write_mesh, []

    def flaky(path, *a):
        calls.append(path)
        if len(calls) == 2:
            raise KeyboardInterrupt
        real(path, *a)

    monkeypatch.setattr(meshseq, "_write_mesh", flaky)
    with pytest.raises(KeyboardInterrupt):
        write_sequence(str(out / "f_%04d.ply"), _seq(rng))
    assert os.listdir(tmp_path) == ([] if fresh else ["out"])
    assert not out.exists() or os.listdir(out) == []


@pytest.mark.parametrize("name", ["dir", "siblings", "glob"])
def test_duplicate_frame_numbers_are_refused(tmp_path, rng, name):
    d = tmp_path / "ply"
    write_sequence(str(d) + os.sep, _seq(rng, T=6))
    (d / "frame_3.ply").write_bytes((d / "frame_0003.ply").read_bytes())
    path = {"dir": str(d), "siblings": str(d / "frame_0001.ply"), "glob": str(d / "frame_*.ply")}[name]
    with pytest.raises(InputError) as err:
        read_sequence(path)
    msg = str(err.value)
    assert "frame number 3" in msg and "frame_0003.ply" in msg and "frame_3.ply" in msg, msg


# --- files written by others -------------------------------------------------

POLY_LINE_VTU = """<?xml version="1.0"?>
<VTKFile type="UnstructuredGrid" version="0.1" byte_order="LittleEndian">
 <UnstructuredGrid><Piece NumberOfPoints="5" NumberOfCells="1">
  <Points><DataArray type="Float64" NumberOfComponents="3" format="ascii">{points}</DataArray></Points>
  <Cells>
   <DataArray type="Int64" Name="connectivity" format="ascii">0 1 2 3 4</DataArray>
   <DataArray type="Int64" Name="offsets" format="ascii">5</DataArray>
   <DataArray type="UInt8" Name="types" format="ascii">4</DataArray>
  </Cells></Piece></UnstructuredGrid></VTKFile>
"""


def test_cells_meshio_skips_are_refused(tmp_path, capsys):
    # A rod exported by ParaView as one VTK_POLY_LINE: meshio warns and drops it, leaving bare points.
    for k in range(2):
        points = " ".join(f"{i} 0 {k}" for i in range(5))
        (tmp_path / f"rod_{k}.vtu").write_text(POLY_LINE_VTU.format(points=points))
    with pytest.raises(FormatError) as err:
        read_sequence(str(tmp_path), format="meshseq")
    assert (f"cells of type VTK_POLY_LINE (4) in {tmp_path / 'rod_0.vtu'} cannot be read (meshio skips them); "
            f"expected triangle, quad, polygon, line, line3 or vertex cells") in str(err.value)
    assert capsys.readouterr().err == ""


def test_volume_cells_are_refused(tmp_path):
    import meshio

    for k in range(2):
        meshio.write(tmp_path / f"v_{k}.vtu", meshio.Mesh(np.eye(4)[:, :3] + k, [("tetra", np.array([[0, 1, 2, 3]]))]))
    with pytest.raises(FormatError, match=r"cells of type tetra \(4 nodes\) in .*v_0\.vtu; penfree reads triangle"):
        read_sequence(str(tmp_path / "v_%d.vtu"))


PLY_POLYGONS = """ply
format ascii 1.0
element vertex 9
property double x
property double y
property double z
element face 4
property list uchar int vertex_indices
end_header
{points}
4 0 1 4 3
4 1 2 5 4
5 3 4 5 8 6
3 6 8 7
"""


def test_quads_and_polygons_are_fanned_polygon_by_polygon(tmp_path):
    frames = [np.array([[i, j, k] for j in range(3) for i in range(3)], float) for k in range(2)]
    for k, x in enumerate(frames):
        (tmp_path / f"sheet_{k}.ply").write_text(PLY_POLYGONS.format(points="\n".join(" ".join(map(str, p)) for p in x)))
    seq = read_sequence(str(tmp_path / "sheet_0.ply"))
    np.testing.assert_array_equal(seq.positions, frames)
    # meshio groups cells by type (quads, pentagon, triangle); each polygon's fan stays together, winding kept
    assert seq.faces.tolist() == [[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4],
                                  [3, 4, 5], [3, 5, 8], [3, 8, 6], [6, 8, 7]]


@pytest.mark.parametrize("how", ["one-file", "directory", "glob", "pattern"])
def test_negative_frame_numbers_houdini(tmp_path, rng, how):
    # Houdini's $F4 writes frame -2 as cloth.-002.ply
    seq = _seq(rng, T=4)
    for s, number in enumerate((-2, -1, 0, 1)):
        meshseq._write_mesh(str(tmp_path / f"cloth.{number:04d}.ply"), seq.positions[s], seq.edges, seq.faces)
    path = {"one-file": "cloth.0000.ply", "directory": "", "glob": "cloth.*.ply", "pattern": "cloth.%04d.ply"}[how]
    back = read_sequence(str(tmp_path / path), format="meshseq")
    np.testing.assert_array_equal(back.positions, seq.positions)


def test_hyphen_before_the_number_is_a_separator(tmp_path, rng):
    seq = _seq(rng, T=3)
    for s in range(3):
        meshseq._write_mesh(str(tmp_path / f"rod-{s + 1:04d}.obj"), seq.positions[s], seq.edges, seq.faces)
    assert frame_files(str(tmp_path)) == [str(tmp_path / f"rod-{s:04d}.obj") for s in (1, 2, 3)]


@pytest.mark.parametrize("numbers,expect", [
    ((12, 13, 15), "frame 14 is missing from {d}: f_13.obj is followed by f_15.obj while the other frames are 1 apart"),
    ((0, 2, 4, 8, 10), "frame 6 is missing from {d}: f_4.obj is followed by f_8.obj while the other frames are 2 apart"),
    ((0, 2, 4, 5, 7), "frames 4 and 5 are 1 apart in {d}: f_4.obj is followed by f_5.obj while the other frames are 2 "
                      "apart"),
], ids=["gap", "gap-in-every-2nd", "off-stride"])
def test_gaps_in_frame_numbers_are_refused(tmp_path, rng, numbers, expect):
    seq = _seq(rng, T=len(numbers))
    for s, n in enumerate(numbers):
        meshseq._write_mesh(str(tmp_path / f"f_{n}.obj"), seq.positions[s], seq.edges, seq.faces)
    for path in (str(tmp_path), str(tmp_path / "f_13.obj") if 13 in numbers else str(tmp_path / "f_*.obj")):
        with pytest.raises(InputError) as err:
            read_sequence(path, format="meshseq")
        assert expect.format(d=tmp_path) in str(err.value)
        assert "expected one constant stride of frame numbers" in str(err.value)


def test_every_kth_frame_is_a_sequence(tmp_path, rng):
    seq = _seq(rng, T=4)
    for s in range(4):
        meshseq._write_mesh(str(tmp_path / f"f_{10 + 5 * s}.obj"), seq.positions[s], seq.edges, seq.faces)
    np.testing.assert_array_equal(read_sequence(str(tmp_path), format="meshseq").positions, seq.positions)


def test_obj_index_out_of_range_names_the_file_and_the_index_as_written(tmp_path):
    for k in range(2):
        (tmp_path / f"a_{k}.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n")
    with pytest.raises(FormatError) as err:
        read_sequence(str(tmp_path), format="meshseq")
    assert (f"vertex index 7 on line 4 of {tmp_path / 'a_0.obj'} is out of range; expected 1 .. 3 "
            f"(the file has 3 vertices)") in str(err.value)


def test_obj_forward_references_are_allowed(tmp_path):
    p = tmp_path / "f_1.obj"
    p.write_text("f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n")  # faces before their vertices
    assert read_obj(str(p))[2].tolist() == [[0, 1, 2]]
