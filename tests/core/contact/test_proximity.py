"""Per-vertex separations: against exact brute force, and bit for bit against the fold
that evaluates every pair from inf (the cap the minima start at changes no bit)."""

import numpy as np
import pytest

from penfree.core.contact import broad_phase as bp
from penfree.core.contact import proximity
from penfree.core.contact.proximity import per_vertex_separation
from penfree.core.topology import edges_from_faces, referenced_vertices
from penfree.errors import InputError

from oracles import ee_sq, pt_sq


def _sheet(n, rng, lift=0.01):
    u = np.linspace(0.0, 1.0, n)
    X, Y = np.meshgrid(u, u, indexing="ij")
    V = np.stack([X, Y, 0.05 * np.sin(5 * X)], -1).reshape(-1, 3) + rng.normal(scale=0.02 / n, size=(n * n, 3))
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)
    V = np.concatenate([V, V + [0.0, 0.0, lift]])  # two layers
    F = np.concatenate([F, F + n * n])
    return np.ascontiguousarray(V), F


def _unpruned(x, E, F, radius, monkeypatch):
    # The fold before pruning: minima from inf, every pair evaluated.
    real = bp._Plan.__init__

    def no_bound(self, *a, **k):
        real(self, *a, **k)
        self.gap_off = -np.inf

    with monkeypatch.context() as m:
        m.setattr(bp._Plan, "__init__", no_bound)
        m.setattr(proximity, "_cap_sq", lambda r: np.inf)
        return per_vertex_separation(x, E, F, radius)


@pytest.mark.parametrize("radius", [0.0, 0.004, 0.012, 0.05, 1.0])
@pytest.mark.parametrize("offset", [0.0, 3e4], ids=["near-origin", "far-from-origin"])
def test_same_bits_as_the_unpruned_fold(rng, monkeypatch, radius, offset):
    V, F = _sheet(18, rng)
    V = V + offset
    E = edges_from_faces(F)
    for f in (F, np.zeros((0, 3), dtype=np.int64)):  # triangle scene, segment scene
        got = per_vertex_separation(V, E, f, radius)
        want = _unpruned(V, E, f, radius, monkeypatch)
        np.testing.assert_array_equal(got.view(np.uint64), want.view(np.uint64))


def test_matches_exact_brute_force(rng):
    from fractions import Fraction

    V, F = _sheet(7, rng, lift=0.02)
    E = edges_from_faces(F)
    radius = 0.06
    X = [[Fraction(float(c)) for c in row] for row in V]
    best = np.full(len(V), radius ** 2)
    for i in range(len(E)):
        for j in range(i + 1, len(E)):
            if set(E[i]) & set(E[j]):
                continue
            d = float(ee_sq(*(X[v] for v in E[i]), *(X[v] for v in E[j])))
            for v in (*E[i], *E[j]):
                best[v] = min(best[v], d)
    used = referenced_vertices(len(V), F, E)
    for v in np.flatnonzero(used):
        for f in range(len(F)):
            if v in F[f]:
                continue
            d = float(pt_sq(X[v], *(X[c] for c in F[f])))
            for u in (v, *F[f]):
                best[u] = min(best[u], d)
    got = per_vertex_separation(V, E, F, radius)
    np.testing.assert_allclose(got, np.minimum(np.sqrt(best), radius), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("radius", [0.0, 1e-300, 0.1, 3.0, 1e150])
def test_cap_root_is_at_least_the_radius(radius):
    c = proximity._cap_sq(radius)
    assert np.sqrt(c) >= radius and c >= radius * radius


@pytest.mark.parametrize("radius", [np.inf, -np.inf, np.nan, -1e-3])
def test_radius_must_be_finite_and_non_negative(radius):
    # An infinite radius inflated every box to the whole space and aborted the process
    # in the grid build; it is now a clear input error, like a negative or NaN one.
    x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0.1], [1, 1, 0.1]])
    E = np.array([[0, 1], [2, 3]], dtype=np.int64)
    with pytest.raises(InputError, match="radius must be finite"):
        per_vertex_separation(x, E, np.zeros((0, 3), dtype=np.int64), radius)
