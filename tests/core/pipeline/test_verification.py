"""The sequence-level verification driver `verify_sequence`: frames, obstacles, start states."""

import numpy as np

from penfree.core.pipeline.verification import verify_sequence

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
