"""Frame chunks (`penfree.formats.chunks`): pooled writes and reads of penfree's layout,
against HDF5's own gzip + shuffle filters and the stdlib's zlib."""

import zlib

import h5py
import numpy as np
import pytest

from penfree.errors import FormatError, InputError
from penfree.formats import read_sequence, write_sequence
from penfree.sequence import Sequence


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("T", [3, 8, 13, 40])
def test_pooled_frame_writes_are_ordinary_gzip_shuffle_chunks(tmp_path, rng, dtype, T):
    # Frames compressed by the thread pool (ISA-L's deflate) and written as raw chunks
    # must be chunks of HDF5's own gzip + shuffle pipeline: the same filters and values,
    # in frame order (odd counts cross the pool's in-flight window), and each chunk a zlib
    # stream that the reference inflater (the stdlib's zlib) turns into exactly the
    # shuffled bytes of HDF5's own chunk, so any reader decodes them.
    from penfree.formats.chunks import GZIP_LEVEL, write_positions

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
    from penfree.formats.chunks import GZIP_LEVEL, _deflate, _shuffled, write_positions

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
    from penfree.formats.chunks import _deflate, _shuffled, write_positions

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
    from penfree.formats.chunks import _deflate, _shuffled, write_positions

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
    from penfree.formats import chunks
    from penfree.formats.result import read_result, write_result

    T, N = 10, 64
    seq = Sequence(positions=(rng.normal(size=(T, N, 3))).astype(np.float32), edges=np.c_[np.arange(N - 1), np.arange(1, N)])
    src = tmp_path / "in.h5"
    write_sequence(src, seq)
    back = read_sequence(src)
    steps = {"frame": np.arange(1, T - 1), "A": np.tile(np.eye(3), (T - 2, 1, 1)), "b": np.zeros((T - 2, 3)),
             "deformed": back.positions[1:T - 1]}
    real, compressed = chunks._deflate, []
    monkeypatch.setattr(chunks, "_deflate", lambda shuffled: compressed.append(shuffled) or real(shuffled))
    write_result(tmp_path / "out.h5", back, steps, {})
    assert len(compressed) == T - 2  # the deformed frames, not the positions
    assert _chunks(tmp_path / "out.h5")[0] == _chunks(src)[0]
    np.testing.assert_array_equal(read_result(tmp_path / "out.h5").sequence.positions, seq.positions)


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
    from penfree.formats.chunks import _inflatable, read_frames

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
    from penfree.formats.chunks import _shuffled, read_frames

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
