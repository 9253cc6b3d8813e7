"""XDMF time series: round trip, the XML ParaView needs to animate geometry, refusals."""

import os
import xml.etree.ElementTree as ET

import h5py
import numpy as np
import pytest

from penfree.errors import FormatError, InputError, OutputExistsError
from penfree.formats import output_paths, read_sequence, write_sequence
from penfree.formats import xdmf
from penfree.sequence import Obstacle, Sequence


RNG_SEED = 5  # seed of the shared `rng` fixture (tests/conftest.py)


def _seq(rng, dtype=np.float64, topo="both"):
    faces = np.array([[0, 1, 2], [1, 2, 3]]) if topo in ("both", "triangles") else None
    edges = np.array([[0, 3], [3, 4]]) if topo in ("both", "segments") else None
    return Sequence(
        positions=rng.random((4, 5, 3)).astype(dtype), faces=faces, edges=edges,
        weights=rng.random(5) + 1, components=np.arange(5) % 2, thickness=0.02, dt=0.25,
        source="xdmf test", attrs={"solver": {"name": "vbd"}},
        obstacles=[Obstacle("floor", rng.random((3, 3)), faces=np.array([[0, 1, 2]])),
                   Obstacle("rod", rng.random((4, 2, 3)), edges=np.array([[0, 1]]))],
    ).validate()


@pytest.mark.parametrize("topo", ["both", "triangles", "segments", "points"])
@pytest.mark.parametrize("dtype", [np.float32, np.float64], ids=["float32", "float64"])
def test_round_trip(tmp_path, rng, dtype, topo):
    seq = _seq(rng, dtype, topo)
    p = str(tmp_path / "anim.xdmf")
    write_sequence(p, seq)
    assert sorted(os.listdir(tmp_path)) == ["anim.xdmf", "anim.xdmf.h5"]
    back = read_sequence(p)
    assert back.positions.dtype == dtype
    np.testing.assert_array_equal(back.positions, seq.positions)
    for name in ("faces", "edges", "weights", "components"):
        a, b = getattr(seq, name), getattr(back, name)
        assert (a is None) == (b is None), name
        if a is not None:
            np.testing.assert_array_equal(a, b)
    assert (back.thickness, back.dt, back.source, back.attrs) == (0.02, 0.25, "xdmf test", {"solver": {"name": "vbd"}})
    assert [(o.name, o.positions.shape) for o in back.obstacles] == [("floor", (3, 3)), ("rod", (4, 2, 3))]
    np.testing.assert_array_equal(back.obstacles[1].positions, seq.obstacles[1].positions)


def test_xml_animates_geometry(tmp_path, rng):
    """ParaView animates a Temporal collection whose grids each carry their own Geometry."""
    seq = _seq(rng, topo="segments")
    p = tmp_path / "anim.xdmf"
    write_sequence(p, seq)
    root = ET.parse(p).getroot()
    main = root.find("Domain/Grid[@Name='penfree']")
    assert main.get("GridType") == "Collection" and main.get("CollectionType") == "Temporal"
    grids = main.findall("Grid")
    assert [float(g.find("Time").get("Value")) for g in grids] == [0.0, 0.25, 0.5, 0.75]
    refs = [g.find("Geometry/DataItem").text for g in grids]
    assert len(set(refs)) == 4 and all(r.startswith("anim.xdmf.h5:/") for r in refs)
    top = grids[0].find("Topology")
    assert (top.get("TopologyType"), top.get("NodesPerElement"), top.get("NumberOfElements")) == ("Polyline", "2", "2")
    assert {g.find("Topology/DataItem").text for g in grids} == {"anim.xdmf.h5:/main/edges"}


def test_outputs_and_overwrite(tmp_path, rng):
    p = str(tmp_path / "a.xdmf")
    assert output_paths(p) == [p, p + ".h5"]
    write_sequence(p, _seq(rng))
    before = {n: (tmp_path / n).read_bytes() for n in os.listdir(tmp_path)}
    with pytest.raises(OutputExistsError):
        write_sequence(p, _seq(rng))
    assert {n: (tmp_path / n).read_bytes() for n in os.listdir(tmp_path)} == before
    write_sequence(p, _seq(rng), overwrite=True)


def test_failure_midway_leaves_nothing(tmp_path, rng, monkeypatch):
    real, calls = xdmf._collection, []

    def flaky(*a, **k):
        calls.append(1)
        if len(calls) == 2:  # after the main grid, while writing obstacles
            raise RuntimeError("boom")
        return real(*a, **k)

    monkeypatch.setattr(xdmf, "_collection", flaky)
    with pytest.raises(RuntimeError):
        write_sequence(tmp_path / "a.xdmf", _seq(rng))
    assert os.listdir(tmp_path) == []


def test_reads_meshio_time_series(tmp_path, rng, monkeypatch):
    import meshio

    monkeypatch.chdir(tmp_path)  # meshio's writer puts its .h5 in the working directory
    pos = rng.random((3, 4, 3))
    p = str(tmp_path / "ts.xdmf")
    with meshio.xdmf.TimeSeriesWriter(p) as w:
        w.write_points_cells(pos[0], [("triangle", np.array([[0, 1, 2], [1, 2, 3]]))])
        for s in range(3):
            w.write_data(float(s), point_data={"positions": pos[s]})
    seq = read_sequence(p)
    np.testing.assert_allclose(seq.positions, pos, rtol=0, atol=0)
    np.testing.assert_array_equal(seq.faces, [[0, 1, 2], [1, 2, 3]])


@pytest.mark.parametrize("text,exc,expect", [
    ("not xml <", FormatError, "is not an XDMF (XML) file"),
    ("<html><body/></html>", FormatError, "is XML but not XDMF"),
    ("<Xdmf><Domain><Grid Name='x' GridType='Uniform'/></Domain></Xdmf>", FormatError, "no Temporal grid collection"),
    ("<Xdmf><Domain><Information Name='penfree' Value='{broken'/>"
     "<Grid Name='penfree' GridType='Collection' CollectionType='Temporal'/></Domain></Xdmf>",
     FormatError, "is a malformed XDMF file"),
], ids=["not-xml", "not-xdmf", "no-time-series", "broken-json"])
def test_bad_xml(tmp_path, text, exc, expect):
    p = tmp_path / "bad.xdmf"
    p.write_text(text)
    with pytest.raises(exc) as err:
        read_sequence(p)
    assert expect in str(err.value)


def test_missing_heavy_data(tmp_path, rng):
    p = tmp_path / "a.xdmf"
    write_sequence(p, _seq(rng))
    os.unlink(str(p) + ".h5")
    with pytest.raises(InputError, match=r"no such file: .*a\.xdmf\.h5"):
        read_sequence(p)


def test_input_files_are_every_heavy_file_the_xml_references(tmp_path, rng):
    # meshio's TimeSeriesWriter puts its arrays in "<stem>.h5", hand-written files anywhere
    from penfree.formats import input_files

    (tmp_path / "data").mkdir()
    pos = rng.random((2, 3, 3))
    with h5py.File(tmp_path / "data" / "geo.h5", "w") as f:
        f["p0"], f["p1"] = pos[0], pos[1]
    with h5py.File(tmp_path / "topo.h5", "w") as f:
        f["faces"] = np.array([[0, 1, 2]])
    grids = "".join(
        f"<Grid Name='g{s}' GridType='Uniform'><Time Value='{s}'/>"
        f"<Topology TopologyType='Triangle' NumberOfElements='1'>"
        f"<DataItem Dimensions='1 3' NumberType='Int' Precision='8' Format='HDF'> topo.h5:/faces </DataItem></Topology>"
        f"<Geometry GeometryType='XYZ'><DataItem Dimensions='3 3' Precision='8' Format='HDF'>"
        f"data/geo.h5:/p{s}</DataItem></Geometry></Grid>" for s in range(2))
    p = tmp_path / "hand.xdmf"
    p.write_text(f"<Xdmf><Domain><Grid Name='x' GridType='Collection' CollectionType='Temporal'>{grids}"
                 f"</Grid></Domain></Xdmf>")
    np.testing.assert_array_equal(read_sequence(p).positions, pos)
    got = {os.path.realpath(f) for f in input_files(str(p))}
    assert {str(p), str(tmp_path / "data" / "geo.h5"), str(tmp_path / "topo.h5")} <= got


def test_input_files_of_a_meshio_time_series(tmp_path, rng, monkeypatch):
    import meshio
    from penfree.formats import input_files

    monkeypatch.chdir(tmp_path)
    with meshio.xdmf.TimeSeriesWriter("sim.xdmf") as w:
        w.write_points_cells(rng.random((3, 3)), [("triangle", np.array([[0, 1, 2]]))])
        for s in range(2):
            w.write_data(float(s), point_data={"positions": rng.random((3, 3))})
    assert str(tmp_path / "sim.h5") in {os.path.realpath(f) for f in input_files("sim.xdmf")}


# --- files written by others -------------------------------------------------

# A 3 x 3 grid of vertices (row-major) and its four quads, counter-clockwise seen from +z.
GRID = np.array([[i, j, 0.0] for j in range(3) for i in range(3)])
QUADS = np.array([[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 7, 6], [4, 5, 8, 7]])
TRIS = np.array([[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]])


def _meshio_series(path, cells, point_data):
    import meshio

    with meshio.xdmf.TimeSeriesWriter(str(path)) as w:
        w.write_points_cells(GRID, cells)
        for s, data in enumerate(point_data):
            w.write_data(float(s), point_data=data)


@pytest.mark.parametrize("cells,faces,edges", [
    ([("quad", QUADS[:2])], [[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]], None),
    ([("triangle", np.array([[0, 4, 8]])), ("quad", QUADS[2:]), ("vertex", np.array([[5]]))],
     [[0, 4, 8], [3, 4, 7], [3, 7, 6], [4, 5, 8], [4, 8, 7]], None),
    ([("line3", np.array([[0, 2, 1], [6, 8, 7]]))], None, [[0, 1], [1, 2], [6, 7], [7, 8]]),  # end0, end1, mid
], ids=["quads", "triangles-quads-vertex", "line3"])
def test_meshio_series_quads_and_line3_are_read_not_dropped(tmp_path, monkeypatch, cells, faces, edges):
    # each quad's two fan triangles stay together and keep its winding
    monkeypatch.chdir(tmp_path)
    pos = [GRID + [0, 0, 0.1 * s] for s in range(3)]
    _meshio_series("ts.xdmf", cells, [{"positions": p} for p in pos])
    seq = read_sequence("ts.xdmf")
    np.testing.assert_array_equal(seq.positions, pos)
    assert (None if seq.faces is None else seq.faces.tolist()) == faces
    assert (None if seq.edges is None else seq.edges.tolist()) == edges


def test_meshio_series_volume_cells_are_refused(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _meshio_series("vol.xdmf", [("tetra", np.array([[0, 1, 3, 4]]))], [{"positions": GRID}] * 2)
    with pytest.raises(InputError) as err:
        read_sequence("vol.xdmf")
    msg = str(err.value)
    assert "vol.xdmf" in msg and "tetra" in msg and "penfree reads triangle, quad, polygon, line" in msg, msg


@pytest.mark.parametrize("fields,expect", [
    ([{"displacement": GRID * 0}] * 3, "no step of the XDMF time series {p} has a point field named 'positions' "
                                       "(point fields: displacement)"),
    ([{"positions": GRID}, {"u": GRID}, {"positions": GRID}], "step 1 of the XDMF time series {p} has no point field "
                                                              "'positions'"),
], ids=["fenics-displacement", "one-step-without"])
def test_meshio_series_without_positions_is_refused(tmp_path, monkeypatch, fields, expect):
    # The mesh written once is the reference state: reading it for every step would be a motionless scene.
    monkeypatch.chdir(tmp_path)
    _meshio_series("u.xdmf", [("quad", QUADS)], fields)
    with pytest.raises(InputError) as err:
        read_sequence("u.xdmf")
    assert expect.format(p="u.xdmf") in str(err.value)
    assert "positions = points + displacement" in str(err.value) or "every step" in str(err.value)


def _hand_xdmf(path, frames, topo, topo_attrs="", geo_attrs='GeometryType="XYZ"', times=None, shared=False):
    """A Temporal collection as ParaView / the Xdmf library write it, heavy data in ``<name>.data.h5``."""
    h5 = path.name + ".data.h5"
    with h5py.File(path.parent / h5, "w") as f:
        f["topo"] = np.asarray(topo)
        for s, x in enumerate(frames):
            f[f"geo{s}"] = np.asarray(x)
    times = range(len(frames)) if times is None else times
    grids = "".join(
        f'<Grid Name="g{s}" GridType="Uniform"><Time Value="{t}"/>'
        f'<Topology TopologyType="Triangle" NumberOfElements="{len(topo)}" {topo_attrs}>'
        f'<DataItem Dimensions="{len(topo)} 3" NumberType="Int" Format="HDF">{h5}:/topo</DataItem></Topology>'
        f'<Geometry {geo_attrs}><DataItem Dimensions="{" ".join(map(str, np.shape(frames[s])))}" NumberType="Float" '
        f'Precision="8" Format="HDF">{h5}:/geo{0 if shared else s}</DataItem></Geometry>'
        f'<Attribute Name="displacement" Center="Node"><DataItem Dimensions="9 3" Format="XML">{" 0" * 27}'
        f'</DataItem></Attribute></Grid>' for s, t in enumerate(times))
    path.write_text(f'<?xml version="1.0" ?><Xdmf Version="3.0"><Domain><Grid Name="ts" GridType="Collection" '
                    f'CollectionType="Temporal">{grids}</Grid></Domain></Xdmf>')
    return path


def test_hand_written_base_offset_is_honoured(tmp_path):
    # 1-based connectivity with BaseOffset="1" and an unused last vertex (so a shift would still be "in range")
    frames = [np.vstack([GRID, [[9, 9, 9]]]) + [0, 0, s] for s in range(2)]
    p = _hand_xdmf(tmp_path / "one_based.xmf", frames, TRIS + 1, topo_attrs='BaseOffset="1"')
    seq = read_sequence(p)
    assert seq.faces.tolist() == TRIS.tolist()
    np.testing.assert_array_equal(seq.positions, frames)


def test_hand_written_frames_follow_time_values(tmp_path):
    frames = [GRID + [0, 0, s] for s in range(4)]
    p = _hand_xdmf(tmp_path / "restart.xmf", frames, TRIS, times=[0.0, 0.5, 1.5, 1.0])  # appended out of order
    np.testing.assert_array_equal(read_sequence(p).positions, [frames[0], frames[1], frames[3], frames[2]])


@pytest.mark.parametrize("times,expect", [
    ([0, 1, 1], "grid 'g1' and grid 'g2' of the main collection have the same Time 1.0 in {p}; expected one grid "
                "per time value"),
    ([0, "soon", 2], "Time 'soon' of grid 'g1' of the main collection in {p} is not a number; expected one finite "
                     "time value per grid"),
], ids=["duplicate", "non-numeric"])
def test_hand_written_bad_time_values_are_refused(tmp_path, times, expect):
    p = _hand_xdmf(tmp_path / "t.xmf", [GRID] * 3, TRIS, times=times)
    with pytest.raises(InputError) as err:
        read_sequence(p)
    assert expect.format(p=p) in str(err.value)


@pytest.mark.parametrize("geo_attrs", ['GeometryType="XY"', 'Type="XY"'], ids=["xdmf2", "xdmf3"])
def test_hand_written_xy_geometry_gets_z_zero(tmp_path, geo_attrs):
    frames = [GRID[:, :2] + [0, 0.5 * s] for s in range(2)]
    seq = read_sequence(_hand_xdmf(tmp_path / "xy.xmf", frames, TRIS, geo_attrs=geo_attrs))
    np.testing.assert_array_equal(seq.positions, [np.column_stack([f, np.zeros(9)]) for f in frames])


def test_hand_written_geometry_must_match_its_type(tmp_path):
    p = _hand_xdmf(tmp_path / "xy3.xmf", [GRID] * 2, TRIS, geo_attrs='Type="XY"')  # XY declared, 3 columns written
    with pytest.raises(InputError, match=r"Geometry XY of grid 'g0' .* shape \(9, 3\) in .*xy3\.xmf; expected \(N, 2\)"):
        read_sequence(p)


def test_hand_written_scene_sharing_one_geometry_is_refused(tmp_path):
    # Static mesh + a per-step displacement attribute: the geometry never moves.
    p = _hand_xdmf(tmp_path / "static.xmf", [GRID] * 3, TRIS, shared=True)
    with pytest.raises(InputError) as err:
        read_sequence(p)
    msg = str(err.value)
    assert (f"the 3 grids of the main collection in {p} share one Geometry dataset static.xmf.data.h5:/geo0, so the "
            f"scene does not move (its grids carry the attributes displacement); expected one Geometry per frame") in msg
