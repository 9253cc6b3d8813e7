"""Deform result files: round trip, strings and JSON attrs, validation on read, atomic write."""

import os

import h5py
import numpy as np
import pytest

from penfree import __version__
from penfree.errors import FormatError, OutputExistsError
from penfree.formats import read_sequence
from penfree.formats import result as result_mod
from penfree.formats.result import is_result_file, read_result, write_result
from penfree.sequence import Sequence


RNG_SEED = 13  # seed of the shared `rng` fixture (tests/conftest.py)


def _inputs(rng, dtype=np.float32, T=5, N=6):
    seq = Sequence(positions=rng.random((T, N, 3)).astype(dtype), edges=np.array([[i, i + 1] for i in range(N - 1)]),
                   weights=np.ones(N), thickness=0.01, attrs={"scene": "rods"}).validate()
    S = T - 1
    steps = {
        "frame": np.arange(1, T),
        "A": np.tile(np.eye(3), (S, 1, 1)) + rng.standard_normal((S, 3, 3)) * 1e-3,
        "b": rng.standard_normal((S, 3)),
        "deformed": rng.random((S, N, 3)),  # float64 on purpose: stored in the input dtype
        "model": np.array(["affine", "rigid", "affine", "translation"][:S]),
        "projection": np.array(["none", "sym", "svd", "none"][:S], dtype=object),
        "certificate_margin": np.array([0.9, 0.8, np.nan, 1.0][:S]),
        "rank": np.array([3, 3, 2, 1][:S]),
        "residual_next_rms": np.array([1.0, 2.0, 3.0, np.nan][:S]),
    }
    attrs = {"input": "rods.h5", "options": {"model": "affine", "margin": 0.0, "weights": None}, "overwrite": False}
    groups = {"stats": {"hit_rate": np.linspace(0, 1, S), "K_any": np.arange(S)},
              "selection": {"ladder": {"models": np.array(["rigid", "affine"]), "rms": np.array([1.0, 0.5])}}}
    return seq, steps, attrs, groups


@pytest.mark.parametrize("dtype", [np.float32, np.float64], ids=["float32", "float64"])
def test_round_trip(tmp_path, rng, dtype):
    seq, steps, attrs, groups = _inputs(rng, dtype)
    p = tmp_path / "deformed.h5"
    write_result(p, seq, steps, attrs, groups=groups)
    assert is_result_file(p)
    res = read_result(p)
    assert res.n_steps == 4 and res.origin == str(p)
    np.testing.assert_array_equal(res.sequence.positions, seq.positions)
    assert res.sequence.positions.dtype == dtype
    assert res.steps["deformed"].dtype == dtype
    np.testing.assert_array_equal(res.steps["deformed"], steps["deformed"].astype(dtype))
    np.testing.assert_array_equal(res.steps["A"], steps["A"])
    assert res.steps["frame"].dtype == np.int64
    assert res.steps["model"].dtype.kind == "U" and res.steps["model"].tolist() == steps["model"].tolist()
    assert res.steps["projection"].tolist() == ["none", "sym", "svd", "none"]
    np.testing.assert_array_equal(res.steps["certificate_margin"], steps["certificate_margin"])  # NaN kept
    assert res.attrs["options"] == attrs["options"] and res.attrs["overwrite"] is False
    assert res.attrs["penfree_format"] == 1 and res.attrs["penfree_version"] == __version__
    assert res.groups["stats"]["K_any"].tolist() == [0, 1, 2, 3]
    assert res.groups["selection"]["ladder"]["models"].tolist() == ["rigid", "affine"]
    with h5py.File(p) as f:
        assert f["steps/deformed"].chunks == (1, 6, 3)
        assert h5py.check_string_dtype(f["steps/model"].dtype).encoding == "utf-8"
    # the result is also a plain layout-v1 sequence file: its input
    back = read_sequence(p)
    np.testing.assert_array_equal(back.positions, seq.positions)
    np.testing.assert_array_equal(back.edges, seq.edges)


def test_plain_sequence_is_not_a_result(tmp_path, rng):
    from penfree.formats import write_sequence

    seq, *_ = _inputs(rng)
    write_sequence(tmp_path / "in.h5", seq)
    (tmp_path / "text.h5").write_text("hello")
    assert not is_result_file(tmp_path / "in.h5")
    assert not is_result_file(tmp_path / "text.h5")
    assert not is_result_file(tmp_path / "missing.h5")
    with pytest.raises(FormatError, match=r"not a deform result; missing dataset steps/frame in .*in\.h5:/steps/frame"):
        read_result(tmp_path / "in.h5")


def _tamper(path, name, value):
    with h5py.File(path, "a") as f:
        del f[name]
        f[name] = value


@pytest.mark.parametrize("name,value,expect", [
    ("steps/frame", np.array([1, 2, 3, 5]), "steps/frame must be in [1, 4] for 5 frames; found 5 in {p}:/steps/frame"),
    ("steps/frame", np.array([0, 1, 2, 3]), "found 0 in {p}:/steps/frame"),
    ("steps/A", np.zeros((4, 3, 2)), "steps/A must be (4, 3, 3); got (4, 3, 2) in {p}:/steps/A"),
    ("steps/b", np.zeros((3, 3)), "steps/b must be (4, 3); got (3, 3) in {p}:/steps/b"),
    ("steps/deformed", np.zeros((4, 5, 3)), "steps/deformed must be (4, 6, 3); got (4, 5, 3) in {p}:/steps/deformed"),
    ("steps/deformed", np.where(np.arange(72).reshape(4, 6, 3) == 40, np.nan, 0.0),
     "step 2 (frame 3) holds NaN or Inf in {p}:/steps/deformed"),
    ("steps/rank", np.zeros(7), "steps/rank must have one row per step (4)"),
], ids=["frame-too-big", "frame-zero", "A-shape", "b-rows", "deformed-vertices", "deformed-nan", "short-column"])
def test_read_validates(tmp_path, rng, name, value, expect):
    _assert_read_fails(tmp_path, rng, name, value, expect)


def _assert_read_fails(tmp_path, rng, name, value, expect, reader=read_result):
    """A written result with dataset `name` replaced by `value` reads (with `reader`) as the
    error `expect`."""
    seq, steps, attrs, _ = _inputs(rng)
    p = str(tmp_path / "r.h5")
    write_result(p, seq, steps, attrs)
    _tamper(p, name, value)
    with pytest.raises(FormatError) as err:
        reader(p)
    assert expect.format(p=p) in str(err.value)


def test_write_refuses_bad_steps_and_existing_output(tmp_path, rng):
    seq, steps, attrs, _ = _inputs(rng)
    p = tmp_path / "r.h5"
    with pytest.raises(FormatError, match="steps/b must be"):
        write_result(p, seq, dict(steps, b=np.zeros((4, 2))), attrs)
    assert not p.exists()
    write_result(p, seq, steps, attrs)
    before = p.read_bytes()
    with pytest.raises(OutputExistsError):
        write_result(p, seq, steps, attrs)
    assert p.read_bytes() == before
    write_result(p, seq, steps, dict(attrs, input="other.h5"), overwrite=True)
    assert read_result(p).attrs["input"] == "other.h5"


@pytest.mark.parametrize("exc", [RuntimeError, KeyboardInterrupt], ids=["error", "ctrl-c"])
def test_write_failure_midway_leaves_nothing(tmp_path, rng, monkeypatch, exc):
    seq, steps, attrs, groups = _inputs(rng)
    real = result_mod._write_array

    def flaky(g, name, *a, **k):
        if name == "deformed":
            raise exc()
        return real(g, name, *a, **k)

    monkeypatch.setattr(result_mod, "_write_array", flaky)
    with pytest.raises(exc):
        write_result(tmp_path / "r.h5", seq, steps, attrs, groups=groups)
    assert os.listdir(tmp_path) == []


# --- what every reader relies on: presence, dtypes, order, finiteness, named file:/dataset -----

def _nan_at(shape, index):
    a = np.zeros(shape)
    a[index] = np.nan
    return a


@pytest.mark.parametrize("name,value,expect", [
    ("steps/frame", np.array([1, 3, 2, 4]),
     "steps/frame must be strictly increasing; found 3 then 2 in {p}:/steps/frame"),
    ("steps/frame", np.array([1, 2, 2, 4]), "found 2 then 2 in {p}:/steps/frame"),
    ("steps/b", _nan_at((4, 3), (1, 0)), "step 1 (frame 2) holds NaN or Inf in {p}:/steps/b"),
    ("steps/A", _nan_at((4, 3, 3), (3, 2, 2)), "step 3 (frame 4) holds NaN or Inf in {p}:/steps/A"),
    ("steps/A", np.full((4, 3, 3), np.inf), "step 0 (frame 1) holds NaN or Inf in {p}:/steps/A"),
    ("steps/model", np.arange(4), "steps/model must be (S,) strings; got int64 in {p}:/steps/model"),
    ("steps/certificate_margin", np.array([b"x", b"y", b"z", b"w"]), "steps/certificate_margin must be numeric"),
    ("steps/residual_next_rms", np.array(["1", "2", "3", "4"], dtype=object),
     "steps/residual_next_rms must be numeric"),
    ("steps/rank", np.float64(3.0), "steps/rank must have one row per step (4); got ()"),
], ids=["frame-unsorted", "frame-repeated", "b-nan", "A-partly-nan", "A-inf", "model-not-text", "margin-bytes",
        "residual-text", "scalar-column"])
def test_read_validates_more(tmp_path, rng, name, value, expect):
    _assert_read_fails(tmp_path, rng, name, value, expect)


def test_per_component_steps_may_be_all_nan(tmp_path, rng):
    # SPEC: steps/A is *the* map applied; a per-component step has none (A all NaN).
    seq, steps, attrs, _ = _inputs(rng)
    steps["A"][2], steps["b"][2] = np.nan, np.nan
    steps["A"][3] = np.nan
    p = tmp_path / "r.h5"
    write_result(p, seq, steps, attrs)
    assert np.isnan(read_result(p).steps["A"][2:]).all()
    steps["b"][3, 1] = np.nan  # a part-NaN b is no per-component marker
    with pytest.raises(FormatError, match=r"step 3 \(frame 4\) holds NaN or Inf in .*r\.h5:/steps/b"):
        write_result(p, seq, steps, attrs, overwrite=True)


@pytest.mark.parametrize("make,expect", [
    (lambda f: (f.__delitem__("steps/frame"), f.create_group("steps/frame")),
     "steps/frame must be a dataset; got a group in {p}:/steps/frame"),
    (lambda f: (f.__delitem__("steps/A"), f.create_group("steps/A")),
     "steps/A must be a dataset; got a group in {p}:/steps/A"),
    (lambda f: (f.__delitem__("steps"), f.create_dataset("steps", data=np.arange(4))),
     "steps must be a group of per-step datasets; got a dataset in {p}:/steps"),
    (lambda f: f.__delitem__("steps/frame"), "missing dataset steps/frame in {p}:/steps/frame"),
], ids=["frame-group", "A-group", "steps-dataset", "frame-missing"])
def test_a_steps_member_makes_a_broken_result_not_a_sequence(tmp_path, rng, make, expect):
    seq, steps, attrs, _ = _inputs(rng)
    p = str(tmp_path / "r.h5")
    write_result(p, seq, steps, attrs)
    with h5py.File(p, "a") as f:
        make(f)
    assert is_result_file(p)  # read as a (broken) result, never silently as the raw sequence
    with pytest.raises(FormatError) as err:
        read_result(p)
    assert expect.format(p=p) in str(err.value)


def test_required_datasets(tmp_path, rng):
    seq, steps, attrs, _ = _inputs(rng)
    p = str(tmp_path / "r.h5")
    write_result(p, seq, {k: v for k, v in steps.items() if k != "certificate_margin"}, attrs)
    assert "certificate_margin" not in read_result(p).steps  # not needed by every reader
    missing = rf"missing dataset steps/certificate_margin in {p}:/steps/certificate_margin"
    with pytest.raises(FormatError, match=missing):
        read_result(p, require=("certificate_margin",))
    for key in ("A", "b", "deformed"):
        write_result(p, seq, steps, attrs, overwrite=True)
        with h5py.File(p, "a") as f:
            del f[f"steps/{key}"]
        with pytest.raises(FormatError, match=rf"missing dataset steps/{key} in {p}:/steps/{key}"):
            read_result(p)


@pytest.mark.parametrize("chosen,expect", [
    (np.array([0, 1, 2, -1]), "selection/chosen must be in [-1, 1] (2 candidates); found 2 at step 2"),
    (np.array([0, -2, 0, 0]), "found -2 at step 1"),
    (np.array([0, 1, 0]), "selection/chosen must be (4,) integer; got (3,) int64"),
    (np.array([0.0, 1.0, 0.0, 0.0]), "selection/chosen must be (4,) integer; got (4,) float64"),
], ids=["past-candidates", "below-minus-one", "short", "float"])
def test_selection_chosen_in_range(tmp_path, rng, chosen, expect):
    seq, steps, attrs, _ = _inputs(rng)
    p = str(tmp_path / "r.h5")
    good = {"candidates": np.array(["rigid", "affine"]), "chosen": np.array([0, 1, -1, 0])}
    write_result(p, seq, steps, attrs, groups={"selection": good})
    assert read_result(p).groups["selection"]["chosen"].tolist() == [0, 1, -1, 0]
    _tamper(p, "selection/chosen", chosen)
    with pytest.raises(FormatError) as err:
        read_result(p)
    assert expect in str(err.value) and f"{p}:/selection/chosen" in str(err.value)


def test_damaged_hdf5_is_reported_not_taken_for_a_sequence(tmp_path, rng):
    seq, steps, attrs, _ = _inputs(rng)
    p = tmp_path / "r.h5"
    write_result(p, seq, steps, attrs)
    data = p.read_bytes()
    (tmp_path / "trunc.h5").write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(FormatError, match="trunc.h5 is a truncated or damaged HDF5 file"):
        is_result_file(tmp_path / "trunc.h5")
    os.mkdir(tmp_path / "dir.h5")
    assert not is_result_file(tmp_path / "dir.h5")


def test_tables_read_equals_the_whole_read_without_frames(tmp_path, rng, monkeypatch):
    """`read_result_tables`: the per-step tables and groups of a whole read, the frame count,
    and of the frames only 0 and 1; no deformed state nor per-vertex dataset is read (a long
    recording's report plans its ranges from it). ``A`` and ``b`` of a 3-vertex scene are kept."""
    from penfree.formats import hdf5
    from penfree.formats.result import read_result_tables

    for N in (12, 3):
        seq, steps, attrs, groups = _inputs(rng, N=N)
        steps["residual_next_per_vertex"] = rng.random((4, N))
        p = str(tmp_path / f"r{N}.h5")
        write_result(p, seq, steps, attrs, groups=groups)
        whole = read_result(p)
        windows, real = [], hdf5.read_positions
        monkeypatch.setattr(hdf5, "read_positions", lambda ds, where, name="positions", window=None:
                            windows.append(window) or real(ds, where, name, window))
        res, T = read_result_tables(p)
        monkeypatch.setattr(hdf5, "read_positions", real)
        assert T == 5 and windows == [(0, 2)] and res.origin == p and res.rows is None
        np.testing.assert_array_equal(res.sequence.positions, whole.sequence.positions[:2])
        dropped = {"deformed"} | ({"residual_next_per_vertex"} if N > 3 else set())
        assert set(res.steps) == set(whole.steps) - dropped
        for k, v in res.steps.items():
            np.testing.assert_array_equal(v, whole.steps[k], err_msg=k)
        assert res.steps["frame"].dtype == np.int64
        assert res.attrs == whole.attrs and res.groups["stats"]["K_any"].tolist() == [0, 1, 2, 3]


@pytest.mark.parametrize("name,value,expect", [
    ("steps/frame", np.array([1, 2, 3, 5]), "steps/frame must be in [1, 4] for 5 frames; found 5 in {p}:/steps/frame"),
    ("steps/A", np.zeros((4, 3, 2)), "steps/A must be (4, 3, 3); got (4, 3, 2) in {p}:/steps/A"),
    ("steps/deformed", np.zeros((4, 5, 3)), "steps/deformed must be (4, 6, 3); got (4, 5, 3) in {p}:/steps/deformed"),
    ("steps/rank", np.zeros(7), "steps/rank must have one row per step (4)"),
    ("steps/model", np.arange(4), "steps/model must be (S,) strings; got int64 in {p}:/steps/model"),
], ids=["frame-too-big", "A-shape", "deformed-vertices", "short-column", "model-not-text"])
def test_tables_read_validates_as_the_whole_read(tmp_path, rng, name, value, expect):
    from penfree.formats.result import read_result_tables

    _assert_read_fails(tmp_path, rng, name, value, expect, reader=read_result_tables)
