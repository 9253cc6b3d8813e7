"""``penfree deform``: the written maps are certified, outputs are safe, options work."""

import json
import os

import h5py
import numpy as np
import pytest

from penfree.core.fit.certificate import certify
from penfree.formats import write_sequence
from penfree.formats.result import read_result
from penfree.sequence import Sequence


def _cloth(T=6, n=6, dtype=np.float64, offset=0.0):
    """A small sheet swinging and stretching (non-affine), optionally far from the origin."""
    g = np.linspace(0.0, 1.0, n)
    X, Y = np.meshgrid(g, g, indexing="ij")
    frames = []
    for t in range(T):
        a = 0.05 * t
        z = 0.1 * np.sin(3 * X + a) * Y
        frames.append(np.stack([X + 0.01 * t * Y, Y * (1 + 0.01 * t), z], axis=-1).reshape(-1, 3))
    F = []
    for i in range(n - 1):
        for j in range(n - 1):
            p, q, r, s = i * n + j, (i + 1) * n + j, i * n + j + 1, (i + 1) * n + j + 1
            F += [[p, q, r], [q, s, r]]
    pos = (np.array(frames) + offset).astype(dtype)
    return Sequence(positions=pos, faces=np.array(F), thickness=0.0).validate()


@pytest.mark.parametrize("model", ["translation", "rigid", "similarity", "affine", "auto"])
def test_every_written_map_is_certified(cli, tmp_path, model):
    src, out = tmp_path / "in.h5", tmp_path / "out.h5"
    write_sequence(src, _cloth())
    r = cli("deform", src, "-o", out, "--model", model, "--json")
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout)
    assert summary["steps"] == 5 and summary["all_certified"]
    res = read_result(out)
    for A, m in zip(res.steps["A"], res.steps["margin_required"]):
        assert certify(A, m)
    # x_def = A x + b up to rounding, from the recorded start positions
    pos = res.sequence.positions
    for k, s in enumerate(res.steps["frame"]):
        np.testing.assert_allclose(res.steps["deformed"][k], pos[s] @ res.steps["A"][k].T + res.steps["b"][k],
                                   rtol=0, atol=1e-12)


@pytest.mark.parametrize("dtype", [np.float32, np.float64], ids=["float32", "float64"])
def test_dtype_kept_and_far_from_origin(cli, tmp_path, dtype):
    src, out = tmp_path / "in.h5", tmp_path / "out.h5"
    seq = _cloth(dtype=dtype, offset=0.0 if dtype == np.float32 else 1e6)
    write_sequence(src, seq)
    assert cli("deform", src, "-o", out, "--model", "affine").exit_code == 0
    res = read_result(out)
    assert res.steps["deformed"].dtype == dtype
    # far from the origin the centred fit loses no digits: the deformed state is as
    # close to the next frame as at the origin (residuals are offset-independent)
    if dtype == np.float64:
        near = tmp_path / "near.h5"
        write_sequence(near, _cloth())
        assert cli("deform", near, "-o", tmp_path / "n.h5", "--model", "affine").exit_code == 0
        np.testing.assert_allclose(res.steps["residual_next_rms"], read_result(tmp_path / "n.h5").steps["residual_next_rms"],
                                   rtol=1e-6, atol=0)


def test_two_frames_single_vertex_and_zero_motion(cli, tmp_path):
    one = Sequence(positions=np.array([[[0.0, 0, 0]], [[0.1, 0, 0]]])).validate()
    write_sequence(tmp_path / "one.h5", one)
    assert cli("deform", tmp_path / "one.h5", "-o", tmp_path / "o1.h5").exit_code == 0
    res = read_result(tmp_path / "o1.h5")
    np.testing.assert_allclose(res.steps["deformed"][0], [[0.2, 0, 0]], rtol=0, atol=1e-15)
    still = Sequence(positions=np.repeat(_cloth().positions[:1], 3, axis=0), faces=_cloth().faces).validate()
    write_sequence(tmp_path / "still.h5", still)
    assert cli("deform", tmp_path / "still.h5", "-o", tmp_path / "o2.h5").exit_code == 0
    res = read_result(tmp_path / "o2.h5")
    np.testing.assert_array_equal(res.steps["deformed"][0], still.positions[1])


def test_frames_weights_and_per_vertex(cli, tmp_path):
    src, out = tmp_path / "in.h5", tmp_path / "out.h5"
    write_sequence(src, _cloth(T=8))
    with h5py.File(src, "a") as f:
        f["masses"] = np.linspace(1.0, 2.0, 36)
    r = cli("deform", src, "-o", out, "--frames", "3:6", "--weights", "masses", "--per-vertex", "--model", "affine")
    assert r.exit_code == 0, r.output
    res = read_result(out)
    assert res.steps["frame"].tolist() == [3, 4, 5]
    assert res.steps["residual_next_per_vertex"].shape == (3, 36)
    assert res.attrs["options"]["weights"] == "masses"
    bad = cli("deform", src, "-o", tmp_path / "x.h5", "--weights", "nope")
    assert bad.exit_code == 2 and "nope" in bad.stderr and not (tmp_path / "x.h5").exists()
    empty = cli("deform", src, "-o", tmp_path / "y.h5", "--frames", "9:")
    assert empty.exit_code == 2 and not (tmp_path / "y.h5").exists()


def test_no_silent_overwrite_and_input_untouched(cli, tmp_path):
    src, out = tmp_path / "in.h5", tmp_path / "out.h5"
    write_sequence(src, _cloth())
    before = (open(src, "rb").read(), os.stat(src).st_mtime_ns)
    out.write_bytes(b"keep me")
    r = cli("deform", src, "-o", out)
    assert r.exit_code == 2 and out.read_bytes() == b"keep me"
    assert cli("deform", src, "-o", src, "--overwrite").exit_code == 2  # never the input
    assert cli("deform", src, "-o", out, "--overwrite").exit_code == 0
    assert (open(src, "rb").read(), os.stat(src).st_mtime_ns) == before
    assert sorted(os.listdir(tmp_path)) == ["in.h5", "out.h5"]


def test_stats_and_selection_groups(cli, tmp_path):
    src, out = tmp_path / "in.h5", tmp_path / "out.h5"
    write_sequence(src, _cloth())
    assert cli("deform", src, "-o", out, "--stats").exit_code == 0  # default model: auto
    res = read_result(out)
    sel = res.groups["selection"]
    assert sel["candidates"][0] == "none" and sel["predicted_k_1pct"].shape[0] == 5
    chosen = [sel["candidates"][j] for j in sel["chosen"]]
    assert chosen == res.steps["model"].tolist()
    assert "hit_rate_next_deformed" in res.groups["stats"]


def test_per_component_output_verifies(cli, tmp_path):
    # Two sheets moving differently: each gets its own certified map, and the result
    # passes `penfree verify` (full CCD between components).
    a, b = _cloth(), _cloth()
    pos_b = b.positions + np.array([0.0, 0.0, 0.5])
    pos_b[:, :, 0] -= 0.02 * np.arange(6)[:, None]
    F = np.concatenate([a.faces, b.faces + 36])
    seq = Sequence(positions=np.concatenate([a.positions, pos_b], axis=1), faces=F).validate()
    src, out = tmp_path / "in.h5", tmp_path / "out.h5"
    write_sequence(src, seq)
    assert cli("deform", src, "-o", out, "--model", "per-component").exit_code == 0
    res = read_result(out)
    comp = res.groups["component_maps"]
    assert comp["labels"].tolist() == [0] * 36 + [1] * 36
    for k in range(len(res.steps["frame"])):
        for A in comp["A"][k]:
            assert certify(A, 0.0)
    v = cli("verify", out)
    assert v.exit_code == 0, v.output


def test_result_records_the_thickness_it_guarantees(cli, tmp_path):
    """`--thickness`/`--contact-radius` given to deform are the result's own attributes,
    so that `verify` and `report` of the result check the separation deform guaranteed
    (they used to check the input's, 0 here)."""
    src, out = tmp_path / "in.h5", tmp_path / "out.h5"
    write_sequence(src, _cloth())
    cli("deform", src, "-o", out, "--thickness", "0.003", "--contact-radius", "0.01", expect=0)
    res = read_result(str(out))
    assert res.sequence.thickness == 0.003
    assert res.sequence.contact_radius == 0.01
    assert res.attrs["options"]["thickness"] == 0.003
    r = cli("verify", out, "--json", expect=0)
    assert json.loads(r.stdout)["thickness"] == 0.003


@pytest.mark.parametrize("option", ["--thickness", "--contact-radius", "--dhat"])
def test_distances_beyond_the_supported_range_are_refused(cli, tmp_path, option):
    """A distance option above `SCALE_MAX` is refused like a file attribute beyond it
    (1e200 overflowed the CCD's squared distances: a traceback and exit 1)."""
    src = tmp_path / "in.h5"
    write_sequence(src, _cloth())
    args = ["deform", src, "-o", tmp_path / "out.h5", option, "1e200"]
    if option == "--dhat":
        args += ["--model", "auto", "--client-model", "isotropic"]
    r = cli(*args, expect=2)
    assert "1e+100" in r.stderr and "Usage:" not in r.output
    cli("verify", src, "--thickness", "1e200", expect=2)


def test_output_inside_an_input_directory_is_refused(cli, tmp_path):
    """A mesh sequence named by its directory is read whole: a result written into it
    would change what it reads as, so deform refuses it as convert does."""
    src, frames = tmp_path / "in.h5", tmp_path / "ply"
    write_sequence(src, _cloth())
    cli("convert", src, frames, "--format", "meshseq", expect=0)
    r = cli("deform", frames, "-o", frames / "res.h5", expect=2)
    assert "inside the input directory" in r.stderr
    cli("deform", frames, "-o", tmp_path / "res.h5", expect=0)


@pytest.mark.parametrize("long_file", [False, True], ids=["whole", "long"])
@pytest.mark.parametrize("frames, total", [(None, 5), ("2:4", 2), ("0:1", None)])
def test_progress_counts_the_selected_steps(cli, tmp_path, monkeypatch, long_file, frames, total):
    """The progress bar's total is the number of steps deform runs (it counted frames: 6 for
    5 steps); a slice selecting no step is the one-line exit 2 before a long file's frame
    ranges read anything."""
    import sys

    import penfree.cli.deform as cli_deform
    import penfree.scaleout.plan  # noqa: F401 (patched below)

    p = tmp_path / "in.h5"
    write_sequence(str(p), _cloth(T=6))
    totals = []

    class Spy(cli_deform.Progress):
        def __init__(self, n, *args, **kwargs):
            totals.append(n)
            super().__init__(n, *args, **kwargs)

    monkeypatch.setattr(cli_deform, "Progress", Spy)
    if long_file:
        monkeypatch.setattr(sys.modules["penfree.scaleout.plan"], "MAX_TASK_BYTES", 100)
    out = tmp_path / "out.h5"
    r = cli("deform", str(p), "-o", str(out), *([] if frames is None else ["--frames", frames]))
    if total is None:
        assert r.exit_code == 2 and f"--frames 0:1 selects no step of {p}, a 6-frame sequence" in r.stderr, r.output
        assert totals == [] and not out.exists()
        return
    assert r.exit_code == 0, r.output
    assert totals == [total] and read_result(str(out)).n_steps == total
