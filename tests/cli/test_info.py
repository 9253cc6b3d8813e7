"""``penfree info``: human and JSON output, result files, and every bad input (also through convert)."""

import json
import os

import h5py
import numpy as np
import pytest

from penfree.formats import write_sequence
from penfree.formats.result import write_result
from penfree.sequence import Sequence


def _seq(T=4, N=5, dtype=np.float64):
    rng = np.random.default_rng(17)
    return Sequence(positions=rng.random((T, N, 3)).astype(dtype),
                    edges=np.array([[i, i + 1] for i in range(N - 1)]), thickness=0.01, dt=0.1).validate()


def test_info_human(cli, tmp_path):
    p = tmp_path / "rods.h5"
    write_sequence(p, _seq())
    r = cli("info", p)
    assert r.exit_code == 0, r.output
    lines = r.stdout.splitlines()
    fields = dict(line.split(":", 1) for line in lines)
    assert fields["frames"].strip() == "4" and fields["kind"].strip() == "segments"
    assert fields["edges"].strip() == "4" and fields["dt"].strip() == "0.1"
    assert "step motion max" in fields and "bbox extent" in fields
    # aligned: every value starts in the same column
    starts = {len(line) - len(line.split(":", 1)[1].lstrip()) for line in lines}
    assert len(starts) == 1


def test_info_json(cli, tmp_path):
    p = tmp_path / "rods.npz"
    write_sequence(p, _seq(dtype=np.float32))
    r = cli("info", p, "--json")
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    assert (d["frames"], d["vertices"], d["n_edges"], d["dtype"], d["kind"]) == (4, 5, 4, "float32", "segments")
    assert len(d["motion"]["per_step_max"]) == 3 and d["thickness"] == pytest.approx(0.01)


def test_info_mesh_pattern(cli, tmp_path):
    write_sequence(str(tmp_path / "A%08d.obj"), _seq())
    r = cli("info", tmp_path / "A%08d.obj", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["frames"] == 4


def test_info_result_file(cli, tmp_path):
    seq = _seq()
    S = 3
    steps = {"frame": np.arange(1, 4), "A": np.tile(np.eye(3), (S, 1, 1)), "b": np.zeros((S, 3)),
             "deformed": seq.positions[1:], "model": np.array(["affine", "affine", "rigid"]),
             "projection": np.array(["none", "sym", "none"]), "certificate_margin": np.array([0.9, 0.4, 1.0])}
    p = tmp_path / "deformed.h5"
    write_result(p, seq, steps, {"input": "rods.h5"})
    r = cli("info", p)
    assert r.exit_code == 0, r.output
    assert "steps:" in r.stdout and "affine x2, rigid x1" in r.stdout and "none x2, sym x1" in r.stdout
    assert "min certificate margin: 0.4" in r.stdout
    d = json.loads(cli("info", p, "--json").stdout)
    assert d["result"]["min_certificate_margin"] == 0.4 and d["result"]["steps"] == 3


# --- every bad input, through info and convert --------------------------------

def _h5(path, **datasets):
    attrs = datasets.pop("attrs", {})
    with h5py.File(path, "w") as f:
        for k, v in datasets.items():
            f[k] = v
        f.attrs.update(attrs)


def _truncated(path):
    write_sequence(path, _seq(T=6, N=200))
    data = open(path, "rb").read()
    with open(path, "wb") as fh:
        fh.write(data[: len(data) // 3])


def _nan_frame(path):
    pos = np.zeros((4, 3, 3))
    pos[2, 1, 0] = np.nan
    _h5(path, positions=pos)


GOOD = np.zeros((3, 4, 3))
BAD = {
    "not-hdf5": (lambda p: open(p, "w").write("just text"), "is not an HDF5 file"),
    "truncated": (_truncated, "is a truncated or damaged HDF5 file"),
    "missing-positions": (lambda p: _h5(p, faces=[[0, 1, 2]]), "{p}:/positions"),
    "wrong-shape": (lambda p: _h5(p, positions=np.zeros((3, 4, 2))), "positions must be (T, N, 3); got (3, 4, 2) in {p}:/positions"),
    "one-frame": (lambda p: _h5(p, positions=np.zeros((1, 4, 3))), "at least 2 frames; got 1 in {p}:/positions"),
    "nan-frame": (_nan_frame, "frame 2 holds NaN or Inf in {p}:/positions"),
    "index-out-of-range": (lambda p: _h5(p, positions=GOOD, faces=[[0, 1, 7]]), "found 7 in {p}:/faces"),
    "negative-index": (lambda p: _h5(p, positions=GOOD, edges=[[-1, 2]]), "found -1 in {p}:/edges"),
    "topology-mismatch": (lambda p: _h5(p, positions=GOOD, faces=[[0, 1]]), "faces must be (M, 3); got (1, 2) in {p}:/faces"),
    "weights-mismatch": (lambda p: _h5(p, positions=GOOD, weights=np.ones(3)), "got (3,) in {p}:/weights"),
    "negative-weights": (lambda p: _h5(p, positions=GOOD, weights=[1.0, -2, 1, 1]), "got min -2 in {p}:/weights"),
    "format-version": (lambda p: _h5(p, positions=GOOD, attrs={"penfree_format": 7}), "unsupported penfree_format 7 in {p}:@penfree_format"),
}


@pytest.mark.parametrize("command", ["info", "convert", "deform", "verify"])
@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_exit_2(cli, tmp_path, case, command):
    build, expect = BAD[case]
    bad = str(tmp_path / "bad.h5")
    build(bad)
    before = (open(bad, "rb").read(), os.stat(bad).st_mtime_ns)
    out = tmp_path / "out.h5"
    r = {"info": lambda: cli("info", bad), "convert": lambda: cli("convert", bad, out),
         "deform": lambda: cli("deform", bad, "-o", out), "verify": lambda: cli("verify", bad)}[command]()
    assert r.exit_code == 2, r.output
    err = r.stderr.strip()
    assert err.startswith("penfree: error: ") and "\n" not in err
    assert bad in err and expect.format(p=bad) in err
    assert "Traceback" not in r.output
    assert sorted(os.listdir(tmp_path)) == ["bad.h5"]  # no output, no temp file
    assert (open(bad, "rb").read(), os.stat(bad).st_mtime_ns) == before  # input untouched


def test_only_the_ending_process_skips_its_exit_collection(tmp_path, monkeypatch):
    from penfree.cli import main
    from penfree.core import memory

    p = tmp_path / "rods.h5"
    write_sequence(p, _seq())
    calls = []
    monkeypatch.setattr(memory, "skip_exit_collection", lambda: calls.append(1))
    with pytest.raises(SystemExit) as e:  # the console script: the process ends here
        main.main(["info", str(p)])
    assert e.value.code == 0 and calls == [1]
    assert main.main(["info", str(p)], standalone_mode=False) == 0  # a caller's process: left alone
    assert calls == [1]


def test_the_command_bounds_openmp_spinning_before_its_kernels(tmp_path, monkeypatch):
    # `penfree` sets GOMP_SPINCOUNT (`parallel.limit_spin_wait`) as it starts, before any
    # parallel kernel loads libgomp, and leaves a user's own OpenMP setting alone.
    from penfree.cli import main
    from penfree.core import parallel

    p = tmp_path / "rods.h5"
    write_sequence(p, _seq())
    env = {k: v for k, v in os.environ.items() if k not in ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")}
    monkeypatch.setattr(os, "environ", env)
    assert main.main(["info", str(p)], standalone_mode=False) == 0
    assert env["GOMP_SPINCOUNT"] == str(parallel.SPIN_COUNT)
    env.pop("GOMP_SPINCOUNT")
    env["OMP_WAIT_POLICY"] = "active"
    assert main.main(["info", str(p)], standalone_mode=False) == 0
    assert "GOMP_SPINCOUNT" not in env
