"""The deform driver end to end: every written step keeps the guarantee (SPEC sections 5
and 8), checked against the exact certificate and against the independent CCD verifier."""

import numpy as np
import pytest

from penfree.core.fit.certificate import certify_map
from penfree.core.pipeline.deform import deform_sequence, deform_stats, step_indices
from penfree.core.trust.stats import compute_stats
from penfree.core.verify.path import verify_step
from penfree.errors import InputError
from penfree.sequence import Sequence

from _geom import grid, rot, two_sheets


def _moving_sheets(gap, thickness, T=5):
    """Two parallel sheets `gap` apart, turning, stretching and drifting together."""
    V, F = two_sheets(n=4, gap=gap)
    frames = [V @ (rot([0, 0, 1], 2.0 * s) @ np.diag([1 + 0.01 * s, 1.0, 1.0])).T + [0.05 * s, 0, 0.02 * s]
              for s in range(T)]
    return Sequence(positions=np.stack(frames), faces=F, thickness=thickness, origin="mem").validate()


@pytest.mark.parametrize("model", ["affine", "auto", "per-component"])
def test_every_written_step_is_certified_and_verifies(model):
    seq = _moving_sheets(gap=1.0, thickness=0.05)
    out = deform_sequence(seq, model=model).steps
    assert out["frame"].tolist() == [1, 2, 3, 4]
    for k, s in enumerate(out["frame"]):
        x, x_def = seq.positions[s], out["deformed"][k]
        if np.isfinite(out["A"][k]).all():  # one global map: the one gate with its margin
            assert certify_map(out["A"][k], out["margin_required"][k])
            np.testing.assert_allclose(x_def, x @ out["A"][k].T + out["b"][k], rtol=0, atol=1e-12)
        assert verify_step(x, x_def, faces=seq.faces, thickness=seq.thickness).ok
    # the map helps: closer to the constant-velocity prediction than doing nothing
    assert np.all(out["residual_pred_rms"] <= out["baseline_pred_rms"])


def test_start_state_inside_the_thickness_creates_no_intersection():
    # sheets 0.01 apart with a thickness of 0.05: the start state already violates it
    seq = _moving_sheets(gap=0.01, thickness=0.05)
    out = deform_sequence(seq).steps
    for k, s in enumerate(out["frame"]):
        x, x_def = seq.positions[s], out["deformed"][k]
        assert certify_map(out["A"][k], 0.0)
        assert verify_step(x, x_def, faces=seq.faces, thickness=0.0).ok


def test_frames_select_steps():
    seq = _moving_sheets(gap=1.0, thickness=0.0)
    out = deform_sequence(seq, frames=(2, 4)).steps
    assert out["frame"].tolist() == [2, 3]
    assert step_indices(5, (None, None)).tolist() == [1, 2, 3, 4]
    with pytest.raises(InputError, match="selects no step"):
        step_indices(5, (0, 1))


@pytest.mark.parametrize("name", ["thickness", "contact_radius"])
@pytest.mark.parametrize("value", [1e200, -1e-3, float("nan"), "0.1mm"])
def test_distances_outside_the_supported_range_are_refused(name, value):
    """The library holds its distance arguments to the range of a file's attributes:
    1e200 overflowed the squared distances instead of being refused."""
    seq = _moving_sheets(gap=1.0, thickness=0.0)
    with pytest.raises(InputError, match=name):
        deform_sequence(seq, **{name: value})
    if name == "thickness":
        with pytest.raises(InputError, match="thickness"):
            verify_step(seq.positions[0], seq.positions[1], faces=seq.faces, thickness=value)


#: Outward triangles of a box whose corners are listed x fastest, then y, then z.
_BOX_FACES = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4], [2, 6, 3], [3, 6, 7],
                       [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])


@pytest.mark.parametrize("thickness", [0.0, 0.01])
@pytest.mark.parametrize("model", ["affine", "translation", "per-component", "auto"])
def test_a_sheet_touching_an_obstacle_is_not_pushed_through_it(model, thickness):
    """A sheet lying exactly on the top face of a closed box obstacle, falling: its
    pairs with the box touch at the start. Such a pair was excused as pre-existing,
    as a scene pair under one nonsingular map is, and the sheet was written inside the
    box (audit). An obstacle does not move with the map: the step must not go down."""
    from penfree.sequence import Obstacle

    B = np.array([[x, y, z] for z in (-1.0, 0.0) for y in (0.0, 1.0) for x in (0.0, 1.0)])
    BF = _BOX_FACES
    x = np.array([[0.3, 0.3, 0], [0.7, 0.3, 0], [0.7, 0.7, 0], [0.3, 0.7, 0.0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    seq = Sequence(positions=np.stack([x + [0, 0, 0.2], x]), faces=F, thickness=thickness,
                   obstacles=[Obstacle(name="box", positions=B, faces=BF)]).validate()
    x_def = deform_sequence(seq, model=model).steps["deformed"][0]
    assert (x_def[:, 2] >= 0.0).all()  # never into the box (the sheet lies inside its xy range)
    pushed = x - [0, 0, 0.2]  # what was written before
    r = verify_step(x, pushed, faces=F, thickness=thickness, obstacles=[(B, B, BF, None)], pre_existing=True)
    assert not r.ok


@pytest.mark.parametrize("thickness", [0.0, 0.01])
@pytest.mark.parametrize("model", ["affine", "translation", "auto"])
def test_particles_stay_above_a_mesh_floor(model, thickness):
    """A scene without edges or faces (particles) falling onto a mesh obstacle: its
    vertices were in no vertex-face pair with the obstacle (a scene's vertices counted
    only with primitives), so deform wrote them through the floor and verify passed it
    (audit); a half-space in the same place was respected."""
    from penfree.sequence import Obstacle

    tri = np.array([[-5, -5, 0], [5, -5, 0], [0, 5, 0.0]])
    x = np.array([[0, 0, 0.05], [0.5, 0, 0.05], [0, 0.5, 0.05], [0.5, 0.5, 0.05]])
    seq = Sequence(positions=np.stack([x + [0, 0, 0.2], x]), thickness=thickness,
                   obstacles=[Obstacle(name="floor", positions=tri, faces=np.array([[0, 1, 2]]))]).validate()
    x_def = deform_sequence(seq, model=model).steps["deformed"][0]
    assert (x_def[:, 2] >= thickness).all()
    through = verify_step(x, x - [0, 0, 0.2], thickness=thickness, obstacles=[(tri, tri, [[0, 1, 2]], None)])
    assert not through.ok and {p[0] for p in through.pairs} == {"vf:0"} and through.n_violations == 4


def test_auto_moves_a_sheet_with_a_few_vertices_inside_a_collider():
    """A recording with pre-existing crossings: 3 of 100 vertices of a sheet sliding over
    a box sit 0.002 inside its top (within the thickness 0.01). Their zero bounds were
    counted as unbounded for every moving candidate (more than 1% of the vertices), so
    `auto` did nothing on steps a translation takes exactly to the prediction."""
    from penfree.sequence import Obstacle

    B = np.array([[x, y, z] for z in (-1.0, 0.0) for y in (-1.0, 1.0) for x in (-1.0, 1.0)])
    box = Obstacle(name="box", positions=B, faces=_BOX_FACES)
    V, F = grid(10)
    x0 = V * (0.6 / 9) + [-0.3, -0.3, 0.05]
    x0[[22, 45, 67], 2] = -0.002
    frames = np.stack([x0 + [0.02 * s, 0.01 * s, 0.0] for s in range(6)])
    seq = Sequence(positions=frames, faces=F, thickness=0.01, contact_radius=0.1, obstacles=[box]).validate()
    out = deform_sequence(seq, model="auto").steps
    assert "none" not in out["model"].tolist()
    for k, s in enumerate(out["frame"]):
        x, x_def = seq.positions[s], out["deformed"][k]
        np.testing.assert_allclose(x_def, 2 * x - seq.positions[s - 1], rtol=0, atol=1e-12)
        assert verify_step(x, x_def, faces=F, thickness=0.01, obstacles=[(B, B, box.faces, None)],
                           pre_existing=True).ok


def _falling_sheet(ground):
    """A 10 x 10 sheet falling 0.03 a step toward the ground z = 0 from 0.095 (contact
    radius 0.02, thickness 0.005), the ground recorded as a half-space or not."""
    from penfree.sequence import Obstacle

    V, F = grid(10)
    x0 = V * (0.5 / 9) + [-0.25, -0.25, 0.095]
    frames = np.stack([x0 - [0.0, 0.0, 0.03 * s] for s in range(4)])
    obstacles = [Obstacle(name="ground", normal=np.array([0.0, 0.0, 1.0]), offset=0.0)] if ground else []
    return Sequence(positions=frames, faces=F, thickness=0.005, contact_radius=0.02, obstacles=obstacles).validate()


@pytest.mark.parametrize("client", [False, True], ids=["static", "client-model"])
def test_auto_stops_a_landing_at_the_contact_radius_of_a_recorded_ground(client):
    """Step 2 predicts the sheet at z = 0.005 (the thickness: the gate allows it); a
    solver holds it at the contact radius 0.02. `auto` predicted its passes toward the
    prediction and took the sheet down to 0.005, from where the real client must climb
    back with tiny trust regions (the falling stack: +18-20% ipctk passes). It now
    predicts toward the prediction clipped at the contact radius above a recorded
    half-space, and no map of step 2 ends below it. Step 1 (prediction at 0.035, clear
    of the ground) moves to the prediction exactly, as without a ground."""
    from penfree.core.pipeline.client_select import ClientModel

    seq = _falling_sheet(ground=True)
    cm = ClientModel(truncation="isotropic", dhat=0.02, faces=seq.faces, obstacles=tuple(seq.obstacles)) \
        if client else None
    out = deform_sequence(seq, model="auto", client_model=cm).steps
    free = deform_sequence(_falling_sheet(ground=False), model="auto", client_model=None).steps
    k1, k2 = list(out["frame"]).index(1), list(out["frame"]).index(2)
    x1 = seq.positions[1]
    if not client:
        np.testing.assert_array_equal(out["deformed"][k1], free["deformed"][k1])
    np.testing.assert_allclose(out["deformed"][k1], 2 * x1 - seq.positions[0], rtol=0, atol=1e-12)
    assert out["deformed"][k2][:, 2].min() >= 0.02 - 1e-9
    assert free["deformed"][k2][:, 2].min() < 0.01  # without a ground: down to the thickness


def test_landing_prediction_keeps_the_bits_of_rows_it_does_not_clip():
    from penfree.core.pipeline.strategy import landing_prediction
    from penfree.sequence import Obstacle

    rng = np.random.default_rng(3)
    x = rng.uniform(0.0, 1.0, (200, 3)).astype(np.float32)
    x_prev = (x + rng.normal(0, 0.05, x.shape)).astype(np.float32)
    ground = Obstacle(name="ground", normal=np.array([0.0, 0.0, 2.0]), offset=0.1)
    x64 = x.astype(np.float64)
    got = landing_prediction(x_prev, x64, [ground], 0.05)
    y = 2 * x64 - x_prev.astype(np.float64)
    clip = y[:, 2] - 0.1 < np.minimum(0.05, x64[:, 2] - 0.1)
    assert 0 < clip.sum() < len(x) and got.dtype == np.float32
    np.testing.assert_array_equal(got[~clip], x_prev[~clip])
    target = 2 * x64[clip] - got[clip].astype(np.float64)
    np.testing.assert_allclose(target[:, 2], 0.1 + np.minimum(0.05, x64[clip, 2] - 0.1), atol=1e-6)
    np.testing.assert_allclose(target[:, :2], y[clip, :2], atol=1e-6)
    assert landing_prediction(x_prev, x64, [], 0.05) is x_prev
    far = Obstacle(name="ground", normal=np.array([0.0, 0.0, 1.0]), offset=-10.0)
    assert landing_prediction(x_prev, x64, [far], 0.05) is x_prev


def _orient(P, v, f):
    """Exact sign-carrying volume of vertex v over face f (rationals)."""
    from fractions import Fraction

    a, b, c, p = ([Fraction(float(t)) for t in P[i]] for i in (*f, v))
    u, w, d = ([q[i] - a[i] for i in range(3)] for q in (b, c, p))
    n = [u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]]
    return sum(n[i] * d[i] for i in range(3))


@pytest.mark.parametrize("dtype, offset", [(np.float64, 0.0), (np.float32, 1e4)])
@pytest.mark.parametrize("model", ["rigid", "affine", "auto"])
def test_touching_pairs_never_cross_by_rounding(dtype, offset, model):
    """Vertex 3 lies exactly on face 0 and a certified rotation moves the scene. The
    exact map keeps it on the face; the written positions are that map rounded, and in
    8 of 20 motions vertex 3 ended beneath face 0 with its triangle's other vertices
    above (4e-18 deep in float64, 4e-4 in float32 at 1e4), two triangles that only
    touched now crossing (audit). A touching pair may now only stay where it is."""
    ang, axis = 0.3, np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R = np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.25, 0.25, 0], [0.25, 0.25, 1], [0.75, 0.25, 1]]) + offset
    x = x.astype(dtype).astype(np.float64)
    F = np.array([[0, 1, 2], [3, 4, 5]])
    c = x.mean(0)
    assert _orient(x, 3, F[0]) == 0
    for seed in range(20):
        shift = np.random.default_rng(seed).normal(size=3) * 0.1
        x_prev = (x - c) @ np.linalg.inv(R).T + c - shift
        for h in (0.0, 0.01):
            seq = Sequence(positions=np.stack([x_prev, x]).astype(dtype), faces=F, thickness=h).validate()
            x_def = deform_sequence(seq, model=model).steps["deformed"][0].astype(np.float64)
            assert _orient(x_def, 3, F[0]) >= 0 or (x_def[[0, 1, 2, 3]] == x[[0, 1, 2, 3]]).all(), (seed, h)
            assert verify_step(x, x_def, faces=F, thickness=h, pre_existing=True).ok, (seed, h)


def test_deform_stats_defaults_to_the_sequence_values():
    seq = _moving_sheets(gap=1.0, thickness=0.05)
    steps = deform_sequence(seq, model="affine").steps
    calls = []
    st = deform_stats(seq, steps, progress=lambda: calls.append(1))
    oracle = compute_stats(positions=seq.positions, frames=steps["frame"], deformed=steps["deformed"],
                           faces=seq.faces, thickness=0.05, contact_radius=seq.contact_radius)
    assert set(st) == set(oracle) and len(calls) == len(steps["frame"])
    for k in oracle:
        np.testing.assert_array_equal(st[k], oracle[k])
    wider = deform_stats(seq, steps, thickness=0.2, contact_radius=0.3)
    oracle = compute_stats(positions=seq.positions, frames=steps["frame"], deformed=steps["deformed"],
                           faces=seq.faces, thickness=0.2, contact_radius=0.3)
    for k in oracle:
        np.testing.assert_array_equal(wider[k], oracle[k])
