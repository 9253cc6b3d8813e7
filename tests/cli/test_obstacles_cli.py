"""Issue 10 through the commands: obstacle forms, the two distances, dirty start states."""

import json
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from penfree.cli import main
from penfree.formats import read_sequence

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))
from _scenes import box_mesh, landing_sheet  # noqa: E402


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _landing_file(path, ground="attr", collider="vertices", contact_radius=0.02, thickness=None):
    """A landing sheet as a simulator writes it: ground normal/offset, collider vertices/faces."""
    pos, F = landing_sheet(n=8, T=6)
    with h5py.File(path, "w") as f:
        f["positions"] = pos.astype(np.float32)
        f["faces"] = F.astype(np.int32)
        f.attrs["contact_radius"] = contact_radius
        if thickness is not None:
            f.attrs["thickness"] = thickness
        g = f.create_group("obstacles/ground_plane")
        g["normal"] = np.array([0.0, 0.0, 1.0])
        if ground == "attr":
            g.attrs["offset"] = 0.0
        else:
            g["offset"] = np.float64(0.0)
        box = box_mesh([2.0, 2.0, 0.0], [2.5, 2.5, 0.4])  # a collider off to the side
        c = f.create_group("obstacles/collider")
        c[collider] = box.positions
        c["faces"] = box.faces
    return path


@pytest.mark.parametrize("ground", ["attr", "dataset"])
@pytest.mark.parametrize("collider", ["vertices", "positions"])
def test_recording_layout_through_every_command(tmp_path, ground, collider):
    src = _landing_file(tmp_path / "landing.h5", ground, collider)
    r = _run("info", src)
    assert r.exit_code == 0, r.output
    assert "contact radius:" in r.output and "0.02" in r.output
    assert "obstacle ground_plane" in r.output and "half-space" in r.output
    r = _run("info", src, "--json")
    d = json.loads(r.output)
    assert d["contact_radius"] == pytest.approx(0.02) and d["thickness"] == 0.0
    for model in ("affine", "auto"):
        out = tmp_path / f"out-{model}.h5"
        r = _run("deform", src, "-o", out, "--model", model, "--json")
        assert r.exit_code == 0, r.output
        assert json.loads(r.output)["all_certified"] is True
        assert read_sequence(out).obstacles[1].is_half_space  # written back (sorted: collider, ground_plane)
        r = _run("verify", out)
        assert r.exit_code == 0, r.output
        r = _run("verify", src)  # the raw recording is clean too
        assert r.exit_code == 0, r.output
        rep = tmp_path / f"rep-{model}"
        r = _run("report", out, "-o", rep, "--no-ladder", "--no-plots", "--fail-if-uncertified")
        assert r.exit_code == 0, r.output
        doc = json.loads((rep / "report.json").read_text())
        assert doc["files"][0]["certificate"]["n_started_dirty"] == 0


def test_contact_radius_is_no_separation(tmp_path):
    """A contact radius far above every gap changes nothing that deform guarantees."""
    src = _landing_file(tmp_path / "landing.h5", contact_radius=0.5)
    r = _run("deform", src, "-o", tmp_path / "out.h5", "--model", "affine", "--json")
    assert r.exit_code == 0, r.output
    assert set(json.loads(r.output)["models"]) - {"none"}  # some step still moves
    r = _run("deform", src, "-o", tmp_path / "out2.h5", "--contact-radius", "0.001", "--thickness", "0.0005",
             "--stats", "--json")
    assert r.exit_code == 0, r.output
    with h5py.File(tmp_path / "out2.h5") as f:
        r_q = f["stats/query_radius"][()]
        pos = f["positions"][()].astype(np.float64)
        frames = f["steps/frame"][()]
    disp = [np.linalg.norm(pos[s] - pos[s - 1], axis=1).max() for s in frames]
    np.testing.assert_allclose(r_q, 0.001 + np.array(disp), rtol=1e-6)


@pytest.mark.parametrize("members", [{"points": np.zeros((3, 3))}, {"vertices": np.zeros((3, 3))},
                                     {"normal": np.array([0.0, 0, 1])}])
def test_obstacle_group_unknown_form(tmp_path, members):
    """obstacle-group-unknown-form: exit 2, one line naming the group and the accepted forms."""
    src = tmp_path / "bad.h5"
    pos, F = landing_sheet(n=4, T=3)
    with h5py.File(src, "w") as f:
        f["positions"] = pos
        f["faces"] = F
        g = f.create_group("obstacles/weird")
        for k, v in members.items():
            g[k] = v
    before = sorted(p.name for p in tmp_path.iterdir())
    for args in (("info", src), ("deform", src, "-o", tmp_path / "o.h5"), ("verify", src)):
        r = _run(*args)
        assert r.exit_code == 2, r.output
        lines = [ln for ln in r.output.splitlines() if ln.strip()]
        assert len(lines) == 1 and "weird" in lines[0] and "Traceback" not in r.output
        if "normal" not in members:
            assert "half-space" in lines[0] or "normal" in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_issue9_finding6_zero_motion_steps_are_certified(tmp_path):
    """issue 9 finding 6: zero-motion steps are not "NOT ALL" / uncertified."""
    pos, F = landing_sheet(n=5, T=4, h0=0.5)
    frames = np.concatenate([np.repeat(pos[:1], 3, axis=0), pos])
    for name, P, h in (("pause", frames, 0.0), ("still", np.repeat(pos[:1], 4, axis=0), 0.0),
                       ("pause-thick", frames, 0.01)):
        src = tmp_path / f"{name}.h5"
        with h5py.File(src, "w") as f:
            f["positions"] = P
            f["faces"] = F
            f.attrs["thickness"] = h
        out = tmp_path / f"{name}-out.h5"
        r = _run("deform", src, "-o", out)
        assert r.exit_code == 0 and "NOT ALL" not in r.output and "all steps" in r.output, r.output
        r = _run("report", out, "-o", tmp_path / f"{name}-rep", "--no-ladder", "--no-plots", "--fail-if-uncertified")
        assert r.exit_code == 0, r.output


def test_pre_existing_crossing_reported(tmp_path):
    """verify on a dirty start: "k pre-existing intersections, unchanged"; --strict fails."""
    tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    rod = np.array([[0.2, 0.2, -0.3], [0.2, 0.2, 0.3]])
    x0 = np.concatenate([tri, rod])
    frames = np.array([x0 + [0.01 * t, 0.005 * t, 0] for t in range(4)])
    src = tmp_path / "dirty.h5"
    with h5py.File(src, "w") as f:
        f["positions"] = frames
        f["faces"] = np.array([[0, 1, 2]])
        f["edges"] = np.array([[3, 4]])
    out = tmp_path / "out.h5"
    r = _run("deform", src, "-o", out, "--model", "affine", "--check-start")
    assert r.exit_code == 0 and "pre-existing" in r.output, r.output
    r = _run("deform", src, "-o", tmp_path / "unchecked.h5", "--model", "affine")
    assert r.exit_code == 0 and "pre-existing" not in r.output, r.output
    r = _run("verify", out)
    assert r.exit_code == 0, r.output
    assert "pre-existing intersections, unchanged" in r.output
    assert _run("verify", out, "--strict").exit_code == 1
    assert _run("verify", src).exit_code == 1  # a raw recording is judged as it is
    for res in (out, tmp_path / "unchecked.h5"):  # stored by deform, or counted by report
        rep = tmp_path / f"rep-{res.stem}"
        r = _run("report", res, "-o", rep, "--no-ladder", "--no-plots")
        assert r.exit_code == 0, r.output
        assert json.loads((rep / "report.json").read_text())["files"][0]["certificate"]["n_started_dirty"] == 3
        assert "pre-existing intersections" in (rep / "report.md").read_text()


@pytest.mark.parametrize("fmt", ["npz", "xdmf", "h5"])
def test_convert_keeps_obstacles_and_distances(tmp_path, fmt):
    src = _landing_file(tmp_path / "landing.h5", thickness=0.001)
    out = tmp_path / f"conv.{fmt}"
    r = _run("convert", src, out)
    assert r.exit_code == 0, r.output
    seq = read_sequence(out)
    assert seq.contact_radius == pytest.approx(0.02) and seq.thickness == pytest.approx(0.001)
    kinds = {ob.name: ob.is_half_space for ob in seq.obstacles}
    assert kinds == {"collider": False, "ground_plane": True}
    hs = next(ob for ob in seq.obstacles if ob.is_half_space)
    assert hs.normal.tolist() == [0.0, 0.0, 1.0] and hs.offset == 0.0


def test_npz_half_space_and_vertices_alias(tmp_path):
    pos, F = landing_sheet(n=5, T=4)
    box = box_mesh([2.0, 2.0, 0.0], [2.5, 2.5, 0.4])
    src = tmp_path / "rec.npz"
    np.savez(src, positions=pos, faces=F, contact_radius=np.float64(0.01),
             **{"obstacles/ground/normal": np.array([0.0, 0, 1]), "obstacles/ground/offset": np.float64(0.0),
                "obstacles/box/vertices": box.positions, "obstacles/box/faces": box.faces})
    r = _run("info", src)
    assert r.exit_code == 0 and "half-space" in r.output and "contact radius:" in r.output, r.output
    r = _run("deform", src, "-o", tmp_path / "out.h5")
    assert r.exit_code == 0, r.output
    assert _run("verify", tmp_path / "out.h5").exit_code == 0
    assert _run("verify", src).exit_code == 0
    r = _run("report", tmp_path / "out.h5", "-o", tmp_path / "rep", "--no-ladder", "--no-plots",
             "--fail-if-uncertified")
    assert r.exit_code == 0, r.output


def test_npz_obstacle_unknown_form(tmp_path):
    pos, F = landing_sheet(n=4, T=3)
    src = tmp_path / "bad.npz"
    np.savez(src, positions=pos, faces=F, **{"obstacles/weird/points": np.zeros((3, 3))})
    for args in (("info", src), ("verify", src)):
        r = _run(*args)
        assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1 and "weird" in r.output, r.output


def test_xdmf_half_space_through_info_and_verify(tmp_path):
    src = _landing_file(tmp_path / "landing.h5")
    out = tmp_path / "conv.xdmf"
    assert _run("convert", src, out).exit_code == 0
    r = _run("info", out)
    assert r.exit_code == 0 and "half-space" in r.output and "obstacle collider" in r.output, r.output
    assert _run("verify", out).exit_code == 0


def test_start_inside_thickness_file_is_certified(tmp_path):
    """Summary truth: a file whose start states lie inside the thickness (two layers
    resting 0.4 h apart) is all certified, moves, verifies, and passes --fail-if-uncertified."""
    h = 0.01
    u = np.linspace(0, 0.3, 5)
    U, V = np.meshgrid(u, u, indexing="ij")
    lower = np.stack([U.ravel(), V.ravel(), np.zeros(25)], axis=1)
    base = np.concatenate([lower, lower + [0, 0, 0.4 * h]])
    F = []
    for i in range(4):
        for j in range(4):
            p, q, r, s = i * 5 + j, (i + 1) * 5 + j, i * 5 + j + 1, (i + 1) * 5 + j + 1
            F += [[p, q, r], [q, s, r]]
    F = np.array(F)
    A = np.array([[1.01, 0.02, 0], [-0.02, 1.0, 0], [0, 0, 1.0]])
    src = tmp_path / "resting.h5"
    with h5py.File(src, "w") as f:
        f["positions"] = np.array([base @ np.linalg.matrix_power(A, t).T for t in range(4)])
        f["faces"] = np.concatenate([F, F + 25])
        f.attrs["thickness"] = h
    out = tmp_path / "out.h5"
    r = _run("deform", src, "-o", out, "--model", "affine", "--json")
    assert r.exit_code == 0, r.output
    d = json.loads(r.output)
    assert d["all_certified"] is True and set(d["models"]) == {"affine"}
    assert _run("verify", out).exit_code == 0
    r = _run("report", out, "-o", tmp_path / "rep", "--no-ladder", "--no-plots", "--fail-if-uncertified")
    assert r.exit_code == 0, r.output
