"""The certificate path of verify over reused neighbour lists gives the verdicts of the
fresh passes (the oracle), step by step and for whole result files, including the
hard cases where the proof must decline (an edge through a face, a pair within g)."""

from pathlib import Path

import numpy as np
import pytest

from penfree.core.pipeline import verification as vf_mod
from penfree.core.pipeline.deform import deform_sequence
from penfree.core.verify.path import _bodies
from penfree.core.pipeline.verification import verify_file
from penfree.core.verify.affine import verify_affine_step
from penfree.core.contact.neighbours import NeighbourList
from penfree.core.verify.reuse import result_lists
from penfree.formats import read_sequence
from penfree.formats.result import write_result

from _geom import rot

SAMPLES = Path(__file__).resolve().parents[3] / "samples"


def _lists(x, edges, faces, skin=None):
    """The verify lists; a fixed skin forces a kept list (the automatic one may answer fresh)."""
    scene = _bodies(x, x, edges, faces, None)[0]
    if skin is None:
        return result_lists(scene.E, scene.F)
    return NeighbourList(scene.E, scene.F, edge_face=True, skin=skin)


def _same(a, b):
    assert (a is None) == (b is None)
    if a is not None:
        assert a.to_dict() == b.to_dict()


@pytest.mark.parametrize("name", ["twisting_cloth.h5", "cables.h5"])
@pytest.mark.parametrize("thickness", [0.0, 1e-3])
@pytest.mark.parametrize("skin", [None, 0.02])
def test_listed_certificate_path_matches_fresh(name, thickness, skin):
    seq = read_sequence(SAMPLES / name)
    pos = np.asarray(seq.positions, dtype=np.float64)
    nl = _lists(pos[0], seq.edges, seq.faces, skin)
    for s in range(1, min(pos.shape[0], 12)):
        x = pos[s]
        A = rot([1, 1, 0], 0.5 * s) @ np.diag([1.0, 1.002, 0.999])
        c = x.mean(axis=0)
        x_def = (x - c) @ A.T + c
        b = c - A @ c
        fresh = verify_affine_step(x, x_def, A, b, edges=seq.edges, faces=seq.faces, thickness=thickness)
        listed = verify_affine_step(x, x_def, A, b, edges=seq.edges, faces=seq.faces, thickness=thickness,
                                    neighbours=nl)
        _same(fresh, listed)
    if skin is not None:
        assert nl.info["builds"] >= 1 and nl.info["fresh"] == 0


def _two_triangles(z_top):
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0],
                  [0.2, 0.2, z_top], [0.3, 0.2, z_top + 0.5], [0.2, 0.3, z_top - 0.5]], dtype=float)
    return x, np.array([[0, 1, 2], [3, 4, 5]])


@pytest.mark.parametrize("case, z_top, thickness", [
    ("edge-pierces-face", 0.0, 0.0),
    ("pair-within-g", 0.6, 0.2),
    ("separated", 0.9, 0.05),
])
def test_hard_cases(case, z_top, thickness):
    x, F = _two_triangles(z_top)
    A = np.eye(3)
    b = np.zeros(3)
    nl = _lists(x, None, F, skin=0.1)
    fresh = verify_affine_step(x, x.copy(), A, b, faces=F, thickness=thickness)
    listed = verify_affine_step(x, x.copy(), A, b, faces=F, thickness=thickness, neighbours=nl)
    _same(fresh, listed)
    assert (fresh is None) == (case != "separated")


@pytest.mark.parametrize("name", ["twisting_cloth_contact.h5", "rods.h5"])
@pytest.mark.parametrize("forced", [False, True])
def test_verify_file_same_report_with_and_without_lists(tmp_path, monkeypatch, name, forced):
    seq = read_sequence(SAMPLES / name)
    seq.positions = np.asarray(seq.positions)[:8]
    out = deform_sequence(seq, model="affine")
    path = tmp_path / "res.h5"
    write_result(path, seq, out.steps, {"options": out.options})
    if forced:  # kept lists with a skin (the automatic choice may answer these steps fresh)
        real = vf_mod._result_lists
        monkeypatch.setattr(vf_mod, "_result_lists", lambda seq, mode: (
            None if real(seq, mode) is None else NeighbourList(real(seq, mode).E, real(seq, mode).F,
                                                               edge_face=True, skin=0.02)))
    with_lists = verify_file(path).to_dict()
    monkeypatch.setattr(vf_mod, "_result_lists", lambda seq, mode: None)
    fresh = verify_file(path).to_dict()
    assert with_lists == fresh
    assert with_lists["ok"]
