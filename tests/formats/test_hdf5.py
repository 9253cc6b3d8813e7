"""HDF5 layout v1: round trips, files written by others, and refused inputs."""

import os
import zlib

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
], ids=["not-hdf5", "missing-positions", "wrong-shape", "one-frame", "inf-frame-1", "index-out-of-range",
        "negative-index", "uint64-index-past-int64", "faces-4-columns", "weights-length", "negative-weights", "format-version-2",
        "text-thickness", "text-positions", "shape-on-half-space"])
def test_bad_inputs(tmp_path, build, exc, expect):
    p = str(tmp_path / "bad.h5")
    build(p)
    with pytest.raises(exc) as err:
        read_sequence(p)
    assert expect.format(p=p) in str(err.value)
    assert "\n" not in str(err.value)


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


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("T", [3, 8, 13, 40])
def test_pooled_frame_writes_are_ordinary_gzip_shuffle_chunks(tmp_path, rng, dtype, T):
    # Frames compressed by the thread pool (ISA-L's deflate) and written as raw chunks
    # must be chunks of HDF5's own gzip + shuffle pipeline: the same filters and values,
    # in frame order (odd counts cross the pool's in-flight window), and each chunk a zlib
    # stream that the reference inflater (the stdlib's zlib) turns into exactly the
    # shuffled bytes of HDF5's own chunk, so any reader decodes them.
    from penfree.formats.hdf5 import GZIP_LEVEL, write_positions

    X = (rng.normal(size=(T, 257, 3)) * 10.0 ** rng.integers(-3, 4, size=(T, 1, 1))).astype(dtype)
    with h5py.File(tmp_path / "pool.h5", "w") as f:
        write_positions(f, "positions", X)
    with h5py.File(tmp_path / "native.h5", "w") as f:
        f.create_dataset("positions", data=X, chunks=(1, 257, 3), compression="gzip",
                         compression_opts=GZIP_LEVEL, shuffle=True)
    with h5py.File(tmp_path / "pool.h5") as a, h5py.File(tmp_path / "native.h5") as b:
        da, db = a["positions"], b["positions"]
        assert (da.dtype, da.chunks, da.compression, da.compression_opts, da.shuffle) == \
               (db.dtype, db.chunks, db.compression, db.compression_opts, db.shuffle)
        np.testing.assert_array_equal(da[:], X)
        for t in range(T):
            (mask_a, blob_a), (mask_b, blob_b) = da.id.read_direct_chunk((t, 0, 0)), db.id.read_direct_chunk((t, 0, 0))
            assert mask_a == mask_b == 0
            assert zlib.decompress(blob_a) == zlib.decompress(blob_b), t


def _chunks(path, name="positions"):
    with h5py.File(path) as f:
        ds = f[name]
        return [ds.id.read_direct_chunk((t, 0, 0))[1] for t in range(ds.shape[0])], ds[:]


@pytest.mark.parametrize("level, shuffle, copied", [(9, True, True), (1, True, True), (4, False, False)])
def test_frames_copied_from_the_source_only_where_they_decode_to_the_same_bytes(tmp_path, rng, level, shuffle,
                                                                               copied):
    # A source chunk (any gzip level) is stored unchanged when it holds exactly the frame;
    # a frame changed in memory, a source without shuffle (another filter pipeline) or a
    # file changed after the read are compressed from the data instead. The values are the
    # data in every case.
    from penfree.formats.hdf5 import GZIP_LEVEL, _deflate, _shuffled, write_positions

    T = 12
    X = (rng.normal(size=(T, 300, 3)) + 1e3).astype(np.float32)
    src = tmp_path / "src.h5"
    with h5py.File(src, "w") as f:
        f.create_dataset("positions", data=X, chunks=(1, 300, 3), compression="gzip", compression_opts=level,
                         shuffle=shuffle)
    Y = X.copy()
    Y[5, 17, 2] += 1.0  # one frame differs from the file
    with h5py.File(tmp_path / "out.h5", "w") as f:
        write_positions(f, "positions", Y, source=str(src))
    blobs, values = _chunks(tmp_path / "out.h5")
    stored, _ = _chunks(src)
    np.testing.assert_array_equal(values, Y)
    for t in range(T):
        if copied and t != 5:
            assert blobs[t] == stored[t], t
        else:
            assert blobs[t] == _deflate(_shuffled(Y[t])), t
    assert (level == GZIP_LEVEL) or not copied or blobs[0] != _deflate(_shuffled(Y[0]))
    # the file changes after the read: nothing stale is copied
    with h5py.File(src, "r+") as f:
        f["positions"][3] = X[3] + 1.0
    with h5py.File(tmp_path / "out2.h5", "w") as f:
        write_positions(f, "positions", X, source=str(src))
    blobs, values = _chunks(tmp_path / "out2.h5")
    np.testing.assert_array_equal(values, X)
    assert blobs[3] == _deflate(_shuffled(X[3]))


def test_a_damaged_source_chunk_is_compressed_afresh(tmp_path, rng):
    # A source chunk that is not a zlib stream, or one cut short, is never copied: the frame
    # is compressed from the data (the inflater's error is caught, not raised).
    from penfree.formats.hdf5 import _deflate, _shuffled, write_positions

    X = rng.normal(size=(9, 40, 3)).astype(np.float32)
    src = tmp_path / "src.h5"
    with h5py.File(src, "w") as f:
        f.create_dataset("positions", data=X, chunks=(1, 40, 3), compression="gzip", shuffle=True)
    with h5py.File(src, "r+") as f:
        good = f["positions"].id.read_direct_chunk((4, 0, 0))[1]
        f["positions"].id.write_direct_chunk((2, 0, 0), b"not a zlib stream")
        f["positions"].id.write_direct_chunk((4, 0, 0), good[: len(good) // 2])
    with h5py.File(tmp_path / "out.h5", "w") as f:
        write_positions(f, "positions", X, source=str(src))
    blobs, values = _chunks(tmp_path / "out.h5")
    np.testing.assert_array_equal(values, X)
    assert blobs[2] == _deflate(_shuffled(X[2])) and blobs[4] == _deflate(_shuffled(X[4]))
    assert zlib.decompress(blobs[2]) == _shuffled(X[2])


@pytest.mark.parametrize("source", ["<memory>", "missing.h5", "not_h5.txt", "other_shape.h5", "float64.h5"])
def test_frames_compressed_when_the_source_cannot_hold_them(tmp_path, rng, source):
    from penfree.formats.hdf5 import _deflate, _shuffled, write_positions

    X = rng.normal(size=(9, 40, 3)).astype(np.float32)
    (tmp_path / "not_h5.txt").write_text("positions")
    with h5py.File(tmp_path / "other_shape.h5", "w") as f:
        f.create_dataset("positions", data=X[:8], chunks=(1, 40, 3), compression="gzip", shuffle=True)
    with h5py.File(tmp_path / "float64.h5", "w") as f:
        f.create_dataset("positions", data=X.astype(np.float64), chunks=(1, 40, 3), compression="gzip", shuffle=True)
    path = source if source == "<memory>" else str(tmp_path / source)
    with h5py.File(tmp_path / "out.h5", "w") as f:
        write_positions(f, "positions", X, source=path)
    blobs, values = _chunks(tmp_path / "out.h5")
    np.testing.assert_array_equal(values, X)
    assert blobs == [_deflate(_shuffled(x)) for x in X]


def test_deform_result_copies_the_input_chunks(tmp_path, rng, monkeypatch):
    # The end-to-end path: a result written from a sequence read from disk stores the
    # input's own chunks for its positions (only the deformed frames are compressed),
    # and reads back the same frames.
    from penfree.formats import hdf5
    from penfree.formats.result import read_result, write_result

    T, N = 10, 64
    seq = Sequence(positions=(rng.normal(size=(T, N, 3))).astype(np.float32), edges=np.c_[np.arange(N - 1), np.arange(1, N)])
    src = tmp_path / "in.h5"
    write_sequence(src, seq)
    back = read_sequence(src)
    steps = {"frame": np.arange(1, T - 1), "A": np.tile(np.eye(3), (T - 2, 1, 1)), "b": np.zeros((T - 2, 3)),
             "deformed": back.positions[1:T - 1]}
    real, compressed = hdf5._deflate, []
    monkeypatch.setattr(hdf5, "_deflate", lambda shuffled: compressed.append(shuffled) or real(shuffled))
    write_result(tmp_path / "out.h5", back, steps, {})
    assert len(compressed) == T - 2  # the deformed frames, not the positions
    assert _chunks(tmp_path / "out.h5")[0] == _chunks(src)[0]
    np.testing.assert_array_equal(read_result(tmp_path / "out.h5").sequence.positions, seq.positions)


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


def _layout_file(path, X, **kw):
    with h5py.File(path, "w") as f:
        f.create_dataset("positions", data=X, chunks=(1,) + X.shape[1:], compression="gzip", shuffle=True, **kw)
        f.create_dataset("edges", data=np.c_[np.arange(X.shape[1] - 1), np.arange(1, X.shape[1])])


@pytest.mark.parametrize("dtype", [np.float32, np.float64, ">f4"])
@pytest.mark.parametrize("T", [7, 8, 13, 40])
def test_pooled_frame_reads_equal_hdf5s_own(tmp_path, rng, dtype, T):
    # Frames inflated by the pool (penfree's layout, at least 8 of them) are the frames HDF5
    # decodes, for a whole file and a frame window (odd counts cross the pool's window); a
    # big-endian dataset or fewer frames are read by HDF5 itself, to the same values.
    from penfree.formats.hdf5 import _inflatable, read_frames

    X = (rng.normal(size=(T, 301, 3)) * 10.0 ** rng.integers(-3, 4, size=(T, 1, 1))).astype(dtype)
    _layout_file(tmp_path / "x.h5", X)
    with h5py.File(tmp_path / "x.h5") as f:
        ds = f["positions"]
        native = np.dtype(dtype).newbyteorder("=")
        assert _inflatable(ds, native) == np.dtype(dtype).isnative
        out = np.empty(X.shape, dtype=native)
        assert read_frames(ds, range(T), out) == (T >= 8 and np.dtype(dtype).isnative)
        rows = [T - 1, 0, *range(2, T - 1)]
        some = np.empty((len(rows),) + X.shape[1:], dtype=native)
        pooled = read_frames(ds, rows, some)
        if pooled:
            np.testing.assert_array_equal(out, ds[:])
            np.testing.assert_array_equal(some, ds[:][rows])
    seq = read_sequence(tmp_path / "x.h5")
    np.testing.assert_array_equal(seq.positions, X)
    np.testing.assert_array_equal(read_sequence(tmp_path / "x.h5", frame_window=(1, T)).positions, X[1:])


def test_pooled_reads_leave_odd_chunks_to_hdf5(tmp_path, rng):
    # A chunk never written (HDF5's fill value) and one stored with its deflate filter
    # skipped (filter mask 2) are each read by HDF5 itself.
    from penfree.formats.hdf5 import _shuffled, read_frames

    T, N = 12, 50
    X = rng.normal(size=(T, N, 3)).astype(np.float32)
    with h5py.File(tmp_path / "x.h5", "w") as f:
        ds = f.create_dataset("positions", shape=X.shape, dtype=np.float32, chunks=(1, N, 3), compression="gzip",
                              shuffle=True, fillvalue=2.5)
        for t in range(T):
            if t == 3:
                continue  # not allocated
            if t == 5:
                ds.id.write_direct_chunk((t, 0, 0), _shuffled(X[t]), filter_mask=2)  # deflate skipped
            else:
                ds[t] = X[t]
    with h5py.File(tmp_path / "x.h5") as f:
        out = np.empty(X.shape, dtype=np.float32)
        assert read_frames(f["positions"], range(T), out)
        kept = [t for t in range(T) if t != 3]
        np.testing.assert_array_equal(out[kept], X[kept])
        np.testing.assert_array_equal(out[3], np.full((N, 3), 2.5, dtype=np.float32))


def test_a_damaged_chunk_read_by_the_pool_is_a_format_error(tmp_path, rng):
    # A chunk that is not a zlib stream is handed to HDF5, whose error names the file.
    T, N = 12, 50
    X = rng.normal(size=(T, N, 3)).astype(np.float32)
    _layout_file(tmp_path / "x.h5", X)
    with h5py.File(tmp_path / "x.h5", "r+") as f:
        f["positions"].id.write_direct_chunk((6, 0, 0), b"\x00garbage" * 20)
    with pytest.raises(FormatError, match=f"{tmp_path / 'x.h5'} is damaged"):
        read_sequence(tmp_path / "x.h5")


def test_a_non_finite_frame_is_named_after_a_pooled_read(tmp_path, rng):
    T, N = 12, 50
    X = rng.normal(size=(T, N, 3)).astype(np.float32)
    X[9, 4, 1] = np.nan
    X[10, 0, 0] = np.inf
    _layout_file(tmp_path / "x.h5", X)
    with pytest.raises(InputError, match=f"positions must be finite; frame 9 holds NaN or Inf in {tmp_path / 'x.h5'}"):
        read_sequence(tmp_path / "x.h5")
