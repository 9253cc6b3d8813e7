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


@pytest.mark.parametrize("chunk_rows, max_chunks", [(1, 10**9), (7, 3), (10**9, 1)],
                         ids=["one-row-chunks", "three-chunks", "one-chunk"])
@pytest.mark.parametrize("workers", [1, 2, 3])
def test_claimed_chunks_give_the_same_bits(rng, monkeypatch, chunk_rows, max_chunks, workers):
    # The folds' workers (rows of the partial minima) claim chunks of rows as they go:
    # any chunking, any number of workers, 1 or 2 threads, the parallel build even on
    # this small scene: the same bits as the unpruned fold.
    import numba

    V, F = _sheet(14, rng)
    E = edges_from_faces(F)
    want = _unpruned(V, E, F, 0.02, monkeypatch)
    monkeypatch.setattr(bp, "_MIN_CHUNK_ROWS", chunk_rows)
    monkeypatch.setattr(bp, "_MIN_CHUNKS", max_chunks)
    monkeypatch.setattr(bp._min_rows, "min_work", 0)
    monkeypatch.setattr(bp._defer_rows, "min_work", 0)
    monkeypatch.setattr(bp._defer_dense, "min_work", 0)
    monkeypatch.setattr(proximity, "partial_chunks", lambda n: workers)
    old = numba.get_num_threads()
    try:
        for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(threads)
            got = per_vertex_separation(V, E, F, 0.02)
            np.testing.assert_array_equal(got.view(np.uint64), want.view(np.uint64))
    finally:
        numba.set_num_threads(old)


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


def _bundle(rng, strands=6, n=40, spacing=0.012, offset=0.0):
    # Parallel wavy strands (segment chains), closer to each other than an edge length.
    t = np.linspace(0.0, 1.0, n)
    V, E = [], []
    for k in range(strands):
        c = np.array([spacing * (k % 3), spacing * (k // 3), 0.0])
        P = np.stack([0.004 * np.sin(9 * t + k), 0.004 * np.cos(7 * t + k), t], 1) + c
        E.append(np.stack([np.arange(n - 1), np.arange(1, n)], 1) + k * n)
        V.append(P + rng.normal(scale=1e-4, size=P.shape))
    return np.ascontiguousarray(np.concatenate(V) + offset), np.concatenate(E).astype(np.int64)


def _scenes(rng, offset):
    V, F = _sheet(14, rng)
    V = V + offset
    Vb, Eb = _bundle(rng, offset=offset)
    none = np.zeros((0, 3), dtype=np.int64)
    # a lone segment far away and a vertex in no primitive: both at the radius
    Vb = np.concatenate([Vb, Vb[:2] + 5.0, Vb[:1] - 5.0])
    Eb = np.concatenate([Eb, [[Vb.shape[0] - 3, Vb.shape[0] - 2]]])
    # Two tips over a large triangle: a tip's term is its vertex-face distance to the
    # triangle (the edges are far apart), which the triangle's vertices get from the
    # nearer tip (6): the far tip (3) is completed while the triangle's vertices are not.
    Vt = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0.3, 0.3, 0.05], [0.3, 0.5, 0.4], [0.5, 0.3, 0.4],
                   [0.05, 0.05, 0.01], [0.05, 0.25, 0.35], [0.25, 0.05, 0.35]]) + offset
    Ft = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]], dtype=np.int64)
    return {"sheet": (V, edges_from_faces(F), F), "bundle": (Vb, Eb, none), "tip": (Vt, edges_from_faces(Ft), Ft)}


@pytest.mark.parametrize("scene", ["sheet", "bundle", "tip"])
@pytest.mark.parametrize("offset", [0.0, 3e2], ids=["near-origin", "far-from-origin"])
@pytest.mark.parametrize("complete_max", [1.0, proximity.COMPLETE_MAX], ids=["restricted", "default"])
def test_reach_gives_the_same_bits(rng, monkeypatch, scene, offset, complete_max):
    # Below, at and above the largest separation: the vertices at the reach are completed
    # by the restricted folds (every vertex with complete_max = 1) and the result is the
    # query at the full radius, bit for bit.
    monkeypatch.setattr(proximity, "COMPLETE_MAX", complete_max)
    V, E, F = _scenes(rng, offset)[scene]
    radius = 0.2 if scene == "tip" else 0.05
    want = per_vertex_separation(V, E, F, radius)
    top = want[want < radius].max()
    assert (want == radius).any() == (scene != "sheet")  # the lone parts; the tip's far vertices
    for rel in (0.0, 0.3, 0.8, 0.97, 1.0, 1.001, 1.5, 100.0):
        got = per_vertex_separation(V, E, F, radius, reach=rel * top)
        np.testing.assert_array_equal(got.view(np.uint64), want.view(np.uint64), err_msg=f"reach {rel} x max")


def test_reach_completes_only_the_vertices_at_it(rng, monkeypatch):
    V, E, F = _scenes(rng, 0.0)["bundle"]
    radius = 0.05
    want = per_vertex_separation(V, E, F, radius)
    seen = []
    real = proximity._complete

    def spy(x, E_, F_, r, C):
        seen.append(C.copy())
        return real(x, E_, F_, r, C)

    monkeypatch.setattr(proximity, "_complete", spy)
    reach = np.sort(want[want < radius])[-5]  # four vertices (and the lone segment) above
    got = per_vertex_separation(V, E, F, radius, reach=reach)
    np.testing.assert_array_equal(got, want)
    (C,) = seen
    used = referenced_vertices(V.shape[0], F, E)
    np.testing.assert_array_equal(C, used & (want >= reach * (1 - 1e-6)))


def test_separation_query_over_a_moving_scene(rng):
    V, E, F = _scenes(rng, 0.0)["sheet"]
    q = proximity.SeparationQuery(E, F)
    for s in range(6):
        # stretch, turn and jitter: the separations change a little from state to state
        c, si = np.cos(0.2 * s), np.sin(0.2 * s)
        R = np.array([[c, -si, 0], [si, c, 0], [0, 0, 1.0]]) * (1 + 0.05 * s)
        x = np.ascontiguousarray(V @ R.T + rng.normal(scale=2e-4, size=V.shape))
        radius = 0.04 + 0.01 * s
        np.testing.assert_array_equal(q(x, radius), per_vertex_separation(x, E, F, radius))
    assert q.info["queries"] == 6 and q.info["reached"] == 5
    assert q.info["reach"] < 0.04


def test_next_reach():
    d = np.array([0.1, 0.2, 0.3, 1.0])
    assert proximity.next_reach(d, 2.0) == pytest.approx(proximity.REACH_HEADROOM * 1.0)
    assert proximity.next_reach(d, 1.0) is None  # a quarter of the vertices at the radius
    assert proximity.next_reach(np.full(3, 1.0), 1.0) is None
    many = np.concatenate([np.full(999, 0.1), [1.0]])
    assert proximity.next_reach(many, 1.0) == pytest.approx(proximity.REACH_HEADROOM * 0.1)


@pytest.mark.parametrize("reach", [np.inf, np.nan, -1.0])
def test_reach_must_be_finite_and_non_negative(reach):
    x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0.1], [1, 1, 0.1]])
    E = np.array([[0, 1], [2, 3]], dtype=np.int64)
    with pytest.raises(InputError, match="reach must be finite"):
        per_vertex_separation(x, E, np.zeros((0, 3), dtype=np.int64), 1.0, reach=reach)


def _yarn(rng, side=12, n=40, spacing=0.004):
    # A dense bundle: side x side parallel wavy strands whose segments (1/39 long) are
    # several spacings long, like the 64K yarn bundle (boxes fill space across the
    # strands, so per-axis cells scan fewer entries than cubes).
    t = np.linspace(0.0, 1.0, n)
    V, E = [], []
    for k in range(side * side):
        c = np.array([spacing * (k % side), spacing * (k // side), 0.0])
        P = np.stack([0.001 * np.sin(9 * t + k), 0.001 * np.cos(7 * t + k), t], 1) + c
        E.append(np.stack([np.arange(n - 1), np.arange(1, n)], 1) + k * n)
        V.append(P + rng.normal(scale=1e-5, size=P.shape))
    return np.ascontiguousarray(np.concatenate(V)), np.concatenate(E).astype(np.int64)


def _cell_scenes(rng):
    scenes = dict(_scenes(rng, 0.0))
    scenes.update({f"{k}-far": v for k, v in _scenes(rng, 3e2).items()})
    none = np.zeros((0, 3), dtype=np.int64)
    scenes["yarn"] = (*_yarn(rng, side=5, n=20), none)
    # exactly planar (zero extent along z) and collinear (zero extent along y and z)
    u = np.linspace(0.0, 1.0, 9)
    X, Y = np.meshgrid(u, u, indexing="ij")
    Vp = np.ascontiguousarray(np.stack([X, Y, 0 * X], -1).reshape(-1, 3))
    idx = np.arange(81).reshape(9, 9)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    Fp = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)
    scenes["planar"] = (Vp, edges_from_faces(Fp), Fp)
    Vl = np.ascontiguousarray(np.stack([np.linspace(0.0, 1.0, 30), np.zeros(30), np.zeros(30)], 1))
    scenes["collinear"] = (Vl, np.stack([np.arange(29), np.arange(1, 30)], 1).astype(np.int64), none)
    return scenes


@pytest.mark.parametrize("radius", [0.0, 0.01, 0.05, 0.3])
def test_cell_shapes_give_the_same_bits(rng, monkeypatch, radius):
    # The cell shape changes which cells a row scans, never the pairs it finds: every
    # combination of the two folds' shapes gives the unpruned fold's bits.
    for name, (V, E, F) in _cell_scenes(rng).items():
        want = _unpruned(V, E, F, radius, monkeypatch)
        for cells in [(a, b) for a in bp.CELL_SHAPES for b in bp.CELL_SHAPES]:
            got = per_vertex_separation(V, E, F, radius, cells=cells)
            np.testing.assert_array_equal(got.view(np.uint64), want.view(np.uint64), err_msg=f"{name} {cells}")
            top = want[want < radius]
            if top.size:  # at a reach, completed at the radius
                got = per_vertex_separation(V, E, F, radius, reach=0.8 * top.max(), cells=cells)
                np.testing.assert_array_equal(got.view(np.uint64), want.view(np.uint64), err_msg=f"{name} {cells}")


def test_cell_shapes_match_exact_brute_force(rng):
    from fractions import Fraction

    V, E = _yarn(rng, side=3, n=12, spacing=0.03)
    radius = 0.05
    X = [[Fraction(float(c)) for c in row] for row in V]
    best = np.full(len(V), radius ** 2)
    for i in range(len(E)):
        for j in range(i + 1, len(E)):
            if not set(E[i]) & set(E[j]):
                d = float(ee_sq(*(X[v] for v in E[i]), *(X[v] for v in E[j])))
                for v in (*E[i], *E[j]):
                    best[v] = min(best[v], d)
    want = np.minimum(np.sqrt(best), radius)
    for cells in bp.CELL_SHAPES:
        got = per_vertex_separation(V, E, np.zeros((0, 3), dtype=np.int64), radius, cells=(cells, "cube"))
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)


def test_per_axis_cells_are_chosen_where_they_scan_less(rng):
    # A dense bundle at its separations' reach: cubes sized by the long axis hold many
    # strands per cell, per-axis cells a few; a sheet's thin axis gains nothing.
    V, E = _yarn(rng)
    none = np.zeros((0, 3), dtype=np.int64)
    d = per_vertex_separation(V, E, none, 0.05)
    infl = 0.5 * 1.1 * d.max()
    lo, hi = bp._box_arrays(V, V, E, infl)
    cost = {c: bp.scan_cost(bp._Plan(lo, hi, E, lo, hi, E, True, infl, listing=False, cells=c))
            for c in bp.CELL_SHAPES}
    assert cost["axis"] < 0.6 * cost["cube"], cost
    assert bp.choose_cells(V, E, E, infl, True) == "axis"
    assert proximity.separation_cells(V, E, none, 2 * infl) == ("axis", "cube")



def _stack(n, layers, gap, rng):
    """`layers` copies of one `_sheet` layer, `gap` apart along z (its thin axis)."""
    V, F = _sheet(n, rng, lift=gap)
    V1, F1 = V[: n * n], F[: F.shape[0] // 2]
    V = np.concatenate([V1 + [0.0, 0.0, k * gap] for k in range(layers)])
    F = np.concatenate([F1 + k * n * n for k in range(layers)])
    return np.ascontiguousarray(V), F


@pytest.mark.parametrize("layers, gap", [(1, 0.0), (2, 0.01)])
def test_slab_cells_are_chosen_for_sheets(rng, layers, gap):
    # A sheet (or two) at its separations' reach: slabs, cells thick across z (the axis
    # of least span) and smaller along the sheet, hold fewer entries that a row scans
    # in vain than cubes, and visit no more cell layers across it.
    V, F = _stack(30, layers, gap, rng)
    E = edges_from_faces(F)
    infl = 0.5 * 1.5 / 30
    lo, hi = bp._box_arrays(V, V, E, infl)
    plans = {c: bp._Plan(lo, hi, E, lo, hi, E, True, infl, listing=False, cells=c) for c in bp.CELL_SHAPES}
    cost = {c: bp.scan_cost(p) for c, p in plans.items()}
    assert cost["slab"] < 0.8 * cost["cube"], cost
    z = 2 if plans["slab"].perm is None else list(plans["slab"].perm).index(2)  # z's place in the key
    assert plans["slab"].dims[z] <= plans["cube"].dims[z]
    assert proximity.separation_cells(V, E, F, 2 * infl)[0] == "slab"


def test_slab_cells_are_not_chosen_for_a_deep_stack(rng):
    # 24 layers closer than a slab's thickness: a slab's cell holds a patch of every
    # layer, so rows scan more entries than in cubes; per-axis cells scan least.
    V, F = _stack(20, 24, 0.05, rng)
    E = edges_from_faces(F)
    infl = 0.5 * 1.5 / 20
    lo, hi = bp._box_arrays(V, V, E, infl)
    cost = {c: bp.scan_cost(bp._Plan(lo, hi, E, lo, hi, E, True, infl, listing=False, cells=c))
            for c in bp.CELL_SHAPES}
    assert cost["slab"] > cost["cube"] > cost["axis"], cost
    assert proximity.separation_cells(V, E, F, 2 * infl) == ("axis", "axis")


def test_separation_query_chooses_cells_once_per_octave(rng, monkeypatch):
    V, E = _yarn(rng, side=6, n=20)
    none = np.zeros((0, 3), dtype=np.int64)
    calls = []
    real = proximity.separation_cells

    def spy(x, E_, F_, rho):
        calls.append(rho)
        return real(x, E_, F_, rho)

    monkeypatch.setattr(proximity, "separation_cells", spy)
    q = proximity.SeparationQuery(E, none)
    for s, radius in enumerate([0.05, 0.05, 0.06, 0.05, 0.3]):
        x = np.ascontiguousarray(V + 1e-4 * s)
        np.testing.assert_array_equal(q(x, radius), per_vertex_separation(x, E, none, radius))
        assert q.info["cells"] in [(a, "cube") for a in bp.CELL_SHAPES]
    # The first query runs at its radius, the others (translations: the same reach) at
    # the reach, another octave; the larger radius of the last changes no reach.
    assert q.info["reached"] == 4
    assert len(calls) == 2, calls
    assert len({np.frexp(r)[1] for r in calls}) == 2


@pytest.mark.parametrize("cells", ["cube", "slab"])
def test_any_axis_order_gives_the_same_bits(rng, monkeypatch, cells):
    # The grid key's axis order (chosen by the plan, or given: the boxes made in it)
    # changes the layout only: every order folds the unpruned fold's bits, and the fold
    # returns the order it used.
    import itertools

    for name, (V, E, F) in _cell_scenes(rng).items():
        radius = 0.05
        want = _unpruned(V, E, F, radius, monkeypatch)
        Q = np.arange(len(V), dtype=np.int64)[:, None]
        chosen = []
        for axes in [None, *itertools.permutations(range(3))]:
            partial = proximity.start_minima(len(V), radius)
            got_axes = [bp.fold_min_sq(V, E, E, radius / 2, partial, True, cells=cells, axes=axes)]
            if F.shape[0]:
                got_axes.append(bp.fold_min_sq(V, Q, F, radius / 2, partial, False, cells=cells, axes=axes))
            got = proximity.capped_separations(partial, radius)
            np.testing.assert_array_equal(got.view(np.uint64), want.view(np.uint64), err_msg=f"{name} {axes}")
            for a in got_axes:
                assert sorted(a.tolist()) == [0, 1, 2]
                if axes is not None:
                    assert a.tolist() == list(axes)
            chosen.append(got_axes[0].tolist())
        # the plan's own choice is one of the orders, and given it back it is kept
        assert chosen[0] in chosen[1:]


def test_separation_query_keeps_each_octaves_axis_order(rng, monkeypatch):
    # The folds' axis orders of an octave's first query are passed to its later ones
    # (no order chosen, no boxes permuted again); every query gives a fresh one's bits.
    V, F = _sheet(12, rng)
    E = edges_from_faces(F)
    seen = []
    real = bp.fold_min_sq

    def spy(*args, axes=None, **kw):
        seen.append(None if axes is None else list(axes))
        return real(*args, axes=axes, **kw)

    monkeypatch.setattr(proximity, "fold_min_sq", spy)
    q = proximity.SeparationQuery(E, F)
    for s in range(4):
        x = np.ascontiguousarray(V + 1e-4 * s * V[:, ::-1])
        want = per_vertex_separation(x, E, F, 0.3)
        seen.clear()
        np.testing.assert_array_equal(q(x, 0.3), want)
        if s >= 2:  # (the first query runs at the radius, the second is the reach's first)
            assert None not in seen and len(seen) == 2, seen
    assert set(q._axes_by_octave) == {np.frexp(0.3)[1], np.frexp(q.info["reach"])[1]}


def test_plan_rejects_an_unknown_cell_shape():
    lo = np.zeros((2, 3))
    hi = np.ones((2, 3))
    T = np.array([[0, 1], [2, 3]], dtype=np.int64)
    with pytest.raises(ValueError, match="cells must be one of"):
        bp._Plan(lo, hi, T, lo, hi, T, True, 0.0, listing=False, cells="sphere")


def test_box_corners_come_with_the_boxes(rng):
    V, F = _sheet(9, rng)
    E = edges_from_faces(F)
    for T in (E, F, np.arange(len(V))[:, None]):
        lo, hi, corners = bp._box_arrays(V, V + 0.01, T, 0.003, corners=True)
        lo2, hi2 = bp._box_arrays(V, V + 0.01, T, 0.003)
        np.testing.assert_array_equal(lo, lo2)
        np.testing.assert_array_equal(hi, hi2)
        np.testing.assert_array_equal(corners, [lo.min(axis=0), hi.max(axis=0)])
    for bad in (np.nan, np.inf):
        W = V.copy()
        W[5, 1] = bad
        with pytest.raises(InputError, match="NaN or infinite"):
            bp._box_arrays(W, W, E, 0.003, corners=True)
