"""``deform --client-model`` and ``report --client ipctk`` (issue 12), in-process."""

from __future__ import annotations

import importlib.util
import json
import os
import sys

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from penfree.cli import main
from penfree.sequence import Sequence


@pytest.fixture()
def two_rods(tmp_path):
    """Two 3-vertex rods 20 apart translating fast (5 per frame), thickness 0.1."""
    from penfree.formats import write_sequence

    s = np.linspace(0.0, 1.0, 3)
    base = np.concatenate([np.c_[s, 0 * s, 0 * s], np.c_[s, 0 * s + 20.0, 0 * s]])
    frames = np.stack([base + [5.0 * t, 0, 0] for t in range(6)])
    seq = Sequence(positions=frames, edges=np.array([[0, 1], [1, 2], [3, 4], [4, 5]]))
    seq.thickness = 0.1
    seq = seq.validate()
    path = tmp_path / "rods.h5"
    write_sequence(str(path), seq)
    return path


def test_deform_client_model_moves_the_fast_rods(two_rods, tmp_path):
    out = tmp_path / "d.h5"
    r = CliRunner().invoke(main, ["deform", str(two_rods), "-o", str(out), "--client-model", "isotropic",
                                  "--dhat", "1.0", "--json"])
    assert r.exit_code == 0, r.output
    with h5py.File(out, "r") as f:
        models = [m.decode() if isinstance(m, bytes) else str(m) for m in f["steps/model"][()]]
        deformed, frames, pos = f["steps/deformed"][()], f["steps/frame"][()], f["positions"][()]
    assert all(m != "none" for m in models)
    np.testing.assert_allclose(deformed, 2 * pos[frames] - pos[frames - 1], atol=1e-9)


def test_deform_client_model_needs_auto(two_rods, tmp_path):
    out = tmp_path / "d.h5"
    r = CliRunner().invoke(main, ["deform", str(two_rods), "-o", str(out), "--model", "affine",
                                  "--client-model", "planar"])
    assert r.exit_code == 2 and "--client-model needs --model auto" in r.output
    assert not out.exists()


def test_deform_dhat_needs_client_model(two_rods, tmp_path):
    """--dhat without --client-model was accepted and ignored."""
    out = tmp_path / "d.h5"
    r = CliRunner().invoke(main, ["deform", str(two_rods), "-o", str(out), "--dhat", "0.01"])
    assert r.exit_code == 2 and "--dhat" in r.output and "--client-model" in r.output
    assert not out.exists()


def test_deform_client_radius_needs_client_model(two_rods, tmp_path):
    out = tmp_path / "d.h5"
    r = CliRunner().invoke(main, ["deform", str(two_rods), "-o", str(out), "--client-radius", "own"])
    assert r.exit_code == 2 and "--client-radius" in r.output and "--client-model" in r.output
    assert not out.exists()


@pytest.mark.parametrize("rule", ["own", "step"])
def test_deform_client_radius_is_the_libraries_and_recorded(two_rods, tmp_path, rule):
    """--client-radius RULE writes what deform_sequence does with ClientModel(radius=RULE),
    and records the rule beside the truncation."""
    from penfree import read_sequence
    from penfree.core.pipeline.client_select import ClientModel
    from penfree.core.pipeline.deform import deform_sequence
    from penfree.formats.result import read_result

    out = tmp_path / "d.h5"
    args = ["deform", str(two_rods), "-o", str(out), "--client-model", "planar", "--dhat", "1.0"]
    r = CliRunner().invoke(main, args + ([] if rule == "step" else ["--client-radius", rule]))
    assert r.exit_code == 0, r.output
    seq = read_sequence(str(two_rods))
    ref = deform_sequence(seq, model="auto", client_model=ClientModel(truncation="planar", dhat=1.0, radius=rule,
                                                                      edges=seq.edges, faces=seq.faces))
    with h5py.File(out, "r") as f:
        np.testing.assert_array_equal(f["steps/deformed"][()], ref.steps["deformed"])
    opts = read_result(str(out)).attrs["options"]
    assert opts["client_model"] == "planar" and opts["client_radius"] == rule


def test_report_client_without_ipctk_exits_2(two_rods, tmp_path, monkeypatch):
    d = tmp_path / "d.h5"
    assert CliRunner().invoke(main, ["deform", str(two_rods), "-o", str(d)]).exit_code == 0
    monkeypatch.setitem(sys.modules, "ipctk", None)  # import ipctk -> ImportError
    out = tmp_path / "rep"
    r = CliRunner().invoke(main, ["report", str(d), "-o", str(out), "--client", "ipctk", "--no-ladder"])
    assert r.exit_code == 2
    assert "pip install 'penfree[ogc]'" in r.output
    assert not out.exists()


def test_report_client_ipctk_table_and_plot(two_rods, tmp_path):
    pytest.importorskip("ipctk", reason="ipctk (penfree[ogc]) not installed; make test installs it")
    d = tmp_path / "d.h5"
    assert CliRunner().invoke(main, ["deform", str(two_rods), "-o", str(d), "--client-model", "isotropic",
                                     "--dhat", "1.0"]).exit_code == 0
    out = tmp_path / "rep"
    r = CliRunner().invoke(main, ["report", str(d), "-o", str(out), "--client", "ipctk", "--dhat", "1.0",
                                  "--no-ladder", "--every", "2"])
    assert r.exit_code == 0, r.output
    doc = json.loads((out / "report.json").read_text())
    cl = doc["files"][0]["client"]
    assert cl["options"]["truncations"] == ["isotropic", "planar"] and cl["options"]["every"] == 2
    assert cl["steps"]["frame"] == [1, 3]  # steps with a next frame, every 2nd
    iso = cl["summary"]["isotropic"]
    # From x: 3 passes a step (tests/core/test_client.py's hand count); from x_def = x_pred: 1.
    assert iso["baseline"] == 6 and iso["step"] == 2
    md = (out / "report.md").read_text()
    assert "Real-client CD passes" in md
    # the headline leads with the real client's totals, in the printed summary and report.md alike
    line = (f"real-client CD passes (ipctk, summed over 2 steps), baseline -> deformed: isotropic rule own 6 -> "
            f"2 (-67%), rule step 6 -> 2 (-67%); planar rule own {cl['summary']['planar']['baseline_own']} -> ")
    assert line in r.output and "R" + line[1:] in md  # "CD" kept as it is
    assert md.index("R" + line[1:]) < md.index("### Summary: baseline vs deformed")
    if doc["plots"]["status"] == "written":
        assert os.path.exists(out / "d_client_passes.png")


def test_deform_and_report_client_replay_the_obstacles(tmp_path):
    """cloth_drape_box (a box and the ground): ``deform --client-model`` predicts with the
    obstacles in the client's mesh (the library's choice with them, which differs from
    the choice without them on frame 12), and ``report --client`` replays with them and
    names them in its options."""
    from pathlib import Path

    from penfree import read_sequence
    from penfree.core.pipeline.client_select import ClientModel
    from penfree.core.pipeline.deform import deform_sequence
    from penfree.core.trust.client_stats import resolve_dhat

    sample = Path(__file__).resolve().parents[2] / "samples" / "cloth_drape_box.h5"
    seq = read_sequence(str(sample))
    dhat = resolve_dhat(None, seq.contact_radius, seq.thickness)
    out = tmp_path / "d.h5"
    r = CliRunner().invoke(main, ["deform", str(sample), "-o", str(out), "--client-model", "isotropic",
                                  "--frames", "12:13"])
    assert r.exit_code == 0, r.output

    def library(obstacles):
        cm = ClientModel(truncation="isotropic", dhat=dhat, edges=seq.edges, faces=seq.faces, obstacles=obstacles)
        return deform_sequence(seq, model="auto", client_model=cm, frames=(12, 13)).steps

    with_ob, without = library(tuple(seq.obstacles)), library(())
    assert with_ob["model"][0] != without["model"][0]
    with h5py.File(out, "r") as f:
        np.testing.assert_array_equal(f["steps/deformed"][()], with_ob["deformed"])
    if importlib.util.find_spec("ipctk") is None:
        pytest.skip("ipctk (penfree[ogc]) not installed; make test installs it")
    rep = tmp_path / "rep"
    r = CliRunner().invoke(main, ["report", str(out), "-o", str(rep), "--client", "ipctk", "--truncation", "isotropic",
                                  "--radius", "step", "--no-ladder", "--no-plots"])
    assert r.exit_code == 0, r.output
    section = json.loads((rep / "report.json").read_text())["files"][0]["client"]
    assert section["options"]["obstacles"] == ["box", "ground"]
    assert "Obstacles in the client's collision mesh: box, ground." in (rep / "report.md").read_text()
    from penfree.core.trust.client import replay_step

    P = seq.positions.astype(float)
    want = replay_step(with_ob["deformed"][0], P[12], 2 * P[12] - P[11], P[13], faces=seq.faces, dhat=dhat,
                       thickness=seq.thickness, client="ipctk", obstacles=seq.obstacles, frame=12)["passes"]
    assert section["steps"]["passes_isotropic_step_deformed"] == [want]
