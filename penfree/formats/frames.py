"""Frames read one at a time: a ``(T, N, 3)`` array that a writer streams instead of holding.

`penfree.scaleout` merges the frame ranges of a long recording into one result; the
result holds the input's positions and every step's deformed state, each as large as
the recording. The merge hands the writers (`chunks.write_positions`, `result.write_result`)
a `Frames` in their place: the writer asks for one frame after another, and only that
frame (and, for the partial results, one range's deformed states) is in memory. The
``--per-vertex`` residuals (``(S, N)`` per dataset) go the same way as `StepRows`.
"""

from __future__ import annotations

import numpy as np

from ..errors import FormatError, InputError
from ..sequence import check_scale


def _float_dtype(ds, where, name) -> np.dtype:
    """The native float dtype a stored positions dataset is read as (integers as float64)."""
    dt = np.dtype(ds.dtype)
    if dt.kind == "f" and dt.itemsize in (4, 8):
        return dt.newbyteorder("=")
    if dt.kind in "fiu":
        return np.dtype(np.float64)
    raise FormatError(f"{name} must be float32 or float64; got {dt} in {where}:/{name}")


class Frames:
    """A read-once ``(T, N, 3)`` float array: ``shape``, ``dtype``, ``ndim`` and ``frame(t)``.

    Subclasses implement `_read(t)`. Every frame read is checked finite; the largest
    magnitude seen is kept, so that `check_scale` can judge the whole array once every
    frame was read (as `Sequence.validate` judges an array in memory).
    """

    ndim = 3

    def __init__(self, shape, dtype, where, name):
        self.shape, self.dtype = tuple(int(s) for s in shape), np.dtype(dtype)
        self.where, self.name = where, name
        self._big = 0.0

    def __len__(self) -> int:
        return self.shape[0]

    def frame(self, t: int) -> np.ndarray:
        """Frame `t` as ``(N, 3)`` of `dtype`; InputError naming it when not finite."""
        return self.check(t, np.asarray(self._read(int(t)), dtype=self.dtype))

    def check(self, t: int, a: np.ndarray) -> np.ndarray:
        """`a`, frame `t` read elsewhere, checked as `frame` checks it."""
        if not np.isfinite(a).all():
            raise InputError(f"{self.name} must be finite; frame {t} holds NaN or Inf in {self.where}:/{self.name}")
        if a.size:
            self._big = max(self._big, float(np.maximum(a.max(), -a.min())))
        return a

    def check_scale(self) -> None:
        """`sequence.check_scale` of every frame read so far, taken together."""
        check_scale(np.array([self._big]), self.where, self.name)

    def _read(self, t: int) -> np.ndarray:
        raise NotImplementedError


#: Frames a `StoredFrames` reads at once from a dataset chunked over several frames.
BLOCK_FRAMES_MAX = 64


class StoredFrames(Frames):
    """The frames of an open HDF5 dataset ``(T, N, 3)`` (float, or integers read as float64).

    A dataset chunked over several frames (not penfree's one frame per chunk) is read a
    chunk's frames at a time (at most `BLOCK_FRAMES_MAX`): frame by frame, every chunk
    would be inflated once per frame it holds.
    """

    def __init__(self, ds, where, name="positions"):
        if ds.ndim != 3 or ds.shape[2] != 3:
            raise FormatError(f"{name} must be (T, N, 3); got {ds.shape} in {where}:/{name}")
        super().__init__(ds.shape, _float_dtype(ds, where, name), where, name)
        self._ds = ds
        self._step = max(1, min(int(ds.chunks[0]), BLOCK_FRAMES_MAX)) if ds.chunks else 1
        self._first, self._block = 0, None

    def _read(self, t):
        if self._step == 1:
            return self._ds[t]
        if self._block is None or not self._first <= t < self._first + len(self._block):
            self._first = t - t % self._step
            self._block = self._ds[self._first:self._first + self._step]
        return self._block[t - self._first]


class StepRows:
    """A read-once ``(S, ...)`` per-step array that `result.write_result` writes block by
    block: ``shape``, ``dtype`` and `blocks` (consecutive row blocks, in order). Unlike
    `Frames`, values are not checked (a ``--per-vertex`` residual to the next frame is NaN
    where there is none)."""

    def __init__(self, shape, dtype):
        self.shape, self.dtype = tuple(int(s) for s in shape), np.dtype(dtype)

    def __len__(self) -> int:
        return self.shape[0]

    def blocks(self):
        """Iterator over ``(rows, ...)`` arrays whose concatenation is the whole array."""
        raise NotImplementedError
