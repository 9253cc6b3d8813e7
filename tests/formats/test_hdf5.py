"""HDF5 layout v1: round trips, files written by others, and refused inputs."""

import os

import h5py
import numpy as np
import pytest

from penfree.errors import FormatError, InputError, OutputExistsError
from penfree.formats import read_sequence, write_sequence
from penfree.sequence import Obstacle, Sequence


RNG_SEED = 7  # seed of the shared `rng` fixture (tests/conftest.py)


def scene_arrays(rng, dtype, kind="triangles"):
    topo = dict(faces=np.array([[0, 1, 2], [1, 2, 3], [2, 3, 4]])) if kind == "triangles" else \
        dict(edges=np.array([[0, 1], [1, 2], [2, 3], [3, 4]]))
    return Sequence(
        positions=(rng.standard_normal((4, 5, 3)) * 10 + 1e4).astype(dtype), weights=rng.random(5) + 0.1,
        components=np.array([0, 0, 1, 1, 1]), thickness=1e-3, dt=1 / 60, source="unit test",
        attrs={"flag": True, "count": 3, "scale": 0.5, "meta": {"solver": "ogc", "iters": [1, 2]},
               "none": None, "tricky": "json:not json"},
        obstacles=[Obstacle("floor", rng.random((4, 3)), faces=np.array([[0, 1, 2], [0, 2, 3]])),
                   Obstacle("pin", rng.random((4, 2, 3)), edges=np.array([[0, 1]]))],
        **topo,
    )


@pytest.mark.parametrize("kind", ["triangles", "segments"])
@pytest.mark.parametrize("dtype", [np.float32, np.float64], ids=["float32", "float64"])
def test_round_trip(tmp_path, rng, dtype, kind):
    seq = scene_arrays(rng, dtype, kind).validate()
    path = str(tmp_path / "frames.h5")
    write_sequence(path, seq)
    back = read_sequence(path)
    assert back.positions.dtype == dtype
    np.testing.assert_array_equal(back.positions, seq.positions)
    for name in ("edges", "faces", "weights", "components"):
        a, b = getattr(seq, name), getattr(back, name)
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_array_equal(a, b)
    assert (back.thickness, back.dt, back.source, back.origin) == (seq.thickness, seq.dt, seq.source, path)
    assert back.attrs == seq.attrs
    assert [o.name for o in back.obstacles] == ["floor", "pin"]
    np.testing.assert_array_equal(back.obstacles[0].positions, seq.obstacles[0].positions)
    np.testing.assert_array_equal(back.obstacles[1].edges, [[0, 1]])
    with h5py.File(path) as f:
        assert f["positions"].chunks == (1, 5, 3)
        assert f.attrs["penfree_format"] == 1


@pytest.mark.parametrize("window", [(0, 2), (1, 3), (2, 4), (1, 99)])
def test_frame_window_reads_a_slice_of_the_frames(tmp_path, rng, window):
    # A scale-out frame range reads only its frames: the window equals the slice of a
    # full read, per-frame obstacles included (static ones whole); stop clips like a slice.
    seq = scene_arrays(rng, np.float32).validate()
    path = str(tmp_path / "frames.h5")
    write_sequence(path, seq)
    full, part = read_sequence(path), read_sequence(path, frame_window=window)
    sl = slice(*window)
    np.testing.assert_array_equal(part.positions, full.positions[sl])
    np.testing.assert_array_equal(part.obstacles[0].positions, full.obstacles[0].positions)  # static
    np.testing.assert_array_equal(part.obstacles[1].positions, full.obstacles[1].positions[sl])
    np.testing.assert_array_equal(part.faces, full.faces)
    assert part.thickness == full.thickness and part.attrs == full.attrs


@pytest.mark.parametrize("window", [(3, 4), (4, 9), (-1, 2)])
def test_frame_window_of_fewer_than_two_frames_is_refused(tmp_path, rng, window):
    seq = scene_arrays(rng, np.float64).validate()
    path = str(tmp_path / "frames.h5")
    write_sequence(path, seq)
    with pytest.raises(InputError, match="frame window .* at least 2 of the 4 frames"):
        read_sequence(path, frame_window=window)


def test_reads_a_minimal_foreign_file(tmp_path, rng):
    """Written by someone else: int32 topology, float32, a contact_radius (not a thickness), odd extension."""
    path = str(tmp_path / "sim.dat")
    pos = rng.random((3, 4, 3)).astype(np.float32)
    with h5py.File(path, "w") as f:
        f["positions"] = pos
        f["edges"] = np.array([[0, 1], [2, 3]], dtype=np.int32)
        f.attrs["contact_radius"] = 0.25
        f.attrs["note"] = np.bytes_(b"bytes attr")
    seq = read_sequence(path)  # recognised by content, not by name
    assert seq.positions.dtype == np.float32 and seq.edges.dtype == np.int64
    assert seq.thickness == 0.0 and seq.contact_radius == 0.25 and seq.dt is None and seq.kind == "segments"
    assert seq.attrs == {"note": "bytes attr"}


def test_existing_output_needs_overwrite(tmp_path, rng):
    seq = scene_arrays(rng, np.float64).validate()
    path = tmp_path / "o.h5"
    write_sequence(path, seq)
    before = path.read_bytes()
    seq.positions = seq.positions + 1
    with pytest.raises(OutputExistsError):
        write_sequence(path, seq)
    assert path.read_bytes() == before
    write_sequence(path, seq, overwrite=True)
    np.testing.assert_array_equal(read_sequence(path).positions, seq.positions)
    assert sorted(os.listdir(tmp_path)) == ["o.h5"]


def test_writer_failure_leaves_no_file(tmp_path, rng, monkeypatch):
    import penfree.formats.hdf5 as hdf5

    def boom(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(hdf5, "write_to_h5", boom)
    with pytest.raises(RuntimeError):
        write_sequence(tmp_path / "o.h5", scene_arrays(rng, np.float32))
    assert os.listdir(tmp_path) == []


def _write(path, **datasets):
    attrs = datasets.pop("attrs", {})
    with h5py.File(path, "w") as f:
        for k, v in datasets.items():
            f[k] = v
        for k, v in attrs.items():
            f.attrs[k] = v


GOOD = np.zeros((3, 4, 3))


@pytest.mark.parametrize("build,exc,expect", [
    (lambda p: open(p, "w").write("not hdf5 at all"), FormatError, "is not an HDF5 file"),
    (lambda p: _write(p, edges=[[0, 1]]), FormatError, "missing dataset positions (T, N, 3) in {p}:/positions"),
    (lambda p: _write(p, positions=np.zeros((3, 4))), FormatError, "positions must be (T, N, 3); got (3, 4) in {p}:/positions"),
    (lambda p: _write(p, positions=np.zeros((1, 4, 3))), InputError, "at least 2 frames; got 1 in {p}:/positions"),
    (lambda p: _write(p, positions=np.where(np.arange(36).reshape(3, 4, 3) == 20, np.inf, 0.0)), InputError,
     "frame 1 holds NaN or Inf in {p}:/positions"),
    (lambda p: _write(p, positions=GOOD, faces=[[0, 1, 4]]), InputError, "found 4 in {p}:/faces"),
    (lambda p: _write(p, positions=GOOD, edges=[[0, -2]]), InputError, "found -2 in {p}:/edges"),
    (lambda p: _write(p, positions=GOOD, faces=np.array([[0, 1, 2**63 + 5]], dtype=np.uint64)), InputError,
     "found 9223372036854775813 in {p}:/faces"),
    (lambda p: _write(p, positions=GOOD, faces=[[0, 1, 2, 3]]), InputError, "faces must be (M, 3); got (1, 4) in {p}:/faces"),
    (lambda p: _write(p, positions=GOOD, weights=np.ones(5)), InputError, "weights must be (4,) to match positions; got (5,) in {p}:/weights"),
    (lambda p: _write(p, positions=GOOD, weights=-np.ones(4)), InputError, "weights must be finite and >= 0; got min -1 in {p}:/weights"),
    (lambda p: _write(p, positions=GOOD, attrs={"penfree_format": 2}), FormatError, "unsupported penfree_format 2 in {p}:@penfree_format"),
    (lambda p: _write(p, positions=GOOD, attrs={"thickness": "thin"}), InputError, "thickness must be a finite number"),
    (lambda p: _write(p, positions=np.array([[[b"a"] * 3] * 4] * 2)), FormatError, "positions must be float32 or float64"),
    (lambda p: _write(p, positions=GOOD, **{"obstacles/floor/normal": [0.0, 0, 1], "obstacles/floor/offset": 0.0,
                                           "obstacles/floor/shape/profile": np.ones(5)}), InputError,
     "a half-space has no analytic shape; found a shape group in {p}:/obstacles/floor/shape"),
    (lambda p: _write(p, positions=GOOD, **{"obstacles/floor/normal": [0.0, 0, 1e-300], "obstacles/floor/offset": 0.0}),
     InputError, "half-space normal must have its largest magnitude in the supported range [1e-100, 1e+100]; got 1e-300 "
     "in {p}:/obstacles/floor/normal"),
    (lambda p: _write(p, positions=GOOD, **{"obstacles/floor/normal": [0.0, 0, 1], "obstacles/floor/offset": 1e300}),
     InputError, "half-space offset must have its largest magnitude in the supported range [1e-100, 1e+100]; got 1e+300"),
], ids=["not-hdf5", "missing-positions", "wrong-shape", "one-frame", "inf-frame-1", "index-out-of-range",
        "negative-index", "uint64-index-past-int64", "faces-4-columns", "weights-length", "negative-weights", "format-version-2",
        "text-thickness", "text-positions", "shape-on-half-space", "tiny-normal", "huge-offset"])
def test_bad_inputs(tmp_path, build, exc, expect):
    p = str(tmp_path / "bad.h5")
    build(p)
    with pytest.raises(exc) as err:
        read_sequence(p)
    assert expect.format(p=p) in str(err.value)
    assert "\n" not in str(err.value)


def test_attributes_whose_bytes_are_not_utf8_are_read_with_replacement_characters(tmp_path, rng):
    """h5py returns a stored string whose bytes are not UTF-8 with lone surrogates, which
    no UTF-8 writer takes: `penfree deform` of such a file ended in a traceback while
    writing its result (found by an adversarial sweep). They read as U+FFFD now, as
    undecodable bytes attributes already did, and the file writes back."""
    from click.testing import CliRunner

    from penfree.cli import main

    p = str(tmp_path / "in.h5")
    write_sequence(p, scene_arrays(rng, np.float64))
    with h5py.File(p, "a") as f:
        f.attrs["source"] = b"sim \xff\xfe"
        f.attrs["note"] = b"\xfeok"
    with h5py.File(p) as f:
        assert f.attrs["note"] == "\udcfeok"  # the form that failed to write
    seq = read_sequence(p)
    assert (seq.source, seq.attrs["note"]) == ("sim \ufffd\ufffd", "\ufffdok")
    write_sequence(str(tmp_path / "copy.h5"), seq)
    assert read_sequence(str(tmp_path / "copy.h5")).attrs["note"] == "\ufffdok"
    out = tmp_path / "out.h5"
    r = CliRunner().invoke(main, ["deform", p, "-o", str(out)])
    assert r.exit_code == 0, r.output
    with h5py.File(out) as f:
        assert f.attrs["note"] == "\ufffdok"


def test_obstacle_name_that_is_not_utf8_is_refused(tmp_path, rng):
    p = str(tmp_path / "in.h5")
    write_sequence(p, scene_arrays(rng, np.float64))
    with h5py.File(p, "a") as f:
        f["obstacles"].move("floor", b"fl\xffoor")
    with pytest.raises(InputError) as err:
        read_sequence(p)
    assert f"obstacle names must be non-empty UTF-8 text without '/' (nor '.' or '..'); got b'fl\\xffoor' in {p}:" \
        "/obstacles" in str(err.value)


def test_truncated_file(tmp_path, rng):
    p = tmp_path / "cut.h5"
    write_sequence(p, scene_arrays(rng, np.float64))
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(FormatError, match=f"{p} is a truncated or damaged HDF5 file"):
        read_sequence(p)


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_sequence(tmp_path / "nope.h5")


def test_scalar_obstacle_positions_are_named(tmp_path):
    """A scalar `obstacles/<name>/positions` (found by the HDF5 fuzz test) raised an
    IndexError; it is a FormatError naming the dataset and the expected shape."""
    import h5py

    p = str(tmp_path / "bad.h5")
    with h5py.File(p, "w") as f:
        f["positions"] = GOOD
        g = f.create_group("obstacles/wall")
        g["positions"] = 1.0
        g["faces"] = np.array([[0, 1, 2]])
    with pytest.raises(FormatError, match=r"obstacles/wall/positions must be \(T, N, 3\); got \(\)"):
        read_sequence(p)


