"""Keep freed large blocks in the C heap instead of returning them to the kernel.

The broad phase allocates scratch arrays of a few to tens of MiB per call (grid
tables, entry boxes, pair buffers). glibc serves blocks above its mmap threshold
with fresh ``mmap`` pages and unmaps them on free, so every call pays a page fault
per 4 KiB on first touch: 45% of a 64K-vertex rods `verify_step` (13.4 ms -> 6.9 ms
with the blocks kept, same process, quiet machine). `retain_freed_memory` raises the
threshold to glibc's 64-bit maximum (32 MiB) and the trim threshold so that freed
blocks are reused. It changes no result, only where memory comes from; it is
process-wide, so the CLI calls it and a library user may (e.g. in a simulator that
calls `penfree.predeform` every step).

Blocks above the threshold, such as a result's deformed frames (78 MB at 64K vertices
x 100 frames), are mapped fresh by glibc whatever the threshold: `populated_empty` maps
them with their pages populated in one call instead (``MAP_POPULATE``).

A process that has loaded Numba's kernels holds about a million Python objects (its
type system); the interpreter's shutdown collects them, cycle by cycle, for ~0.2 s.
`skip_exit_collection` lets a process that is about to end skip that.
"""

from __future__ import annotations

import atexit
import ctypes
import gc
import mmap
import sys

import numpy as np

#: glibc's mallopt parameters (malloc.h) and the largest accepted mmap threshold on 64-bit.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_MMAP_THRESHOLD_MAX = 32 << 20
_TRIM_THRESHOLD = (1 << 31) - 1


def retain_freed_memory() -> bool:
    """Ask glibc to keep freed blocks up to 32 MiB for reuse; True when it agreed.

    False (nothing changed) on other C libraries and platforms. Idempotent.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # musl and others: no glibc mallopt
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_MAX)) and bool(mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD))


def skip_exit_collection():
    """Let this process's interpreter end without its garbage collections; idempotent.

    At exit, before the interpreter tears its modules down, every object alive is moved
    to the collector's permanent generation (`gc.freeze`), which no collection visits:
    objects are still freed by their reference counts, every ``atexit`` handler and
    ``weakref.finalize`` still runs (HDF5 still closes its files); only cycles of objects
    unreachable at exit stay unfreed, their ``__del__`` not run (penfree relies on none:
    its temporary files are removed by `penfree.formats.atomic` as the command ends, and
    the operating system frees the memory). After a command that loaded the kernels, the
    interpreter's shutdown took 0.19-0.23 s and takes 0.02 s (64K-vertex runs, AMD Zen 4
    under KVM). For the CLI's process (which ends after its command) and for the workers
    of a local cluster of its own (`penfree.scaleout`), whose shutdown the command waits
    for; a library user's process is left alone.
    """
    global _exit_collection_skipped
    atexit.unregister(gc.freeze)
    atexit.register(gc.freeze)  # the last registered runs first
    _exit_collection_skipped = True


#: Whether `skip_exit_collection` ran in this process.
_exit_collection_skipped = False


#: Arrays from this size on are mapped with their pages populated (`populated_empty`):
#: glibc maps blocks this large fresh (`_MMAP_THRESHOLD_MAX`), page by page on first touch.
POPULATE_MIN_BYTES = _MMAP_THRESHOLD_MAX


def populated_empty(shape, dtype) -> np.ndarray:
    """A writable C-contiguous array of `shape` and `dtype`, its contents unspecified.

    From `POPULATE_MIN_BYTES` on, on Linux, it is anonymous memory mapped with its pages
    populated at once (``MAP_POPULATE``: zeroed by the kernel in one call) rather than
    faulted in 4 KiB at a time as it is first written: filling a 64K x 99 float32 result
    frame by frame took 186 ms after ``np.empty`` and 28 ms here, mapping included
    (issue 13, AMD Zen 4 under KVM). Smaller arrays, and other platforms: ``np.empty``.
    The mapping lives as long as the array (and its views).
    """
    dtype = np.dtype(dtype)
    count = int(np.prod(shape, dtype=np.int64)) if len(shape) else 1
    nbytes = count * dtype.itemsize
    flag = getattr(mmap, "MAP_POPULATE", None)
    if nbytes < POPULATE_MIN_BYTES or flag is None or not sys.platform.startswith("linux"):
        return np.empty(shape, dtype=dtype)
    try:
        buf = mmap.mmap(-1, nbytes, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS | flag)
    except (OSError, ValueError):  # no such mapping here: the ordinary allocation
        return np.empty(shape, dtype=dtype)
    return np.frombuffer(buf, dtype=dtype, count=count).reshape(shape)
