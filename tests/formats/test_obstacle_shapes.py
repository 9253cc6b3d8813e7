"""An obstacle's exact analytic solid (`Obstacle.shape`) through every format that keeps obstacles.

The USD reader is checked against an oracle of the solid itself: a solid of revolution is
convex, so a point lies in it when its meridian coordinates (distance from the axis, height
along it) lie in the solid's meridian section, the 2D convex hull of the two rounded discs'
sections (each a segment of half-width ``disc`` at ``-+height/2`` swept by a circle of radius
``round``), sampled finely on its boundary.
"""

import h5py
import numpy as np
import pytest
from click.testing import CliRunner
from pxr import Gf, Sdf, Usd, UsdGeom

from penfree.cli import main
from penfree.errors import InputError
from penfree.formats import _usd_shapes as shapes
from penfree.formats import read_sequence, write_sequence
from penfree.formats.result import DeformResult, deformed_sequence
from penfree.sequence import AnalyticShape, Obstacle, Sequence

T = 4
#: Samples on each rounding circle of the oracle's section: the sampled hull lies inside the
#: true one by at most round * (1 - cos(pi / 720)) ~ 1e-5 of a radius.
CIRCLE_SAMPLES = 721


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _rotation(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def _capsule_obstacle(rng, kinematic):
    """A capsule (radius 0.2, height 1, axis Y) under rotation, non-uniform scale and a
    translation that moves per frame when `kinematic`; its mesh as the USD reader makes it."""
    V, F = shapes.capsule(0.2, 1.0, "Y")
    L = np.diag([1.0, 2.0, 0.5]) @ _rotation(rng)
    c = np.array([3.0, -1.0, 0.25])
    if kinematic:
        cs = c + rng.normal(size=(T, 3))
        profile = np.array([[1.0, 0.0, 0.2, 0.0, 0.2 + 0.01 * k] for k in range(T)])
        transform = np.stack([np.vstack([L, ck]) for ck in cs])
        X = np.stack([V @ L + ck for ck in cs])
    else:
        profile = np.array([1.0, 0.0, 0.2, 0.0, 0.2])
        transform = np.vstack([L, c])
        X = V @ L + c
    return Obstacle("pill", positions=X, faces=F,
                    shape=AnalyticShape("Capsule", 1, profile, transform))


def _scene(rng, kinematic):
    x = np.array([[0.0, 0, 5], [1, 0, 5], [0, 1, 5]])
    return Sequence(positions=x[None] + 0.01 * np.arange(T)[:, None, None], faces=np.array([[0, 1, 2]]),
                    thickness=1e-3, dt=0.1,
                    obstacles=[_capsule_obstacle(rng, kinematic),
                               Obstacle("floor", normal=np.array([0.0, 0, 1]), offset=-3.0)]).validate()


def _assert_same_shape(got, want):
    assert got is not None
    assert (got.source, got.axis) == (want.source, want.axis)
    for name in ("profile", "transform"):
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == np.float64 and a.shape == b.shape and np.array_equal(a, b), name


# --- round trips ---------------------------------------------------------------------

@pytest.mark.parametrize("ext", [".h5", ".npz", ".xdmf", ".usda", ".usdc"])
@pytest.mark.parametrize("kinematic", [False, True], ids=["static", "kinematic"])
def test_round_trip_keeps_the_shape_exactly(tmp_path, rng, ext, kinematic):
    seq = _scene(rng, kinematic)
    path = tmp_path / f"scene{ext}"
    write_sequence(path, seq)
    back = read_sequence(path)
    got = {ob.name: ob for ob in back.obstacles}
    assert set(got) == {"pill", "floor"}
    _assert_same_shape(got["pill"].shape, seq.obstacles[0].shape)
    assert np.array_equal(got["pill"].positions, seq.obstacles[0].positions)
    assert got["floor"].is_half_space and got["floor"].shape is None


def test_obstacles_without_a_shape_stay_without(tmp_path, rng):
    seq = _scene(rng, False)
    seq.obstacles[0].shape = None
    for ext in (".h5", ".npz", ".xdmf", ".usda"):
        write_sequence(tmp_path / f"plain{ext}", seq)
        assert all(ob.shape is None for ob in read_sequence(tmp_path / f"plain{ext}").obstacles), ext
    with h5py.File(tmp_path / "plain.h5") as f:
        assert "shape" not in f["obstacles/pill"]


def test_hdf5_layout(tmp_path, rng):
    seq = _scene(rng, True)
    write_sequence(tmp_path / "s.h5", seq)
    with h5py.File(tmp_path / "s.h5") as f:
        g = f["obstacles/pill/shape"]
        assert (g.attrs["source"], g.attrs["axis"]) == ("Capsule", "Y")
        assert g["profile"].shape == (T, 5) and g["profile"].dtype == np.float64
        assert g["transform"].shape == (T, 4, 3) and g["transform"].dtype == np.float64


@pytest.mark.parametrize("window", [(0, 2), (1, 3), (2, 99)])
def test_frame_window_slices_a_per_frame_shape(tmp_path, rng, window):
    seq = _scene(rng, True)
    seq.obstacles.append(_capsule_obstacle(rng, False))
    seq.obstacles[-1].name = "still"
    path = tmp_path / "s.h5"
    write_sequence(path, seq)
    part = {ob.name: ob for ob in read_sequence(path, frame_window=window).obstacles}
    sl = slice(*window)
    _assert_same_shape(part["pill"].shape, seq.obstacles[0].shape.take(sl))
    assert part["pill"].shape.profile.shape[0] == len(range(T)[sl])
    _assert_same_shape(part["still"].shape, seq.obstacles[-1].shape)  # one row for every frame


def test_deformed_states_take_the_shape_of_their_frames(rng):
    seq = _scene(rng, True)
    frames = np.array([1, 3])
    res = DeformResult(sequence=seq, steps={"frame": frames, "deformed": seq.positions[frames]}, origin="r.h5")
    out = deformed_sequence(res)
    _assert_same_shape(out.obstacles[0].shape, seq.obstacles[0].shape.take(frames))
    assert np.array_equal(out.obstacles[0].positions, seq.obstacles[0].positions[frames])


# --- the USD reader: the solid the tessellation contains -----------------------------

def _oracle(y, axis, profile):
    """Signed distance-like value of local points `y` (n, 3) from the solid of `profile`: the
    largest signed distance to an edge line of its meridian section (> 0 outside, < 0 inside,
    0 on it; for an outside point at most its distance)."""
    from scipy.spatial import ConvexHull

    h, ab, rb, at, rt = profile
    th = np.linspace(0.0, 2.0 * np.pi, CIRCLE_SAMPLES)
    ring = np.c_[np.cos(th), np.sin(th)]
    section = np.vstack([[s, z] + r * ring for a, r, z in ((ab, rb, -h / 2), (at, rt, h / 2)) for s in (-a, a)])
    eq = ConvexHull(section).equations
    rho = np.linalg.norm(np.delete(y, axis, axis=1), axis=1)
    return (np.c_[rho, y[:, axis]] @ eq[:, :2].T + eq[:, 2]).max(axis=1)


#: kind -> (size attributes, the profile they make).
KINDS = {
    "Sphere": ({"radius": 0.4}, (0.0, 0.0, 0.4, 0.0, 0.4)),
    "Capsule": ({"radius": 0.2, "height": 1.0}, (1.0, 0.0, 0.2, 0.0, 0.2)),
    "Capsule_1": ({"radiusBottom": 0.3, "radiusTop": 0.1, "height": 0.8}, (0.8, 0.0, 0.3, 0.0, 0.1)),
    "Cylinder": ({"radius": 0.25, "height": 0.6}, (0.6, 0.25, 0.0, 0.25, 0.0)),
    "Cylinder_1": ({"radiusBottom": 0.1, "radiusTop": 0.35, "height": 0.5}, (0.5, 0.1, 0.0, 0.35, 0.0)),
    "Cone": ({"radius": 0.3, "height": 0.9}, (0.9, 0.3, 0.0, 0.0, 0.0)),
}


def _stage_with(path, kind, axis, sizes, moving=False):
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 0.5)  # the transform carries the unit too
    UsdGeom.Xform.Define(stage, "/World")
    cloth = UsdGeom.Mesh.Define(stage, "/World/Cloth")
    cloth.CreateFaceVertexCountsAttr([3])
    cloth.CreateFaceVertexIndicesAttr([0, 1, 2])
    for t in range(3):
        cloth.GetPointsAttr().Set([(0, 0, 9 - t), (1, 0, 9 - t), (0, 1, 9 - t)], float(t))
    prim = stage.DefinePrim("/World/Shape", kind)
    for name, value in sizes.items():
        prim.CreateAttribute(name, Sdf.ValueTypeNames.Double).Set(value)
    if axis is not None:
        prim.CreateAttribute("axis", Sdf.ValueTypeNames.Token).Set(axis)
    xf = UsdGeom.Xformable(prim)
    move = xf.AddTranslateOp()
    for t in range(3 if moving else 1):
        move.Set(Gf.Vec3d(1.0, -2.0, 0.5 + t), float(t) if moving else Usd.TimeCode.Default())
    xf.AddRotateXYZOp().Set(Gf.Vec3f(30.0, 10.0, 70.0))
    xf.AddScaleOp().Set(Gf.Vec3f(1.0, 2.0, 0.5))
    stage.GetRootLayer().Save()
    return stage, xf


@pytest.mark.parametrize("axis", ["X", "Z"])
@pytest.mark.parametrize("kind", list(KINDS))
def test_usd_reader_gives_the_solid_its_mesh_contains(tmp_path, kind, axis):
    sizes, profile = KINDS[kind]
    stage, xf = _stage_with(tmp_path / "s.usda", kind, axis, sizes)
    (ob,) = read_sequence(tmp_path / "s.usda").obstacles
    sh = ob.shape
    assert (sh.source, sh.axis) == (kind, "XYZ".index(axis))
    assert sh.profile.shape == (5,) and np.array_equal(sh.profile, profile)
    M = np.array(xf.ComputeLocalToWorldTransform(0)) * 0.5
    assert sh.transform.shape == (4, 3) and np.array_equal(sh.transform, np.vstack([M[:3, :3], M[3, :3]]))
    # Every world vertex of the mesh, taken back through the shape's transform, lies on or
    # outside the solid, and close to it (the tessellations' vertices: at most 1.8% out).
    L, c = sh.transform[:3], sh.transform[3]
    y = (ob.positions - c) @ np.linalg.inv(L)
    g = _oracle(y, sh.axis, sh.profile)
    size = max(profile)
    assert g.min() >= -1e-9 * size
    assert g.max() <= 0.02 * size
    if kind == "Cone":  # the apex, on the solid at +height/2
        apex = np.zeros(3)
        apex[sh.axis] = profile[0] / 2
        assert np.min(np.linalg.norm(y - apex, axis=1)) <= 1e-12 * size


def test_oracle_rejects_wrong_profiles(tmp_path):
    """The bounds above can fail: the cone's mesh against the cone upside down (its ring
    lies far outside: the tightness bound) and against a cone 5% too large (vertices inside)."""
    sizes, (h, ab, rb, at, rt) = KINDS["Cone"]
    _stage_with(tmp_path / "s.usda", "Cone", "Z", sizes)
    (ob,) = read_sequence(tmp_path / "s.usda").obstacles
    y = (ob.positions - ob.shape.transform[3]) @ np.linalg.inv(ob.shape.transform[:3])
    assert _oracle(y, 2, (h, at, rt, ab, rb)).max() > 0.1 * h
    assert _oracle(y, 2, (1.05 * h, 1.05 * ab, rb, at, rt)).min() < -1e-3 * h


def test_usd_cube_has_no_shape(tmp_path):
    _stage_with(tmp_path / "s.usda", "Cube", None, {"size": 1.0})
    (ob,) = read_sequence(tmp_path / "s.usda").obstacles
    assert ob.shape is None and ob.positions.shape == (8, 3)


def test_usd_time_sampled_size_and_transform_give_per_frame_rows(tmp_path):
    stage, xf = _stage_with(tmp_path / "s.usda", "Cylinder_1", "Y", {"height": 0.8}, moving=True)
    prim = stage.GetPrimAtPath("/World/Shape")
    bottom = prim.CreateAttribute("radiusBottom", Sdf.ValueTypeNames.Double)
    prim.CreateAttribute("radiusTop", Sdf.ValueTypeNames.Double).Set(0.1)
    for t, r in enumerate([0.3, 0.3, 0.35]):
        bottom.Set(r, float(t))
    stage.GetRootLayer().Save()
    (ob,) = read_sequence(tmp_path / "s.usda").obstacles
    sh = ob.shape
    assert sh.profile.shape == (3, 5) and sh.transform.shape == (3, 4, 3)
    assert np.array_equal(sh.profile, [[0.8, r, 0, 0.1, 0] for r in (0.3, 0.3, 0.35)])
    for t in range(3):
        M = np.array(xf.ComputeLocalToWorldTransform(t)) * 0.5
        assert np.array_equal(sh.transform[t], np.vstack([M[:3, :3], M[3, :3]]))
        y = (ob.positions[t] - sh.transform[t, 3]) @ np.linalg.inv(sh.transform[t, :3])
        assert _oracle(y, 1, sh.profile[t]).min() >= -1e-9


def test_usd_to_penfree_to_usd_keeps_the_shape(tmp_path):
    """A USD Cone -> HDF5 -> USD (mesh + penfree:shape attributes) -> read: the same solid."""
    _stage_with(tmp_path / "a.usda", "Cone", "X", KINDS["Cone"][0], moving=True)
    first = read_sequence(tmp_path / "a.usda")
    assert _run("convert", tmp_path / "a.usda", tmp_path / "a.h5").exit_code == 0
    assert _run("convert", tmp_path / "a.h5", tmp_path / "b.usda").exit_code == 0
    info = _run("info", tmp_path / "b.usda")
    assert "penfree obstacle (mesh of a Cone; its exact shape is kept too)" in info.output, info.output
    (ob,) = read_sequence(tmp_path / "b.usda").obstacles
    _assert_same_shape(ob.shape, first.obstacles[0].shape)
    assert ob.shape.transform.shape == (3, 4, 3)
    assert np.array_equal(ob.positions, first.obstacles[0].positions)


def test_usd_stored_shape_follows_a_transform_added_later(tmp_path, rng):
    """The stored transform is the prim's own: moving the written prim moves the solid with its mesh."""
    seq = _scene(rng, False)
    write_sequence(tmp_path / "a.usda", seq)
    stage = Usd.Stage.Open(str(tmp_path / "a.usda"))
    UsdGeom.Xformable(stage.GetPrimAtPath("/World/Obstacles/pill")).AddTranslateOp().Set(Gf.Vec3d(0, 0, 10))
    stage.GetRootLayer().Save()
    (ob,) = [o for o in read_sequence(tmp_path / "a.usda").obstacles if o.name == "pill"]
    want = seq.obstacles[0].shape.transform + [[0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 10]]
    assert np.allclose(ob.shape.transform, want, rtol=0, atol=1e-12)
    assert np.allclose(ob.positions, seq.obstacles[0].positions + [0, 0, 10], rtol=0, atol=1e-5)


# --- refused inputs --------------------------------------------------------------------

def _h5_with_shape(path, edit):
    seq = _scene(np.random.default_rng(1), True)
    write_sequence(path, seq)
    with h5py.File(path, "a") as f:
        edit(f, f["obstacles/pill/shape"])


def _replace(name, value):
    def edit(f, g):
        del g[name]
        g[name] = value
    return edit


@pytest.mark.parametrize("edit,expect", [
    (lambda f, g: g.__delitem__("profile"), "shape needs a dataset profile (5,) or (T, 5)"
                                            " (height, disc_bottom, round_bottom, disc_top, round_top) in {p}:/obstacles/pill/shape/profile"),
    (_replace("profile", np.zeros((T, 4))), "shape profile must be numeric (5,) or (T, 5)"),
    (_replace("transform", np.array([b"abc"] * 12).reshape(4, 3)), "in {p}:/obstacles/pill/shape/transform"),
    (lambda f, g: g.attrs.__setitem__("axis", "W"), "shape attribute axis must be X, Y or Z; got 'W' in {p}:/obstacles/pill/shape:@axis"),
    (lambda f, g: g.attrs.__delitem__("source"), "in {p}:/obstacles/pill/shape:@source"),
    (lambda f, g: f.copy(g, f["obstacles/floor"], "shape"), "a half-space has no analytic shape; found a shape group in {p}:/obstacles/floor/shape"),
    (lambda f, g: (f["obstacles/pill"].__delitem__("shape"), f["obstacles/pill"].create_dataset("shape", data=1.0)),
     "shape must be a group with attrs source, axis and datasets profile, transform in {p}:/obstacles/pill/shape"),
    (_replace("profile", -np.ones((T, 5))), "shape profile must be finite and >= 0 in {p}:/obstacles/pill/shape/profile"),
    (_replace("transform", np.zeros((T, 4, 3))), "nonsingular linear part in every frame in {p}:/obstacles/pill/shape/transform"),
], ids=["missing-profile", "profile-4-columns", "text-transform", "axis-W", "no-source", "shape-on-half-space",
        "shape-is-a-dataset", "negative-profile", "singular-transform"])
def test_hdf5_bad_shape_is_one_line_exit_2(tmp_path, edit, expect):
    p = str(tmp_path / "bad.h5")
    _h5_with_shape(p, edit)
    with pytest.raises(InputError) as err:
        read_sequence(p)
    assert expect.format(p=p) in str(err.value)
    r = _run("verify", p)
    assert r.exit_code == 2 and expect.format(p=p) in r.output and "Traceback" not in r.output, r.output


def test_hdf5_window_names_a_per_frame_shape_of_the_wrong_length(tmp_path):
    p = str(tmp_path / "bad.h5")
    _h5_with_shape(p, _replace("profile", np.ones((T + 1, 5))))
    with pytest.raises(InputError, match=rf"shape profile must be \(5,\) or \({T}, 5\).* got \({T + 1}, 5\) in "
                                         rf"{p}:/obstacles/pill/shape/profile"):
        read_sequence(p, frame_window=(0, 2))


def test_npz_bad_shape(tmp_path, rng):
    write_sequence(tmp_path / "s.npz", _scene(rng, False))
    arrays = dict(np.load(tmp_path / "s.npz"))
    for key, value, expect in (("axis", np.str_("Q"), "shape axis must be X, Y or Z; got 'Q'"),
                               ("transform", np.zeros(12), "shape transform must be numeric (4, 3)")):
        bad = dict(arrays, **{f"obstacles/pill/shape/{key}": value})
        p = str(tmp_path / f"bad_{key}.npz")
        np.savez(p, **bad)
        with pytest.raises(InputError) as err:
            read_sequence(p)
        assert expect in str(err.value) and f"{p}:/obstacles/pill/shape/{key}" in str(err.value)
    bad = {k: v for k, v in arrays.items() if k != "obstacles/pill/shape/profile"}
    np.savez(tmp_path / "missing.npz", **bad)
    with pytest.raises(InputError, match="got nothing in .*missing.npz:/obstacles/pill/shape/profile"):
        read_sequence(tmp_path / "missing.npz")


def test_xdmf_bad_shape(tmp_path, rng):
    write_sequence(tmp_path / "s.xdmf", _scene(rng, False))
    text = (tmp_path / "s.xdmf").read_text()
    assert text.count('Name="penfree_shape"') == 1
    (tmp_path / "s.xdmf").write_text(text.replace('&quot;axis&quot;: &quot;Y&quot;', '&quot;axis&quot;: 7'))
    with pytest.raises(InputError, match="shape axis must be X, Y or Z .* penfree_shape Information of "
                                         "collection obstacle:pill in .*s.xdmf"):
        read_sequence(tmp_path / "s.xdmf")


# --- deform results ------------------------------------------------------------------------

@pytest.mark.parametrize("long_file", [False, True], ids=["whole", "frame-ranges"])
def test_deform_result_keeps_the_input_shape(tmp_path, rng, monkeypatch, long_file):
    """``deform in.h5 -o out.h5``, also in frame ranges merged afterwards (each range reads
    a window of the per-frame shape; the merge must write all of it)."""
    import sys

    from penfree.formats.result import read_result

    if long_file:
        monkeypatch.setattr(sys.modules["penfree.scaleout.plan"], "MAX_TASK_BYTES", 100)
    seq = _scene(rng, True)
    write_sequence(tmp_path / "in.h5", seq)
    r = _run("deform", tmp_path / "in.h5", "-o", tmp_path / "out.h5")
    assert r.exit_code == 0, r.output
    got = {ob.name: ob for ob in read_result(str(tmp_path / "out.h5")).sequence.obstacles}
    _assert_same_shape(got["pill"].shape, seq.obstacles[0].shape)


def test_deform_of_a_usd_stage_keeps_the_shape(tmp_path):
    from penfree.formats.result import read_result

    _stage_with(tmp_path / "a.usda", "Capsule", "X", KINDS["Capsule"][0], moving=True)
    r = _run("deform", tmp_path / "a.usda", "-o", tmp_path / "out.h5")
    assert r.exit_code == 0, r.output
    (ob,) = read_result(str(tmp_path / "out.h5")).sequence.obstacles
    _assert_same_shape(ob.shape, read_sequence(tmp_path / "a.usda").obstacles[0].shape)


def test_frame_ranges_check_the_whole_per_frame_shape(tmp_path, monkeypatch):
    """A bad frame of a per-frame shape outside every range's window still fails the merge."""
    import sys

    monkeypatch.setattr(sys.modules["penfree.scaleout.plan"], "MAX_TASK_BYTES", 100)
    p = tmp_path / "in.h5"

    def bad_last_frame(f, g):
        profile = g["profile"][()]
        profile[-1, 2] = -1.0
        g["profile"][...] = profile

    _h5_with_shape(p, bad_last_frame)
    r = _run("deform", p, "--frames", "0:2", "-o", tmp_path / "out.h5")
    assert r.exit_code == 2, r.output
    assert f"shape profile must be finite and >= 0 in {p}:/obstacles/pill/shape/profile" in r.output
    assert not (tmp_path / "out.h5").exists()
