"""`gate.deviation_bound` against exact rational arithmetic; the near pairs of a gate
that knows the start separations against the full query."""

from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from penfree.core.contact.proximity import per_vertex_separation
from penfree.core.topology import edges_from_faces
from penfree.core.verify.gate import StepGate, deviation_bound
from penfree.core.verify.pairs import near_pairs

from _scenes import grid_faces, sheet


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


def _pair_sets(pairs):
    return {(k, int(i), int(j)) for k, ij, _ in pairs for i, j in ij}


def test_a_scene_topology_made_once_gives_the_same_pairs_and_verdicts(rng):
    # The gate of every step of a recording takes one `SceneTopology`: the same near
    # pairs (with and without kept vertices; with a free vertex, which disables `keep`)
    # and the same verdicts as gates that read edges and faces themselves.
    from penfree.core.verify.path import SceneTopology

    V, F = _resting_sheets(rng, gap=0.003)
    E = edges_from_faces(F)
    h, R = 0.002, 0.01
    topo = SceneTopology(len(V), None, F)
    assert {tuple(e) for e in np.sort(topo.E, axis=1)} == {tuple(e) for e in np.sort(E, axis=1)}
    d = per_vertex_separation(V, E, F, R)
    for keep in (None, d < R):
        assert _pair_sets(near_pairs(V, None, F, R, keep, topo)) == _pair_sets(near_pairs(V, None, F, R, keep))
    assert topo.all_referenced
    Vf = np.concatenate([V, [[0.55, 0.55, 0.001]]])  # a free vertex: `keep` is ignored
    topo_f = SceneTopology(len(Vf), None, F)
    assert not topo_f.all_referenced
    df = per_vertex_separation(Vf, E, F, R)
    assert _pair_sets(near_pairs(Vf, None, F, R, df < R, topo_f)) == _pair_sets(near_pairs(Vf, None, F, R, df < R))
    verdicts = []
    for s in (1.0, 0.97, 0.6):
        for k in range(3):
            A = np.diag([1.0, 1.0, s]) @ np.linalg.qr(np.eye(3) + 0.01 * k * rng.normal(size=(3, 3)))[0]
            b = 0.01 * k * rng.normal(size=3)
            maps = [(A, b, None)]
            x_def = V @ A.T + b
            verdicts.append(StepGate(V, faces=F, thickness=h).passes(x_def, maps))
            assert StepGate(V, faces=F, thickness=h, topology=topo).passes(x_def, maps) == verdicts[-1]
    assert any(verdicts) and not all(verdicts)


def test_a_scene_topology_of_other_vertices_is_refused(rng):
    from penfree.core.verify.path import SceneTopology
    from penfree.errors import InputError

    V, F = _resting_sheets(rng)
    with pytest.raises(InputError, match="a topology of"):
        near_pairs(V[:-1], None, F[F.max(axis=1) < len(V) - 1], 0.01, topology=SceneTopology(len(V), None, F))
    with pytest.raises(InputError, match="faces"):
        SceneTopology(len(V) - 1, None, F)


def test_separations_and_near_pairs_count_a_free_vertex(rng):
    # A vertex in no primitive still meets faces (SPEC section 7, as ipctk counts such
    # points): a free vertex resting on the lower sheet is in its own separation and in
    # those of the faces under it (it was in none: a bound let it move into the sheet
    # undetected), and the near-pair query restricted by them finds its pairs.
    from penfree.core.contact.distance import indexed_distance

    V, F = _resting_sheets(rng, gap=0.05)
    V = np.concatenate([V, [[0.55, 0.55, 0.001]]])
    E = edges_from_faces(F)
    R = 0.01
    d = per_vertex_separation(V, E, F, R)
    free = np.c_[np.full(len(F), len(V) - 1), F]
    near_faces = F[indexed_distance(V, free, "vf") < R]  # brute force
    assert near_faces.size and d[-1] < R
    np.testing.assert_array_equal(np.flatnonzero(d[:-1] < R), np.unique(near_faces))
    want = _close(near_pairs(V, None, F, R), V, R)
    assert want and all(k == "vf" and i == len(V) - 1 for k, i, _ in want)
    assert _close(near_pairs(V, None, F, R, keep=d < R), V, R) == want


def _vf_crosses(x0, x1, v, f):
    """Exact: does vertex `v` pass through triangle `f` on the straight path x0 -> x1?
    (A sign change of the orientation, bisected to 2^-200, inside the triangle there.)"""
    P = [[[Fraction(float(c)) for c in X[i]] for X in (x0, x1)] for i in (v, *f)]

    def at(t):
        return [[a + t * (b - a) for a, b in zip(*P[k])] for k in range(4)]

    def sub(a, b):
        return [p - q for p, q in zip(a, b)]

    def cross(a, b):
        return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]

    def dot(a, b):
        return sum(p * q for p, q in zip(a, b))

    def orient(t):
        p, a, b, c = at(t)
        return dot(cross(sub(b, a), sub(c, a)), sub(p, a))

    def inside(t):
        p, a, b, c = at(t)
        n = cross(sub(b, a), sub(c, a))
        w0 = dot(cross(sub(b, p), sub(c, p)), n)
        w1 = dot(cross(sub(c, p), sub(a, p)), n)
        return min(w0, w1, dot(n, n) - w0 - w1) >= 0

    lo, hi = Fraction(0), Fraction(1)
    if orient(lo) * orient(hi) > 0:
        return False
    if orient(hi) == 0:
        return inside(hi)
    for _ in range(200):
        mid = (lo + hi) / 2
        if (orient(mid) > 0) == (orient(lo) > 0):
            lo = mid
        else:
            hi = mid
    return inside(lo) or inside(hi)


@pytest.mark.parametrize("dtype, gap", [(np.float64, 1e-17), (np.float32, 1e-8)])
@pytest.mark.parametrize("model", ["affine", "rigid", "auto"])
def test_rounding_of_x_def_never_crosses_at_thickness_0(dtype, gap, model):
    """A vertex `gap` above a face (below the rounding of x_def) under a certified
    rotation: the exact map keeps them apart, its rounded x_def crossed (the gate only
    certified the map at thickness 0). Every written step must keep the vertex above."""
    from penfree.core.pipeline.deform import deform_sequence
    from penfree.core.verify.path import verify_step
    from penfree.core.pipeline.predeform import predeform
    from penfree.sequence import Sequence

    F = np.array([[0, 1, 2]])
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.25, 0.25, gap]]) + [0.395, -0.372, 0.0]
    th = 0.2
    R = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
    x = x.astype(dtype)
    x_prev = (2 * x.astype(np.float64) - x.astype(np.float64) @ R.T).astype(dtype)
    assert verify_step(x, x, faces=F).ok
    seq = Sequence(positions=np.stack([x_prev, x]), faces=F).validate()
    x_def = deform_sequence(seq, model=model).steps["deformed"][0]
    assert not _vf_crosses(x, x_def, 3, (0, 1, 2))
    assert verify_step(x, x_def, faces=F).ok
    if model == "affine":
        r = predeform(x_prev, x, faces=F, contact_radius=0.01)
        assert not _vf_crosses(x, r.x_def, 3, (0, 1, 2))


def test_rounding_of_a_float32_x_def_never_crosses_at_thickness_0():
    """A random float32 scene (found by an adversarial search; tests/data) where auto's
    map, certified, was written rounded to float32 through a face 1.5e-8 away."""
    from penfree.core.pipeline.deform import deform_sequence
    from penfree.core.verify.path import verify_step
    from penfree.sequence import Sequence

    d = np.load(Path(__file__).parents[2] / "data" / "gate_rounding_f32.npz")
    x, F = d["x"], d["F"]
    seq = Sequence(positions=np.stack([d["x_prev"], x]), faces=F).validate()
    x_def = deform_sequence(seq, model="auto").steps["deformed"][0]
    assert x_def.dtype == np.float32
    for v in range(len(x)):
        for f in F:
            if v not in f:
                assert not _vf_crosses(x, x_def, v, tuple(f)), (v, f)
    assert verify_step(x, x_def, faces=F).ok


@pytest.mark.parametrize("case", ["ee", "vf"])
def test_ill_conditioned_pairs_are_not_taken_apart_by_their_computed_distance(case):
    """Nearly parallel rod segments 2e-19 apart (computed: 5e-11) and a vertex 1.2e-18
    over a 1e-6 wide triangle (computed: 1.1e-12), found by an adversarial search
    (tests/data). A computed distance lies above the true one by up to ~sqrt(u) of the
    scale, so neither may prove such a pair apart: deform wrote crossing steps at
    thickness 0, and verify's certificate path passed them."""
    from penfree.core.pipeline.deform import deform_sequence
    from penfree.core.verify.affine import verify_affine_step
    from penfree.core.verify.path import verify_step
    from penfree.sequence import Sequence

    d = np.load(Path(__file__).parents[2] / "data" / f"gate_rounding_{case}.npz")
    topo = {"faces": d["faces"]} if "faces" in d.files else {"edges": d["edges"]}
    x = d["pos"][1]
    bad = verify_step(x, d["x_def"], **topo, pre_existing=True)
    assert not bad.ok  # the step an earlier version wrote crosses (the exact CCD at thickness 0)
    r = verify_affine_step(x, d["x_def"], d["A"], d["b"], **topo)
    assert r is None or not r.ok
    seq = Sequence(positions=d["pos"], **topo).validate()
    for model in ("auto", "translation", "rigid", "affine"):
        x_def = deform_sequence(seq, model=model).steps["deformed"][0]
        assert verify_step(x, x_def, **topo, pre_existing=True).ok, model
        if case == "vf":
            assert not _vf_crosses(x, x_def, 3, (0, 1, 2)), model


@pytest.mark.parametrize("thickness", [0.0, 0.01])
def test_gate_refuses_to_move_a_touching_pair(thickness):
    """The apex of a triangle rests exactly on face 0. Two maps moving the triangles
    apart push the apex up through the face; one map moving both would keep them
    touching, but its written positions are rounded and can cross (`test_deform.py::
    test_touching_pairs_never_cross_by_rounding`). Both were excused as pre-existing;
    a touching pair may now only stay where it is."""
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.25, 0.25, 0], [0.5, 0.1, -1], [0.1, 0.5, -1.0]])
    F = np.array([[0, 1, 2], [3, 4, 5]])
    gate = StepGate(x, faces=F, thickness=thickness)
    lift = np.array([0, 0, 0.3])
    up = x + np.r_[np.zeros((3, 3)), np.tile(lift, (3, 1))]
    assert not gate.passes(up, [(np.eye(3), np.zeros(3), np.arange(3)), (np.eye(3), lift, np.arange(3, 6))])
    assert not gate.passes(x + lift, [(np.eye(3), lift, None)])
    assert gate.passes(x.copy(), [(np.eye(3), np.zeros(3), None)])


@pytest.mark.parametrize("thickness", [0.0, 0.01])
@pytest.mark.parametrize("kind", ["rods", "sheets"])
def test_gate_refuses_two_maps_that_pass_their_objects_through_each_other(thickness, kind):
    """Two objects 0.5 apart, each moved by its own map (a translation: every
    certificate passes), the upper one down through the lower one. No near pair exists
    at the start and no single map's certificate covers a pair that two maps move: the
    gate runs the CCD of the whole path, whatever the strategy that proposed the maps
    checked. Moving both by one map, or only apart, passes."""
    if kind == "rods":
        s = np.linspace(-0.5, 0.5, 6)
        low = np.stack([s, np.zeros(6), np.zeros(6)], 1)
        high = np.stack([np.zeros(6), s, np.full(6, 0.5)], 1)
        topo = {"edges": np.array([[i, i + 1] for i in range(5)] + [[6 + i, 7 + i] for i in range(5)])}
    else:
        u, v = sheet(4)
        low = np.stack([u - 0.5, v - 0.5, np.zeros(16)], 1)
        high = low + [0.05, 0.03, 0.5]
        topo = {"faces": np.vstack([grid_faces(4), grid_faces(4) + 16])}
    x = np.vstack([low, high])
    n = len(low)
    lower, upper = np.arange(n), np.arange(n, 2 * n)
    gate = StepGate(x, thickness=thickness, **topo)
    down, up = np.array([0, 0, -1.0]), np.array([0, 0, 0.2])
    through = x.copy()
    through[upper] += down
    assert not gate.passes(through, [(np.eye(3), np.zeros(3), lower), (np.eye(3), down, upper)])
    apart = x.copy()
    apart[upper] += up
    assert gate.passes(apart, [(np.eye(3), np.zeros(3), lower), (np.eye(3), up, upper)])
    assert gate.passes(x + down, [(np.eye(3), down, None)])


@pytest.mark.parametrize("origin", [0.0, 100.0, 1e3, 1e4])
def test_float32_far_from_the_origin_keeps_its_maps_at_a_thickness(origin):
    """Two sheets 0.01 apart turning and drifting, stored as float32 at `origin`, with a
    thickness of 5e-4: storing x_def rounds it by 4e-6 at 100 and 5e-4 at 1e4, more than
    h / 200. The gate allows the rounding of the dtype (up to h), so up to 1e3 the steps
    keep the maps of the same scene at the origin in float64 (every map was refused
    before, from 100 on), and every written step verifies at the thickness."""
    from penfree.core.pipeline.deform import deform_sequence
    from penfree.core.verify.path import verify_step
    from penfree.sequence import Sequence

    from _geom import rot, two_sheets

    V, F = two_sheets(n=4, gap=0.01)
    frames = np.stack([V @ rot([0, 0, 1], 0.5 * s).T + [0.002 * s, 0, 0.001 * s] for s in range(5)])
    h = 5e-4
    ref = deform_sequence(Sequence(positions=frames, faces=F).validate(), model="affine", thickness=h).steps
    assert set(ref["model"]) == {"affine"}
    P = (frames + origin).astype(np.float32)
    out = deform_sequence(Sequence(positions=P, faces=F).validate(), model="affine", thickness=h).steps
    if origin <= 1e3:  # at 1e4 float32 steps by 1e-3, twice h: some maps round too far
        assert list(out["model"]) == list(ref["model"])
    for k, s in enumerate(out["frame"]):
        assert verify_step(P[s], out["deformed"][k], faces=F, thickness=h, pre_existing=True).ok
    gate = StepGate(P[1], faces=F, thickness=h)
    limit = gate.rounding_limit(P[1].astype(np.float64), np.dtype(np.float32))
    assert limit == max(0.005 * h, min(h, 2.0 * 2.0**-23 * float(np.abs(P[1]).max())))
    assert gate.rounding_limit(P[1].astype(np.float64), np.dtype(np.float64)) == 0.005 * h


def test_gate_refuses_a_rounding_beyond_the_thickness():
    """An x_def farther from its map than the thickness (not a rounding: an edit) fails
    the gate in float32 as in float64, even far from the origin."""
    from _geom import two_sheets

    V, F = two_sheets(n=3, gap=0.01)
    h = 5e-4
    for origin, dtype in ((0.0, np.float64), (1e3, np.float32)):
        x = (V + origin).astype(dtype)
        gate = StepGate(x, faces=F, thickness=h)
        b = np.array([0.0, 0.0, 1e-3])
        moved = (x.astype(np.float64) + b).astype(dtype)
        assert gate.passes(moved, [(np.eye(3), b, None)])
        edited = moved.copy()
        edited[0, 0] += dtype(2 * h)
        assert not gate.passes(edited, [(np.eye(3), b, None)])
