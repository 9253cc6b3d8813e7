"""Every written step of `deform`, judged by an oracle penfree does not share code with:
IPC Toolkit's CCD on every candidate pair of the step's path, each hit confirmed or
cleared by the pair's Euclidean distance along the path, and the half-spaces' signed
distances at both ends.

The scenes are the contact-rich inputs of real recordings: a sheet landing on the
ground (a half-space, a floor mesh), resting on it at, below and above the thickness,
two sheets squeezed together over a box, rods on the ground, a chain of interlocked
links, float32 data and coordinates far from the origin. Obstacles are held at the step's frame (SPEC section 5). A pair that starts
within the thickness is pre-existing and skipped (SPEC section 6).
"""

import importlib.util

import numpy as np
import pytest

from penfree.core.pipeline.deform import deform_sequence
from penfree.core.trust.bounds import scene_arrays
from penfree.sequence import Obstacle

from _geom import rot
from _samples import SAMPLES
from _scenes import box_mesh, chain_links, grid_faces, landing_sheet, rods_on_ground, scene, sheet

pytestmark = pytest.mark.skipif(importlib.util.find_spec("ipctk") is None,
                                reason="ipctk (penfree[ogc]) not installed; make test installs it")

#: Path samples of a flagged pair's distance, then a bounded minimisation around the least.
_SAMPLES = 257


#: Golden-section steps after the samples: the bracket shrinks to 0.618^100 ~ 1e-21 of
#: a sample interval.
_REFINE_STEPS = 100


def _pair_min_distance(c, V0, V1, E, F):
    """The smallest Euclidean distance of candidate `c` along the straight path V0 -> V1:
    the least of `_SAMPLES` samples, refined by golden-section search in the intervals
    beside it. (scipy's bounded Brent stops at ``sqrt(eps) t``: a vertex crossing the
    floor 0.06 a step came out 2e-10 away, above the oracle's touch level.)"""

    def dist(t):
        return float(np.sqrt(c.compute_distance((1.0 - t) * V0 + t * V1, E, F)))

    ts = np.linspace(0.0, 1.0, _SAMPLES)
    d = np.array([dist(t) for t in ts])
    k = int(np.argmin(d))
    a, b = ts[max(k - 1, 0)], ts[min(k + 1, _SAMPLES - 1)]
    g = 0.5 * (np.sqrt(5.0) - 1.0)
    p, q = b - g * (b - a), a + g * (b - a)
    fp, fq = dist(p), dist(q)
    least = min(float(d.min()), fp, fq)
    for _ in range(_REFINE_STEPS):
        if fp <= fq:
            b, q, fq = q, p, fp
            p = b - g * (b - a)
            fp = dist(p)
        else:
            a, p, fp = p, q, fq
            q = a + g * (b - a)
            fq = dist(q)
        least = min(least, fp, fq)
    return least


def _guarded(fn, *args, **kwargs):
    """`fn`'s answer, or a hit where ipctk fails (its additive CCD can exhaust memory on a
    query): ``(True, 0.0)``, which the distance along the path then decides."""
    try:
        return fn(*args, **kwargs)
    except MemoryError:
        return (True, 0.0)


def oracle_violations(seq, s, x0, x1, thickness, first=False):
    """Pairs and vertices of step `s` (x0 -> x1, obstacles at frame s) that start farther
    than `thickness` and come closer along the path: ``[(kind, ids, start, least)]``
    (with `first`, only the first pair of each kind found)."""
    import ipctk

    N = x0.shape[0]
    _, E, F = scene_arrays(seq.positions[0], seq.edges, seq.faces)
    found = []
    V0, V1, Es, Fs = [x0], [x1], [E.astype(np.int32)], [F.astype(np.int32)]
    off = N
    for ob in seq.obstacles:
        if ob.is_half_space:
            n = np.asarray(ob.normal, np.float64) / np.linalg.norm(ob.normal)
            d0, d1 = x0 @ n - ob.offset, x1 @ n - ob.offset
            for v in np.flatnonzero((d0 > thickness) & (d1 < thickness) | (d0 > 0) & (d1 <= 0)):
                found.append(("plane", (int(v),), float(d0[v]), float(d1[v])))
            continue
        P = np.asarray(ob.frame(s), np.float64)
        V0.append(P), V1.append(P)
        if ob.faces is not None and len(ob.faces):
            f = np.asarray(ob.faces, np.int32) + off
            Fs.append(f), Es.append(ipctk.edges(f))
        else:
            Es.append(np.asarray(ob.edges, np.int32) + off)
        off += P.shape[0]
    V0, V1 = np.vstack(V0), np.vstack(V1)
    mesh = ipctk.CollisionMesh(V0, np.vstack(Es), np.vstack(Fs))
    if off > N:  # obstacle-obstacle pairs are not the scene's
        mesh.can_collide = ipctk.make_static_obstacle_filter(N)
    # Two narrow phases, and the distance at the end: ipctk's Tight Inclusion misses
    # nearly parallel edges that start within the thickness in the max-norm and close
    # below it (`test_the_oracle_sees_what_tight_inclusion_misses`); its iterations are
    # capped (it then reports a hit: conservative)
    narrows = (ipctk.TightInclusionCCD(tolerance=1e-6, max_iterations=100_000), ipctk.AdditiveCCD())
    if all(_guarded(ipctk.is_step_collision_free, mesh, V0, V1, min_distance=thickness, narrow_phase_ccd=nc)
           is True for nc in narrows):
        C = None
    else:
        C = ipctk.Candidates()
        C.build(mesh, V0, V1, inflation_radius=thickness)
    ME, MF = mesh.edges, mesh.faces
    for kind, cands in (("ee", C.ee_candidates), ("fv", C.fv_candidates)) if C is not None else ():
        for c in cands:
            if first and found and found[-1][0] == kind:
                break
            d0 = float(np.sqrt(c.compute_distance(V0, ME, MF)))
            if not d0 > thickness:
                continue  # pre-existing: within the thickness at the start
            q0, q1 = c.dof(V0, ME, MF), c.dof(V1, ME, MF)
            if not (np.sqrt(c.compute_distance(V1, ME, MF)) < thickness
                    or any(_guarded(c.ccd, q0, q1, min_distance=thickness, narrow_phase_ccd=nc)[0]
                           for nc in narrows)):
                continue
            # the narrow phases' hits are conservative (Tight Inclusion tests the minimum
            # separation in the max-norm, so it flags pairs up to sqrt(3) thickness
            # apart): the distance along the path decides
            least = _pair_min_distance(c, V0, V1, ME, MF)
            if least < thickness * (1.0 - 1e-9) or least < 1e-10:
                found.append((kind, tuple(int(v) for v in c.vertex_ids(ME, MF)), d0, least))
    return found


def _check_result(seq, model, thickness, frames=None):
    """`deform` of `seq`, every written step judged by the oracle; the steps."""
    out = deform_sequence(seq, model=model, thickness=thickness, frames=frames).steps
    for k, s in enumerate(out["frame"]):
        x0 = np.asarray(seq.positions[s], np.float64)
        x1 = np.asarray(out["deformed"][k], np.float64)
        assert oracle_violations(seq, int(s), x0, x1, thickness) == [], (model, thickness, int(s), out["model"][k])
    return out


def _landing(dtype, origin, rest=1e-3):
    P, F = landing_sheet(n=9, T=6, rest=rest, speed=0.03, tilt=0.3)
    rng = np.random.default_rng(7)
    P = P + rng.normal(0.0, 1e-4, P.shape) * (P[..., 2:3] > rest + 1e-9) + origin
    return P.astype(dtype), F


def _floor(kind, origin):
    if kind == "half-space":
        return Obstacle("ground", normal=np.array([0.0, 0.0, 1.0]), offset=origin)
    P = np.array([[-5.0, -5, 0], [6, -5, 0], [6, 6, 0], [-5, 6, 0]]) + origin
    return Obstacle("floor", positions=P, faces=np.array([[0, 1, 2], [0, 2, 3]]))


@pytest.mark.parametrize("dtype,origin", [(np.float64, 0.0), (np.float32, 0.0), (np.float64, 1e3), (np.float32, 1e3)],
                         ids=["float64", "float32", "far-from-origin", "float32-far-from-origin"])
@pytest.mark.parametrize("floor", ["half-space", "mesh"])
@pytest.mark.parametrize("model", ["auto", "affine"])
def test_landing_sheet_keeps_the_guarantee_for_ipctk(dtype, origin, floor, model):
    """Resting 1e-3 above the ground, at thicknesses below, at and above the rest gap
    (resting vertices then start inside it): no step brings a pair or a vertex closer."""
    P, F = _landing(dtype, origin)
    seq = scene(P, faces=F, obstacles=[_floor(floor, origin)], contact_radius=0.02)
    moved = 0
    for thickness in (0.0, 5e-4, 1e-3, 2e-3):
        out = _check_result(seq, model, thickness)
        moved += int(np.count_nonzero(out["model"] != "none"))
    assert moved > 0  # not vacuous: maps were applied


@pytest.mark.parametrize("floor", ["half-space", "mesh"])
@pytest.mark.parametrize("kind", ["stack", "spin"])
@pytest.mark.parametrize("model", ["auto", "rigid"])
def test_rods_on_the_ground_keep_the_guarantee_for_ipctk(model, kind, floor):
    """Segment scenes against the ground: rods coming down across rods that rest on it, and
    rods falling while they spin and landing (the recording itself sweeps rods through each
    other in the air: pre-existing crossings), at thicknesses 0 and 2e-3 (above some
    resting gaps), in float64 and float32 (a throwaway audit ran 360 such runs, 1,612
    moved steps, with no violation)."""
    P, E = rods_on_ground(kind)
    moved = 0
    for dtype, thickness in ((np.float64, 0.0), (np.float32, 2e-3)):
        seq = scene(P.astype(dtype), edges=E, obstacles=[_floor(floor, 0.0)], thickness=thickness)
        moved += int(np.count_nonzero(_check_result(seq, model, thickness)["model"] != "none"))
    assert moved > 0


@pytest.mark.parametrize("model", ["auto", "per-component"])
def test_interlocked_links_keep_the_guarantee_for_ipctk(model):
    """A swinging chain of closed loops whose links close in on each other where they
    cross (down to 5e-5 apart; the constant-velocity prediction drives links through
    each other on most steps), at thicknesses 0 and 1.5e-3 (above many of those gaps:
    pre-existing), in float64 and float32. `per-component` moves each link by its own map,
    so only the step gate's near-pair check keeps two links apart (a throwaway audit of
    the scene with 3 slides, 2 seeds, a floor mesh or none, 3 thicknesses and 4 models: 288
    runs, 2,395 moved steps, no violation)."""
    P, E = chain_links()
    moved = 0
    for dtype, thickness in ((np.float64, 0.0), (np.float32, 1.5e-3)):
        seq = scene(P.astype(dtype), edges=E, thickness=thickness, contact_radius=2e-3)
        moved += int(np.count_nonzero(_check_result(seq, model, thickness)["model"] != "none"))
    assert moved > 0


@pytest.mark.parametrize("model", ["auto", "affine", "per-component"])
def test_squeezed_sheets_over_a_box_keep_the_guarantee_for_ipctk(model):
    """Two sheets 5e-4 apart pressed together while sinking onto a box and the ground."""
    n, T, gap = 7, 6, 5e-4
    u, v = sheet(n, 0.5)
    rng = np.random.default_rng(3)
    frames = []
    for t in range(T):
        lo = np.stack([u, v, np.full_like(u, 0.1)], 1)
        hi = np.stack([u, v, np.full_like(u, 0.1 + gap * max(0.2, 1 - 0.15 * t))], 1)
        frames.append(np.vstack([lo, hi]) + rng.normal(0, gap * 0.05, (2 * n * n, 3)) + [0.01 * t, 0, -0.005 * t])
    F = np.vstack([grid_faces(n), grid_faces(n) + n * n])
    obstacles = [box_mesh([0.2, 0.2, -0.2], [0.3, 0.3, 0.095]),
                 Obstacle("ground", normal=np.array([0.0, 0, 1]), offset=0.0)]
    seq = scene(np.array(frames), faces=F, obstacles=obstacles, contact_radius=0.01)
    moved = 0
    for thickness in (0.0, 0.5 * gap, gap):
        moved += int(np.count_nonzero(_check_result(seq, model, thickness)["model"] != "none"))
    assert moved > 0


def test_the_oracle_finds_a_path_through_the_floor_and_a_sheet():
    """The oracle can fail: the constant-velocity prediction of a landing step goes
    through the floor mesh, the half-space and, for a sheet falling onto another, the
    other sheet; each is found, and the recorded (safe) step is not."""
    P, F = _landing(np.float64, 0.0)
    s = 4
    x0 = P[s]
    x_pred = 2.0 * P[s] - P[s - 1] - [0.0, 0.0, 0.05]  # pushed down through the ground
    for floor in ("half-space", "mesh"):
        seq = scene(P, faces=F, obstacles=[_floor(floor, 0.0)], contact_radius=0.02)
        kinds = {f[0] for f in oracle_violations(seq, s, x0, x_pred, 0.0, first=True)}
        if floor == "half-space":
            assert kinds == {"plane"}
        else:  # the sheet's vertices through the floor's faces (and its edges past the diagonal)
            assert "fv" in kinds and kinds <= {"fv", "ee"}
        assert oracle_violations(seq, s, x0, P[s + 1], 0.0) == []
    # self contact: a sheet 0.01 above another, moved 0.02 down through it; and at a
    # thickness of 0.005, moved 0.007 down (the gap falls to 0.003)
    n = 5
    u, v = sheet(n)
    two = np.vstack([np.stack([u, v, np.zeros_like(u)], 1), np.stack([u, v, np.full_like(u, 0.01)], 1)])
    F2 = np.vstack([grid_faces(n), grid_faces(n) + n * n])
    seq = scene(np.stack([two, two]), faces=F2)
    for drop, thickness in ((0.02, 0.0), (0.007, 0.005)):
        moved = two.copy()
        moved[n * n:, 2] -= drop
        found = oracle_violations(seq, 0, two, moved, thickness, first=True)
        assert found and {f[0] for f in found} <= {"ee", "fv"}
        assert all(f[3] < thickness or f[3] < 1e-10 for f in found)


def _turn(axis, angle):
    """The rotation by `angle` radians about `axis` (`_geom.rot` takes degrees)."""
    return rot(axis, np.degrees(angle))


def _turning_rods(w, gap, m=12, T=6):
    """Two rods of m vertices: one along x, the other `gap` above it turning `w` rad a
    step about z."""
    s = np.linspace(-0.3, 0.3, m)
    low = np.stack([s, np.zeros(m), np.zeros(m)], 1)
    high = np.stack([s, np.zeros(m), np.full(m, gap)], 1)
    P = np.array([np.vstack([low, high @ _turn([0, 0, 1], w * t).T]) for t in range(T)])
    E = np.array([[i, i + 1] for i in range(m - 1)] + [[m + i, m + i + 1] for i in range(m - 1)])
    return P, E


def _spinning_sheet(w, axis, gap, n=6, T=6):
    """A sheet spinning `w` rad a step about `axis` through its centre, `gap` above another."""
    u, v = sheet(n, 0.4)
    low = np.stack([u - 0.2, v - 0.2, np.zeros_like(u)], 1)
    c = np.array([0.0, 0.0, gap])
    P = np.array([np.vstack([low, low @ _turn(axis, w * t).T + c]) for t in range(T)])
    return P, np.vstack([grid_faces(n), grid_faces(n) + n * n])


def _tumbling_sheet(w, height, n=6, T=6):
    """A sheet tumbling `w` rad a step about a horizontal axis `height` above the ground."""
    u, v = sheet(n, 0.3)
    flat = np.stack([u - 0.15, v - 0.15, np.zeros_like(u)], 1)
    P = np.array([flat @ _turn([1, 0.2, 0], w * t).T + [0.01 * t, 0.0, height] for t in range(T)])
    return P, grid_faces(n)


def test_the_oracle_finds_a_vertex_crossing_the_floor_mesh():
    """The recorded step 1 -> 2 of a sheet tumbling 0.7 rad a step takes two vertices
    through the floor mesh (z 0.046 -> -0.014 and 0.054 -> -0.002). The distance along the
    path must come out below the touch level: scipy's bounded Brent stopped at 2e-10 and
    the oracle saw nothing, where the half-space found both."""
    P, F = _tumbling_sheet(0.7, 0.16)
    found = {}
    for floor in ("half-space", "mesh"):
        seq = scene(P, faces=F, obstacles=[_floor(floor, 0.0)], contact_radius=0.01)
        found[floor] = {f[1][0] for f in oracle_violations(seq, 1, P[1], P[2], 0.0)}
    assert found["half-space"] == found["mesh"] == {24, 30}


def test_a_rigid_half_turn_is_not_squashed_onto_a_line():
    """At step 4 of the turning rods the rigid fit is nearly a half-turn, whose `sym`
    projection at margin 0 is ``A ~ n n^T``: it puts both rods on one line (every pair
    within 4e-13 along the path, which the oracle flags). Margin 0 proves the guarantee
    in exact arithmetic, but deform certifies every map at 0.1, at thickness 0 too."""
    from penfree import fit_step
    from penfree.core.fit.certificate import certify_map

    P, E = _turning_rods(0.7, 1e-3)
    r = fit_step(P[3], P[4], model="rigid", margin=0.0)
    assert np.linalg.svd(r.A, compute_uv=False)[-1] < 1e-9  # the map margin 0 admits
    seq = scene(P, edges=E, contact_radius=0.01)
    out = _check_result(seq, "rigid", 0.0)
    assert out["margin_required"].tolist() == [0.1] * (seq.n_frames - 1)
    for k in range(len(out["frame"])):
        assert certify_map(out["A"][k], 0.1)
        assert np.linalg.svd(out["A"][k], compute_uv=False)[-1] >= 0.1 * (1 - 1e-9)
    assert np.count_nonzero(out["model"] != "none") >= 4


@pytest.mark.parametrize("model", ["auto", "affine", "per-component", "rigid"])
def test_large_rotations_keep_the_guarantee_for_ipctk(model):
    """Half a turn and more per step near contact, at thicknesses 0 and 1.5e-3: a sheet
    spinning 2.5 and 3.1 rad a step 2e-3 above another (about z and a tilted axis), a
    sheet tumbling 2.5 rad a step 0.16 above the ground (half-space and floor mesh), rods
    turning 0.7-2.5 rad a step 1e-3 above each other."""
    scenes = []
    for w, axis in ((2.5, [0, 0, 1]), (3.1, [1, 1, 0.3])):
        P, F = _spinning_sheet(w, axis, 2e-3)
        scenes.append(scene(P, faces=F, contact_radius=0.01))
    for floor in ("half-space", "mesh"):
        P, F = _tumbling_sheet(2.5, 0.16)
        scenes.append(scene(P, faces=F, obstacles=[_floor(floor, 0.0)], contact_radius=0.01))
    for w in (0.7, 1.5, 2.5):
        P, E = _turning_rods(w, 1e-3)
        scenes.append(scene(P, edges=E, contact_radius=0.01))
    moved = 0
    for seq in scenes:
        for thickness in (0.0, 1.5e-3):
            moved += int(np.count_nonzero(_check_result(seq, model, thickness)["model"] != "none"))
    assert moved > 0


@pytest.mark.parametrize("name,frames", [("twisted_cables.h5", (20, 40)), ("twisting_cloth_contact.h5", (26, 30)),
                                         ("carried_stack.h5", (0, 20)), ("cloth_drape_box.h5", (10, 13))])
def test_samples_keep_the_guarantee_for_ipctk(name, frames):
    """Bundled recordings in contact (cables wrapped into a rope, a twisting strip folded
    onto itself, a carried stack, cloth on a box on the ground), `auto` at their
    thickness (half their contact radius) and at 0.9 contact radii, which puts their
    closest pairs (about one contact radius apart) near or inside the thickness."""
    from penfree.formats import read_sequence

    seq = read_sequence(str(SAMPLES / name))
    for thickness in (seq.thickness, 0.9 * seq.contact_radius):
        out = _check_result(seq, "auto", thickness, frames)
        assert np.count_nonzero(out["model"] != "none") > 0


#: Two nearly parallel cable edges (twisted_cables.h5, step 33, pushed sideways) that
#: start 2.246e-3 apart and end 1.989e-3 apart, below a thickness of 1.997e-3; in the
#: max-norm they start 1.79e-3 apart, already within it.
_PARALLEL_T0 = [[-0.002716248156502843, 0.011204931885004044, 0.6646082997322083],
                [-0.0026678163558244705, 0.011603071354329586, 0.6601147055625916],
                [-0.0009270524024032056, 0.009794611483812332, 0.6651420593261719],
                [-0.0008850950980558991, 0.010193250142037868, 0.6606494188308716]]
_PARALLEL_T1 = [[-0.0020135134520813305, 0.01692795347617316, 0.6590797277305055],
                [-0.0019508853911151189, 0.017529708881149707, 0.6543906652014346],
                [-0.0001861959226702925, 0.016103579754475433, 0.6590792596642422],
                [-0.00012033976835070545, 0.01675373141096393, 0.6543429638767273]]
_PARALLEL_THICKNESS = 0.0019970414201183283


def test_the_oracle_sees_what_tight_inclusion_misses():
    """Nearly parallel edges closing below the thickness: ipctk 1.6.1's Tight Inclusion
    reports no collision (nor on twice the motion), its additive CCD and the distances
    do; penfree's `verify_step` flags the pair, as a raw step and as a deform step."""
    import ipctk

    from penfree.core.contact.ccd import ccd_edge_edge
    from penfree.core.verify.path import verify_step
    from oracles import ee_sq

    x0, x1, th = np.array(_PARALLEL_T0), np.array(_PARALLEL_T1), _PARALLEL_THICKNESS
    assert np.sqrt(ee_sq(*x0)) > th > np.sqrt(ee_sq(*x1))
    E = np.array([[0, 1], [2, 3]])
    seq = scene(np.stack([x0, x1]), edges=E)
    assert oracle_violations(seq, 0, x0, x1, th) == [("ee", (0, 1, 2, 3), pytest.approx(np.sqrt(ee_sq(*x0))),
                                                      pytest.approx(np.sqrt(ee_sq(*x1)), rel=1e-6))]
    mesh = ipctk.CollisionMesh(x0, E.astype(np.int32), np.zeros((0, 3), np.int32))
    C = ipctk.Candidates()
    C.build(mesh, x0, x1, inflation_radius=th)
    (c,) = C.ee_candidates
    q0 = c.dof(x0, mesh.edges, mesh.faces)
    for scale in (1.0, 2.0):  # ipctk's Tight Inclusion misses it
        q1 = c.dof(x0 + scale * (x1 - x0), mesh.edges, mesh.faces)
        assert c.ccd(q0, q1, min_distance=th)[0] is False
    assert c.ccd(q0, c.dof(x1, mesh.edges, mesh.faces), min_distance=th, narrow_phase_ccd=ipctk.AdditiveCCD())[0]
    hit, _ = ccd_edge_edge(x0[None], x1[None], th)
    assert hit.tolist() == [True]
    for pre_existing in (False, True):
        r = verify_step(x0, x1, edges=E, thickness=th, pre_existing=pre_existing)
        assert not r.ok and [p[:3] for p in r.pairs] == [("ee", 0, 1)]


@pytest.mark.parametrize("name", ["twisted_cables.h5", "carried_stack.h5", "cloth.h5"])
def test_verify_misses_no_violation_the_oracle_finds(name):
    """Sample steps with a random cluster of vertices pushed off its path (1-6x the
    step's motion), at thickness 0, the file's and 0.9 contact radii: `verify_step` (the
    deform reading) flags every step in which the oracle finds a pair or a vertex
    violating, and some steps violate (the check is not vacuous)."""
    from penfree.core.contact.obstacles import as_verify_obstacles
    from penfree.core.verify.path import verify_step
    from penfree.formats import read_sequence

    seq = read_sequence(str(SAMPLES / name))
    rng = np.random.default_rng(11)
    verdicts = []
    for _ in range(16):
        s = int(rng.integers(1, seq.n_frames - 1))
        x0 = np.asarray(seq.positions[s], np.float64)
        x1 = np.asarray(seq.positions[s + 1], np.float64)
        th = float(rng.choice([0.0, seq.thickness, 0.9 * seq.contact_radius]))
        scale = float(np.quantile(np.linalg.norm(x1 - x0, axis=1), 0.99)) + 1e-3
        r = np.linalg.norm(x0 - x0[int(rng.integers(0, x0.shape[0]))], axis=1)
        w = np.exp(-(r / (rng.uniform(1, 5) * scale)) ** 2)[:, None]
        x1 = x1 + w * rng.normal(0.0, rng.uniform(1.0, 6.0) * scale, 3)
        obstacles, names = as_verify_obstacles(seq.obstacles, s, s)
        ok = verify_step(x0, x1, edges=seq.edges, faces=seq.faces, thickness=th, obstacles=obstacles,
                         obstacle_names=names, pre_existing=True).ok
        found = oracle_violations(seq, s, x0, x1, th, first=True)
        # a false alarm is allowed (SPEC section 6), a miss is not
        assert not (ok and found), (name, s, th, found[:2])
        verdicts.append(bool(found))
    assert any(verdicts)
