"""Property: the separation lower bound that ``penfree verify`` prints is never above the truth.

Random scenes of a few triangles or segments move in a straight line from frame
0 to frame 1; for every step printed "OK (..., min separation >= X)" the bound X
must not exceed the true minimum distance between non-adjacent primitives over
the path. The oracle is brute force: exact point-triangle and segment-segment
distances (Ericson, Real-Time Collision Detection 5.1.5 / 5.1.9) at 101 times,
whose minimum is at or above the true minimum over [0, 1].
"""

import itertools
import re

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from penfree.formats import write_sequence
from penfree.sequence import Sequence


def point_triangle(p, a, b, c):
    """Exact distance from p to triangle abc (Ericson 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = ab @ ap, ac @ ap
    if d1 <= 0 and d2 <= 0:
        return np.linalg.norm(p - a)
    bp = p - b
    d3, d4 = ab @ bp, ac @ bp
    if d3 >= 0 and d4 <= d3:
        return np.linalg.norm(p - b)
    vc = d1 * d4 - d3 * d2
    if vc <= 0 and d1 >= 0 and d3 <= 0:
        return np.linalg.norm(p - (a + d1 / (d1 - d3) * ab))
    cp = p - c
    d5, d6 = ab @ cp, ac @ cp
    if d6 >= 0 and d5 <= d6:
        return np.linalg.norm(p - c)
    vb = d5 * d2 - d1 * d6
    if vb <= 0 and d2 >= 0 and d6 <= 0:
        return np.linalg.norm(p - (a + d2 / (d2 - d6) * ac))
    va = d3 * d6 - d5 * d4
    if va <= 0 and (d4 - d3) >= 0 and (d5 - d6) >= 0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return np.linalg.norm(p - (b + w * (c - b)))
    denom = 1.0 / (va + vb + vc)
    v, w = vb * denom, vc * denom
    return np.linalg.norm(p - (a + ab * v + ac * w))


def segment_segment(p1, q1, p2, q2):
    """Exact distance between segments p1q1 and p2q2 (Ericson 5.1.9)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = d1 @ d1, d2 @ d2, d2 @ r
    if a <= 1e-300 and e <= 1e-300:
        return np.linalg.norm(r)
    if a <= 1e-300:
        s, t = 0.0, np.clip(f / e, 0, 1)
    else:
        c = d1 @ r
        if e <= 1e-300:
            t, s = 0.0, np.clip(-c / a, 0, 1)
        else:
            b = d1 @ d2
            den = a * e - b * b
            s = np.clip((b * f - c * e) / den, 0, 1) if den > 0 else 0.0
            t = (b * s + f) / e
            if t < 0:
                t, s = 0.0, np.clip(-c / a, 0, 1)
            elif t > 1:
                t, s = 1.0, np.clip((b - c) / a, 0, 1)
    return np.linalg.norm((p1 + d1 * s) - (p2 + d2 * t))


def true_min_distance(x0, x1, faces=None, edges=None, n_t=101):
    """Brute force over times: min over non-adjacent vertex-face and edge-edge pairs (>= the true min)."""
    if faces is not None:
        edges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1),
                          axis=0)
    best = np.inf
    for t in np.linspace(0.0, 1.0, n_t):
        x = (1 - t) * x0 + t * x1
        if faces is not None:
            for v, f in itertools.product(range(len(x)), range(len(faces))):
                if v not in faces[f]:
                    best = min(best, point_triangle(x[v], *x[faces[f]]))
        for e, g in itertools.combinations(range(len(edges)), 2):
            if not set(edges[e]) & set(edges[g]):
                best = min(best, segment_segment(*x[edges[e]], *x[edges[g]]))
    return best


def _rotation(axis, angle):
    axis = axis / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


@st.composite
def scenes(draw):
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    triangles = draw(st.booleans())
    k = draw(st.integers(2, 3))
    per = 3 if triangles else 2
    size = draw(st.sampled_from([0.3, 1.0]))
    x0 = np.concatenate([rng.random(3) * 2 + size * rng.standard_normal((per, 3)) for _ in range(k)])
    # each primitive moves rigidly (small rotation + translation), or all move as one
    x1 = np.empty_like(x0)
    for i in range(k):
        blk = slice(per * i, per * (i + 1))
        R = _rotation(rng.standard_normal(3), draw(st.floats(0.0, 0.3)))
        c = x0[blk].mean(axis=0)
        x1[blk] = (x0[blk] - c) @ R.T + c + draw(st.floats(0.0, 0.5)) * rng.standard_normal(3)
    topo = np.arange(k * per).reshape(k, per)
    if not triangles:
        topo = topo.reshape(-1, 2)
    thickness = draw(st.sampled_from([0.0, 1e-3, 0.01, 0.05]))
    return x0, x1, topo, triangles, thickness


def _bound(line):
    m = re.search(r"min separation (>= ([0-9.eE+-]+)|> 0)", line)
    return None if m is None else (0.0 if m.group(2) is None else float(m.group(2)))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(scene=scenes())
def test_printed_separation_never_exceeds_the_true_minimum(cli, tmp_path_factory, scene):
    x0, x1, topo, triangles, thickness = scene
    d = tmp_path_factory.mktemp("bound")
    seq = Sequence(positions=np.stack([x0, x1]), thickness=thickness,
                   **({"faces": topo} if triangles else {"edges": topo}))
    write_sequence(str(d / "in.h5"), seq.validate())
    r = cli("verify", d / "in.h5", folder=d)
    step_line = r.stdout.splitlines()[0]
    bound = _bound(step_line)
    if r.exit_code == 1:
        assert "VIOLATION" in step_line and bound is None
        return
    assert r.exit_code == 0 and bound is not None, r.output
    truth = true_min_distance(x0, x1, **({"faces": topo} if triangles else {"edges": topo}))
    assert bound <= truth, f"printed min separation >= {bound} but the true minimum is at most {truth}"
    assert thickness < truth or thickness == 0  # an OK verdict: every pair stays beyond the thickness


def test_oracle_distances():
    a, b, c = np.array([0.0, 0, 0]), np.array([1.0, 0, 0]), np.array([0.0, 1, 0])
    assert point_triangle(np.array([0.2, 0.2, 0.5]), a, b, c) == 0.5
    assert np.isclose(point_triangle(np.array([2.0, 0, 0]), a, b, c), 1.0)
    assert np.isclose(segment_segment(a, b, np.array([0.5, -1, 1.0]), np.array([0.5, 1, 1.0])), 1.0)
    assert np.isclose(segment_segment(a, b, np.array([3.0, 0, 0]), np.array([4.0, 0, 0])), 2.0)
