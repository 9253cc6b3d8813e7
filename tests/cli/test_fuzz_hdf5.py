"""Fuzzing the HDF5 layout: no file reaches a traceback (issue 9 acceptance).

Hypothesis builds HDF5 files with random shapes, dtypes, values, attributes and
links (soft, external, dangling, groups where datasets belong) for the sequence
layout and the deform-result layout, and runs ``info``, ``verify``, ``deform`` and
``report`` (also with every file long: in frame ranges) on them through the `cli` fixture: exit 0, 1 or 2 only, one stderr
line on 2, nothing written but the named output, no traceback.
"""

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

DTYPES = ["<f8", ">f8", "<f4", "<i4", "u1", "?", "<c8", "S3"]
VALUES = st.sampled_from([0.0, 1.0, -1.0, 0.5, 1e-320, 1e308, np.nan, np.inf, -np.inf, 3.0, 7.0])


@st.composite
def arrays(draw, ndim=None, last=None, min_len=0):
    nd = draw(st.integers(0, 4)) if ndim is None else ndim
    shape = [draw(st.integers(min_len, 4)) for _ in range(nd)]
    if last is not None and nd:
        shape[-1] = last
    dtype = np.dtype(draw(st.sampled_from(DTYPES)))
    size = int(np.prod(shape)) if shape else 1
    vals = np.array(draw(st.lists(VALUES, min_size=size, max_size=size)), dtype=np.float64).reshape(shape)
    if dtype.kind == "S":
        return vals.astype(str).astype(dtype)
    with np.errstate(all="ignore"):
        if dtype.kind in "iub":
            vals = np.nan_to_num(vals, nan=0, posinf=7, neginf=-1).clip(-1, 7)
        return vals.astype(dtype)


def plausible_positions(draw):
    T, N = draw(st.integers(1, 4)), draw(st.integers(1, 5))
    base = np.random.default_rng(draw(st.integers(0, 2**16))).random((T, N, 3))
    if draw(st.booleans()):
        base[draw(st.integers(0, T - 1)), 0, 0] = draw(VALUES)
    dtype = draw(st.sampled_from(["<f8", "<f4", ">f8"]))
    with np.errstate(over="ignore"):  # a huge draw cast to float32 is inf: bad input, on purpose
        return base.astype(dtype)


ATTR_VALUES = st.sampled_from([0.001, -1.0, np.nan, np.inf, "abc", "json:{", "json:[1, 2]", "json:null",
                               np.arange(3.0), True, np.int64(2**62), 1, 0])
LINKS = st.sampled_from(["soft-missing", "external-missing", "group", "none"])


def _put(g, name, draw, value):
    link = draw(LINKS)
    if link == "soft-missing":
        g[name] = h5py.SoftLink("/nowhere")
    elif link == "external-missing":
        g[name] = h5py.ExternalLink("missing.h5", "/x")
    elif link == "group":
        g.create_group(name)
    else:
        g[name] = value


@st.composite
def h5_layouts(draw):
    """A recipe: callable(path) writing one fuzzed file."""
    pos = plausible_positions(draw) if draw(st.booleans()) else draw(arrays())
    parts = {}
    for name, k in (("faces", 3), ("edges", 2), ("weights", None), ("components", None)):
        if not draw(st.booleans()):
            continue
        if k and draw(st.booleans()):  # plausible indices, maybe out of range or repeated
            rows = draw(st.lists(st.lists(st.integers(-1, 6), min_size=k, max_size=k), max_size=4))
            parts[name] = np.array(rows, dtype=np.int64).reshape(-1, k)
        else:
            parts[name] = draw(arrays(ndim=2 if k else 1, last=k))
    attrs = {k: draw(ATTR_VALUES) for k in draw(st.sets(st.sampled_from(
        ["thickness", "dt", "contact_radius", "penfree_format", "source", "note"]), max_size=4))}
    obstacle = draw(st.sampled_from(["none", "ok", "random", "dataset"]))
    steps = draw(st.sampled_from(["none", "random", "plausible"]))
    link_positions = draw(st.booleans()) and draw(st.booleans())
    seed_draws = {name: draw(arrays()) for name in ("A", "b", "deformed", "certificate_margin")}
    frame = draw(arrays(ndim=1))
    obstacle_pos = draw(arrays())
    link_choices = [draw(LINKS) for _ in range(6)]

    def write(path):
        with h5py.File(path, "w") as f:
            if link_positions:
                f["positions"] = h5py.SoftLink("/missing_positions") if link_choices[0] != "group" else \
                    h5py.ExternalLink("missing.h5", "/positions")
            else:
                f["positions"] = pos
            for name, a in parts.items():
                f[name] = a
            for k, v in attrs.items():
                f.attrs[k] = v
            if obstacle == "ok":
                g = f.create_group("obstacles/floor")
                g["positions"] = np.array([[0, 0, -1], [1, 0, -1], [0, 1, -1.0]])
                g["faces"] = np.array([[0, 1, 2]])
            elif obstacle == "random":
                g = f.create_group("obstacles/o")
                lk = link_choices[1]
                if lk == "none":
                    g["positions"] = obstacle_pos
                elif lk == "group":
                    g.create_group("positions")
                else:
                    g["positions"] = h5py.SoftLink("/nowhere")
                if link_choices[2] != "none":
                    g["faces"] = h5py.SoftLink("/nowhere")
            elif obstacle == "dataset":
                f["obstacles"] = np.zeros(3)
            if steps != "none":
                s = f.create_group("steps")
                if steps == "plausible" and isinstance(pos, np.ndarray) and pos.ndim == 3 and pos.shape[0] >= 2:
                    S = pos.shape[0] - 1
                    s["frame"] = np.arange(1, S + 1)
                    s["A"] = np.repeat(np.eye(3)[None], S, axis=0)
                    s["b"] = np.zeros((S, 3))
                    s["deformed"] = pos[1:]
                    s["certificate_margin"] = np.ones(S)
                    for k, lk in zip(("A", "certificate_margin"), link_choices[3:5]):
                        if lk != "none":
                            del s[k]
                            if lk == "group":
                                s.create_group(k)
                            elif lk == "soft-missing":
                                s[k] = h5py.SoftLink("/nowhere")
                            else:
                                s[k] = seed_draws[k]
                else:
                    s["frame"] = frame
                    for k, a in seed_draws.items():
                        s[k] = a
    return write


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                  HealthCheck.too_slow])
@given(layout=h5_layouts(), command=st.sampled_from(["info", "verify", "deform", "report", "report-long"]))
def test_no_hdf5_layout_reaches_a_traceback(cli, tmp_path_factory, layout, command):
    """(``report-long``: `report` with every file long, read by its tables then in ranges.)"""
    import sys

    import penfree.scaleout.plan  # noqa: F401 (patched below)

    d = tmp_path_factory.mktemp("fuzz")
    src = d / "in.h5"
    layout(str(src))
    out = {"deform": ["-o", d / "out.h5"], "report": ["-o", d / "rep", "--no-plots"]}
    command, long_file = command.split("-")[0], command.endswith("-long")
    args = [command, src] + out.get(command, [])
    plan = sys.modules["penfree.scaleout.plan"]
    saved = plan.MAX_TASK_BYTES
    plan.MAX_TASK_BYTES = 1 if long_file else saved
    try:  # the fixture asserts: exit 0/1/2, one line on 2, no traceback, nothing else written
        r = cli(*args, folder=d)
    finally:
        plan.MAX_TASK_BYTES = saved
    assert r.exit_code in (0, 1, 2)


@pytest.mark.parametrize("where", ["positions", "faces", "weights", "obstacles/o/positions", "steps/A"])
def test_dangling_links_are_one_line_errors(cli, tmp_path, where):
    src = tmp_path / "in.h5"
    with h5py.File(src, "w") as f:
        f["positions"] = np.random.default_rng(0).random((3, 4, 3))
        f["faces"] = np.array([[0, 1, 2]])
        if where.startswith("steps"):
            s = f.create_group("steps")
            s["frame"], s["b"], s["deformed"] = np.array([1, 2]), np.zeros((2, 3)), f["positions"][1:]
        parent = where.rsplit("/", 1)[0] if "/" in where else "/"
        if where in f:
            del f[where]
        f.require_group(parent)
        f[where] = h5py.SoftLink("/nowhere")
    for command in ("info", "verify"):
        r = cli(command, src, expect=2)
        assert "penfree: error:" in r.stderr
