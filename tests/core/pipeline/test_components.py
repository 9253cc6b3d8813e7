"""Per-component maps: each component certified, components whose paths meet merged."""

import numpy as np
import pytest

from penfree.core.fit.certificate import certify
from penfree.core.pipeline.components import component_labels, per_component_step
from penfree.core.verify.gate import StepGate
from penfree.core.verify.path import verify_step


def two_rods(n=20, gap=0.2, dz=0.0):
    """Two parallel straight rods along x, `gap` apart in y and `dz` in z."""
    t = np.linspace(0.0, 1.0, n)
    a = np.stack([t, np.zeros(n), np.zeros(n)], axis=1)
    b = np.stack([t, np.full(n, gap), np.full(n, dz)], axis=1)
    E = np.array([[i, i + 1] for i in range(n - 1)] + [[n + i, n + i + 1] for i in range(n - 1)])
    return np.concatenate([a, b]), E


def rot_z(deg):
    th = np.deg2rad(deg)
    return np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])


def test_labels_from_topology_and_dataset():
    V, E = two_rods(5)
    np.testing.assert_array_equal(component_labels(10, edges=E), [0] * 5 + [1] * 5)
    F = np.array([[0, 1, 2], [3, 4, 5]])
    np.testing.assert_array_equal(component_labels(7, faces=F), [0, 0, 0, 1, 1, 1, 2])
    np.testing.assert_array_equal(component_labels(4, components=[7, 7, -3, 7]), [1, 1, 0, 1])


def test_separate_affine_motions_are_recovered_per_component():
    # Rod a translates, rod b rotates about its own centre: each component's map is
    # exact, no path meets another, one CCD round.
    V, E = two_rods(dz=0.02)
    labels = component_labels(len(V), edges=E)
    x_pred = V.copy()
    x_pred[:20] += [0.0, -0.01, 0.0]
    cb = V[20:].mean(axis=0)
    x_pred[20:] = cb + (V[20:] - cb) @ rot_z(3.0).T
    x_prev = 2 * V - x_pred
    cs = per_component_step(x_prev, V, labels, edges=E)
    assert len(np.unique(cs.group)) == 2 and cs.rounds == 1
    np.testing.assert_allclose(cs.x_def, x_pred, rtol=0, atol=1e-12)
    for A in cs.A:
        assert certify(A, 0.0)
    assert verify_step(V, cs.x_def, edges=E).ok


def test_crossing_component_paths_are_merged():
    # Each rod translates rigidly, toward and through the other: each component's map
    # alone is exact and certified, but the two straight paths cross. The CCD must
    # catch it and the shared map must be safe.
    V, E = two_rods(gap=0.2)
    labels = component_labels(len(V), edges=E)
    x_pred = V.copy()
    x_pred[:20] += [0.0, 0.3, 0.0]   # rod a passes y = 0.2 where rod b is
    x_pred[20:] += [0.0, -0.3, 0.0]
    x_prev = 2 * V - x_pred
    res_split = verify_step(V, x_pred, edges=E)
    assert not res_split.ok  # the per-component targets themselves would collide
    cs = per_component_step(x_prev, V, labels, edges=E)
    assert len(np.unique(cs.group)) == 1 and cs.rounds == 2
    assert verify_step(V, cs.x_def, edges=E).ok
    assert certify(cs.A[0], 0.0)


@pytest.mark.parametrize("thickness", [0.0, 0.02, 0.05], ids=["no-thickness", "thin", "thick"])
def test_near_pass_respects_thickness(thickness):
    # Rod b slides down past rod a's line, 0.03 above it in z: the paths stay 0.03
    # apart, which is fine up to thickness 0.03 and a violation beyond it (then the two
    # components must share a map).
    V, E = two_rods(gap=0.2, dz=0.03)
    labels = component_labels(len(V), edges=E)
    x_pred = V.copy()
    x_pred[20:] += [0.0, -0.4, 0.0]
    x_prev = 2 * V - x_pred
    cs = per_component_step(x_prev, V, labels, edges=E, thickness=thickness)
    assert (len(np.unique(cs.group)) == 1) == (thickness > 0.03)
    # Pairs closer than thickness / margin are the deform gate's to check (StepGate): a
    # step it lets through verifies, and one it refuses would have violated or is refused
    # conservatively; between the rods here, the thin cases need no refusal.
    gate = StepGate(V, edges=E, thickness=thickness)
    maps = [(cs.A[c], cs.b[c], np.flatnonzero(labels == c)) for c in range(2)]
    ok = verify_step(V, cs.x_def, edges=E, thickness=thickness).ok
    if thickness <= 0.03:
        assert ok and gate.passes(cs.x_def, maps)
    assert not gate.passes(cs.x_def, maps) or ok


@pytest.mark.parametrize("thickness", [0.0, 0.01])
def test_components_touching_at_the_start_share_a_map(thickness):
    """The apex of a hanging triangle rests exactly on another object's face and rises:
    a pair touching at the start was excused as pre-existing between two groups' maps,
    and the apex was pushed through the face (audit). Two groups with a touching pair
    share one map, under which the contact stays as it was."""
    from penfree.core.pipeline.deform import deform_sequence
    from penfree.core.verify.pairs import start_intersections
    from penfree.sequence import Sequence

    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.25, 0.25, 0], [0.5, 0.1, -1], [0.1, 0.5, -1.0]])
    F = np.array([[0, 1, 2], [3, 4, 5]])
    x_prev = x.copy()
    x_prev[3:, 2] -= 0.3
    seq = Sequence(positions=np.stack([x_prev, x]), faces=F, thickness=thickness).validate()
    x_def = deform_sequence(seq, model="per-component").steps["deformed"][0]
    # edges 3-4 and 3-5 through face 0's interior: the count grew when the apex was pushed up
    assert start_intersections(x_def, None, F) <= start_intersections(x, None, F)
    n = np.cross(x_def[1] - x_def[0], x_def[2] - x_def[0])
    assert np.dot(n, x_def[3] - x_def[0]) <= 1e-12  # the apex never above the face
