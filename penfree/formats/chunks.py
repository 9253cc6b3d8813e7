"""The frames of an HDF5 dataset as penfree stores them: one ``(1, N, 3)`` frame per chunk,
through HDF5's shuffle then deflate filters, compressed and inflated here by a thread pool.

HDF5 compresses and inflates one chunk after another on the calling thread (2.3 s of
writing a 64K x 100 frames result, issue 13). Here the chunks are read and written raw
(`read_direct_chunk`, `write_direct_chunk`) in the filters' own layout (`_shuffled`), and
ISA-L's deflate (`isal`, which releases the GIL) compresses and inflates them in a pool:
any HDF5 reader sees an ordinary gzip + shuffle dataset. Anything else (another layout,
a chunk not allocated, filters skipped, a damaged chunk) is left to HDF5 itself.
"""

from __future__ import annotations

import os
import zlib
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import h5py
import numpy as np
from isal import isal_zlib

from .frames import Frames

#: gzip level 4 + shuffle: smooth float frames shrink ~2x, noisy ones much less (17% on
#: the 64K reference recordings; level 1 saves little time, BENCHMARKS.md). HDF5's own
#: filter uses it for the small datasets it compresses itself.
GZIP_LEVEL = 4
#: The level of ISA-L's deflate (`isal`, levels 0-3) for the frames compressed here: the
#: same standard zlib streams any HDF5 reader inflates, ~15x zlib's speed at level 4 for
#: ~2% more bytes on the 64K reference recordings (issue 13, BENCHMARKS.md).
ISAL_LEVEL = 1
#: Frame datasets of at least this many frames are compressed (`write_positions`) and
#: inflated (`read_frames`) by a thread pool of at most this many threads.
_POOL_MIN_FRAMES = 8
_POOL_MAX_WORKERS = 4


def _inflatable(ds, dtype) -> bool:
    """Whether the chunks of `ds` can be inflated here into frames of `dtype`: one
    ``(1, N, 3)`` frame per chunk, stored as `dtype` itself (a native float), through
    exactly HDF5's shuffle then deflate filters (penfree's own layout)."""
    if ds.ndim != 3 or ds.chunks != (1,) + ds.shape[1:] or np.dtype(ds.dtype) != dtype:
        return False
    return dtype.kind == "f" and dtype.isnative and _shuffle_deflate(ds)


def _workers() -> int:
    """Threads of a frame pool: the cores, at most `_POOL_MAX_WORKERS`."""
    return max(1, min(os.cpu_count() or 1, _POOL_MAX_WORKERS))


def _shuffle_deflate(ds) -> bool:
    """Whether the filters of dataset `ds` are exactly HDF5's shuffle, then deflate."""
    plist = ds.id.get_create_plist()
    pipeline = [plist.get_filter(k)[0] for k in range(plist.get_nfilters())]
    return pipeline == [h5py.h5z.FILTER_SHUFFLE, h5py.h5z.FILTER_DEFLATE]


def read_frames(ds, rows, out) -> bool:
    """``out[i] = ds[k]`` for the i-th frame `k` of `rows`, the chunks inflated by a thread
    pool (ISA-L, which releases the GIL, as `write_positions` deflates them); False, with
    nothing read, unless `ds` holds penfree's layout (`_inflatable`) and there are at least
    `_POOL_MIN_FRAMES` rows.

    Each chunk is read raw and unshuffled here; a chunk that is not allocated, whose
    filters were skipped, or that does not inflate to exactly one frame is read by HDF5
    itself (its fill value, or its own error for a damaged file).
    """
    if len(rows) < _POOL_MIN_FRAMES or out.shape[0] != len(rows) or not _inflatable(ds, out.dtype):
        return False
    size = out.dtype.itemsize

    def inflate(i, blob):
        raw = _inflated(blob)
        frame = out[i].reshape(-1).view(np.uint8).reshape(-1, size)
        if raw is None or len(raw) != frame.size:
            return False
        frame[...] = np.frombuffer(raw, dtype=np.uint8).reshape(size, -1).T  # undo the shuffle
        return True

    def finish(i, k, job):
        if job is None or not job.result():
            out[i] = ds[k]

    workers = _workers()
    with ThreadPoolExecutor(max_workers=workers) as pool:
        pending = deque()  # at most 2 x workers chunks in flight
        for i, k in enumerate(rows):
            try:
                mask, blob = ds.id.read_direct_chunk((int(k), 0, 0))
            except (OSError, KeyError, ValueError, RuntimeError):
                mask, blob = -1, None  # not allocated (or unreadable): HDF5 reads the frame
            pending.append((i, k, pool.submit(inflate, i, blob) if mask == 0 else None))
            if len(pending) == 2 * workers:
                finish(*pending.popleft())
        for job in pending:
            finish(*job)
    return True


def _shuffled(frame: np.ndarray) -> bytes:
    """One chunk as HDF5's shuffle filter lays it out: the bytes of every element grouped
    by position (all first bytes, then all second bytes, ...)."""
    raw = np.ascontiguousarray(frame).view(np.uint8).reshape(-1, frame.dtype.itemsize)
    return np.ascontiguousarray(raw.T).tobytes()


def _deflate(shuffled: bytes) -> bytes:
    """A shuffled chunk (`_shuffled`) as the deflate filter stores it: a zlib stream
    (ISA-L's deflate at `ISAL_LEVEL`, which releases the GIL)."""
    return isal_zlib.compress(shuffled, ISAL_LEVEL)


def _reused_or_deflated(frame: np.ndarray, stored) -> bytes:
    """`stored` (a source chunk's ``(filter_mask, bytes)``, or None) if it decodes to
    exactly `frame`'s bytes, else `frame` shuffled and deflated."""
    shuffled = _shuffled(frame)
    if stored is not None and stored[0] == 0 and _inflated(stored[1]) == shuffled:
        return stored[1]
    return _deflate(shuffled)


def _inflated(blob: bytes):
    """The bytes a zlib stream inflates to (ISA-L, which releases the GIL), or None when
    `blob` is not one (a damaged chunk: HDF5 or a fresh compression decides)."""
    try:
        return isal_zlib.decompress(blob)
    except (zlib.error, isal_zlib.error):
        return None


@contextmanager
def _chunk_source(source, name, data):
    """The dataset `name` of HDF5 file `source` if its chunks can be stored unchanged as
    those of `data` (same shape and dtype, one frame per chunk, shuffle then deflate), else
    None. Whether a chunk holds the frame is still checked per chunk (`_reused_or_deflated`)."""
    ds = None
    f = None
    if source and os.path.isfile(source):  # not an HDF5 file: h5py's OSError below
        try:
            f = h5py.File(source, "r")
            cand = f.get(name)
            if (isinstance(cand, h5py.Dataset) and cand.shape == data.shape and cand.dtype == data.dtype
                    and cand.chunks == (1,) + data.shape[1:] and _shuffle_deflate(cand)):
                ds = cand
        except (OSError, KeyError, ValueError, RuntimeError):
            ds = None
    try:
        yield ds
    finally:
        if f is not None:
            f.close()


def write_positions(g, name, positions, dtype=None, source=None) -> None:
    """``(T, N, 3)`` with one frame per chunk, gzip + shuffle.

    The frames are compressed by a thread pool (ISA-L releases the GIL) and written as
    raw chunks with the filters' own layout (`_shuffled`, `_deflate`), so any HDF5 reader
    sees an ordinary gzip + shuffle dataset; HDF5 itself compresses one chunk after
    another on the calling thread (2.3 s of a 64K x 100 frames result, issue 13).

    `positions` may be a `frames.Frames`: its frames are read one after another (a long
    recording is never held whole; `penfree.scaleout`'s merge).

    `source` (a file path, or None): where the frames may already be stored, as dataset
    `name` of an HDF5 file (a deform result copies its input's positions). A stored chunk
    is written unchanged when it decompresses to exactly the frame's bytes; inflating and
    comparing costs a fraction of deflating (the 64K x 100 positions of a result: 0.69 ->
    ~0.2 s). Any other chunk, or a changed file, is compressed as usual.
    """
    streamed = isinstance(positions, Frames)  # read frame by frame (`frames`), never held whole
    positions = positions if streamed else np.asarray(positions)
    dtype = np.dtype(dtype or positions.dtype)
    data = positions if streamed else positions.astype(dtype, copy=False)
    chunks = (1,) + positions.shape[1:] if positions.ndim == 3 and np.prod(positions.shape) else None
    if not streamed and (chunks is None or data.shape[0] < _POOL_MIN_FRAMES):
        g.create_dataset(
            name, data=data, chunks=chunks,
            compression="gzip" if chunks else None, compression_opts=GZIP_LEVEL if chunks else None,
            shuffle=bool(chunks),
        )
        return
    dset = g.create_dataset(name, shape=data.shape, dtype=dtype, chunks=chunks, compression="gzip",
                            compression_opts=GZIP_LEVEL, shuffle=True)
    workers = _workers()
    with _chunk_source(source, name, data) as src, ThreadPoolExecutor(max_workers=workers) as pool:
        # written in frame order, at most 2 x workers frames in flight: memory stays a
        # few compressed frames, however long the sequence
        pending = deque()  # (frame, its compression), in frame order
        for t in range(data.shape[0]):
            stored = None
            if src is not None:
                try:
                    stored = src.id.read_direct_chunk((t, 0, 0))
                except (OSError, KeyError, ValueError, RuntimeError):
                    stored = None  # not allocated, unreadable: compress the frame
            frame = data.frame(t).astype(dtype, copy=False) if streamed else data[t]
            pending.append((t, pool.submit(_reused_or_deflated, frame, stored)))
            if len(pending) == 2 * workers:
                t0, blob = pending.popleft()
                dset.id.write_direct_chunk((t0, 0, 0), blob.result())
        for t0, blob in pending:
            dset.id.write_direct_chunk((t0, 0, 0), blob.result())
