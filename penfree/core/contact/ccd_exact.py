"""Exact CCD decision for thickness 0, in rational arithmetic (the rare ambiguous queries).

The float64 inputs are exact dyadic rationals, so the question "do the closed
primitives touch at some t in [0, t_max]?" has an exact answer, decided here
with `fractions.Fraction` polynomials in t (degree <= 6, `penfree.core.polynomial`):

- vertex-face: contacts happen at roots of the coplanarity cubic
  c(t) = det[f1 - f0, f2 - f0, p - f0]. If c is not identically 0, each root r
  in [0, t_max] is checked with an exact inside test at r. If c == 0 (always
  coplanar), the first contact is either at t = 0 or with p on an edge of the
  triangle (p cannot enter the interior of a planar triangle without crossing
  its boundary), so the query reduces to three point-edge CCDs.
- edge-edge: the same with c(t) = det[ea1 - ea0, eb1 - eb0, eb0 - ea0]; when
  always coplanar, the first contact puts an endpoint of one segment on the
  other, so four point-edge CCDs.
- point-edge: collinearity times are the common roots of the three components
  of (p - a) x (b - a); if always collinear, the first contact is at t = 0 or
  with p on an endpoint (linear equations).

Signs of polynomials at an irrational root r are decided exactly: r is
isolated by Sturm sequences in an interval where the square-free defining
polynomial q changes sign; s(r) = 0 iff gcd(q, s) changes sign there;
otherwise the interval is bisected until s has no root in it.
Slow (milliseconds per query) and meant only for the queries the float
kernel cannot decide. Degenerate configurations (zero-length edges, triangles
collapsing to segments) are handled, not approximated.
"""

from fractions import Fraction

from ..polynomial import add, count_roots, divmod_poly, evaluate, gcd, mul, sign, squarefree, sturm, sub, trim


# --- roots in [0, t_max] -----------------------------------------------------------


class _Root:
    """A real root r of square-free q: exact (lo == hi) or alone in (lo, hi), q(lo) q(hi) < 0."""

    __slots__ = ("q", "lo", "hi")

    def __init__(self, q, lo, hi):
        self.q, self.lo, self.hi = q, lo, hi

    def sign(self, s):
        """Exact sign of the polynomial s at r."""
        s = trim(s)
        if not s:
            return 0
        if self.lo == self.hi:
            return sign(evaluate(s, self.lo))
        g = gcd(self.q, s)
        if len(g) > 1 and sign(evaluate(g, self.lo)) * sign(evaluate(g, self.hi)) < 0:
            return 0
        s_seq = sturm(squarefree(s))
        while True:
            lo, hi = self.lo, self.hi
            if evaluate(s, lo) != 0 and evaluate(s, hi) != 0 and count_roots(s_seq, lo, hi) == 0:
                return sign(evaluate(s, (lo + hi) / 2))
            mid = (lo + hi) / 2
            qm = evaluate(self.q, mid)
            if qm == 0:
                self.lo = self.hi = mid
                return sign(evaluate(s, mid))
            if sign(qm) == sign(evaluate(self.q, lo)):
                self.lo = mid
            else:
                self.hi = mid


def _roots(p, t_max):
    """All real roots of p (not identically 0) in [0, t_max], as `_Root`s."""
    q = squarefree(trim(p))
    out = []
    if len(q) <= 1:
        return out
    for end in (Fraction(0), t_max):
        if evaluate(q, end) == 0:
            out.append(_Root(q, end, end))
            q = divmod_poly(q, [-end, Fraction(1)])[0]  # deflate: q stays square-free
    if len(q) <= 1:
        return out
    seq = sturm(q)
    stack = [(Fraction(0), t_max)]
    while stack:
        a, b = stack.pop()
        n = count_roots(seq, a, b)
        if n == 0:
            continue
        if n == 1:
            out.append(_Root(q, a, b))
            continue
        k = 2
        while True:  # split at a point that is not a root (q has <= 6 roots)
            m = a + (b - a) / 2 + (b - a) / (2 ** (k + 2)) * (k - 2)
            if evaluate(q, m) != 0:
                break
            k += 1
        stack += [(a, m), (m, b)]
    return out


# --- geometry on linear-in-t points ------------------------------------------------


def _vec(x0, x1):
    """Point x0 + t (x1 - x0) as 3 polynomials."""
    return [trim([Fraction(a), Fraction(b) - Fraction(a)]) for a, b in zip(x0, x1)]


def _vsub(a, b):
    return [sub(x, y) for x, y in zip(a, b)]


def _dot(a, b):
    return add(add(mul(a[0], b[0]), mul(a[1], b[1])), mul(a[2], b[2]))


def _cross(a, b):
    return [
        sub(mul(a[1], b[2]), mul(a[2], b[1])),
        sub(mul(a[2], b[0]), mul(a[0], b[2])),
        sub(mul(a[0], b[1]), mul(a[1], b[0])),
    ]


def _at_zero(t_max):
    return _Root([Fraction(0), Fraction(1)], Fraction(0), Fraction(0))


def _on_segment(r, p, a, b):
    """p(r) in the closed segment [a(r), b(r)]."""
    ab = _vsub(b, a)
    ap = _vsub(p, a)
    L = _dot(ab, ab)
    if r.sign(L) == 0:
        return all(r.sign(c) == 0 for c in ap)
    if any(r.sign(c) != 0 for c in _cross(ap, ab)):
        return False
    d = _dot(ap, ab)
    return r.sign(d) >= 0 and r.sign(sub(L, d)) >= 0


def _in_triangle(r, p, f0, f1, f2):
    """p(r) in the closed triangle, given coplanarity at r."""
    n = _cross(_vsub(f1, f0), _vsub(f2, f0))
    if all(r.sign(c) == 0 for c in n):
        return _on_segment(r, p, f0, f1) or _on_segment(r, p, f1, f2) or _on_segment(r, p, f2, f0)
    for a, b in ((f0, f1), (f1, f2), (f2, f0)):
        if r.sign(_dot(_cross(_vsub(b, a), _vsub(p, a)), n)) < 0:
            return False
    return True


def _segments_meet(r, a0, a1, b0, b1):
    """Closed segments intersect at r, given coplanarity at r."""
    da, db, w = _vsub(a1, a0), _vsub(b1, b0), _vsub(b0, a0)
    m = _cross(da, db)
    if all(r.sign(c) == 0 for c in m):
        return (
            _on_segment(r, a0, b0, b1) or _on_segment(r, a1, b0, b1)
            or _on_segment(r, b0, a0, a1) or _on_segment(r, b1, a0, a1)
        )
    mm = _dot(m, m)
    for s in (_dot(_cross(w, db), m), _dot(_cross(w, da), m)):
        if r.sign(s) < 0 or r.sign(sub(mm, s)) < 0:
            return False
    return True


def _point_point(p, a, t_max):
    d = _vsub(p, a)
    times = set()
    for c in d:
        if not c:
            continue
        if len(c) == 1:
            return False
        times.add(-c[0] / c[1])
    if not times:
        return True
    return len(times) == 1 and 0 <= next(iter(times)) <= t_max


def _point_edge(p, a, b, t_max):
    w = _cross(_vsub(p, a), _vsub(b, a))
    nonzero = [c for c in w if c]
    if not nonzero:
        return _on_segment(_at_zero(t_max), p, a, b) or _point_point(p, a, t_max) or _point_point(p, b, t_max)
    g = nonzero[0]
    for c in nonzero[1:]:
        g = gcd(g, c)
    return any(_on_segment(r, p, a, b) for r in _roots(g, t_max))


def exact_vertex_face(x_t0, x_t1, t_max=1.0):
    """Exact answer: do point and closed triangle touch for some t in [0, t_max]?

    Parameters
    ----------
    x_t0, x_t1 : (4, 3) float
        Rows p, f0, f1, f2; every float is taken as the exact rational it is.
    t_max : float
    """
    t_max = Fraction(t_max)
    p, f0, f1, f2 = (_vec(x_t0[i], x_t1[i]) for i in range(4))
    c = _dot(_cross(_vsub(f1, f0), _vsub(f2, f0)), _vsub(p, f0))
    if c:
        return any(_in_triangle(r, p, f0, f1, f2) for r in _roots(c, t_max))
    return (
        _in_triangle(_at_zero(t_max), p, f0, f1, f2)
        or _point_edge(p, f0, f1, t_max) or _point_edge(p, f1, f2, t_max) or _point_edge(p, f2, f0, t_max)
    )


def exact_edge_edge(x_t0, x_t1, t_max=1.0):
    """Exact answer: do the closed segments touch for some t in [0, t_max]? Rows ea0, ea1, eb0, eb1."""
    t_max = Fraction(t_max)
    a0, a1, b0, b1 = (_vec(x_t0[i], x_t1[i]) for i in range(4))
    c = _dot(_cross(_vsub(a1, a0), _vsub(b1, b0)), _vsub(b0, a0))
    if c:
        return any(_segments_meet(r, a0, a1, b0, b1) for r in _roots(c, t_max))
    return (
        _segments_meet(_at_zero(t_max), a0, a1, b0, b1)
        or _point_edge(a0, b0, b1, t_max) or _point_edge(a1, b0, b1, t_max)
        or _point_edge(b0, a0, a1, t_max) or _point_edge(b1, a0, a1, t_max)
    )
