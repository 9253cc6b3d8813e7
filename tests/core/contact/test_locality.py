"""Spatial relabelling: a permutation that keeps neighbours close, taken only where the
labels carry no locality, and queries on the relabelled scene give the same bits."""

import warnings

import numpy as np
import pytest

from penfree.core.contact import locality
from penfree.core.contact.locality import Relabelling, morton_order, needs_relabelling, relabelling
from penfree.core.contact.proximity import SeparationQuery, per_vertex_separation
from penfree.core.topology import edges_from_faces
from penfree.errors import InputError

NONE = np.zeros((0, 3), dtype=np.int64)


def _sheet(side, rng, layers=2, lift=0.01):
    """`layers` wavy sheets of side x side vertices, numbered row by row, one above the other."""
    u = np.linspace(0.0, 1.0, side)
    X, Y = np.meshgrid(u, u, indexing="ij")
    V0 = np.stack([X, Y, 0.05 * np.sin(5 * X)], -1).reshape(-1, 3)
    idx = np.arange(side * side).reshape(side, side)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F0 = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    V = np.concatenate([V0 + [0.0, 0.0, k * lift] for k in range(layers)])
    V = V + rng.normal(scale=0.02 / side, size=V.shape)
    F = np.concatenate([F0 + k * side * side for k in range(layers)]).astype(np.int64)
    return np.ascontiguousarray(V), F


def _bundle(rng, strands=9, n=60):
    """Wavy strands (segment chains) closer to each other than an edge length, numbered
    strand by strand."""
    t = np.linspace(0.0, 1.0, n)
    V, E = [], []
    for k in range(strands):
        c = np.array([0.012 * (k % 3), 0.012 * (k // 3), 0.0])
        V.append(np.stack([0.004 * np.sin(9 * t + k), 0.004 * np.cos(7 * t + k), t], 1) + c)
        E.append(np.stack([np.arange(n - 1), np.arange(1, n)], 1) + k * n)
    V = np.concatenate(V)
    return np.ascontiguousarray(V + rng.normal(scale=1e-4, size=V.shape)), np.concatenate(E).astype(np.int64)


def _shuffled(rng, V, E, F, flip=True):
    """The same scene with its vertex labels, edge and face rows shuffled, and (with
    `flip`) half of its edges' endpoints swapped: what a remesher may write."""
    n = V.shape[0]
    perm = rng.permutation(n)  # new vertex k is old vertex perm[k]
    inv = np.empty(n, dtype=np.int64)
    inv[perm] = np.arange(n)
    E2 = inv[E][rng.permutation(E.shape[0])]
    if flip:
        swap = rng.random(E2.shape[0]) < 0.5
        E2[swap] = E2[swap][:, ::-1]
    F2 = inv[F][rng.permutation(F.shape[0])] if F.shape[0] else F
    return np.ascontiguousarray(V[perm]), np.ascontiguousarray(E2), np.ascontiguousarray(F2), perm


def _force(monkeypatch):
    monkeypatch.setattr(locality, "GAP_MIN", -1)
    monkeypatch.setattr(locality, "GAP_SHARE", 0.0)


def test_morton_order_keeps_neighbours_close(rng):
    x = rng.random((5000, 3))
    perm = morton_order(x)
    np.testing.assert_array_equal(np.sort(perm), np.arange(x.shape[0]))
    step = np.median(np.linalg.norm(np.diff(x[perm], axis=0), axis=1))
    random_step = np.median(np.linalg.norm(np.diff(x, axis=0), axis=1))
    assert step < 0.1 * random_step


@pytest.mark.parametrize("case", ["single-vertex", "coincident", "collinear", "planar", "far-from-origin",
                                  "non-finite", "empty"])
def test_morton_order_of_hard_inputs(rng, case):
    x = {
        "single-vertex": np.array([[1.0, 2.0, 3.0]]),
        "coincident": np.ones((7, 3)),
        "collinear": np.outer(rng.random(50), [1.0, 2.0, -1.0]),
        "planar": np.c_[rng.random((50, 2)), np.zeros(50)],
        "far-from-origin": 1e8 + rng.random((50, 3)),
        "non-finite": np.r_[rng.random((5, 3)), [[np.nan, 0, 0], [np.inf, 1, 1], [0, -np.inf, 0]]],
        "empty": np.zeros((0, 3)),
    }[case]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        perm = morton_order(x)
    assert perm.dtype == np.int64
    np.testing.assert_array_equal(np.sort(perm), np.arange(x.shape[0]))
    if case in ("coincident", "single-vertex"):
        np.testing.assert_array_equal(perm, np.arange(x.shape[0]))  # ties keep label order
    if case == "collinear":  # along the line: the order of the parameter
        np.testing.assert_array_equal(x[perm, 0], np.sort(x[:, 0]))


def test_relabelling_keeps_each_primitives_vertex_order(rng):
    V, F = _sheet(6, rng, layers=1)
    V, E, F, _ = _shuffled(rng, V, edges_from_faces(F), F)
    r = Relabelling(V, E, F)
    # the same rows in the new labels, each row's vertices in their order
    assert sorted(map(tuple, r.E.tolist())) == sorted(map(tuple, r.inv[E].tolist()))
    assert sorted(map(tuple, r.F.tolist())) == sorted(map(tuple, r.inv[F].tolist()))
    # listed by their smallest new label
    assert np.all(np.diff(r.E.min(axis=1)) >= 0) and np.all(np.diff(r.F.min(axis=1)) >= 0)
    np.testing.assert_array_equal(r.E, r.inv[E][r.edge_order])
    np.testing.assert_array_equal(r.F, r.inv[F][r.face_order])
    np.testing.assert_array_equal(r.positions(V), V[r.perm])
    # (edge, face) pairs of the new lists: the caller's edges and faces, sorted
    ef = np.stack([rng.integers(0, E.shape[0], 40), rng.integers(0, F.shape[0], 40)], axis=1)
    back = r.edge_face_to_caller(ef)
    want = sorted(zip(r.edge_order[ef[:, 0]].tolist(), r.face_order[ef[:, 1]].tolist()))
    assert list(map(tuple, back.tolist())) == want
    d = rng.random(V.shape[0])
    np.testing.assert_array_equal(r.to_caller(d[r.perm]), d)


def test_only_unordered_labels_are_relabelled(rng):
    V, F = _sheet(64, rng)  # 8192 vertices numbered row by row: median edge gap 64
    E = edges_from_faces(F)
    Vb, Eb = _bundle(rng, strands=81, n=64)  # numbered along the strands: gap 1
    assert not needs_relabelling(V.shape[0], E) and relabelling(V, E, F) is None
    assert not needs_relabelling(Vb.shape[0], Eb)
    for x, e, f in ((V, E, F), (Vb, Eb, NONE)):
        xs, es, fs, _ = _shuffled(rng, x, e, f)  # random labels: gap ~ n / 3
        assert needs_relabelling(xs.shape[0], es)
        assert isinstance(relabelling(xs, es, fs), Relabelling)
    assert not needs_relabelling(10, np.zeros((0, 2), dtype=np.int64))


@pytest.mark.parametrize("scene", ["sheet", "bundle"])
@pytest.mark.parametrize("flip", [False, True], ids=["edges-as-built", "edges-flipped"])
def test_separations_do_not_change_under_relabelling(rng, scene, flip):
    # The distance kernels see the same coordinates in the same order whatever the
    # labels (each edge keeps its endpoints' order): relabelled, the same bits.
    if scene == "sheet":
        V, F = _sheet(12, rng)
        E = edges_from_faces(F)
    else:
        (V, E), F = _bundle(rng), NONE
    want = per_vertex_separation(V, E, F, 0.03)
    Vs, Es, Fs, perm = _shuffled(rng, V, E, F, flip=flip)
    if flip:  # the flipped endpoints change the edge-edge kernels' argument order: their reference
        want = per_vertex_separation(V, np.ascontiguousarray(perm[Es]), F, 0.03)
    got = per_vertex_separation(Vs, Es, Fs, 0.03)
    np.testing.assert_array_equal(got.view(np.uint64), want[perm].view(np.uint64))


@pytest.mark.parametrize("scene", ["sheet", "bundle"])
def test_relabelled_query_gives_the_same_bits(rng, monkeypatch, scene):
    # Forced on small scenes: a moving state sequence, queries at their radius and at
    # the reach (completed vertices), bit for bit the plain query of the caller's labels.
    _force(monkeypatch)
    if scene == "sheet":
        V, F = _sheet(14, rng)
        E = edges_from_faces(F)
    else:
        (V, E), F = _bundle(rng), NONE
    V, E, F, _ = _shuffled(rng, V, E, F)
    q = SeparationQuery(E, F)
    for s in range(5):
        c, si = np.cos(0.2 * s), np.sin(0.2 * s)
        R = np.array([[c, -si, 0], [si, c, 0], [0, 0, 1.0]]) * (1 + 0.05 * s)
        x = np.ascontiguousarray(V @ R.T + rng.normal(scale=2e-4, size=V.shape) + 3e2 * (s == 4))
        radius = 0.04 + 0.01 * s
        got = q(x, radius)
        np.testing.assert_array_equal(got.view(np.uint64), per_vertex_separation(x, E, F, radius).view(np.uint64))
    assert q.info["relabelled"] and q.info["reached"] == 4


def test_separation_query_relabels_a_shuffled_scene_once(rng, monkeypatch):
    V, F = _sheet(64, rng)
    E = edges_from_faces(F)
    built = []
    real = locality.Relabelling.__init__

    def spy(self, *a):
        built.append(1)
        real(self, *a)

    monkeypatch.setattr(locality.Relabelling, "__init__", spy)
    q = SeparationQuery(E, F)
    q(V, 0.02)
    assert not q.info["relabelled"]
    Vs, Es, Fs, _ = _shuffled(rng, V, E, F)
    qs = SeparationQuery(Es, Fs)
    for s in range(3):
        x = np.ascontiguousarray(Vs + 1e-4 * s)
        np.testing.assert_array_equal(qs(x, 0.02), per_vertex_separation(x, Es, Fs, 0.02))
    assert qs.info["relabelled"] and len(built) == 1


def test_a_state_of_another_size_is_queried_as_given(rng, monkeypatch):
    # The scene relabelled from its first state; a later state with one more (isolated)
    # vertex does not fit the relabelling and is answered on the scene as given.
    _force(monkeypatch)
    (V, E), F = _bundle(rng), NONE
    q = SeparationQuery(E, F)
    q(V, 0.03)
    assert q.info["relabelled"]
    x = np.ascontiguousarray(np.r_[V, [[9.0, 9.0, 9.0]]])
    np.testing.assert_array_equal(q(x, 0.03), per_vertex_separation(x, E, F, 0.03))
    r = Relabelling(V, E, F)
    assert r.fits(V) and not r.fits(x)
    with pytest.raises(InputError, match=r"x must be \(540, 3\) like the relabelled scene"):
        r.positions(x)
