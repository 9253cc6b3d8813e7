"""The client's collision mesh with obstacles (`client_scene`), and replays over it:
brute-force separations without obstacle pairs, the ground as a square, own client against ipctk."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from penfree import read_sequence
from penfree.core.contact.distance import edge_edge_distance, point_triangle_distance
from penfree.core.trust.client import ClientQuery, replay_step
from penfree.core.trust.client_scene import ClientScene
from penfree.core.trust.client_stats import client_counts, resolve_dhat
from penfree.errors import InputError
from penfree.sequence import Obstacle

HAVE_IPCTK = importlib.util.find_spec("ipctk") is not None
needs_ipctk = pytest.mark.skipif(not HAVE_IPCTK, reason="ipctk (penfree[ogc]) not installed; make test installs it")
SAMPLES = Path(__file__).resolve().parents[3] / "samples"
GROUND = Obstacle("ground", normal=np.array([0.0, 0.0, 2.0]), offset=0.0)  # z > 0, a normal of length 2


def _sheet(nx, ny, h, spacing=0.1, origin=(0.0, 0.0)):
    """A flat grid of triangles at height `h`."""
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    x = np.stack([origin[0] + spacing * i.ravel(), origin[1] + spacing * j.ravel(), np.full(i.size, h)], 1)
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return x, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def _box(lo, hi, frames=None):
    """A closed box mesh obstacle (8 vertices, 12 faces); `frames`: (T,) z offsets."""
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], float)
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    P = c if frames is None else np.stack([c + [0, 0, dz] for dz in frames])
    return Obstacle("box", positions=P, faces=F)


def _oracle(X, E, F, n, R):
    """Per-vertex separations over every pair of the whole mesh but pairs of two obstacle
    primitives (ids >= n), adjacent pairs skipped: SPEC section 7 written out."""
    d = np.full(len(X), np.inf)
    for v in range(len(X)):
        for f in F:
            if v in f or (v >= n and (f >= n).all()):
                continue
            dist = point_triangle_distance(X[[v]], X[[f[0]]], X[[f[1]]], X[[f[2]]])[0]
            for w in (v, *f):
                d[w] = min(d[w], dist)
    for a in range(len(E)):
        for b in range(a + 1, len(E)):
            ea, eb = E[a], E[b]
            if set(ea) & set(eb) or ((ea >= n).all() and (eb >= n).all()):
                continue
            dist = edge_edge_distance(X[[ea[0]]], X[[ea[1]]], X[[eb[0]]], X[[eb[1]]])[0]
            for w in (*ea, *eb):
                d[w] = min(d[w], dist)
    return np.minimum(d, R)


def test_topology_follows_the_scene_in_list_order():
    x, F = _sheet(3, 3, 0.05)
    box = _box((1, 1, 0), (2, 2, 1))
    sc = ClientScene(x, None, F, [box, GROUND])
    assert (sc.n, sc.m) == (9, 9 + 8 + 3)
    np.testing.assert_array_equal(sc.F[:len(F)], F)
    np.testing.assert_array_equal(sc.F[len(F):len(F) + 12], box.faces + 9)
    np.testing.assert_array_equal(sc.F[-1:], [[17, 18, 19]])
    assert (sc.E_scene < 9).all() and (sc.E_obstacles >= 9).all() and (sc.F_obstacles >= 9).all()
    assert len(sc.E_obstacles) == 18 + 3  # a closed box's edges, the ground triangle's


@pytest.mark.parametrize("far", [0.0, 1e5], ids=["near-origin", "far-from-origin"])
def test_ground_triangle_distances_are_the_planes(rng, far):
    """Every scene vertex of every state lies over the ground's triangle, more than the
    reach inside its edges: its distance to the triangle is its distance to the plane,
    and the triangle is the same for every state of the replay."""
    x = rng.uniform(-1, 1, (50, 3)) + [far, -far, 0.0]
    x[:, 2] = np.abs(x[:, 2]) + 0.01
    xs = [x + rng.normal(0, 0.3, x.shape), x, x + [3.0, 0, 0], x]
    reach = 0.7
    sc = ClientScene(x, None, None, [GROUND])
    states = sc.states(None, xs, reach, ref=1)
    tri = states[0][50:]
    for S in states:
        np.testing.assert_array_equal(S[50:], tri)
        P = S[:50]
        d = point_triangle_distance(P, *(np.repeat(tri[[k]], 50, 0) for k in range(3)))
        np.testing.assert_allclose(d, np.abs(P[:, 2]), rtol=0, atol=1e-9 * (1 + far))
        for k in range(3):  # each edge of the triangle is farther than the reach from every vertex
            a, b = tri[k], tri[(k + 1) % 3]
            t = np.clip((P - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1)
            assert (np.linalg.norm(P - (a + t[:, None] * (b - a)), axis=1) > reach).all()
    np.testing.assert_allclose(tri[:, 2], 0.0, atol=1e-9 * (1 + far))


def test_kinematic_obstacle_targets_the_next_frame_or_its_last_velocity():
    x, F = _sheet(2, 2, 1.0)
    box = _box((0, 0, -1), (1, 1, 0.5), frames=[0.0, 0.1, 0.3])
    sc = ClientScene(x, None, F, [box])
    for s, want_target in ((1, 0.3), (2, 0.5)):  # frame 2 is the last: 0.3 + (0.3 - 0.1)
        start, target = sc.states(s, [x, x + 1.0], 0.1, n_start=1)
        np.testing.assert_allclose(start[4:], box.frame(s))
        np.testing.assert_allclose(target[4:], box.frame(0) + [0, 0, want_target], atol=1e-15)
    with pytest.raises(InputError, match=r"must be \(4, 3\)"):
        sc.states(1, [x[:3]], 0.1)


@pytest.mark.parametrize("h", [0.02, 0.3], ids=["resting-on-the-box", "above-the-box"])
def test_cross_separations_leave_obstacle_pairs_out(h):
    """The own client's separations over the mesh: the scene's own query and the
    cross terms; a box standing on the ground (touching it) is no contact."""
    x, F = _sheet(4, 4, 1.0 + h, spacing=0.3, origin=(-0.2, -0.2))
    box, R = _box((0, 0, 0), (0.6, 0.6, 1.0)), 0.5
    q = ClientQuery(x, None, F, [box, GROUND])
    X = q.scene.states(0, [x], R)[0]
    got = q.separations(X, R)
    want = _oracle(X, q.E, q.F, len(x), R)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert (got[16:24] > 0).all()  # the box's bottom corners touch the ground: not counted


def test_replay_needs_the_frame_and_the_querys_obstacles():
    x, F = _sheet(3, 3, 0.05)
    with pytest.raises(InputError, match="mesh obstacles need the step's frame"):
        replay_step(x, x, x, x, faces=F, dhat=0.1, client="own", obstacles=[_box((1, 1, 0), (2, 2, 1))])
    r = replay_step(x, x, x, x, faces=F, dhat=0.1, client="own", obstacles=[GROUND])  # a plane has no frames
    assert r["passes"] == 1
    q = ClientQuery(x, None, F)
    with pytest.raises(InputError, match="built for another scene"):
        replay_step(x, x, x, x, faces=F, dhat=0.1, client="own", obstacles=[GROUND], frame=1, query=q)


@pytest.mark.parametrize("client", ["own", pytest.param("ipctk", marks=needs_ipctk)])
@pytest.mark.parametrize("truncation", ["isotropic", "planar"])
def test_the_ground_holds_a_resting_sheet_back(client, truncation):
    """A sheet resting 0.01 over the ground, dhat 0.02: every region's radius is 0.45 of
    R = 0.04 with nothing near, 0.0045 over the ground. A move of 0.01 sideways and
    0.012 down (through the ground) needs one pass without the ground; with it, both
    filters hold it back. Sliding along the ground, and moving down 0.008 (less than
    the gap over 0.9), is held back by the isotropic filter only: the planar one
    truncates motion that would cross its plane, not the rest."""
    x, F = _sheet(5, 5, 0.01)
    kw = dict(faces=F, dhat=0.02, truncation=truncation, client=client)
    down = x + [0.01, 0.0, -0.012]
    free = replay_step(x, x, down, down, **kw)
    held = replay_step(x, x, down, down, obstacles=[GROUND], frame=1, **kw)
    assert (free["passes"], free["converged"]) == (1, True)
    assert held["passes"] >= 2 and held["iterations"] >= 1, held
    if truncation == "isotropic":  # each pass closes 0.45 of the gap: never through
        assert not held["converged"] and held["n_truncated"] == 25, held  # the sheet's vertices only
    # (the planar filter closes 0.9 of the gap a pass; below 1e-10 ipctk's filter skips
    # the pair, and the sheet goes through)
    for move in ([0.015, 0.0, 0.0], [0.01, 0.0, -0.008]):
        y = x + move
        r = replay_step(x, x, y, y, obstacles=[GROUND], frame=1, **kw)
        assert (r["passes"] == 1) == (truncation == "planar"), (move, r)


@needs_ipctk
@pytest.mark.parametrize("rule", ["step", "own"])
def test_own_client_matches_ipctk_with_obstacles_isotropic(rule):
    """cloth_drape_box (a box and the ground): the own client's isotropic replays with
    the obstacles count the passes and iterations of ipctk's, from x and half-way."""
    seq = read_sequence(SAMPLES / "cloth_drape_box.h5")
    P = seq.positions
    dhat = resolve_dhat(None, seq.contact_radius, seq.thickness)
    kw = dict(faces=seq.faces, dhat=dhat, thickness=seq.thickness, truncation="isotropic", radius=rule,
              obstacles=seq.obstacles)
    for s in (6, 30, 52):
        x = P[s].astype(float)
        x_pred = 2 * x - P[s - 1]
        for start in (x, 0.5 * (x + x_pred)):
            a = replay_step(start, x, x_pred, P[s + 1], client="own", frame=s, **kw)
            b = replay_step(start, x, x_pred, P[s + 1], client="ipctk", frame=s, **kw)
            assert (a["passes"], a["iterations"]) == (b["passes"], b["iterations"]), (s, rule)


def test_client_counts_replay_the_obstacles():
    """`client_counts` with the sequence's obstacles is each step's replay with them
    (and differs from the replay without them on this sample)."""
    seq = read_sequence(SAMPLES / "cloth_drape_box.h5")
    P = np.asarray(seq.positions[:34], dtype=np.float64)
    dhat = resolve_dhat(None, seq.contact_radius, seq.thickness)
    frames = np.array([2, 31, 32])  # steps near the box
    kw = dict(faces=seq.faces, dhat=dhat, thickness=seq.thickness, truncations=("isotropic",), radii=("step",),
              client="own")
    with_ob = client_counts(P, P[frames], frames, obstacles=seq.obstacles, **kw)
    without = client_counts(P, P[frames], frames, **kw)
    want = [replay_step(P[s], P[s], 2 * P[s] - P[s - 1], P[s + 1], faces=seq.faces, dhat=dhat,
                        thickness=seq.thickness, client="own", obstacles=seq.obstacles, frame=s)["passes"]
            for s in frames]
    np.testing.assert_array_equal(with_ob["passes_isotropic_baseline"], want)
    assert with_ob["passes_isotropic_baseline"].sum() > without["passes_isotropic_baseline"].sum()


@pytest.fixture(scope="module")
def crossed_cables():
    """twisted_cables with the ground 0.5 dhat below its lowest point and a wall (one
    large triangle) through the middle of the cables: pairs at distance 0, within the
    thickness, as in a recording with pre-existing crossings."""
    seq = read_sequence(SAMPLES / "twisted_cables.h5")
    P = np.asarray(seq.positions[:8], dtype=np.float64)
    dhat = resolve_dhat(None, seq.contact_radius, seq.thickness)
    lo, hi = P.reshape(-1, 3).min(0), P.reshape(-1, 3).max(0)
    mid = 0.5 * (lo[0] + hi[0])
    wall = Obstacle("wall", positions=np.array([[mid, lo[1] - 1, lo[2] - 1], [mid, hi[1] + 1, lo[2] - 1],
                                                [mid, lo[1] - 1, hi[2] + 1]]), faces=np.array([[0, 1, 2]]))
    ground = Obstacle("ground", normal=np.array([0.0, 0.0, 1.0]), offset=lo[2] - 0.5 * dhat)
    return seq, P, dhat, [ground, wall]


@needs_ipctk
def test_crossings_give_ipctk_no_negative_radii(crossed_cables):
    """ipctk 1.6.1 gives a vertex with a pair within the thickness the radius
    0.45 (d - thickness) < 0 (its warm start would move it backwards); the replay's
    ipctk client clamps it at 0, the OGC bound (SPEC section 7) the own client has."""
    import ipctk

    from penfree.core.trust.client import ClientQuery, make_client

    seq, P, dhat, obstacles = crossed_cables
    x = P[1]
    q = ClientQuery(x, seq.edges, None, obstacles)
    X = q.scene.states(1, [x], 0.1)[0]
    mesh = ipctk.CollisionMesh(np.asfortranarray(X), np.asfortranarray(q.E, dtype=np.int32),
                               np.asfortranarray(q.F, dtype=np.int32))
    mesh.can_collide = ipctk.make_static_obstacle_filter(len(x))
    tr = ipctk.ogc.TrustRegion(dhat)
    tr.update(mesh, np.asfortranarray(X), ipctk.NormalCollisions(), seq.thickness)
    raw = np.asarray(tr.trust_region_radii)
    assert (raw < 0).any()
    cl = make_client("ipctk", X, q.E, q.F, dhat, seq.thickness, "isotropic", n_dynamic=len(x))
    cl.set_radius(2 * dhat)
    assert cl.update(X)  # clamped
    np.testing.assert_array_equal(np.asarray(cl.tr.trust_region_radii), np.maximum(raw, 0.0))
    moved, passes = cl.warm_start(X, X + [1e-4, 0.0, 0.0])
    assert np.isfinite(moved).all() and passes == 2
    np.testing.assert_array_equal(moved[raw[:len(X)] <= 0], X[raw[:len(X)] <= 0])  # radius 0: held still
    own = make_client("own", X, q.E, q.F, dhat, seq.thickness, "isotropic", q)
    own.set_radius(2 * dhat)
    own.update(X)
    np.testing.assert_allclose(own.radii, np.maximum(raw, 0.0), rtol=0, atol=1e-15)


@needs_ipctk
@pytest.mark.parametrize("rule", ["step", "own"])
@pytest.mark.parametrize("truncation", ["isotropic", "planar"])
def test_own_client_matches_ipctk_through_crossings(crossed_cables, truncation, rule):
    """With radii of 0 at the crossings the own client still counts ipctk's passes and
    iterations (a vertex of radius 0 stays in the warm start, and at its region's centre
    moves unhindered in ipctk's isotropic filter, whose ratio is 0 / 0 there)."""
    seq, P, dhat, obstacles = crossed_cables
    kw = dict(edges=seq.edges, dhat=dhat, thickness=seq.thickness, truncation=truncation, radius=rule,
              obstacles=obstacles)
    for s in (1, 4, 6):
        x_pred = 2 * P[s] - P[s - 1]
        a = replay_step(P[s], P[s], x_pred, P[s + 1], client="own", frame=s, **kw)
        b = replay_step(P[s], P[s], x_pred, P[s + 1], client="ipctk", frame=s, **kw)
        assert (a["passes"], a["iterations"]) == (b["passes"], b["iterations"]), s
