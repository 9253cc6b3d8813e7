"""Test oracles shared across test modules: brute-force broad phase and exact distances.

Slow and obviously right, never used by penfree itself. Importable by name because
tests/conftest.py puts tests/ on sys.path.
"""

from fractions import Fraction

import numpy as np

from penfree.core.topology import as_positions, as_topology


# --- broad phase: O(n^2) box overlap in numpy ------------------------------------------


def _brute(loA, hiA, TA, loB, hiB, TB, self_query):
    rows = []
    for s in range(0, loA.shape[0], 512):
        ov = np.all((loA[s:s + 512, None, :] <= hiB[None]) & (loB[None] <= hiA[s:s + 512, None, :]), axis=2)
        for a in range(TA.shape[1]):
            for b in range(TB.shape[1]):
                ov &= TA[s:s + 512, a, None] != TB[None, :, b]
        if self_query:
            ov &= np.arange(s, s + ov.shape[0])[:, None] < np.arange(loB.shape[0])[None]
        i, j = np.nonzero(ov)
        rows.append(np.stack([i + s, j], axis=1))
    if not rows:
        return np.zeros((0, 2), dtype=np.int64)
    return np.concatenate(rows).astype(np.int64)


def _motion(V_t0, V_t1, inflation):
    return as_positions(V_t0, "V_t0"), as_positions(V_t1, "V_t1"), float(inflation)


def _np_boxes(V_t0, V_t1, T, inflation):
    lo = np.minimum(V_t0[T], V_t1[T]).min(axis=1) - inflation
    hi = np.maximum(V_t0[T], V_t1[T]).max(axis=1) + inflation
    return lo, hi


def edge_edge_candidates_brute(V_t0, V_t1, E, inflation=0.0) -> np.ndarray:
    """O(M^2) numpy oracle of `edge_edge_candidates`."""
    V_t0, V_t1, inflation = _motion(V_t0, V_t1, inflation)
    E = as_topology(E, 2, V_t0.shape[0], "E")
    lo, hi = _np_boxes(V_t0, V_t1, E, inflation)
    return _brute(lo, hi, E, lo, hi, E, True)


def edge_edge_candidates_between_brute(V_t0, V_t1, EA, EB, inflation=0.0) -> np.ndarray:
    """O(|EA| |EB|) numpy oracle of `edge_edge_candidates_between`."""
    V_t0, V_t1, inflation = _motion(V_t0, V_t1, inflation)
    EA = as_topology(EA, 2, V_t0.shape[0], "EA")
    EB = as_topology(EB, 2, V_t0.shape[0], "EB")
    return _brute(*_np_boxes(V_t0, V_t1, EA, inflation), EA,
                  *_np_boxes(V_t0, V_t1, EB, inflation), EB, False)


def vertex_face_candidates_brute(V_t0, V_t1, F, inflation=0.0, vertices=None) -> np.ndarray:
    """O(n M) numpy oracle of `vertex_face_candidates`."""
    V_t0, V_t1, inflation = _motion(V_t0, V_t1, inflation)
    F = as_topology(F, 3, V_t0.shape[0], "F")
    n = V_t0.shape[0]
    Q = np.arange(n, dtype=np.int64) if vertices is None else np.unique(np.asarray(vertices, dtype=np.int64))
    Q = np.ascontiguousarray(Q[:, None])
    pairs = _brute(*_np_boxes(V_t0, V_t1, Q, inflation), Q,
                   *_np_boxes(V_t0, V_t1, F, inflation), F, False)
    pairs[:, 0] = Q[pairs[:, 0], 0]
    return pairs


def vertex_face_candidates_between_brute(V_t0, V_t1, vertices, F, inflation=0.0) -> np.ndarray:
    """O(n M) numpy oracle of `vertex_face_candidates_between`."""
    assert vertices is not None
    return vertex_face_candidates_brute(V_t0, V_t1, F, inflation, vertices)


# --- exact squared distances (oracle), Fraction arithmetic ----------------------------


def _d(a, b):
    return [x - y for x, y in zip(a, b)]


def _dot(a, b):
    return sum(x * y for x, y in zip(a, b))


def pe_sq(p, a, b):
    ab, ap = _d(b, a), _d(p, a)
    L = _dot(ab, ab)
    s = Fraction(0) if L == 0 else min(max(_dot(ap, ab) / L, Fraction(0)), Fraction(1))
    q = [x + s * y for x, y in zip(a, ab)]
    r = _d(p, q)
    return _dot(r, r)


def ee_sq(a0, a1, b0, b1):
    best = min(pe_sq(a0, b0, b1), pe_sq(a1, b0, b1), pe_sq(b0, a0, a1), pe_sq(b1, a0, a1))
    da, db, w = _d(a1, a0), _d(b1, b0), _d(b0, a0)
    A, B, C = _dot(da, da), _dot(da, db), _dot(db, db)
    den = A * C - B * B
    if den != 0:  # interior critical point of the (convex) squared distance
        u = (_dot(w, da) * C - _dot(w, db) * B) / den
        v = (_dot(w, da) * B - _dot(w, db) * A) / den
        if 0 <= u <= 1 and 0 <= v <= 1:
            r = _d([x + u * y for x, y in zip(a0, da)], [x + v * y for x, y in zip(b0, db)])
            best = min(best, _dot(r, r))
    return best


def pt_sq(p, f0, f1, f2):
    best = min(pe_sq(p, f0, f1), pe_sq(p, f1, f2), pe_sq(p, f2, f0))
    e1, e2, w = _d(f1, f0), _d(f2, f0), _d(p, f0)
    A, B, C = _dot(e1, e1), _dot(e1, e2), _dot(e2, e2)
    den = A * C - B * B
    if den != 0:
        u = (_dot(w, e1) * C - _dot(w, e2) * B) / den
        v = (_dot(w, e2) * A - _dot(w, e1) * B) / den
        if u >= 0 and v >= 0 and u + v <= 1:
            r = _d(w, [u * x + v * y for x, y in zip(e1, e2)])
            best = min(best, _dot(r, r))
    return best


def exact_dist_sq(kind, x_t0, x_t1, t):
    """Exact squared distance of the primitives at the rational time t."""
    t = Fraction(t)
    pts = [[Fraction(a) + t * (Fraction(b) - Fraction(a)) for a, b in zip(p0, p1)] for p0, p1 in zip(x_t0, x_t1)]
    return ee_sq(*pts) if kind == "ee" else pt_sq(*pts)
