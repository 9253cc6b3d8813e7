"""The own client's stencil lists against fresh `candidate_stencils` queries (the oracle)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import penfree.core.trust.client as client_mod
from penfree import read_sequence
from penfree.core.trust.bounds import scene_arrays
from penfree.core.trust.client import ClientQuery, replay_step
from penfree.core.trust.client_stats import resolve_dhat
from penfree.core.trust.planar import (
    PLANAR_PARALLEL_EPS, _moving, _planar_ratios, candidate_stencils, planar_filter,
)
from penfree.core.trust.stencil_list import StencilList, contains, region

from _geom import grid
from tests._samples import SAMPLES


def _layers(rng, n=8, layers=3, gap=0.03):
    """`layers` sheets of n x n vertices 0.3 wide, `gap` apart, jittered."""
    h = 0.3 / (n - 1)
    sheets = [grid(n, k * gap) for k in range(layers)]
    V = np.concatenate([Vk * [h, h, 1.0] for Vk, _ in sheets])
    F = np.concatenate([Fk + k * n * n for k, (_, Fk) in enumerate(sheets)])
    return V + rng.normal(0, 0.004, V.shape), F


def _rods(rng, n_rods=6, per=10):
    t = np.linspace(0, 0.4, per)
    V = np.concatenate([np.column_stack([t, np.full(per, 0.03 * k), 0.01 * np.sin(7 * t + k)])
                        for k in range(n_rods)]) + rng.normal(0, 0.004, (n_rods * per, 3))
    E = np.concatenate([np.column_stack([np.arange(per - 1), np.arange(1, per)]) + k * per for k in range(n_rods)])
    return V, E


def _fresh(x, E, F, radius, keep=None):
    st, kinds = candidate_stencils(x, E, F, radius)
    if keep is not None:
        sel = keep(st)
        st, kinds = st[sel], kinds[sel]
    return st, kinds


def _states(rng, lo, hi, n):
    """States in the region: random, its two corners, and each vertex at one corner or
    the other (boxes touching at a region's face)."""
    yield lo
    yield hi
    for _ in range(n):
        yield lo + rng.random(lo.shape) * (hi - lo)
        yield np.where(rng.random(lo.shape) < 0.5, lo, hi)


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("scene", ["layers", "rods"])
def test_a_list_answers_every_state_of_its_region_like_a_fresh_query(scene, seed):
    rng = np.random.default_rng(seed)
    if scene == "layers":
        V, F0 = _layers(rng)
        _, E, F = scene_arrays(V, None, F0)
    else:
        V, E0 = _rods(rng)
        _, E, F = scene_arrays(V, E0, None)
    step = rng.normal(0, 0.01, V.shape)
    lo, hi = region([V, V + step, V + 2 * step + rng.normal(0, 0.003, V.shape)])
    radius = 0.02
    keep = (lambda st: (st < V.shape[0] - 5).any(axis=1)) if seed == 2 else None  # a scene filter
    lst = StencilList(lo, hi, E, F, radius, keep)
    for x in _states(rng, lo, hi, 6):
        assert lst.covers(x)
        st, kinds = lst.stencils_at(x)
        f_st, f_kinds = _fresh(x, E, F, radius, keep)
        assert st.dtype == f_st.dtype and kinds.dtype == f_kinds.dtype
        np.testing.assert_array_equal(st, f_st)
        np.testing.assert_array_equal(kinds, f_kinds)
        assert st.shape[0] <= len(lst)
    assert len(lst) > 0
    wide = StencilList(lo, hi, E, F, 1.0, keep)  # every pair within the radius: the list's own arrays
    st, kinds = wide.stencils_at(V)
    assert st is wide.stencils and kinds is wide.kinds
    f_st, f_kinds = _fresh(V, E, F, 1.0, keep)
    np.testing.assert_array_equal(st, f_st)
    np.testing.assert_array_equal(kinds, f_kinds)


def test_a_state_outside_its_region_is_not_covered():
    rng = np.random.default_rng(3)
    V, E = _rods(rng)
    lo, hi = region([V, V + 0.01])
    lst = StencilList(lo, hi, *scene_arrays(V, E, None)[1:], 0.02)
    for k in range(3):
        y = hi.copy()
        y[4, k] = np.nextafter(hi[4, k], np.inf)  # one ulp beyond
        assert not lst.covers(y)
        z = lo.copy()
        z[7, k] = np.nextafter(lo[7, k], -np.inf)
        assert not lst.covers(z)
    y = hi.copy()
    y[0, 0] = np.nan
    assert not lst.covers(y)
    assert contains((lo, hi), region([V + 0.005])) and not contains((lo, hi), region([V - 0.005]))


def test_a_region_is_padded_past_an_arrival_rounded_beyond_its_target():
    """``x + (y - x)`` can round an ulp past ``y``: the region still holds it."""
    x = np.array([[0.1, 0.7, 1e5], [-3.3, 2.0 / 3.0, 0.0]])
    y = np.array([[0.3, -0.1, 1e5 + 0.1], [-3.2999999, 0.1, 1e-9]])
    lo, hi = region([x, y])
    assert ((lo <= x + (y - x)) & (x + (y - x) <= hi)).all()
    assert (lo < np.minimum(x, y)).all() and (hi > np.maximum(x, y)).all()


@pytest.fixture(scope="module")
def stack():
    seq = read_sequence(str(SAMPLES / "falling_stack.h5"))
    return dataclasses.replace(seq, positions=np.asarray(seq.positions[18:23], dtype=np.float64))


def test_planar_replays_count_the_same_from_lists(stack, monkeypatch):
    """The falling stack's dense contact (layers resting on each other and on the ground),
    planar, both radius rules: every replay's passes, iterations and truncated vertices
    with the lists, as with a fresh query at every pass; and the lists answered."""
    P = stack.positions
    dhat = resolve_dhat(None, stack.contact_radius, stack.thickness)
    obstacles = tuple(stack.obstacles)

    def replays(after):
        monkeypatch.setattr(client_mod, "STENCIL_LIST_AFTER", after)
        q = ClientQuery(P[0], stack.edges, stack.faces, obstacles)
        out = []
        for s in (3,):
            x, x_pred = P[s], 2 * P[s] - P[s - 1]
            for rule in ("step", "own"):
                for y in (P[s + 1], 0.5 * (x + P[s + 1])):
                    r = replay_step(x, x, x_pred, y, edges=stack.edges, faces=stack.faces, dhat=dhat,
                                    thickness=stack.thickness, truncation="planar", radius=rule, client="own",
                                    query=q, obstacles=obstacles, frame=s, max_iter=4)
                    out.append((r["passes"], r["iterations"], r["n_truncated"], r["converged"]))
        return out, q.info

    fresh, info0 = replays(10**9)
    listed, info = replays(2)
    assert listed == fresh
    assert info0["listed"] == 0 and info["listed"] > 0 and info["lists"] > 0
    assert max(p for p, *_ in fresh) > 3  # replays long enough for a list to answer


def test_stencils_of_still_vertices_are_skipped_without_a_change():
    """A stencil none of whose vertices moves more than a quarter of the parallel
    threshold per component changes no ratio: the ratios with the skip equal those
    computed over every stencil (zero, tiny, NaN and large moves mixed)."""
    rng = np.random.default_rng(11)
    V, F0 = _layers(rng, n=7, layers=3, gap=0.01)
    _, E, F = scene_arrays(V, None, F0)
    st, kinds = candidate_stencils(V, E, F, 0.03)
    dx = rng.normal(0, 0.005, V.shape)
    pick = rng.random(V.shape[0])
    dx[pick < 0.4] = 0.0
    dx[(pick >= 0.4) & (pick < 0.6)] = rng.uniform(-0.24, 0.24, (np.count_nonzero((pick >= 0.4) & (pick < 0.6)), 3)) \
        * PLANAR_PARALLEL_EPS
    dx[(pick >= 0.6) & (pick < 0.62), 1] = np.nan
    moving = _moving(dx)
    assert 0 < np.count_nonzero(moving) < V.shape[0]
    runs = []
    for m in (moving, np.ones(V.shape[0], dtype=bool)):
        partial = np.ones((3, V.shape[0]))
        _planar_ratios(st.shape[0], V, dx, m, st, kinds, 0.9, partial)
        runs.append(partial.min(axis=0))
    np.testing.assert_array_equal(runs[0], runs[1])
    assert (runs[0] < 1.0).any()
    out, n = planar_filter(V, np.nan_to_num(dx), V, 0.05, st, kinds)
    assert n > 0 and np.isfinite(out).all()
