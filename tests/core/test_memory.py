"""`retain_freed_memory`: glibc agrees on Linux; elsewhere nothing changes and False is returned."""

import ctypes
import sys

import numpy as np
import pytest

from penfree.core import memory


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc mallopt is Linux-only")
def test_glibc_accepts_and_results_do_not_change():
    from penfree.core.contact.broad_phase import edge_edge_candidates

    rng = np.random.default_rng(3)
    x0 = rng.random((400, 3))
    x1 = x0 + 0.01 * rng.standard_normal((400, 3))
    E = np.stack([np.arange(399), np.arange(1, 400)], axis=1)
    before = edge_edge_candidates(x0, x1, E, 0.05)
    try:
        ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        pytest.skip("not glibc")
    assert memory.retain_freed_memory() is True
    assert memory.retain_freed_memory() is True  # idempotent
    assert np.array_equal(edge_edge_candidates(x0, x1, E, 0.05), before)


def test_without_glibc_nothing_changes(monkeypatch):
    def no_libc(name, *a, **k):
        raise OSError(f"{name}: cannot open shared object file")

    monkeypatch.setattr(memory.ctypes, "CDLL", no_libc)
    assert memory.retain_freed_memory() is False
    monkeypatch.setattr(memory.sys, "platform", "darwin")
    assert memory.retain_freed_memory() is False


@pytest.mark.parametrize("shape, dtype", [((3, 4), np.float64), ((2, 1 << 20, 3), np.float32), ((0, 5), np.int64),
                                          ((5 << 20,), np.float64)])
def test_populated_empty_is_a_writable_array_of_the_shape(shape, dtype):
    # Small arrays are np.empty; from POPULATE_MIN_BYTES on (the last two) on Linux, a
    # populated anonymous mapping: either way writable, C-contiguous, and it keeps what
    # is written for as long as it lives, views included.
    a = memory.populated_empty(shape, dtype)
    assert a.shape == shape and a.dtype == dtype and a.flags.c_contiguous and a.flags.writeable
    a[...] = np.arange(a.size, dtype=dtype).reshape(shape)
    view = a.reshape(-1)[::7]
    del a
    np.testing.assert_array_equal(view, np.arange(0, view.size * 7, 7, dtype=dtype))
    big = np.prod(shape) * np.dtype(dtype).itemsize >= memory.POPULATE_MIN_BYTES
    owner = view
    while isinstance(owner, np.ndarray) and owner.base is not None:
        owner = owner.base
    owner = owner.obj if isinstance(owner, memoryview) else owner
    if big and sys.platform.startswith("linux"):
        import mmap

        assert isinstance(owner, mmap.mmap)  # the pages come from the mapping
    else:
        assert isinstance(owner, np.ndarray)


def test_populated_empty_falls_back_without_the_mapping(monkeypatch):
    monkeypatch.delattr(memory.mmap, "MAP_POPULATE", raising=False)
    a = memory.populated_empty((5 << 20,), np.float64)
    assert a.shape == (5 << 20,) and a.flags.writeable and a.flags.owndata


#: A process that leaves an HDF5 file open, a `weakref.finalize` and an ``atexit`` handler
#: (registered first, so it runs last) that records the collector's frozen object count.
_EXIT_PROBE = """
import atexit, gc, sys, weakref
import h5py, numpy as np
out = sys.argv[1]
atexit.register(lambda: open(out + ".count", "w").write(str(gc.get_freeze_count())))
class Held:
    pass
held = Held()
weakref.finalize(held, lambda: open(out + ".finalized", "w").write("yes"))
f = h5py.File(out + ".h5", "w")
f["x"] = np.arange(5)
if sys.argv[2] == "skip":
    from penfree.core.memory import skip_exit_collection
    skip_exit_collection()
"""


@pytest.mark.parametrize("mode", ["skip", "collect"])
def test_exit_without_collection_still_runs_every_handler(tmp_path, mode):
    import subprocess

    import h5py

    out = str(tmp_path / "probe")
    r = subprocess.run([sys.executable, "-c", _EXIT_PROBE, out, mode], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    frozen = int(open(out + ".count").read())
    # the freeze ran before the handlers registered earlier, and those still ran
    assert (frozen > 1000) if mode == "skip" else frozen == 0
    assert open(out + ".finalized").read() == "yes"
    with h5py.File(out + ".h5", "r") as f:  # left open: closed and flushed at exit all the same
        assert f["x"][()].tolist() == [0, 1, 2, 3, 4]
