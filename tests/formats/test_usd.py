"""USD in and out (issue 14): stages built here with pxr directly are the oracle for the reader."""

import json
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner
from numpy.testing import assert_allclose
from pxr import Gf, Sdf, Usd, UsdGeom, UsdPhysics, Vt

from penfree.cli import main
from penfree.errors import InputError
from penfree.formats import detect_format, read_sequence, write_sequence
from penfree.formats import _usd_shapes as shapes
from penfree.formats.usd import read_usd
from penfree.sequence import Sequence

SAMPLES = Path(__file__).resolve().parents[2] / "samples"
SAMPLE = SAMPLES / "cloth_drop.usda"


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _stage(path, mpu=1.0, tcps=24.0, start_end=None, layer=None):
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    stage.SetTimeCodesPerSecond(tcps)
    if start_end is not None:
        stage.SetStartTimeCode(start_end[0])
        stage.SetEndTimeCode(start_end[1])
    if layer is not None:
        stage.GetRootLayer().customLayerData = layer
    UsdGeom.Xform.Define(stage, "/World")
    return stage


def _mesh(stage, path, frames, counts, indices, codes=None):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([int(c) for c in counts]))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([int(i) for i in np.ravel(indices)]))
    codes = range(len(frames)) if codes is None else codes
    for x, t in zip(frames, codes):
        code = t if isinstance(t, Usd.TimeCode) else float(t)
        mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(np.asarray(x, dtype=np.float32)), code)
    return mesh


def _sheet(z, n=4, h=0.1):
    """A flat n x n grid at height z: vertices (n*n, 3) and its quads."""
    u = np.arange(n) * h
    x, y = np.meshgrid(u, u, indexing="ij")
    V = np.stack([x.ravel(), y.ravel(), np.full(n * n, float(z))], axis=1)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    v = (i * n + j).ravel()
    return V, np.stack([v, v + n, v + n + 1, v + 1], axis=1)


def _falling_sheet(stage, zs, path="/World/Cloth"):
    V, Q = _sheet(0.0)
    return _mesh(stage, path, [V + [0, 0, z] for z in zs], [4] * len(Q), Q), V, Q


def _error_line(result):
    lines = result.stderr.strip().splitlines()
    assert result.exit_code == 2, result.output
    assert len(lines) == 1 and "Traceback" not in result.output, result.output
    return lines[0]


# --- round trips -----------------------------------------------------------------------

def _sequence(kind, dtype):
    rng = np.random.default_rng(14)
    if kind == "triangles":
        V, Q = _sheet(0.0, n=5)
        faces = np.concatenate([Q[:, [0, 1, 2]], Q[:, [0, 2, 3]]])
        topo = {"faces": faces}
    else:
        V = np.zeros((12, 3))
        V[:, 0] = np.arange(12) * 0.1
        V[6:, 1] = 0.3
        topo = {"edges": np.array([[i, i + 1] for i in range(11) if i != 5])}
    X = 1e3 + V[None] + rng.normal(scale=1e-3, size=(4,) + V.shape)  # far from the origin: every digit counts
    return Sequence(positions=X.astype(dtype), thickness=1e-3, dt=1 / 60, source="round trip", **topo).validate()


@pytest.mark.parametrize("ext", [".usda", ".usdc"])
@pytest.mark.parametrize("kind", ["triangles", "segments"])
@pytest.mark.parametrize("dtype", [np.float32, np.float64], ids=["float32", "float64"])
def test_round_trip_usd_hdf5_usd_is_exact(tmp_path, dtype, kind, ext):
    seq = _sequence(kind, dtype)
    a, h5, b = tmp_path / f"a{ext}", tmp_path / "a.h5", tmp_path / f"b{ext}"
    write_sequence(a, seq)
    assert _run("convert", a, h5).exit_code == 0
    assert _run("convert", h5, b).exit_code == 0
    first, back = read_sequence(a), read_sequence(b)
    for got in (first, read_sequence(h5), back):
        assert got.positions.dtype == dtype
        assert np.array_equal(got.positions, seq.positions)
        assert got.thickness == seq.thickness
        assert got.dt == pytest.approx(seq.dt, rel=1e-12)
    name = "faces" if kind == "triangles" else "edges"
    assert np.array_equal(getattr(first, name), getattr(back, name))
    assert np.array_equal(np.sort(getattr(first, name), axis=1), np.sort(getattr(seq, name), axis=1))
    if kind == "segments":  # one component per curve, both ways
        assert np.array_equal(first.components, np.repeat([0, 1], 6))
        assert np.array_equal(back.components, first.components)


def test_sample_round_trips_through_hdf5(tmp_path):
    """A stage from another writer (quads, transform, centimetres) -> HDF5 -> USD -> the same metres."""
    first = read_sequence(SAMPLE)
    assert _run("convert", SAMPLE, tmp_path / "s.h5").exit_code == 0
    assert _run("convert", tmp_path / "s.h5", tmp_path / "s.usdc").exit_code == 0
    back = read_sequence(tmp_path / "s.usdc")
    assert np.array_equal(back.positions, first.positions) and np.array_equal(back.faces, first.faces)
    assert back.attrs["usd_time_codes"] == first.attrs["usd_time_codes"] == list(np.arange(1.0, 13.0))
    assert back.dt == pytest.approx(first.dt, rel=1e-12)


def test_detects_usd_by_extension():
    assert {detect_format(f"a{e}") for e in (".usd", ".usda", ".usdc", ".USDA")} == {"usd"}


# --- units, time, triangulation ----------------------------------------------------------

def test_centimetre_stage_reads_in_metres(tmp_path):
    path = tmp_path / "cm.usda"
    stage = _stage(path, mpu=0.01, tcps=30.0, layer={"thickness": 0.5})
    mesh, V, Q = _falling_sheet(stage, [50.0, 49.0, 47.0], path="/World/Cloth")
    mesh.GetPrim().CreateAttribute("contact_radius", Sdf.ValueTypeNames.Double, custom=True).Set(2.0)
    # Time codes 0, 2, 4: two codes per frame at 30 codes per second.
    attr = mesh.GetPointsAttr()
    samples = [np.asarray(attr.Get(t)) for t in (0.0, 1.0, 2.0)]
    attr.Clear()
    for x, t in zip(samples, (0.0, 2.0, 4.0)):
        attr.Set(Vt.Vec3fArray.FromNumpy(x), t)
    stage.GetRootLayer().Save()
    seq = read_sequence(path)
    expected = np.stack(samples).astype(np.float64) * 0.01
    assert seq.positions.dtype == np.float64
    assert np.array_equal(seq.positions, expected)
    assert seq.thickness == 0.5 * 0.01 and seq.contact_radius == 2.0 * 0.01
    assert seq.dt == pytest.approx(2 / 30, rel=1e-15)
    assert seq.attrs["usd_meters_per_unit"] == 0.01 and seq.attrs["usd_time_codes"] == [0.0, 2.0, 4.0]


def test_quads_and_ngons_are_triangulated_and_recorded(tmp_path):
    path = tmp_path / "poly.usda"
    stage = _stage(path)
    rng = np.random.default_rng(3)
    # A square, a regular pentagon and a triangle, all convex and in the plane z = 0.
    ang = 2 * np.pi * np.arange(5) / 5
    V = np.vstack([[[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]],
                   np.stack([3 + np.cos(ang), np.sin(ang), np.zeros(5)], axis=1),
                   [[5, 0, 0], [6, 0, 0], [5, 1, 0]]])
    frames = [V + rng.normal(scale=1e-3, size=3) for _ in range(2)]  # a rigid shift: areas unchanged
    _mesh(stage, "/World/Poly", frames, [4, 5, 3], np.arange(12))
    stage.GetRootLayer().Save()
    seq = read_sequence(path)
    assert seq.faces.tolist() == [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7], [4, 7, 8], [9, 10, 11]]
    assert seq.attrs["usd_triangulated"] == 2
    # Oracle: the triangles tile the polygons (total area = square + pentagon + triangle).
    x = seq.positions[0].astype(np.float64)
    area = 0.5 * np.linalg.norm(np.cross(x[seq.faces[:, 1]] - x[seq.faces[:, 0]],
                                         x[seq.faces[:, 2]] - x[seq.faces[:, 0]]), axis=1).sum()
    assert area == pytest.approx(1.0 + 2.5 * np.sin(2 * np.pi / 5) + 0.5, rel=1e-6)
    info = _run("info", path)
    assert info.exit_code == 0 and "2 of 3 polygons fan-triangulated" in info.output


def test_left_handed_winding_and_holes(tmp_path):
    path = tmp_path / "lh.usda"
    stage = _stage(path)
    V, Q = _sheet(0.0, n=3)
    mesh = _mesh(stage, "/World/M", [V, V + 0.1], [4] * 4, Q)
    mesh.CreateOrientationAttr("leftHanded")
    mesh.CreateHoleIndicesAttr(Vt.IntArray([1]))
    stage.GetRootLayer().Save()
    seq = read_sequence(path)
    keep = Q[[0, 2, 3]]
    expected = np.concatenate([[[q[0], q[k + 1], q[k]] for k in (1, 2)] for q in keep])
    assert seq.faces.tolist() == expected.tolist()


def test_stage_range_limits_frames_and_deform_takes_frames(tmp_path):
    path = tmp_path / "range.usda"
    stage = _stage(path, start_end=(2, 6))
    _falling_sheet(stage, 1.0 - 0.01 * np.arange(10) ** 2)
    stage.GetRootLayer().Save()
    seq = read_sequence(path)
    assert seq.n_frames == 5 and seq.attrs["usd_time_codes"] == [2.0, 3.0, 4.0, 5.0, 6.0]
    assert np.allclose(seq.positions[:, 0, 2], 1.0 - 0.01 * np.arange(2, 7) ** 2, rtol=0, atol=1e-7)
    out = tmp_path / "d.h5"
    r = _run("deform", path, "-o", out, "--frames", "1:3")
    assert r.exit_code == 0, r.output
    with h5py.File(out, "r") as f:
        assert f["steps/frame"][()].tolist() == [1, 2]


# --- prims, curves, distances -----------------------------------------------------------

def _curves(stage, path, frames, counts, ctype="linear", wrap="nonperiodic"):
    curves = UsdGeom.BasisCurves.Define(stage, path)
    curves.CreateTypeAttr(ctype)
    curves.CreateWrapAttr(wrap)
    curves.CreateCurveVertexCountsAttr(Vt.IntArray(list(counts)))
    for t, x in enumerate(frames):
        curves.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(np.asarray(x, dtype=np.float32)), float(t))
    return curves


def test_linear_curves_one_component_per_curve(tmp_path):
    path = tmp_path / "curves.usda"
    stage = _stage(path)
    x = np.random.default_rng(5).random((7, 3))
    _curves(stage, "/World/Open", [x, x + 0.1], [3, 4])
    _curves(stage, "/World/Loop", [x[:4] + 2, x[:4] + 2.1], [4], wrap="periodic")
    stage.GetRootLayer().Save()
    seq = read_sequence(path)
    assert seq.edges.tolist() == [[0, 1], [1, 2], [3, 4], [4, 5], [5, 6], [7, 8], [8, 9], [9, 10], [10, 7]]
    assert seq.components.tolist() == [0] * 3 + [1] * 4 + [2] * 4


def test_prims_choose_the_scene_in_the_given_order(tmp_path):
    path = tmp_path / "two.usda"
    stage = _stage(path)
    _falling_sheet(stage, [1.0, 0.9], path="/World/A")
    _falling_sheet(stage, [2.0, 1.9], path="/World/B")
    _falling_sheet(stage, [3.0, 2.9], path="/World/C")
    stage.GetRootLayer().Save()
    every = read_sequence(path)
    assert every.n_vertices == 48 and every.components.tolist() == np.repeat([0, 1, 2], 16).tolist()
    two = read_sequence(path, prims=["/World/C", "/World/A"])
    assert np.array_equal(two.positions[:, :16], every.positions[:, 32:])
    assert np.array_equal(two.positions[:, 16:], every.positions[:, :16])
    assert two.attrs["usd_prims"] == ["/World/C", "/World/A"]
    out = tmp_path / "c.h5"
    assert _run("convert", path, out, "--prim", "/World/B").exit_code == 0
    assert read_sequence(out).n_vertices == 16
    line = _error_line(_run("convert", path, tmp_path / "x.h5", "--prim", "/World/Nope"))
    assert "/World/Nope" in line and "two.usda" in line and not (tmp_path / "x.h5").exists()
    line = _error_line(_run("convert", out, tmp_path / "y.h5", "--prim", "/World/B"))
    assert "prims" in line and not (tmp_path / "y.h5").exists()


def test_distances_prim_attribute_wins_over_layer_and_must_agree(tmp_path):
    path = tmp_path / "dist.usda"
    stage = _stage(path, layer={"penfree": {"thickness": 0.01, "contact_radius": 0.02}})
    a, _, _ = _falling_sheet(stage, [1.0, 0.9], path="/World/A")
    a.GetPrim().CreateAttribute("penfree:thickness", Sdf.ValueTypeNames.Double, custom=True).Set(0.003)
    stage.GetRootLayer().Save()
    seq = read_sequence(path)
    assert seq.thickness == 0.003 and seq.contact_radius == 0.02
    b, _, _ = _falling_sheet(stage, [2.0, 1.9], path="/World/B")
    b.GetPrim().CreateAttribute("thickness", Sdf.ValueTypeNames.Double, custom=True).Set(0.004)
    stage.GetRootLayer().Save()
    with pytest.raises(InputError, match="thickness differs between scene prims"):
        read_sequence(path)


# --- obstacles ---------------------------------------------------------------------------

def _cube_corners(size):
    h = size / 2
    return np.array([[x, y, z] for x in (-h, h) for y in (-h, h) for z in (-h, h)])


def test_cube_collider_used_by_verify(tmp_path):
    """A sheet sinking into a static box: verify names the box; the same sheet above it passes."""
    for name, zs, code in (("safe", [1.0, 0.9, 0.8], 0), ("hit", [1.0, 0.9, 0.4], 1)):
        path = tmp_path / f"{name}.usda"
        stage = _stage(path)
        _falling_sheet(stage, zs)
        box = UsdGeom.Cube.Define(stage, "/World/Box")
        box.CreateSizeAttr(1.0)
        box.AddTranslateOp().Set(Gf.Vec3d(0.15, 0.15, 0.0))  # top face at z = 0.5
        stage.GetRootLayer().Save()
        seq = read_sequence(path)
        (ob,) = seq.obstacles
        assert ob.name == "Box" and ob.positions.shape == (8, 3) and len(ob.faces) == 12
        assert np.array_equal(np.sort(ob.positions, axis=0), np.sort(_cube_corners(1.0) + [0.15, 0.15, 0], axis=0))
        r = _run("verify", path)
        assert r.exit_code == code, r.output
        if code:
            assert "step     1 -> frame 2: VIOLATION" in r.output and ":Box" in r.output
            assert "step     0 -> frame 1: OK" in r.output


def test_collision_mesh_and_named_obstacle(tmp_path):
    path = tmp_path / "meshes.usda"
    stage = _stage(path)
    cloth, _, _ = _falling_sheet(stage, [1.0, 0.9])
    UsdPhysics.CollisionAPI.Apply(cloth.GetPrim())  # simulated cloth often has it: deforming points keep it scene
    V, Q = _sheet(0.0)
    ground = _mesh(stage, "/World/Ground", [V - [0.5, 0.5, 0]], [4] * len(Q), Q)
    UsdPhysics.CollisionAPI.Apply(ground.GetPrim())
    _mesh(stage, "/World/Prop", [V + [0, 0, 0.2]], [4] * len(Q), Q)  # static, no collision API
    rigid = _mesh(stage, "/World/Rigid", [V + [0, 0, 0.5]] * 2, [4] * len(Q), Q)  # same points twice
    move = rigid.AddTranslateOp()
    move.Set(Gf.Vec3d(0, 0, 0), 0.0)
    move.Set(Gf.Vec3d(0, 0, 1), 1.0)
    inst = UsdGeom.PointInstancer.Define(stage, "/World/Joints")
    UsdGeom.Sphere.Define(stage, "/World/Joints/sphere")
    inst.CreatePrototypesRel().AddTarget("/World/Joints/sphere")
    stage.GetRootLayer().Save()
    seq = read_sequence(path)
    assert seq.attrs["usd_prims"] == ["/World/Cloth"]
    assert [ob.name for ob in seq.obstacles] == ["Ground"] and seq.obstacles[0].faces.shape == (18, 3)
    seq = read_sequence(path, obstacles=["/World/Prop"])
    assert [ob.name for ob in seq.obstacles] == ["Ground", "Prop"]
    assert np.array_equal(seq.obstacles[1].positions, (V + [0, 0, 0.2]).astype(np.float32).astype(np.float64))
    r = _run("info", path, "--obstacle", "/World/Prop")
    assert r.exit_code == 0 and "usd prim /World/Prop (Mesh): obstacle - named with --obstacle" in r.output
    r = _run("info", path)
    assert "usd prim /World/Prop (Mesh): ignored - static" in r.output
    assert "usd prim /World/Rigid (Mesh): ignored - moves rigidly" in r.output
    assert "usd prim /World/Joints/sphere (Sphere): ignored - prototype of a PointInstancer" in r.output
    assert "usd prim /World/Cloth (Mesh): scene - deforming points (read as scene despite" in r.output
    rigid = read_sequence(path, obstacles=["/World/Rigid"]).obstacles[1]
    assert rigid.name == "Rigid" and rigid.positions.shape == (2, 16, 3)
    assert np.array_equal(rigid.positions[1] - rigid.positions[0], np.tile([0, 0, 1.0], (16, 1)))


def test_kinematic_collider_transform(tmp_path):
    """A box whose parent moves up (time-sampled translate) hits a hovering sheet in step 1."""
    path = tmp_path / "kin.usda"
    stage = _stage(path, mpu=0.5)
    _falling_sheet(stage, [2.0, 2.01, 2.02])
    rig = UsdGeom.Xform.Define(stage, "/World/Lift")
    lift = rig.AddTranslateOp()
    heights = [0.0, 0.5, 2.0]
    for t, z in enumerate(heights):
        lift.Set(Gf.Vec3d(0.15, 0.15, z), float(t))
    box = UsdGeom.Cube.Define(stage, "/World/Lift/Box")
    box.CreateSizeAttr(2.0)
    box.AddScaleOp().Set(Gf.Vec3f(1.0, 1.0, 0.5))
    stage.GetRootLayer().Save()
    seq = read_sequence(path)
    (ob,) = seq.obstacles
    corners = _cube_corners(2.0) * [1.0, 1.0, 0.5]
    assert ob.positions.shape == (3, 8, 3)
    for k, z in enumerate(heights):
        assert np.allclose(ob.positions[k], (corners + [0.15, 0.15, z]) * 0.5, rtol=0, atol=1e-15)
    r = _run("verify", path)
    assert r.exit_code == 1 and "step     1 -> frame 2: VIOLATION" in r.output and ":Box" in r.output
    assert "step     0 -> frame 1: OK" in r.output


def test_sphere_and_capsule_colliders_contain_the_transformed_shape(tmp_path):
    """World-space tessellations (non-uniform scale, rotation) hold sampled surface points of the shape."""
    from scipy.spatial import ConvexHull

    path = tmp_path / "round.usda"
    stage = _stage(path)
    _falling_sheet(stage, [5.0, 4.9])
    sph = UsdGeom.Sphere.Define(stage, "/World/Ball")
    sph.CreateRadiusAttr(0.4)
    cap = UsdGeom.Capsule.Define(stage, "/World/Pill")
    cap.CreateRadiusAttr(0.2)
    cap.CreateHeightAttr(1.0)
    cap.CreateAxisAttr("X")
    for prim, at in ((sph, (1.0, 2.0, 3.0)), (cap, (-1.0, 0.0, 0.5))):
        prim.AddTranslateOp().Set(Gf.Vec3d(*at))
        prim.AddRotateXYZOp().Set(Gf.Vec3f(30.0, 10.0, 70.0))
        prim.AddScaleOp().Set(Gf.Vec3f(1.0, 2.0, 0.5))
    stage.GetRootLayer().Save()
    seq = read_sequence(path)
    rng = np.random.default_rng(7)
    s = rng.normal(size=(5000, 3))
    s /= np.linalg.norm(s, axis=1)[:, None]
    local = {"Ball": 0.4 * s,
             "Pill": np.vstack([0.2 * s + [0.5, 0, 0], 0.2 * s - [0.5, 0, 0]])}
    for ob in seq.obstacles:
        M = np.array(UsdGeom.Xformable(stage.GetPrimAtPath(f"/World/{ob.name}")).ComputeLocalToWorldTransform(0))
        pts = local[ob.name] @ M[:3, :3] + M[3, :3]
        hull = ConvexHull(ob.positions)
        assert (pts @ hull.equations[:, :3].T + hull.equations[:, 3] <= 1e-12).all(), ob.name
        # the exact solid beside the mesh: the same transform (test_obstacle_shapes checks the profiles)
        assert ob.shape.source == {"Ball": "Sphere", "Pill": "Capsule"}[ob.name]
        assert np.array_equal(ob.shape.transform, np.vstack([M[:3, :3], M[3, :3]])), ob.name


def test_plane_becomes_half_space(tmp_path):
    path = tmp_path / "plane.usda"
    stage = _stage(path, mpu=0.01)
    _falling_sheet(stage, [10.0, 9.0])
    plane = UsdGeom.Plane.Define(stage, "/World/Floor")
    plane.CreateAxisAttr("Y")
    plane.AddTranslateOp().Set(Gf.Vec3d(0.0, 0.0, 5.0))
    plane.AddRotateXOp().Set(90.0)  # local +Y -> world +Z
    stage.GetRootLayer().Save()
    seq = read_usd(str(path))  # the reader alone; validation of half-spaces is issue 10's
    (ob,) = seq.obstacles
    assert ob.is_half_space and ob.name == "Floor"
    assert np.allclose(ob.normal, [0, 0, 1], rtol=0, atol=1e-15) and ob.offset == pytest.approx(0.05, abs=1e-15)
    lift = plane.AddTranslateOp(opSuffix="lift")
    lift.Set(Gf.Vec3d(0, 0, 0), 0.0)
    lift.Set(Gf.Vec3d(0, 0, 1), 1.0)
    stage.GetRootLayer().Save()
    with pytest.raises(InputError, match="time-varying transform.*plane.usda:/World/Floor"):
        read_usd(str(path))


def test_plane_collider_used_by_verify(tmp_path):
    """A sheet sinking through a floor plane: verify names the floor; above it, verify passes."""
    for name, zs, code in (("above", [1.0, 0.9, 0.8], 0), ("through", [1.0, 0.9, -0.1], 1)):
        path = tmp_path / f"{name}.usda"
        stage = _stage(path)
        _falling_sheet(stage, zs)
        UsdGeom.Plane.Define(stage, "/World/Floor").CreateAxisAttr("Z")
        stage.GetRootLayer().Save()
        seq = read_sequence(path)
        assert seq.obstacles[0].is_half_space
        info = _run("info", path)
        assert info.exit_code == 0 and "usd prim /World/Floor (Plane): obstacle - half-space" in info.output
        r = _run("verify", path)
        assert r.exit_code == code, r.output
        if code:
            assert "Floor" in r.output
        h5 = tmp_path / f"{name}.h5"
        assert _run("convert", path, h5).exit_code == 0
        assert read_sequence(h5).obstacles[0].is_half_space


# --- writer: deformed states ------------------------------------------------------------------

def test_deformed_export_has_two_time_sampled_prims_and_obstacles(tmp_path):
    d, out = tmp_path / "d.h5", tmp_path / "d.usda"
    assert _run("deform", SAMPLE, "-o", d).exit_code == 0
    r = _run("convert", d, out, "--deformed")
    assert r.exit_code == 0, r.output
    with h5py.File(d, "r") as f:
        frames, deformed = f["steps/frame"][()], f["steps/deformed"][()]
    stage = Usd.Stage.Open(str(out))
    codes = np.arange(1.0, 13.0)
    rec, dfm = stage.GetPrimAtPath("/World/Recorded"), stage.GetPrimAtPath("/World/Deformed")
    assert rec.GetTypeName() == dfm.GetTypeName() == "Mesh"
    assert rec.GetAttribute("points").GetTimeSamples() == list(codes)
    assert dfm.GetAttribute("points").GetTimeSamples() == list(codes[frames])
    for k, s in enumerate(frames):
        assert np.array_equal(np.asarray(dfm.GetAttribute("points").Get(codes[s])), deformed[k].astype(np.float32))
    # Standard schemas only: what usdview and Blender open.
    for prim in stage.Traverse():
        assert prim.GetTypeName() in ("Xform", "Mesh", "BasisCurves", "Plane"), prim.GetPath()
        assert set(prim.GetAppliedSchemas()) <= {"PhysicsCollisionAPI"}
    assert sorted(p.GetName() for p in stage.GetPrimAtPath("/World/Obstacles").GetChildren()) == ["Ball", "Box"]
    # Read back: the recorded frames by default, the deformed states on request, both exact.
    assert np.array_equal(read_sequence(out).positions, read_sequence(SAMPLE).positions)
    assert np.array_equal(read_sequence(out, prims=["/World/Deformed"]).positions, deformed)


@pytest.mark.parametrize("dtype", [np.float32, np.float64], ids=["float32", "float64"])
def test_mesh_obstacles_round_trip(tmp_path, dtype):
    """Static and kinematic mesh obstacles (faces, edges) survive HDF5 -> USD -> HDF5 exactly."""
    from penfree.sequence import Obstacle

    seq = _sequence("triangles", dtype)
    rng = np.random.default_rng(9)
    V, F = shapes.cube(1.0)
    seq.obstacles = [
        Obstacle("box", positions=V + 5.0, faces=F),
        Obstacle("lid", positions=V[None] + rng.normal(size=(4, 1, 3)), faces=F),
        Obstacle("rail", positions=rng.random((5, 3)), edges=np.array([[0, 1], [1, 2], [2, 3], [3, 4]])),
    ]
    seq.validate()
    write_sequence(tmp_path / "a.h5", seq)
    assert _run("convert", tmp_path / "a.h5", tmp_path / "a.usda").exit_code == 0
    assert _run("convert", tmp_path / "a.usda", tmp_path / "b.h5").exit_code == 0
    back = read_sequence(tmp_path / "b.h5")
    assert np.array_equal(back.positions, seq.positions)
    got = {ob.name: ob for ob in back.obstacles}
    for ob in seq.obstacles:
        assert np.array_equal(got[ob.name].positions, ob.positions), ob.name
        for name in ("faces", "edges"):
            a, b = getattr(ob, name), getattr(got[ob.name], name)
            assert (a is None and (b is None or not len(b))) or np.array_equal(a, b), (ob.name, name)


def test_writer_refuses_points_without_topology(tmp_path):
    seq = Sequence(positions=np.zeros((2, 5, 3))).validate()
    with pytest.raises(InputError, match="neither faces nor edges"):
        write_sequence(tmp_path / "x.usda", seq)
    assert not (tmp_path / "x.usda").exists()


def test_writer_refuses_edges_outside_faces(tmp_path):
    seq = Sequence(positions=np.zeros((2, 5, 3)), faces=np.array([[0, 1, 2], [2, 3, 4]]),
                   edges=np.array([[0, 4]])).validate()
    with pytest.raises(InputError, match="edge.*outside its faces"):
        write_sequence(tmp_path / "x.usda", seq)
    assert not (tmp_path / "x.usda").exists()


# --- the committed sample -----------------------------------------------------------------

def test_sample_through_info_deform_verify_report(tmp_path):
    info = _run("info", SAMPLE)
    assert info.exit_code == 0, info.output
    for text in ("usd prim /World/Rig/Cloth (Mesh): scene", "100 of 100 polygons fan-triangulated",
                 "usd prim /World/Box (Cube): obstacle", "usd prim /World/Ball (Sphere): obstacle",
                 "metersPerUnit 0.01", "timeCodesPerSecond 24", "1..12 (12 frames"):
        assert text in info.output
    d = json.loads(_run("info", SAMPLE, "--json").output)
    assert d["frames"] == 12 and d["vertices"] == 121 and d["thickness"] == pytest.approx(0.002, rel=1e-15)
    assert [ob["static"] for ob in d["obstacles"]] == [False, True]
    out = tmp_path / "d.h5"
    r = _run("deform", SAMPLE, "-o", out, "--stats")
    assert r.exit_code == 0, r.output
    r = _run("verify", out)
    assert r.exit_code == 0 and "11 step(s) checked" in r.output and "all steps safe" in r.output, r.output
    r = _run("report", out, "-o", tmp_path / "rep", "--no-plots", "--no-ladder")
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "rep" / "report.json").read_text())["files"][0]["summary"]["n_steps"] == 11


@pytest.fixture(scope="module")
def usd_cloth():
    sys.path.insert(0, str(SAMPLES))
    try:
        import usd_cloth as mod
    finally:
        sys.path.remove(str(SAMPLES))
    return mod


def test_sample_is_what_the_generator_writes(tmp_path, usd_cloth):
    usd_cloth.build(str(tmp_path / "again.usda"))
    assert (tmp_path / "again.usda").read_bytes() == SAMPLE.read_bytes()


def test_sample_world_positions_match_the_generator(usd_cloth):
    """Oracle for transforms and units: the rig's rotateZ(15 deg) then translate (0, 0, 45) cm, in metres."""
    seq = read_sequence(SAMPLE)
    a = np.radians(15.0)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    for k in range(usd_cloth.FRAMES):
        local = usd_cloth.sheet(k).astype(np.float32).astype(np.float64)
        expected = (local @ R.T + [0, 0, 45.0]) * 0.01
        assert_allclose(seq.positions[k], expected, rtol=0, atol=1e-15)
    d = json.loads(_run("info", SAMPLE, "--json").output)["usd"]
    assert d["meters_per_unit"] == 0.01 and d["dt"] == 1 / 24 and d["time_codes"]["count"] == 12
    assert {p["path"]: p["role"] for p in d["prims"]} == {
        "/World/Rig/Cloth": "scene", "/World/Box": "obstacle", "/World/Ball": "obstacle"}


# --- bad input ------------------------------------------------------------------------------

def _bad_no_usable_prim(path):
    stage = _stage(path)
    V, Q = _sheet(0.0)
    _mesh(stage, "/World/Static", [V], [4] * len(Q), Q)
    stage.GetRootLayer().Save()
    return "/World/Static"


def _bad_point_count(path):
    stage = _stage(path)
    mesh, V, Q = _falling_sheet(stage, [1.0, 0.9])
    mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(np.vstack([V, V[:2]]).astype(np.float32)), 2.0)
    stage.GetRootLayer().Save()
    return "/World/Cloth"


def _bad_cubic(path):
    stage = _stage(path)
    x = np.random.default_rng(2).random((4, 3))
    _curves(stage, "/World/Hair", [x, x + 0.1], [4], ctype="cubic")
    stage.GetRootLayer().Save()
    return "/World/Hair"


@pytest.mark.parametrize("make,words", [
    (_bad_no_usable_prim, ("no usable prim", "static")),
    (_bad_point_count, ("point count changes", "16 at time code 0, 18 at 2")),
    (_bad_cubic, ("cubic curves", "not supported", "resample")),
], ids=["no-usable-prim", "point-count-changes", "cubic-curves"])
@pytest.mark.parametrize("command", ["convert", "info", "deform"])
def test_bad_input_one_line_exit_2_no_output(tmp_path, make, words, command):
    path = tmp_path / "bad.usda"
    prim = make(path)
    out = tmp_path / "out.h5"
    args = {"convert": ("convert", path, out), "info": ("info", path), "deform": ("deform", path, "-o", out)}
    line = _error_line(_run(*args[command]))
    assert str(path) in line and prim in line and all(w in line for w in words), line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.usda"]


@pytest.mark.parametrize("direction", ["read", "write"])
def test_missing_usd_core_says_how_to_install(tmp_path, monkeypatch, direction):
    h5 = tmp_path / "in.h5"
    write_sequence(h5, _sequence("triangles", np.float32))
    write_sequence(tmp_path / "in.usda", _sequence("triangles", np.float32))
    before = sorted(p.name for p in tmp_path.iterdir())
    monkeypatch.setitem(sys.modules, "pxr", None)  # as if usd-core were not installed
    src, dst = (tmp_path / "in.usda", tmp_path / "out.h5") if direction == "read" else (h5, tmp_path / "out.usda")
    line = _error_line(_run("convert", src, dst))
    assert "pip install 'penfree[usd]'" in line and str(src if direction == "read" else dst) in line
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.parametrize("case", ["text", "truncated-crate", "empty"])
def test_not_a_stage_is_one_line(tmp_path, case):
    if case == "text":
        path = tmp_path / "junk.usda"
        path.write_text("this is not usd\n")
    elif case == "truncated-crate":
        write_sequence(tmp_path / "whole.usdc", _sequence("triangles", np.float64))
        path = tmp_path / "junk.usdc"
        path.write_bytes((tmp_path / "whole.usdc").read_bytes()[:2000])
    else:
        path = tmp_path / "junk.usd"
        path.write_bytes(b"")
    line = _error_line(_run("convert", path, tmp_path / "out.h5"))
    assert path.name in line and "not a readable USD stage" in line
    assert not (tmp_path / "out.h5").exists()


def test_shapes_module_contains_cube_exactly():
    # The USD cube of size 2 is [-1, 1]^3, as the schema says.
    V, _ = shapes.cube(2.0)
    assert np.array_equal(V, _cube_corners(2.0))


def test_verify_prims_and_obstacles_choose_the_scene(tmp_path):
    """`verify --prim/--obstacle` checks what it names: sheet A falls through sheet B."""
    path = tmp_path / "through.usda"
    stage = _stage(path)
    _falling_sheet(stage, [1.0, 0.8], path="/World/A")
    _falling_sheet(stage, [0.9, 0.91], path="/World/B")
    stage.GetRootLayer().Save()
    for args in ((), ("--prim", "/World/A", "--obstacle", "/World/B")):
        both = _run("verify", path, *args)
        assert both.exit_code == 1 and "VIOLATION" in both.output, (args, both.output)
    for prim in ("/World/A", "/World/B"):
        alone = _run("verify", path, "--prim", prim)
        assert alone.exit_code == 0 and "all steps safe" in alone.output, alone.output
    line = _error_line(_run("verify", path, "--prim", "/World/Nope"))
    assert "/World/Nope" in line and "through.usda" in line


# --- real exports: how DCC tools and Omniverse author colliders --------------------------------

def _surface_points(kind, rng, k=4000):
    """Points on the surface of a unit-parameter shape in its local frame (axis Z), for the hull test."""
    s = rng.normal(size=(k, 3))
    s /= np.linalg.norm(s, axis=1)[:, None]
    theta = rng.uniform(0, 2 * np.pi, k)
    ring = np.c_[np.cos(theta), np.sin(theta), np.zeros(k)]
    h = rng.uniform(-0.5, 0.5, k)
    if kind == "Cylinder":  # radius 0.3, height 1.2: side and both cap rims
        return np.vstack([0.3 * ring + np.c_[0 * h, 0 * h, 1.2 * h], 0.3 * ring + [0, 0, 0.6], 0.3 * ring - [0, 0, 0.6]])
    if kind == "Cone":  # radius 0.3, height 1.2, apex at +0.6
        f = rng.uniform(0, 1, k)[:, None]
        return np.vstack([(1 - f) * (0.3 * ring - [0, 0, 0.6]) + f * np.array([0, 0, 0.6]), [[0, 0, 0.6]]])
    if kind == "Cylinder_1":  # bottom 0.3, top 0.1, height 1.2
        f = rng.uniform(0, 1, k)[:, None]
        return (1 - f) * (0.3 * ring - [0, 0, 0.6]) + f * (0.1 * ring + [0, 0, 0.6])
    return np.vstack([0.3 * s - [0, 0, 0.6], 0.1 * s + [0, 0, 0.6]])  # Capsule_1: bottom 0.3, top 0.1


@pytest.mark.parametrize("kind", ["Cylinder", "Cone", "Cylinder_1", "Capsule_1"])
def test_cylinder_cone_and_two_radius_colliders_contain_their_shape(tmp_path, kind):
    """Omniverse and Houdini author these as colliders; they were ignored (verify passed a sheet through them)."""
    from scipy.spatial import ConvexHull

    path = tmp_path / "round.usda"
    stage = _stage(path)
    _falling_sheet(stage, [5.0, 4.9])
    prim = stage.DefinePrim("/World/Shape", kind)
    sizes = {"Cylinder": {"radius": 0.3}, "Cone": {"radius": 0.3},
             "Cylinder_1": {"radiusBottom": 0.3, "radiusTop": 0.1}, "Capsule_1": {"radiusBottom": 0.3, "radiusTop": 0.1}}
    for name, value in {**sizes[kind], "height": 1.2}.items():
        prim.GetAttribute(name).Set(value)
    prim.GetAttribute("axis").Set("Z")
    xf = UsdGeom.Xformable(prim)
    xf.AddTranslateOp().Set(Gf.Vec3d(1.0, -2.0, 0.5))
    xf.AddRotateXYZOp().Set(Gf.Vec3f(30.0, 10.0, 70.0))
    xf.AddScaleOp().Set(Gf.Vec3f(1.0, 2.0, 0.5))
    stage.GetRootLayer().Save()
    (ob,) = read_sequence(path).obstacles
    assert ob.name == "Shape" and ob.positions.ndim == 2
    M = np.array(xf.ComputeLocalToWorldTransform(0))
    pts = _surface_points(kind, np.random.default_rng(3)) @ M[:3, :3] + M[3, :3]
    hull = ConvexHull(ob.positions)
    assert (pts @ hull.equations[:, :3].T + hull.equations[:, 3] <= 1e-12).all()
    # Tight: the mesh is the shape's hull grown by at most the polygons' corner factor (0.5% of a radius).
    assert hull.volume <= 1.03 * ConvexHull(pts).volume


def test_collider_sizes_authored_only_as_time_samples(tmp_path):
    """Houdini writes every attribute as time samples: the sizes are read at each frame, not the schema default."""
    path = tmp_path / "sampled.usda"
    stage = _stage(path)
    _falling_sheet(stage, [3.0, 2.5, 2.0])
    ball = UsdGeom.Sphere.Define(stage, "/World/Ball")
    ball.GetRadiusAttr().Set(2.0, 0.0)  # one time sample: the value at every time
    box = UsdGeom.Cube.Define(stage, "/World/Box")
    box.AddTranslateOp().Set(Gf.Vec3d(10.0, 0.0, 0.0))
    for t, size in enumerate([1.0, 2.0, 3.0]):
        box.GetSizeAttr().Set(size, float(t))
    stage.GetRootLayer().Save()
    ball_ob, box_ob = read_sequence(path).obstacles
    V, F = shapes.sphere(2.0)
    assert np.array_equal(ball_ob.positions, V) and np.array_equal(ball_ob.faces, F)
    assert box_ob.positions.shape == (3, 8, 3)
    for k, size in enumerate([1.0, 2.0, 3.0]):
        assert np.array_equal(np.sort(box_ob.positions[k], axis=0), np.sort(_cube_corners(size) + [10, 0, 0], axis=0))
    r = _run("verify", path)  # the sheet (0 .. 0.3 wide) sinks from z = 3 into the ball of radius 2
    assert r.exit_code == 1 and ":Ball" in r.output and "step     1 -> frame 2: VIOLATION" in r.output


def _prop(path, collider=True):
    prop = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(prop, 1.0)
    root = UsdGeom.Xform.Define(prop, "/Prop")
    prop.SetDefaultPrim(root.GetPrim())
    V, Q = _sheet(0.0, n=3, h=0.5)
    board = _mesh(prop, "/Prop/Board", [V - [0.5, 0.5, 0.0]], [4] * len(Q), Q, codes=[Usd.TimeCode.Default()])
    if collider:
        UsdPhysics.CollisionAPI.Apply(board.GetPrim())
    prop.GetRootLayer().Save()


@pytest.mark.parametrize("instanceable", [False, True], ids=["referenced", "instanced"])
def test_colliders_inside_instanced_references_are_read(tmp_path, instanceable):
    """Omniverse props are instanceable: their colliders live under instance proxies and were dropped."""
    _prop(tmp_path / "prop.usda")
    path = tmp_path / "scene.usda"
    stage = _stage(path)
    _falling_sheet(stage, [1.0, -1.0])
    board = stage.DefinePrim("/World/Board", "Xform")
    board.GetReferences().AddReference(str(tmp_path / "prop.usda"))
    board.SetInstanceable(instanceable)
    stage.GetRootLayer().Save()
    (ob,) = read_sequence(path).obstacles
    assert ob.name == "Board" and ob.positions.shape == (9, 3)
    r = _run("verify", path)
    assert r.exit_code == 1 and ":Board" in r.output, r.output
    info = _run("info", path)
    assert "usd prim /World/Board/Board (Mesh): obstacle - mesh with PhysicsCollisionAPI" in info.output


def _skinned_board(stage, path, lift, skel_offset=(0.0, 0.0, 0.0), collider=True):
    """A 3 x 3 board skinned to a one-joint skeleton whose animation lifts it by `lift[t]` at time t."""
    from pxr import UsdSkel

    root = UsdSkel.Root.Define(stage, path)
    root.AddTranslateOp().Set(Gf.Vec3d(*skel_offset))
    skel = UsdSkel.Skeleton.Define(stage, f"{path}/Skel")
    skel.CreateJointsAttr(["root"])
    skel.CreateBindTransformsAttr(Vt.Matrix4dArray([Gf.Matrix4d(1.0)]))
    skel.CreateRestTransformsAttr(Vt.Matrix4dArray([Gf.Matrix4d(1.0)]))
    anim = UsdSkel.Animation.Define(stage, f"{path}/Skel/Anim")
    anim.CreateJointsAttr(["root"])
    anim.CreateRotationsAttr(Vt.QuatfArray([Gf.Quatf(1.0)]))
    anim.CreateScalesAttr(Vt.Vec3hArray([Gf.Vec3h(1.0)]))
    for t, z in enumerate(lift):
        anim.CreateTranslationsAttr().Set(Vt.Vec3fArray([Gf.Vec3f(0.0, 0.0, z)]), float(t))
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPrim().GetPath()])
    V, Q = _sheet(0.0, n=3, h=0.2)
    V = V - [0.2, 0.2, 0.0]
    board = _mesh(stage, f"{path}/Board", [V], [4] * len(Q), Q, codes=[Usd.TimeCode.Default()])
    binding = UsdSkel.BindingAPI.Apply(board.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel.GetPrim().GetPath()])
    binding.CreateJointIndicesPrimvar(False, 1).Set(Vt.IntArray([0] * len(V)))
    binding.CreateJointWeightsPrimvar(False, 1).Set(Vt.FloatArray([1.0] * len(V)))
    binding.CreateGeomBindTransformAttr(Gf.Matrix4d(1.0))
    if collider:
        UsdPhysics.CollisionAPI.Apply(board.GetPrim())
    return V


def test_skinned_collider_is_posed_by_its_skeleton(tmp_path):
    """A character body bound to a skeleton (Blender armatures, Omniverse avatars) was read in its rest pose."""
    path = tmp_path / "skin.usda"
    stage = _stage(path)
    _falling_sheet(stage, [0.55, 0.5, 0.45])
    V = _skinned_board(stage, "/World/Body", lift=[0.0, 0.2, 1.0], skel_offset=(0.05, 0.0, 0.0))
    _skinned_board(stage, "/World/Arm", lift=[0.0, 0.1, 0.2], skel_offset=(5.0, 0.0, 0.0), collider=False)
    stage.GetRootLayer().Save()
    (body,) = read_sequence(path).obstacles
    assert body.name == "Board" and body.positions.shape == (3, 9, 3)
    for k, z in enumerate([0.0, 0.2, 1.0]):
        assert_allclose(body.positions[k], V + [0.05, 0.0, z], rtol=0, atol=1e-7)
    r = _run("verify", path)  # the body rises through the hovering sheet in step 1 only
    assert r.exit_code == 1 and "step     1 -> frame 2: VIOLATION" in r.output and ":Board" in r.output
    assert "step     0 -> frame 1: OK" in r.output
    info = _run("info", path)
    assert "usd prim /World/Body/Board (Mesh): obstacle - skinned mesh with PhysicsCollisionAPI" in info.output
    assert "usd prim /World/Arm/Board (Mesh): ignored - skinned, posed by a skeleton" in info.output
    arm = read_sequence(path, obstacles=["/World/Arm/Board"]).obstacles[1]
    assert_allclose(arm.positions[2], V + [5.0, 0.0, 0.2], rtol=0, atol=1e-7)


def test_guide_prims_are_not_scene_or_obstacles_unless_colliders(tmp_path):
    path = tmp_path / "roles.usda"
    stage = _stage(path)
    _falling_sheet(stage, [1.0, 0.9])
    guide, _, _ = _falling_sheet(stage, [1.0, 0.9], path="/World/ClothGuide")  # a hidden duplicate of the cloth
    guide.CreatePurposeAttr("guide")
    helper = UsdGeom.Cube.Define(stage, "/World/BBoxHelper")  # a bounding-box helper around the cloth
    helper.CreatePurposeAttr("guide")
    collider = UsdGeom.Cube.Define(stage, "/World/HiddenCollider")  # colliders are often guides: kept
    collider.CreatePurposeAttr("guide")
    collider.AddTranslateOp().Set(Gf.Vec3d(0.0, 0.0, -5.0))
    UsdPhysics.CollisionAPI.Apply(collider.GetPrim())
    stage.GetRootLayer().Save()
    seq = read_sequence(path)
    assert seq.attrs["usd_prims"] == ["/World/Cloth"] and [ob.name for ob in seq.obstacles] == ["HiddenCollider"]
    info = _run("info", path)
    assert "usd prim /World/ClothGuide (Mesh): ignored - guide purpose" in info.output
    assert "usd prim /World/BBoxHelper (Cube): ignored - guide purpose" in info.output
    named = read_sequence(path, obstacles=["/World/BBoxHelper"])
    assert [ob.name for ob in named.obstacles] == ["BBoxHelper", "HiddenCollider"]


def test_collider_of_an_unsupported_type_is_refused(tmp_path):
    path = tmp_path / "points.usda"
    stage = _stage(path)
    _falling_sheet(stage, [1.0, 0.9])
    pts = UsdGeom.Points.Define(stage, "/World/Grains")
    pts.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.zeros((4, 3), dtype=np.float32)))
    UsdPhysics.CollisionAPI.Apply(pts.GetPrim())
    stage.GetRootLayer().Save()
    line = _error_line(_run("verify", path))
    assert str(path) in line and "/World/Grains" in line and "PhysicsCollisionAPI" in line and "Points" in line


def _scaled_floor(path, scale):
    """A stage with a falling sheet and a floor Plane (axis Z) at z = 0.5 under `scale`; its world transform."""
    stage = _stage(path)
    _falling_sheet(stage, [1.0, 0.9])
    plane = UsdGeom.Plane.Define(stage, "/World/Floor")
    plane.CreateAxisAttr("Z")
    plane.AddTranslateOp().Set(Gf.Vec3d(0.0, 0.0, 0.5))
    plane.AddScaleOp().Set(Gf.Vec3f(*scale))
    stage.GetRootLayer().Save()
    return np.array(plane.ComputeLocalToWorldTransform(0))


@pytest.mark.parametrize("scale,normal", [
    ((1.0, 1.0, 0.0), (0.0, 0.0, 1.0)),  # flattened along its own axis: still the plane z = 0.5
    ((2.0, 3.0, -1.0), (0.0, 0.0, -1.0)),  # mirrored: the free side follows the geometry
    ((1.0, 2.0, 4.0), (0.0, 0.0, 1.0)),
], ids=["zero-axis-scale", "mirrored", "scaled"])
def test_plane_normal_under_singular_and_mirrored_scales(tmp_path, scale, normal):
    M = _scaled_floor(tmp_path / "plane.usda", scale)
    (ob,) = read_usd(str(tmp_path / "plane.usda")).obstacles
    assert np.array_equal(ob.normal, normal) and ob.offset == 0.5 * normal[2]
    if all(scale):  # where the transform is invertible, the inverse-transpose rule is the oracle
        n = np.linalg.solve(M[:3, :3], [0.0, 0.0, 1.0])
        assert_allclose(ob.normal, n / np.linalg.norm(n), rtol=0, atol=1e-15)


def test_plane_flattened_within_itself_is_refused(tmp_path):
    path = tmp_path / "plane.usda"
    _scaled_floor(path, (0.0, 1.0, 1.0))
    line = _error_line(_run("info", path))
    assert str(path) in line and "/World/Floor" in line and "flattens it" in line


def test_time_varying_topology_and_distances(tmp_path):
    path = tmp_path / "hair.usda"
    stage = _stage(path)
    x = np.random.default_rng(2).random((6, 3))
    hair = _curves(stage, "/World/Hair", [x, x + 0.01, x + 0.02], [3, 3])
    for t, counts in enumerate([[3, 3], [2, 4], [6]]):
        hair.GetCurveVertexCountsAttr().Set(Vt.IntArray(counts), float(t))
    stage.GetRootLayer().Save()
    line = _error_line(_run("info", path))
    assert str(path) in line and "/World/Hair" in line and "curveVertexCounts changes over time" in line

    path = tmp_path / "thick.usda"
    stage = _stage(path)
    cloth, _, _ = _falling_sheet(stage, [1.0, 0.9])
    attr = cloth.GetPrim().CreateAttribute("penfree:thickness", Sdf.ValueTypeNames.Double)
    attr.Set(0.01, 0.0)
    attr.Set(0.01, 1.0)
    stage.GetRootLayer().Save()
    assert read_sequence(path).thickness == 0.01
    attr.Set(0.02, 1.0)
    stage.GetRootLayer().Save()
    line = _error_line(_run("info", path))
    assert "penfree:thickness" in line and "0.01 .. 0.02" in line


def test_mesh_without_faces_is_refused(tmp_path):
    path = tmp_path / "cloud.usda"
    stage = _stage(path)
    mesh = UsdGeom.Mesh.Define(stage, "/World/Cloth")
    V, _ = _sheet(0.0)
    for t in range(2):
        mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy((V + [0, 0, t]).astype(np.float32)), float(t))
    stage.GetRootLayer().Save()
    line = _error_line(_run("verify", path))
    assert str(path) in line and "/World/Cloth" in line and "without faces" in line
