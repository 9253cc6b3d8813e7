"""Test oracles shared across test modules: exact distances in rational arithmetic.

Slow and obviously right, never used by penfree itself. Importable by name because
tests/conftest.py puts tests/ on sys.path.
"""

from fractions import Fraction


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
