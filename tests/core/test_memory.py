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
