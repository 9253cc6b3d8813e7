"""The deform driver (issue 10): obstacles, real start states, fallbacks, summary truth.

Every written step is checked against independent oracles: `verify_step` with the
obstacles held at the step's frame (the deform-result reading) and a brute-force
exact test of every vertex against every half-space.
"""

from fractions import Fraction

import numpy as np
import pytest

from penfree.core.fit.certificate import certify
from penfree.core.verify.gate import StepGate, deform_margin, margin_rule
from penfree.core.contact.obstacles import as_verify_obstacles
from penfree.core.pipeline.deform import deform_sequence, required_margin, summarize_steps
from penfree.core.verify.path import verify_step
from penfree.core.pipeline.verification import verify_result
from penfree.formats.result import DeformResult

from _geom import rot
from _scenes import box_mesh, floor_half_space, floor_mesh, grid_faces, landing_sheet, scene, sheet


def _half_space_oracle(x, ob, thickness):
    """Exact, vertex by vertex: n . x - offset >= thickness |n| (> 0 at thickness 0)."""
    n = [Fraction(float(c)) for c in ob.normal]
    norm = float(np.linalg.norm(ob.normal))
    for p in np.asarray(x, dtype=np.float64):
        s = sum(a * Fraction(float(b)) for a, b in zip(n, p)) - Fraction(float(ob.offset))
        if thickness == 0 and not s > 0 or thickness > 0 and not s >= Fraction(thickness * norm):
            return False
    return True


def _check_written(seq, out, thickness=None):
    """Every written step: path verified with obstacles at frame s; half-spaces by brute force."""
    h = seq.thickness if thickness is None else thickness
    st = out.steps
    for k, s in enumerate(st["frame"]):
        x, x_def = seq.positions[s], st["deformed"][k]
        obs, names = as_verify_obstacles(seq.obstacles, s, s)
        r = verify_step(x, x_def, edges=seq.edges, faces=seq.faces, thickness=h, obstacles=obs,
                        obstacle_names=names, pre_existing=True)
        assert r.ok, (s, r.pairs)
        for ob in seq.obstacles:
            if ob.is_half_space and _half_space_oracle(x, ob, h):
                assert _half_space_oracle(x_def, ob, h), (s, ob.name)
        if np.isfinite(st["A"][k]).all():
            assert certify(st["A"][k], st["margin_required"][k])


def _nontrivial(out):
    return [str(m) for m in out.steps["model"] if str(m) not in ("none",)]


@pytest.mark.parametrize("model", ["affine", "auto"])
@pytest.mark.parametrize("floor", ["mesh", "half-space"])
def test_cloth_landing_on_floor(model, floor):
    """cloth-landing-on-floor-mesh / cloth-landing-on-half-space."""
    pos, F = landing_sheet()
    ob = floor_mesh() if floor == "mesh" else floor_half_space()
    seq = scene(pos, faces=F, obstacles=[ob])
    out = deform_sequence(seq, model=model)
    _check_written(seq, out)
    assert _nontrivial(out), out.steps["model"]
    # a step that starts half landed still moves (a shortened step of the preferred map)
    landed = [(pos[s, :, 2] < 2e-3).any() for s in out.steps["frame"]]
    assert any(m != "none" for m, h in zip(out.steps["model"].tolist(), landed) if h), out.steps["model"]
    assert summarize_steps(out.steps)["all_certified"]
    # Without the obstacle the same fits would go through the floor on the landed steps.
    free = deform_sequence(scene(pos, faces=F), model=model)
    assert any(free.steps["deformed"][k][:, 2].min() <= 0 for k in range(len(free.steps["frame"])))


def test_cloth_on_box_edge():
    """cloth-on-box-edge: a sheet resting on a box top, its free end falling past the edge."""
    n, T = 9, 6
    u, v = sheet(n)
    frames = []
    for t in range(T):
        over = np.maximum(u - 0.5, 0.0)  # beyond the box edge at u = 0.5
        z = 0.201 - over * (0.2 + 0.08 * t)
        frames.append(np.stack([u - 0.01 * over * t, v, z], axis=1))
    seq = scene(np.array(frames), faces=grid_faces(n), obstacles=[box_mesh([-0.5, -0.5, -0.2], [0.5, 1.5, 0.2])])
    for model in ("affine", "auto"):
        out = deform_sequence(seq, model=model)
        _check_written(seq, out)


def test_cable_pile_on_ground():
    """cable-pile-on-ground: segments resting on and falling onto a half-space."""
    rng = np.random.default_rng(3)
    rods, E, k = [], [], 0
    for c in range(6):
        m = 12
        base = np.stack([np.linspace(0, 1, m), np.full(m, 0.1 * c), np.full(m, 0.002 + 0.02 * c)], axis=1)
        rods.append(base)
        E += [[k + i, k + i + 1] for i in range(m - 1)]
        k += m
    x0 = np.concatenate(rods)
    frames = [x0 + [0, 0, 0]]
    vel = np.where(x0[:, 2:] > 0.01, -0.012, 0.0) * [0, 0, 1] + rng.normal(0, 1e-4, x0.shape) * [1, 1, 0]
    for t in range(1, 6):
        nxt = frames[-1] + vel
        nxt[:, 2] = np.maximum(nxt[:, 2], 0.002)
        frames.append(nxt)
    seq = scene(np.array(frames), edges=np.array(E), obstacles=[floor_half_space()], thickness=5e-4)
    for model in ("affine", "auto", "per-component"):
        out = deform_sequence(seq, model=model)
        _check_written(seq, out)


def test_kinematic_obstacle_moving_in():
    """kinematic-obstacle-moving-in: a plate sweeping towards a falling sheet; held at frame s."""
    pos, F = landing_sheet(n=8, T=6, h0=0.5, tilt=0.0)
    T = pos.shape[0]
    plate = np.array([[-1, -1, 0.0], [2, -1, 0.0], [2, 2, 0.0], [-1, 2, 0.0]])
    P = np.array([plate + [0, 0, 0.05 * t + 0.3] for t in range(T)])  # rising towards the sheet
    ob = floor_mesh()
    ob.positions, ob.name = P, "plate"
    seq = scene(pos, faces=F, obstacles=[ob])
    out = deform_sequence(seq, model="affine")
    _check_written(seq, out)


@pytest.mark.parametrize("thickness_share", [0.0, 1.0])
def test_start_inside_contact_radius(thickness_share):
    """start-inside-contact-radius: two layers resting at 0.4 r, turning and stretching together."""
    r = 0.01
    n = 6
    u, v = sheet(n, 0.5)
    F = grid_faces(n)
    lower = np.stack([u, v, np.zeros_like(u)], axis=1)
    base = np.concatenate([lower, lower + [0, 0, 0.4 * r]])
    FF = np.concatenate([F, F + len(u)])
    A = rot([0, 0, 1], 2.0) @ np.diag([1.01, 1.0, 1.0])
    frames = [base @ np.linalg.matrix_power(A, t).T for t in range(4)]
    seq = scene(np.array(frames), faces=FF, contact_radius=r, thickness=thickness_share * r)
    out = deform_sequence(seq, model="affine")
    models = set(out.steps["model"].tolist())
    assert models == {"affine"}, models
    assert summarize_steps(out.steps)["all_certified"]
    _check_written(seq, out)


def test_pre_existing_crossing():
    """pre-existing-crossing: an edge already through a face; the path keeps it as it was."""
    tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    rod = np.array([[0.2, 0.2, -0.3], [0.2, 0.2, 0.3], [0.2, 0.2, 0.9]])
    x0 = np.concatenate([tri, rod])
    A = rot([1, 1, 0.3], 3.0)
    frames = np.array([x0 @ np.linalg.matrix_power(A, t).T + [0.01 * t, 0, 0] for t in range(4)])
    seq = scene(frames, faces=np.array([[0, 1, 2]]), edges=np.array([[3, 4], [4, 5]]))
    out = deform_sequence(seq, model="affine", check_start=True)
    assert set(out.steps["model"].tolist()) == {"affine"}
    assert (out.steps["start_intersections"] > 0).all()
    assert summarize_steps(out.steps)["steps_started_dirty"] == len(out.steps["frame"])
    res = DeformResult(sequence=seq, steps=out.steps, origin="mem")
    for k, s in enumerate(out.steps["frame"]):
        r = verify_step(seq.positions[s], out.steps["deformed"][k], edges=seq.edges, faces=seq.faces,
                        pre_existing=True)
        assert r.ok and r.n_pre_existing > 0
        raw = verify_step(seq.positions[s], out.steps["deformed"][k], edges=seq.edges, faces=seq.faces)
        assert not raw.ok  # the recording itself is judged for raw sequences
    for mode in ("ccd", "auto"):
        rep = verify_result(res, mode=mode)
        assert rep.ok and rep.n_started_dirty == len(out.steps["frame"])
        assert not verify_result(res, mode=mode, strict=True).ok


def test_pulling_through_a_crossing_is_caught():
    """The pre-existing reading is no loophole: sliding the crossing edge off the face fails."""
    tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    rod = np.array([[0.2, 0.2, -0.3], [0.2, 0.2, 0.3]])
    x0 = np.concatenate([tri, rod])
    x1 = x0.copy()
    x1[3:] += [2.0, 0, 0]
    r = verify_step(x0, x1, edges=[[3, 4]], faces=[[0, 1, 2]], pre_existing=True)
    assert not r.ok


def test_zero_motion_steps_are_certified():
    """issue 9 finding 6: identical frames (and a pause before motion) are certified."""
    pos, F = landing_sheet(n=5, T=4, h0=0.5)
    still = np.concatenate([np.repeat(pos[:1], 3, axis=0), pos])
    for frames, h in ((still, 0.0), (np.repeat(pos[:1], 4, axis=0), 0.0), (still, 0.01)):
        out = deform_sequence(scene(frames, faces=F, thickness=h), model="auto")
        assert summarize_steps(out.steps)["all_certified"]


def test_start_within_thickness_summary_is_true():
    """A start state inside the thickness: every written map passes its own certificate."""
    n = 5
    u, v = sheet(n, 0.3)
    F = grid_faces(n)
    lower = np.stack([u, v, np.zeros_like(u)], axis=1)
    base = np.concatenate([lower, lower + [0, 0, 0.002]])
    frames = np.array([base + [0.01 * t, 0, 0] for t in range(4)])
    seq = scene(frames, faces=np.concatenate([F, F + len(u)]), thickness=0.005)
    out = deform_sequence(seq, model="affine")
    summary = summarize_steps(out.steps)
    assert summary["all_certified"]
    assert (out.steps["margin_required"] == margin_rule(0.005)).all()
    _check_written(seq, out)


def test_margin_rules():
    """The guarantee's margin (verify, report checks) is 0 at thickness 0; deform's is 0.1
    at every thickness (`test_a_rigid_half_turn_is_not_squashed_onto_a_line`)."""
    assert margin_rule(0.0) == 0.0 and margin_rule(1e-3) == 0.1
    assert deform_margin(0.0) == 0.1 and deform_margin(1e-3) == 0.1
    assert required_margin(0.0) == 0.1 and required_margin(0.0, 0.05) == 0.1
    assert required_margin(1e-3, 0.3) == 0.3 and required_margin(1e-3, 0.01) == 0.1


def test_shortened_step_is_a_prefix_of_the_path():
    from penfree.core.pipeline.strategy import Outcome, StepInput, shortened

    rng = np.random.default_rng(5)
    x = rng.normal(size=(20, 3))
    A = rot([1, 2, 3], 20.0) @ np.diag([1.2, 0.9, 1.0])
    b = np.array([0.1, -0.2, 0.3])
    o = Outcome(A, b, x @ A.T + b, "affine", "none", 0.5, 3, 0.0, [(A, b, None)])
    step = StepInput(1, x, x, x, x, 0.0, 0.0, None)
    for alpha in (0.5, 0.1):
        so = shortened(o, step, alpha)
        np.testing.assert_allclose(so.x_def, x + alpha * (o.x_def - x), atol=1e-14)
        np.testing.assert_allclose(so.x_def, x @ so.A.T + so.b, atol=1e-14)
        assert certify(so.A, 0.0) and so.model == f"affine-short{alpha:g}"


def test_gate_refuses_a_map_through_the_floor_and_falls_back():
    pos, F = landing_sheet()
    seq = scene(pos, faces=F, obstacles=[floor_half_space()])
    s = pos.shape[0] - 1
    gate = StepGate(pos[s], faces=F, obstacles=seq.obstacles, frame=s)
    down = pos[s] - [0, 0, 0.01]
    assert not gate.passes(down, [(np.eye(3), np.array([0, 0, -0.01]), None)])
    assert gate.passes(pos[s].copy(), [(np.eye(3), np.zeros(3), None)])  # doing nothing


def test_trust_region_sees_the_floor():
    """A vertex resting on the floor gets a small bound; auto's predictor sees the same terms."""
    from penfree.core.trust.bounds import trust_region_bounds

    pos, F = landing_sheet()
    x = pos[-1]
    b_free = trust_region_bounds(x, faces=F, query_radius=0.05)
    b_floor = trust_region_bounds(x, faces=F, query_radius=0.05, obstacles=[floor_half_space()])
    b_mesh = trust_region_bounds(x, faces=F, query_radius=0.05, obstacles=[floor_mesh()])
    resting = x[:, 2] < 0.002
    assert resting.any() and (b_floor[resting] <= 0.45 * 1e-3 + 1e-12).all()
    assert (b_free[resting] > 10 * b_floor[resting]).all()
    # The same vertex-plane terms from a floor mesh; its edges add edge-edge terms on top.
    np.testing.assert_allclose(b_mesh[resting], b_floor[resting], rtol=1e-9)
    assert (b_mesh <= b_free + 1e-15).all() and (b_floor <= b_free + 1e-15).all()


def test_gate_checks_near_pairs_the_margin_does_not_cover():
    """Two layers 2h apart squeezed to 0.4h: the certificate at margin 0.1 passes, the
    near-pair CCD refuses; a mild squeeze that keeps h passes (oracle: verify_step)."""
    h = 0.01
    n = 5
    u, v = sheet(n, 0.3)
    F = grid_faces(n)
    lower = np.stack([u, v, np.zeros_like(u)], axis=1)
    x = np.concatenate([lower, lower + [0, 0, 2 * h]])
    FF = np.concatenate([F, F + len(u)])
    gate = StepGate(x, faces=FF, thickness=h)
    for sz, expect in ((0.2, False), (0.8, True)):
        A = np.diag([1.0, 1.0, sz])
        assert certify(A, margin_rule(h))
        x_def = x @ A.T
        ok = verify_step(x, x_def, faces=FF, thickness=h, pre_existing=True).ok
        assert ok == expect
        assert gate.passes(x_def, [(A, np.zeros(3), None)]) == expect


def test_resting_means_clearly_inside_the_thickness():
    """Deform-result reading: a pair at 0.5 h may come closer (not touch); a pair that
    starts at h itself must keep h."""
    h = 0.01
    for start, end, ok in ((0.5 * h, 0.2 * h, True), (0.5 * h, -0.2 * h, False), (h * (1 + 1e-12), 0.5 * h, False)):
        x0 = np.array([[0.0, 0, 0], [1, 0, 0], [0.5, -0.5, start], [0.5, 0.5, start]])
        x1 = x0.copy()
        x1[2:, 2] = end
        r = verify_step(x0, x1, edges=[[0, 1], [2, 3]], thickness=h, pre_existing=True)
        assert r.ok == ok, (start, end, r.pairs)


def test_query_radius_contact_distance():
    """r_q = contact radius + largest predicted move; the contact radius never below the thickness."""
    from penfree.core.trust.stats import compute_stats, contact_distance

    assert contact_distance(0.02, 0.01) == 0.02 and contact_distance(0.0, 0.01) == 0.01
    pos, F = landing_sheet(n=5, T=4)
    frames = np.arange(1, 4)
    disp = np.array([np.linalg.norm(pos[s] - pos[s - 1], axis=1).max() for s in frames])
    for h, r, expect in ((0.01, 0.0, 0.01), (0.01, 0.03, 0.03), (0.0, 0.0, 0.0)):
        st = compute_stats(pos, deformed=pos[frames], frames=frames, faces=F, thickness=h, contact_radius=r)
        np.testing.assert_allclose(st["query_radius"], expect + disp, rtol=1e-12)
