"""The certified float filters of `orient` against exact rational arithmetic: a sign is
never wrong, and a segment-triangle pair is never cleared when it meets."""

from fractions import Fraction

import numpy as np
import pytest

from penfree.core.contact.broad_phase import edge_face_candidates
from penfree.core.contact.intersection import segments_triangles_intersect
from penfree.core.contact.orient import orient3d_sign, segment_may_meet_triangle, segment_may_meet_triangle_at
from penfree.core.topology import edges_from_faces


def _exact_orient(a, b, c, d):
    m = [[Fraction(float(p[k])) - Fraction(float(d[k])) for k in range(3)] for p in (a, b, c)]
    det = (m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
           - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
           + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]))
    return (det > 0) - (det < 0)


def _near_coplanar(rng, n):
    """Quadruples with the fourth point within a few ulps of the others' plane."""
    P = rng.normal(size=(n, 4, 3)) * 10.0 ** rng.integers(-3, 4, size=(n, 1, 1))
    w = rng.uniform(-1, 2, size=(n, 2))
    P[:, 3] = P[:, 0] + w[:, :1] * (P[:, 1] - P[:, 0]) + w[:, 1:] * (P[:, 2] - P[:, 0])
    P[:, 3] *= 1.0 + rng.integers(-4, 5, size=(n, 1)) * 2.0 ** -52
    return P


def test_orient3d_sign_is_never_wrong(rng):
    P = np.concatenate([_near_coplanar(rng, 400), rng.normal(size=(200, 4, 3))])
    P[:50, 3] = P[:50, 0]  # degenerate: a repeated point
    known = 0
    for a, b, c, d in P:
        s = orient3d_sign(a, b, c, d)
        if s != 0:  # unknown (0) is always allowed
            known += 1
            assert s == _exact_orient(a, b, c, d)
    assert known >= 200  # the generic quadruples are decided


def _pairs(rng, n):
    """Segments and triangles that touch, cross, nearly touch or miss (exact ties included)."""
    tri = rng.uniform(-1, 1, size=(n, 3, 3))
    u, v = rng.uniform(0, 1, size=(2, n))
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    hit = tri[:, 0] + u[:, None] * (tri[:, 1] - tri[:, 0]) + v[:, None] * (tri[:, 2] - tri[:, 0])
    d = rng.normal(size=(n, 3))
    s = rng.uniform(-1.5, 1.5, size=(n, 2))
    seg = np.stack([hit + s[:, :1] * d, hit + s[:, 1:] * d], axis=1)
    seg[: n // 8, 0] = tri[: n // 8, 1]  # an end point on a corner
    seg[n // 8: n // 4, 0] = 0.5 * (tri[n // 8: n // 4, 0] + tri[n // 8: n // 4, 2])  # on an edge
    seg[n // 4: n // 3, 1] = seg[n // 4: n // 3, 0]  # zero-length segments
    tri[n // 3: n // 2, 2] = 0.5 * (tri[n // 3: n // 2, 0] + tri[n // 3: n // 2, 1])  # degenerate triangles
    return seg, tri


def test_segment_filter_never_clears_a_meeting_pair(rng):
    seg, tri = _pairs(rng, 600)
    meet = segments_triangles_intersect(seg, tri)
    cleared = np.array([not segment_may_meet_triangle(s[0], s[1], t[0], t[1], t[2]) for s, t in zip(seg, tri)])
    assert meet.sum() > 100 and not np.any(cleared & meet)
    assert cleared.sum() > 0.3 * (~meet).sum()  # and it clears most of the misses


def test_indexed_filter_is_the_row_filter(rng):
    # The coordinate kernel behind the broad phase's edge-face filter gives the row
    # version's verdict on every pair, exact ties and degenerate triangles included,
    # and so never clears a meeting pair either (exact oracle).
    seg, tri = _pairs(rng, 600)
    seg[:40] = _near_coplanar(rng, 40)[:, :2]  # nearly coplanar with their triangles
    tri[:40] = _near_coplanar(rng, 40)[:, 1:]
    V = np.concatenate([seg, tri], axis=1).reshape(-1, 3)  # pair k: rows 5k .. 5k + 4
    rows = [segment_may_meet_triangle(s[0], s[1], t[0], t[1], t[2]) for s, t in zip(seg, tri)]
    at = [segment_may_meet_triangle_at(V, 5 * k, 5 * k + 1, 5 * k + 2, 5 * k + 3, 5 * k + 4) for k in range(len(seg))]
    assert at == rows
    meet = segments_triangles_intersect(seg, tri)
    assert meet.sum() > 100 and not np.any(meet & ~np.array(at))
    assert 0.2 * len(at) < sum(at) < len(at)  # both verdicts occur


def _crossing_sheets(rng, n=9):
    """Two crumpled sheets pushed through each other: (V, E, F)."""
    u = np.linspace(0, 1, n)
    X, Y = np.meshgrid(u, u, indexing="ij")
    V0 = np.stack([X, Y, 0.05 * np.sin(7 * X + 3 * Y)], -1).reshape(-1, 3)
    V1 = np.stack([Y + 0.03, X + 0.02, 0.05 * np.cos(5 * X - 4 * Y)], -1).reshape(-1, 3)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F0 = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    V = np.concatenate([V0, V1]) + rng.normal(scale=1e-4, size=(2 * n * n, 3))
    F = np.concatenate([F0, F0 + n * n]).astype(np.int64)
    return V, edges_from_faces(F).astype(np.int64), F


def test_edge_face_candidates_are_a_superset_of_the_intersections(rng):
    # Every intersecting (edge, face) pair sharing no vertex is a candidate, and
    # candidates have overlapping boxes.
    V, E, F = _crossing_sheets(rng)
    cand = edge_face_candidates(V, E, F)
    k, f = np.meshgrid(np.arange(len(E)), np.arange(len(F)), indexing="ij")
    k, f = k.ravel(), f.ravel()
    share = (E[k][:, :, None] == F[f][:, None, :]).any(axis=(1, 2))
    k, f = k[~share], f[~share]
    meet = segments_triangles_intersect(V[E[k]], V[F[f]])
    truth = set(zip(k[meet].tolist(), f[meet].tolist()))
    got = set(map(tuple, cand.tolist()))
    assert len(truth) > 10 and truth <= got
    lo_e, hi_e = V[E].min(1), V[E].max(1)
    lo_f, hi_f = V[F].min(1), V[F].max(1)
    ck, cf = cand[:, 0], cand[:, 1]
    assert np.all((lo_e[ck] <= hi_f[cf]) & (lo_f[cf] <= hi_e[ck]))
    assert len(got) < len(k) // 10


def test_edge_face_candidates_identical_for_one_and_two_threads(rng, monkeypatch):
    import numba

    from penfree.core.contact import broad_phase as bp

    V, E, F = _crossing_sheets(rng, n=17)
    for k in (bp._fill_chunks, bp._gather_chunks):
        monkeypatch.setattr(k, "min_work", 0)
    monkeypatch.setattr(bp, "_PAIR_CHUNK_MIN_ROWS", 16)  # many chunks on a small scene
    out = []
    try:
        for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(threads)
            out.append(edge_face_candidates(V, E, F))
    finally:
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    assert len(out[0]) > 10
    np.testing.assert_array_equal(out[0], out[1])
