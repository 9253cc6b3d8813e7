"""`gate.deviation_bound` against exact rational arithmetic; the near pairs of a gate
that knows the start separations against the full query."""

from fractions import Fraction

import numpy as np
import pytest

from penfree.core.contact.proximity import per_vertex_separation
from penfree.core.topology import edges_from_faces
from penfree.core.verify.gate import StepGate, deviation_bound
from penfree.core.verify.pairs import near_pairs


def _exact_max_dev_sq(x, x_def, A, b):
    best = Fraction(0)
    for v in range(len(x)):
        q = Fraction(0)
        for i in range(3):
            y = sum(Fraction(float(A[i, j])) * Fraction(float(x[v, j])) for j in range(3)) + Fraction(float(b[i]))
            q += (Fraction(float(x_def[v, i])) - y) ** 2
        best = max(best, q)
    return best


def test_deviation_bound_is_rigorous_and_tight(rng):
    for scale, noise in ((1.0, 0.0), (1e3, 1e-12), (1e-2, 1e-6)):
        x = rng.normal(size=(60, 3)) * scale
        A = rng.normal(size=(3, 3))
        b = rng.normal(size=3) * scale
        x_def = x @ A.T + b + rng.normal(size=x.shape) * noise * scale
        d = deviation_bound(x, x_def, A, b)
        exact = _exact_max_dev_sq(x, x_def, A, b)
        assert Fraction(d) ** 2 >= exact
        assert d <= float(exact) ** 0.5 + 1e-13 * scale * 10
    assert deviation_bound(np.zeros((0, 3)), np.zeros((0, 3)), np.eye(3), np.zeros(3)) == 0.0


def _resting_sheets(rng, n=12, gap=0.004, offset=0.0):
    # Two sheets, the upper one sagging into the lower one's contact zone at one corner.
    u = np.linspace(0.0, 1.0, n)
    X, Y = np.meshgrid(u, u, indexing="ij")
    low = np.stack([X, Y, 0.0 * X], -1).reshape(-1, 3)
    high = low + [0.0, 0.0, 0.1]
    high[:, 2] -= (0.1 - gap) * np.exp(-((high[:, 0] ** 2 + high[:, 1] ** 2) / 0.05))
    V = np.concatenate([low, high]) + rng.normal(scale=1e-4, size=(2 * n * n, 3)) + offset
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)
    return np.ascontiguousarray(V), np.concatenate([F, F + n * n])


def _close(pairs, x, R):
    from penfree.core.contact.distance import indexed_distance

    return {(kind, int(i), int(j)) for kind, ij, idx in pairs for (i, j), d in zip(ij, indexed_distance(x, idx, kind))
            if d < R}


@pytest.mark.parametrize("offset", [0.0, 1e3], ids=["near-origin", "far-from-origin"])
@pytest.mark.parametrize("cap", [0.5, 1.0, 3.0])
def test_near_pairs_kept_by_separations_are_the_close_pairs(rng, offset, cap):
    # The primitives whose vertices all have separations below R hold every pair within
    # R, whatever radius the separations were capped at; the query over them is smaller.
    V, F = _resting_sheets(rng, offset=offset)
    E = edges_from_faces(F)
    R = 0.01
    d = per_vertex_separation(V, E, F, cap * R)
    full = near_pairs(V, None, F, R)
    kept = near_pairs(V, None, F, R, keep=d < R)
    want = _close(full, V, R)
    assert len(want) > 5  # the sagging corner
    assert _close(kept, V, R) == want
    got = {(k, int(i), int(j)) for k, ij, _ in kept for i, j in ij}
    assert got <= {(k, int(i), int(j)) for k, ij, _ in full for i, j in ij}
    if cap >= 1.0:  # below R every vertex is kept
        assert sum(len(ij) for _, ij, _ in kept) < 0.2 * sum(len(ij) for _, ij, _ in full)


def test_gate_verdicts_with_and_without_separations(rng):
    # Shrinking maps need the near pairs (reach (h + 2 delta) / sigma): the verdicts of a
    # gate that knows the separations equal the full query's, passing and failing ones.
    V, F = _resting_sheets(rng, gap=0.003)
    E = edges_from_faces(F)
    h = 0.002
    plain = StepGate(V, faces=F, thickness=h)
    told = StepGate(V, faces=F, thickness=h)
    told.use_separations(per_vertex_separation(V, E, F, 0.05))
    assert told._separations is not None
    verdicts = []
    for s in (1.0, 0.995, 0.97, 0.9, 0.6):
        for k in range(3):
            A = np.diag([1.0, 1.0, s]) @ np.linalg.qr(np.eye(3) + 0.01 * k * rng.normal(size=(3, 3)))[0]
            b = 0.01 * k * rng.normal(size=3)
            x_def = V @ A.T + b
            maps = [(A, b, None)]
            verdicts.append(plain.passes(x_def, maps))
            assert told.passes(x_def, maps) == verdicts[-1]
    assert any(verdicts) and not all(verdicts)


def test_near_pairs_ignore_separations_with_a_free_vertex(rng):
    # A vertex in no primitive has pairs with faces that no separation records: a free
    # vertex resting on the lower sheet is near it although every sheet vertex is far.
    V, F = _resting_sheets(rng, gap=0.05)
    V = np.concatenate([V, [[0.55, 0.55, 0.001]]])
    E = edges_from_faces(F)
    R = 0.01
    d = per_vertex_separation(V, E, F, R)
    assert not (d[:-1] < R).any()
    want = _close(near_pairs(V, None, F, R), V, R)
    assert want and all(k == "vf" and i == len(V) - 1 for k, i, _ in want)
    assert _close(near_pairs(V, None, F, R, keep=d < R), V, R) == want
