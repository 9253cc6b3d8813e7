"""Topology helpers against direct Python constructions."""

import numpy as np
import pytest

from penfree.core.topology import (
    as_positions,
    as_topology,
    edges_from_faces,
    referenced_vertices,
    scene_edges,
    vertex_incidence,
)
from penfree.errors import InputError


RNG_SEED = 11  # seed of the shared `rng` fixture (tests/conftest.py)


def test_edges_from_faces_matches_set(rng):
    F = rng.integers(0, 40, (120, 3))
    want = sorted({tuple(sorted((int(f[a]), int(f[b])))) for f in F for a, b in ((0, 1), (1, 2), (2, 0))
                   if f[a] != f[b]})
    E = edges_from_faces(F)
    assert E.dtype == np.int64 and E.flags.c_contiguous
    assert E.tolist() == [list(e) for e in want]


def test_edges_of_a_grid():
    # an n x n vertex grid triangulated into 2 (n-1)^2 faces has
    # 2 n (n - 1) axis edges plus (n - 1)^2 diagonals
    n = 6
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    E = edges_from_faces(F)
    assert len(E) == 2 * n * (n - 1) + (n - 1) ** 2
    assert np.all(E[:, 0] < E[:, 1])


def test_edges_from_faces_degenerate_and_empty():
    assert edges_from_faces([[0, 0, 1]]).tolist() == [[0, 1]]
    assert edges_from_faces(np.zeros((0, 3), int)).shape == (0, 2)
    with pytest.raises(InputError, match=r"faces must be \(F, 3\)"):
        edges_from_faces([[0, 1]])
    with pytest.raises(InputError, match="integer"):
        edges_from_faces([[0.0, 1.0, 2.0]])


def test_vertex_incidence(rng):
    F = rng.integers(0, 25, (60, 3))
    offsets, prims = vertex_incidence(F, 30)
    assert offsets.shape == (31,) and offsets[-1] == F.size
    for v in range(30):
        want = [f for f in range(len(F)) for c in F[f] if c == v]
        assert prims[offsets[v]:offsets[v + 1]].tolist() == want


def test_referenced_vertices():
    used = referenced_vertices(6, np.array([[0, 1]]), None, np.array([[3, 4, 1]]))
    assert used.tolist() == [True, True, False, True, True, False]


def test_validation_messages():
    with pytest.raises(InputError, match=r"V must be \(N, 3\); got \(4, 2\)"):
        as_positions(np.zeros((4, 2)))
    with pytest.raises(InputError, match="finite"):
        as_positions(np.array([[0.0, np.inf, 0.0]]))
    with pytest.raises(InputError, match=r"E indices must lie in \[0, 3\); got range \[-1, 2\]"):
        as_topology(np.array([[0, 2], [-1, 1]]), 2, 3)
    assert as_positions(np.ones((2, 3), np.float32)).dtype == np.float64
    assert as_topology(None, 3, 5).shape == (0, 3)


def test_index_messages_show_the_indices_as_given():
    """A uint64 index 2**64 - 1 was reported as range [-1, 0]; rows without indices ((3, 0)) counted as none."""
    with pytest.raises(InputError, match=r"got range \[0, 18446744073709551615\]"):
        as_topology(np.array([[0, 2**64 - 1]], dtype=np.uint64), 2, 3)
    with pytest.raises(InputError, match=r"E must be \(M, 2\); got \(3, 0\)"):
        as_topology(np.zeros((3, 0), dtype=np.int64), 2, 3)
    for empty in (np.zeros(0, np.int64), np.zeros((0, 2), np.int64), np.zeros((0, 3), np.int64), []):
        assert as_topology(empty, 2, 3).shape == (0, 2)


def _edge_set_oracle(E, F):
    """Plain-Python edge set: sorted pairs of the faces' sides and the segments, no (i, i)."""
    out = {tuple(sorted(e)) for e in E}
    for f in F:
        out |= {tuple(sorted((f[a], f[b]))) for a, b in ((0, 1), (1, 2), (2, 0))}
    return sorted(p for p in out if p[0] != p[1])


@pytest.mark.parametrize("case", ["segments-only", "segments-degenerate", "faces-only", "mixed", "degenerate"])
def test_scene_edges_against_set_oracle(rng, case):
    n = 12
    E = rng.integers(0, n, size=(8, 2)) if case != "faces-only" else np.zeros((0, 2), np.int64)
    F = rng.integers(0, n, size=(6, 3)) if not case.startswith("segments") else np.zeros((0, 3), np.int64)
    if case == "segments-only":
        E[:, 1] = (E[:, 0] + 1 + E[:, 1] % (n - 1)) % n  # no (i, i): the copy path
    if case in ("degenerate", "segments-degenerate"):
        E[:3, 1] = E[:3, 0]  # (i, i) segments
    if case == "degenerate":
        F[0] = [4, 4, 5]  # a face repeating a vertex
    E_before = E.copy()
    got = scene_edges(E, F)
    got[...] = -1  # the result is the caller's: the input is never aliased
    np.testing.assert_array_equal(E, E_before)
    got = scene_edges(E, F)
    assert got.dtype == np.int64 and got.flags.c_contiguous
    assert (got[:, 0] != got[:, 1]).all()
    if len(F):
        assert [tuple(e) for e in got.tolist()] == _edge_set_oracle(E.tolist(), F.tolist())
    else:  # segments keep their order (pair indices refer to it); only (i, i) go
        assert got.tolist() == [e for e in E.tolist() if e[0] != e[1]]


def test_scene_edges_remembered_by_content_not_identity(rng):
    # The same mesh asked for again (each step of a recording) comes from the memo; a
    # changed mesh in the same array, or a caller writing into a result, must not.
    n = 30
    E = rng.integers(0, n, size=(5, 2))
    F = rng.integers(0, n, size=(40, 3))
    first = scene_edges(E, F)
    first[:] = -1  # the caller owns what it got
    again = scene_edges(E.copy(), F.copy())
    assert [tuple(e) for e in again.tolist()] == _edge_set_oracle(E.tolist(), F.tolist())
    F[0] = [0, 1, 2]
    E[0] = [3, 4]
    changed = scene_edges(E, F)
    assert [tuple(e) for e in changed.tolist()] == _edge_set_oracle(E.tolist(), F.tolist())


def test_referenced_vertices_against_numpy():
    from penfree.core.topology import referenced_vertices

    rng = np.random.default_rng(3)
    F, E = rng.integers(0, 300, (200, 3)), rng.integers(0, 300, (150, 2))
    want = np.zeros(300, bool)
    want[F.ravel()] = True
    want[E.ravel()] = True
    np.testing.assert_array_equal(referenced_vertices(300, F, E), want)
    np.testing.assert_array_equal(referenced_vertices(300, None, np.zeros((0, 2), np.int64)), np.zeros(300, bool))
    np.testing.assert_array_equal(referenced_vertices(4, np.array([[0, -1]])), [True, False, False, True])
    with pytest.raises(IndexError):
        referenced_vertices(4, np.array([[0, 4]]))
