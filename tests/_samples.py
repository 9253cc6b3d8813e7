"""The committed samples (`samples/`) as the sample tests read them."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import h5py

SAMPLES = Path(__file__).resolve().parents[1] / "samples"


def load_module(name):
    """`samples/<name>.py` (e.g. the checker) as a module."""
    spec = importlib.util.spec_from_file_location(f"penfree_samples_{name}", SAMPLES / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def load_sample(name) -> dict:
    """Every top-level dataset of `samples/<name>.h5` (not the ``obstacles`` group), plus
    ``attrs``, ``chunks`` (of positions), ``name``, ``bytes``."""
    path = SAMPLES / f"{name}.h5"
    assert path.exists(), f"missing committed sample {path}"
    with h5py.File(path, "r") as f:
        data = {k: f[k][()] for k in f if isinstance(f[k], h5py.Dataset)}
        data["attrs"] = dict(f.attrs)
        data["chunks"] = f["positions"].chunks
    data["name"] = name
    data["bytes"] = path.stat().st_size
    return data
