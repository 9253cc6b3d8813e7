"""Analytic colliders through the commands: `deform` and `verify` judge the exact solid.

The scene is the gap session 32 found: a small triangle resting between a Sphere collider
and its containing icosphere (inside the mesh, outside the shape), whose constant-velocity
prediction goes into the sphere. The mesh alone cannot see it; the solid does.
"""

import json

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from penfree.cli import main
from penfree.formats import _usd_shapes as shapes

R = 0.03


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _under_a_vertex():
    V, F = shapes.sphere(R)
    n = V[np.argmax(V[:, 2])] / np.linalg.norm(V[np.argmax(V[:, 2])])
    a = np.cross(n, [1.0, 0, 0])
    a /= np.linalg.norm(a)
    return V, F, n, np.cross(n, a), a


def _write(path, frames, *, shape=True):
    V, F, *_ = _under_a_vertex()
    with h5py.File(path, "w") as f:
        f["positions"] = np.asarray(frames)
        f["faces"] = np.array([[0, 1, 2]])
        g = f.create_group("obstacles/ball")
        g["positions"], g["faces"] = V, F
        if shape:
            s = g.create_group("shape")
            s.attrs["source"], s.attrs["axis"] = "Sphere", "Z"
            s["profile"] = np.array([0.0, 0.0, R, 0.0, R])
            s["transform"] = np.vstack([np.eye(3), np.zeros(3)])
    return path


def _frames(heights):
    _, _, n, a, b = _under_a_vertex()
    tri = n * R + 1e-4 * np.array([a, -a + b, -a - b])
    return np.array([tri + n * h for h in heights])


def test_verify_of_a_recording_sees_a_triangle_entering_the_sphere_through_the_mesh_s_shell(tmp_path):
    """0.2 mm above the sphere (inside its icosphere), then 0.1 mm inside: the mesh sees
    nothing (no face of it is crossed), the solid sees the step."""
    frames = _frames([5e-4, 2e-4, -1e-4])
    r = _run("verify", _write(tmp_path / "with.h5", frames), "--json")
    assert r.exit_code == 1, r.output
    steps = json.loads(r.output)["steps"]
    assert [s["ok"] for s in steps] == [True, False]
    r = _run("verify", _write(tmp_path / "without.h5", frames, shape=False))
    assert r.exit_code == 0, r.output  # the mesh alone: the gap the solid closes


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("model", ["affine", "auto", "translation"])
def test_deform_keeps_a_triangle_resting_in_the_shell_out_of_the_sphere(tmp_path, model, dtype):
    frames = _frames([5e-4, 2e-4, -1e-4, -1e-4]).astype(dtype)
    src = _write(tmp_path / "in.h5", frames)
    out = tmp_path / "out.h5"
    r = _run("deform", src, "-o", out, "--model", model)
    assert r.exit_code == 0, r.output
    with h5py.File(out, "r") as f:
        deformed, frame = f["steps/deformed"][...], f["steps/frame"][...]
        assert "obstacles/ball/shape/profile" in f  # carried into the result, for verify
    k = list(frame).index(1)
    assert deformed.dtype == dtype
    assert np.linalg.norm(deformed[k].astype(np.float64), axis=1).min() > R
    assert not np.array_equal(deformed[k], frames[1])  # it still moved toward the next frame
    r = _run("verify", out)
    assert r.exit_code == 0, r.output


def test_verify_of_a_result_moved_into_the_sphere_fails(tmp_path):
    """A tampered result: the step from 0.2 mm above, stored 0.1 mm inside (as the
    mesh-only gate wrote it), with a translation map that matches it."""
    frames = _frames([5e-4, 2e-4, -1e-4])
    src = _write(tmp_path / "in.h5", frames)
    out = tmp_path / "out.h5"
    assert _run("deform", src, "-o", out, "--model", "translation").exit_code == 0
    _, _, n, _, _ = _under_a_vertex()
    with h5py.File(out, "r+") as f:
        k = list(f["steps/frame"][...]).index(1)
        d = f["steps/deformed"][...]
        d[k] = frames[1] - n * 3e-4
        f["steps/deformed"][...] = d
        if "steps/A" in f:
            A = f["steps/A"][...]
            A[k] = np.eye(3)
            f["steps/A"][...] = A
        if "steps/b" in f:
            b = f["steps/b"][...]
            b[k] = -n * 3e-4
            f["steps/b"][...] = b
    r = _run("verify", out, "--json")
    assert r.exit_code == 1, r.output


def test_info_names_the_solid(tmp_path):
    src = _write(tmp_path / "in.h5", _frames([5e-4, 2e-4]))
    r = _run("info", src)
    assert r.exit_code == 0 and "exact solid: Sphere" in r.output, r.output
    r = _run("info", _write(tmp_path / "mesh.h5", _frames([5e-4, 2e-4]), shape=False), "--json")
    assert json.loads(r.output)["obstacles"][0]["solid"] is None
