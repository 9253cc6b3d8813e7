"""The ``rigid-repeat`` target: the step's own rigid motion applied again."""

from __future__ import annotations

import numpy as np
import pytest

import penfree
from penfree.core.fit.auto import candidate_maps
from penfree.core.fit.certificate import certify_map
from penfree.core.fit.models import apply_map, fit_moments, fit_rigid_repeat
from penfree.core.pipeline.client_select import corotated_target


def _rotation(axis, theta):
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k)
    Kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(theta) * Kx + (1.0 - np.cos(theta)) * Kx @ Kx


def _frames(x0, R, pivot, v, n=4):
    """Constant angular velocity about `pivot` (R per step) plus a constant velocity `v`."""
    out = [np.asarray(x0, dtype=np.float64)]
    for _ in range(n - 1):
        out.append(pivot + (out[-1] - pivot) @ R.T + v)
    return out


@pytest.mark.parametrize("theta", [1e-3, 0.05, 0.4])
def test_next_frame_of_a_constant_angular_velocity_rotation(theta):
    """T(x) is the next frame to rounding; 2 x - x_prev is off by O(theta^2) of the radius."""
    rng = np.random.default_rng(1)
    x0 = rng.normal(size=(40, 3))
    R = _rotation([1.0, 2.0, 0.5], theta)
    fr = _frames(x0, R, np.array([0.3, -1.0, 2.0]), np.array([0.01, 0.02, -0.03]))
    m = fit_moments(fr[1], fr[2])
    D, u, rank = fit_rigid_repeat(m)
    assert rank == 3
    np.testing.assert_allclose(D + np.eye(3), R, rtol=0, atol=1e-13)
    x_def, _ = apply_map(fr[2], D, u, m.c)
    scale = np.abs(fr[3]).max()
    np.testing.assert_allclose(x_def, fr[3], rtol=0, atol=1e-14 * scale)
    # the constant-velocity target misses the rotation by about theta^2 r
    assert np.abs((2 * fr[2] - fr[1]) - fr[3]).max() > 0.05 * theta ** 2


def test_collinear_points_fall_back_to_the_translation():
    x0 = np.column_stack([np.linspace(0, 1, 5), np.zeros(5), np.zeros(5)])
    fr = _frames(x0, _rotation([0, 0, 1], 0.1), np.zeros(3), np.zeros(3))
    D, u, rank = fit_rigid_repeat(fit_moments(fr[1], fr[2]))
    assert rank < 2 and not D.any()
    np.testing.assert_allclose(u, fit_moments(fr[1], fr[2]).u)


def test_candidate_is_certified_and_only_on_request():
    """With ``repeat``, candidate_maps adds the rotation, certified exactly like the others."""
    rng = np.random.default_rng(2)
    fr = _frames(rng.normal(size=(30, 3)), _rotation([0, 1, 1], 0.2), np.zeros(3), np.zeros(3))
    m = fit_moments(fr[1], fr[2])
    names = [c.name for c in candidate_maps(m)]
    assert "rigid-repeat" not in names
    cand = next(c for c in candidate_maps(m, repeat=True) if c.name == "rigid-repeat")
    assert certify_map(cand.A, 0.0) and penfree.certify(cand.A)
    np.testing.assert_array_equal(cand.D, cand.A - np.eye(3))


def _spinning_squares(axis, theta, lift=0.0):
    """Two unit squares 0.3 apart spinning rigidly about their centre (+ `lift` in z)."""
    side = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    x0 = np.concatenate([side, side + [0, 0, 0.3]]) - [0.5, 0.5, 0.15] + [0, 0, lift]
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4]])
    return _frames(x0, _rotation(axis, theta), np.array([0, 0, lift]), np.zeros(3)), edges


def test_corotated_target():
    """Constant velocity in the co-rotating frame: the next frame of a constant angular
    velocity rotation to rounding, and 2 x - x_prev (to rounding) without rotation."""
    fr, _ = _spinning_squares([0, 1, 1], 0.3)
    m = fit_moments(fr[1], fr[2])
    D, u, _ = fit_rigid_repeat(m)
    y = corotated_target(fr[1], fr[2], np.eye(3) + D, u, m.c)
    np.testing.assert_allclose(y, fr[3], rtol=0, atol=1e-14)
    x_prev = fr[1] + np.random.default_rng(3).normal(0, 0.01, fr[1].shape)
    m = fit_moments(x_prev, fr[2])
    np.testing.assert_allclose(corotated_target(x_prev, fr[2], np.eye(3), m.u, m.c), 2 * fr[2] - x_prev,
                               rtol=0, atol=1e-15)


def test_predeform_replays_it_and_the_gate_holds():
    """A spinning pair of squares: the rigid-repeat map is always replayed by the client
    model; above a floor it may be applied, and whatever is applied passed the step
    gate: with the floor just below, no vertex path crosses it."""
    fr, edges = _spinning_squares([1, 0, 0], 0.3, lift=0.8)
    r = penfree.predeform(fr[1], fr[2], edges=edges, contact_radius=0.01)
    row = next(t for t in r.table if t["name"] == "rigid-repeat")
    assert row["client_passes"] is not None
    assert penfree.certify(r.A)
    np.testing.assert_allclose(fr[2] @ r.A.T + r.b, r.x_def, atol=1e-13)
    # the rotation about x swings the lowest corner down (0.39 -> 0.32): a floor at
    # 0.36 is crossed by T(x) and by the full steps toward the prediction
    floor = penfree.Obstacle("floor", normal=np.array([0.0, 0, 1]), offset=0.36)
    assert fr[2][:, 2].min() > 0.37 and fr[3][:, 2].min() < 0.33
    g = penfree.predeform(fr[1], fr[2], edges=edges, contact_radius=0.01, thickness=1e-3, obstacles=[floor])
    assert g.model != "rigid-repeat"
    assert np.all(g.x_def[:, 2] > 0.36 + 1e-3)
