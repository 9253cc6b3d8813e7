"""Half-space obstacles: exact decisions, and the gate's guarantee (hypothesis property)."""

from fractions import Fraction

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from penfree.core.verify.gate import StepGate
from penfree.core.contact.obstacles import half_space_verdict
from penfree.sequence import Obstacle


def _exact_side(p, normal, offset):
    return sum(Fraction(float(a)) * Fraction(float(b)) for a, b in zip(normal, p)) - Fraction(float(offset))


def test_half_space_decided_exactly_at_the_plane():
    n = np.array([0.0, 0.0, 1.0])
    x0 = np.array([[0.0, 0, 0.1], [0.3, 0.2, 0.1]])
    # one vertex ends exactly on the plane, one a rounding step above it
    x1 = np.array([[0.0, 0, 0.0], [0.3, 0.2, np.nextafter(0.0, 1.0)]])
    start, path, pre, _ = half_space_verdict(x0, x1, n, 0.0, 0.0)
    assert start.tolist() == [] and path.tolist() == [0] and pre.tolist() == []


def test_half_space_offsets_far_from_the_origin():
    n = np.array([0.0, 0.6, 0.8])
    off = 1e6
    p = np.array([[0.0, 6e5, 8e5]])  # on the plane: 0.6 * 6e5 + 0.8 * 8e5 = 1e6
    start, path, _, _ = half_space_verdict(p, p, n, off, 0.0)
    exact = _exact_side(p[0], n, off)
    assert (len(start) == 1) == (not exact > 0)


def test_pre_existing_reading():
    n = np.array([0.0, 0.0, 1.0])
    h = 0.01
    x0 = np.array([[0, 0, 0.5], [0, 0, 0.004], [0, 0, -0.02]])
    x1 = np.array([[0, 0, 0.2], [0, 0, 0.001], [0, 0, -0.01]])  # rests closer, stays; behind comes out
    start, path, pre, _ = half_space_verdict(x0, x1, n, 0.0, h, pre_existing=True)
    assert path.tolist() == [] and pre.tolist() == [2] and start.tolist() == []
    x1[2, 2] = -0.03  # deeper behind the plane: refused
    x1[1, 2] = -1e-6  # resting vertex crossing: refused
    _, path, _, _ = half_space_verdict(x0, x1, n, 0.0, h, pre_existing=True)
    assert path.tolist() == [1, 2]


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), thickness=st.sampled_from([0.0, 1e-3, 0.02]),
       scale=st.floats(0.01, 0.3))
def test_certified_maps_never_cross_a_half_space(seed, thickness, scale):
    """Hypothesis: a random map the gate lets through keeps every vertex on the free side."""
    rng = np.random.default_rng(seed)
    normal = rng.normal(size=3)
    normal /= np.linalg.norm(normal)
    offset = float(rng.normal())
    x = rng.normal(size=(30, 3))
    s = x @ normal - offset
    x += np.outer(np.maximum(0.0, thickness + rng.uniform(0, 0.05, 30) - s), normal)  # all on the free side
    faces = np.array([[i, i + 1, i + 2] for i in range(0, 27, 3)])
    A = np.eye(3) + scale * rng.normal(size=(3, 3))
    b = scale * rng.normal(size=3)
    c = x.mean(axis=0)
    x_def = x + (x - c) @ (A - np.eye(3)).T + b
    gate = StepGate(x, faces=faces, thickness=thickness,
                    obstacles=[Obstacle("plane", normal=normal, offset=offset)])
    if gate.passes(x_def, [(A, b - (A - np.eye(3)) @ c, None)]):
        for p in x_def:
            d = _exact_side(p, normal, offset)
            # the gate compares with thickness |n| in floating point; |n| = 1 up to rounding
            assert d > 0 if thickness == 0 else d >= Fraction(thickness) * Fraction(1 - 1e-12)


def test_gate_passes_small_maps_above_a_plane():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(30, 3))
    x[:, 2] = np.abs(x[:, 2]) + 0.05
    gate = StepGate(x, obstacles=[Obstacle("ground", normal=np.array([0.0, 0.0, 1.0]), offset=0.0)])
    A = np.eye(3) + 0.01 * rng.normal(size=(3, 3))
    assert gate.passes(x @ A.T, [(A, np.zeros(3), None)])
    assert not gate.passes(x - [0, 0, 1.0], [(np.eye(3), np.array([0, 0, -1.0]), None)])


def test_half_space_thickness_is_decided_on_the_exact_norm():
    """A vertex exactly more than h from a plane whose rounded h |n| lies above the
    exact one: it was classified as resting inside h, so a path to 0.5 h passed (audit).
    The level thickness |n| is irrational; it is now decided on the squares."""
    from decimal import Decimal, getcontext

    from penfree.core.contact.obstacles import half_space_verdict

    getcontext().prec = 60
    th = 0.01
    rng = np.random.default_rng(3)
    while True:  # a normal and a float c with th |n| <= c < fl(th fl(|n|))
        n = np.array([rng.uniform(0.2, 1), rng.uniform(0.2, 1), 0.0])
        c = np.nextafter(th * float(np.linalg.norm(n)), 0)
        if Decimal(c) >= Decimal(th) * sum(Decimal(float(a)) ** 2 for a in n).sqrt():
            break
    x0 = np.array([c * n / np.dot(n, n)])
    x1 = x0 - 0.5 * th * n / np.linalg.norm(n)  # to half the thickness
    start, path, pre, _ = half_space_verdict(x0, x1, n, 0.0, th, pre_existing=True)
    assert path.tolist() == [0] and pre.tolist() == []
    start, _, _, _ = half_space_verdict(x0, x0, n, 0.0, th)
    exact = sum(Fraction(float(a)) * Fraction(float(b)) for a, b in zip(n, x0[0]))
    at_least_h = exact >= 0 and exact ** 2 >= Fraction(th) ** 2 * sum(Fraction(float(a)) ** 2 for a in n)
    assert (start.tolist() == []) == at_least_h
