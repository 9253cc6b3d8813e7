"""The sequence-level verification driver `verify_sequence`: frames, obstacles, start states."""

import numpy as np
import pytest

from penfree.core.pipeline.verification import verify_sequence
from penfree.errors import InputError

from _geom import grid, two_sheets


def test_verify_sequence_with_moving_obstacle():
    from penfree import Obstacle, Sequence

    V, F = grid(3, 1.0)
    floor = np.array([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0.0]])
    # the sheet stays put; the floor rises 0.6 per frame and reaches it between frames 1 and 2
    ob = Obstacle("floor", np.stack([floor + [0, 0, 0.6 * s] for s in range(3)]), faces=np.array([[0, 1, 2], [0, 2, 3]]))
    seq = Sequence(positions=np.stack([V] * 3), faces=F, obstacles=[ob], origin="mem").validate()
    calls = []
    rep = verify_sequence(seq, progress=lambda: calls.append(1))
    assert [s.ok for s in rep.steps] == [True, False] and len(calls) == 2
    kinds = {p[0] for p in rep.steps[1].result.pairs}
    assert kinds <= {"fv:floor", "ee:floor", "vf:floor"} and "vf:floor" in kinds
    assert all(0.6 < p[3] <= 2 / 3 for p in rep.steps[1].result.pairs)
    assert not rep.ok and rep.n_failed == 1
    only_first = verify_sequence(seq, frames=(0, 2))
    assert len(only_first.steps) == 1 and only_first.ok


def test_sequence_rechecks_start_intersections_after_a_failed_step():
    from penfree import Sequence

    V, F = two_sheets()
    seg = np.array([[1.5, 1.6, -1.0], [1.5, 1.6, 2.0]])  # pierces both sheets in every frame
    W = np.r_[V, seg]
    E = np.array([[len(V), len(V) + 1]])
    frames = np.stack([W + [0.01 * s, 0, 0] for s in range(3)])
    rep = verify_sequence(Sequence(positions=frames, faces=F, edges=E).validate())
    assert [s.result.n_start_violations for s in rep.steps] == [2, 2]
    clean = verify_sequence(Sequence(positions=np.stack([V + [0, 0, 0.1 * s] for s in range(4)]), faces=F).validate())
    assert clean.ok and len(clean.steps) == 3


def _apex_on_a_face(tmp_path, name, x_def, A, b, groups=None, dtype=np.float64):
    """A result file: a triangle's apex (vertex 3) rests exactly on face 0 at the start."""
    from penfree.formats.result import write_result
    from penfree.sequence import Sequence

    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.25, 0.25, 0], [0.5, 0.1, -1], [0.1, 0.5, -1.0]])
    x_prev = x - [0, 0, 0.3]
    seq = Sequence(positions=np.stack([x_prev, x, x]).astype(dtype), faces=np.array([[0, 1, 2], [3, 4, 5]])).validate()
    steps = {"frame": np.array([1]), "A": np.asarray(A, float)[None], "b": np.asarray(b, float)[None],
             "deformed": np.asarray(x_def, float)[None], "certificate_margin": np.array([0.0])}
    write_result(tmp_path / name, seq, steps, {}, groups=groups)
    return tmp_path / name, x


@pytest.mark.parametrize("mode", ["auto", "ccd"])
def test_a_touching_pair_is_excused_only_when_it_does_not_move(tmp_path, mode):
    """A pair touching at the start is pre-existing only when none of its vertices
    moves. Before, verify passed results pushing the apex up through face 0 (rc 0),
    whether its steps/A (the identity) had moved nothing or two components' maps moved
    the two triangles apart; and even one map moving both is written rounded, which can
    make the pair cross (`test_deform.py::test_touching_pairs_never_cross_by_rounding`)."""
    from penfree.core.pipeline.verification import verify_file

    x = _apex_on_a_face(tmp_path, "probe.h5", np.zeros((6, 3)), np.eye(3), np.zeros(3))[1]
    up = x + np.r_[np.zeros((3, 3)), np.tile([0, 0, 0.3], (3, 1))]
    nan = np.full((3, 3), np.nan), np.full(3, np.nan)
    two = {"component_maps": {"labels": np.array([0, 0, 0, 1, 1, 1]), "A": np.stack([np.eye(3)] * 2)[None],
                              "b": np.array([[[0, 0, 0], [0, 0, 0.3]]])}}
    still = x + np.r_[np.tile([0, 0, -0.3], (2, 1)), np.zeros((4, 3))]  # vertices 0, 1 drop; 2-5 stay
    cases = {  # name: (x_def, A, b, groups, dtype, verdict)
        "forged_map": (up, np.eye(3), np.zeros(3), None, np.float64, False),
        "two_maps": (up, *nan, two, np.float64, False),
        "one_map": (x + [0, 0, 0.3], np.eye(3), [0, 0, 0.3], None, np.float64, False),
        "one_map_float32": ((x + [0.1, 0.2, 0.3]).astype(np.float32), np.eye(3), [0.1, 0.2, 0.3], None,
                            np.float32, False),
        "nothing": (x, np.eye(3), np.zeros(3), None, np.float64, True),
        "face_0_moves_away": (still, np.eye(3), np.zeros(3), None, np.float64, False),
    }
    for name, (x_def, A, b, groups, dtype, verdict) in cases.items():
        path = _apex_on_a_face(tmp_path, name + ".h5", x_def, A, b, groups, dtype)[0]
        rep = verify_file(path, mode=mode)
        assert rep.ok is verdict, name
        res = rep.steps[0].result
        assert res.n_pre_existing > 0, name  # the start contact is reported either way
        if not verdict:
            assert ("vf", 3, 0) in [p[:3] for p in res.pairs], name


def test_malformed_component_maps_are_unusable_input(tmp_path):
    """A per-component step's certificates are those of its component_maps/A; a missing
    or malformed one is unusable input naming the dataset (it raised IndexError,
    TypeError or KeyError, or was read with another step's maps)."""
    from penfree.core.pipeline.verification import verify_file

    x = _apex_on_a_face(tmp_path, "x.h5", np.zeros((6, 3)), np.eye(3), np.zeros(3))[1]
    nan = np.full((3, 3), np.nan), np.full(3, np.nan)
    two, labels, b = np.stack([np.eye(3)] * 2)[None], np.array([0, 0, 0, 1, 1, 1]), np.zeros((1, 2, 3))
    for k, A in enumerate([None, np.zeros((1, 2, 3)), np.repeat(two, 2, axis=0), np.array(["a"]),
                           {"x": np.zeros(2)}, two * np.nan]):
        maps = {"labels": labels, "b": b} if A is None else {"labels": labels, "A": A, "b": b}
        path = _apex_on_a_face(tmp_path, f"bad{k}.h5", x + [0, 0, 0.3], *nan, {"component_maps": maps})[0]
        with pytest.raises(InputError, match=f"in .*bad{k}.h5:/component_maps/A$"):
            verify_file(path, mode="ccd")


@pytest.mark.parametrize("mode", ["auto", "ccd"])
def test_a_long_report_holds_one_edges_array(tmp_path, mode):
    """Every step's result names its pairs by the scene's edges; a report of thousands of
    steps held a copy per step (0.4 MB a step at 8K vertices, 2.9 GB for 6,000 steps). The
    steps now share one array, equal to each step's own."""
    from pathlib import Path

    from penfree.core.pipeline.deform import deform_sequence
    from penfree.core.pipeline.verification import verify_result
    from penfree.core.topology import scene_edges
    from penfree.formats import read_sequence
    from penfree.formats.result import DeformResult

    seq = read_sequence(str(Path(__file__).resolve().parents[3] / "samples" / "twisting_cloth.h5"))
    out = deform_sequence(seq, model="affine", frames=(0, 12))
    res = DeformResult(sequence=seq, steps=out.steps, groups=out.groups)
    for rep in (verify_result(res, mode=mode), verify_sequence(seq, frames=(0, 12))):
        assert len(rep.steps) == 11
        E = rep.steps[0].result.edges
        np.testing.assert_array_equal(E, scene_edges(np.zeros((0, 2), np.int64), seq.faces))
        assert all(st.result.edges is E for st in rep.steps)
