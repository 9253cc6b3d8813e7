"""Exact univariate polynomials and Sturm sequences, shared by the certificate and the exact CCD.

A polynomial is a list of exact coefficients (``int`` or `fractions.Fraction`),
lowest degree first; the zero polynomial is ``[]``. Nothing here rounds: the
certificate (`penfree.core.fit.certificate`) runs over the integers, the exact CCD
(`penfree.core.contact.ccd_exact`) over the rationals.

>>> mul([-1, 1], [1, 1])          # (t - 1)(t + 1)
[-1, 0, 1]
>>> count_roots_01([-1, 0, 4])    # 4 t^2 - 1: one root, 1/2, in [0, 1]
1
"""

from __future__ import annotations

import math
from fractions import Fraction

# --- ring operations (any exact coefficients) ----------------------------------------


def trim(p):
    """`p` without trailing zero coefficients (``[]`` for the zero polynomial)."""
    p = list(p)
    while p and p[-1] == 0:
        p.pop()
    return p


def add(p, q):
    n = max(len(p), len(q))
    return trim([(p[i] if i < len(p) else 0) + (q[i] if i < len(q) else 0) for i in range(n)])


def neg(p):
    return [-c for c in p]


def sub(p, q):
    return add(p, neg(q))


def mul(p, q):
    if not p or not q:
        return []
    out = [0] * (len(p) + len(q) - 1)
    for i, a in enumerate(p):
        if a:
            for j, b in enumerate(q):
                out[i + j] += a * b
    return trim(out)


def evaluate(p, x):
    """``p(x)`` by Horner's rule, exact."""
    acc = Fraction(0)
    for c in reversed(p):
        acc = acc * x + c
    return acc


def deriv(p):
    return trim([i * p[i] for i in range(1, len(p))])


def sign(x):
    return (x > 0) - (x < 0)


def sign_changes(values):
    """Sign changes along `values`, zeros skipped (Sturm's count)."""
    signs = [v > 0 for v in values if v != 0]
    return sum(1 for a, b in zip(signs, signs[1:]) if a != b)


# --- field operations (Fraction coefficients) ----------------------------------------


def divmod_poly(p, q):
    """Quotient and remainder of `p` by the nonzero `q` (rational coefficients)."""
    p = list(p)
    quo = [Fraction(0)] * max(1, len(p) - len(q) + 1)
    while len(p) >= len(q) and p:
        k = len(p) - len(q)
        f = p[-1] / q[-1]
        quo[k] = f
        for i, c in enumerate(q):
            p[i + k] -= f * c
        p = trim(p)
    return trim(quo), p


def gcd(p, q):
    """Monic greatest common divisor (``[]`` when both are zero)."""
    p, q = trim(p), trim(q)
    while q:
        p, q = q, divmod_poly(p, q)[1]
    if not p:
        return []
    lead = p[-1]
    return [c / lead for c in p]


def squarefree(p):
    """`p` divided by ``gcd(p, p')``: the same roots, each simple."""
    g = gcd(p, deriv(p))
    return divmod_poly(p, g)[0] if len(g) > 1 else p


def sturm(p):
    """Sturm sequence ``p, p', -rem(p, p'), ...`` of a square-free `p`."""
    seq = [p, deriv(p)]
    while len(seq[-1]) > 1:
        r = divmod_poly(seq[-2], seq[-1])[1]
        if not r:
            break
        seq.append(neg(r))
    return seq


def variations(seq, x):
    """Sign changes of the Sturm sequence `seq` at `x`."""
    return sign_changes([evaluate(p, x) for p in seq])


def count_roots(seq, a, b):
    """Distinct roots in ``(a, b]`` of the square-free ``seq[0]`` (`seq` from `sturm`)."""
    return variations(seq, a) - variations(seq, b)


# --- integer polynomials: roots in [0, 1] without fractions ---------------------------


def _prem_pos(a, b):
    """A positive multiple of the remainder of `a` divided by `b` (exact, integers)."""
    lb = b[-1]
    sb = 1 if lb > 0 else -1
    alb = abs(lb)
    r = list(a)
    db = len(b) - 1
    while len(r) - 1 >= db and any(r):
        k = len(r) - 1 - db
        lr = r[-1]
        # |lb| r - sign(lb) lr x^k b: leading terms cancel, multiplier |lb| > 0.
        r = [alb * c for c in r]
        for i, c in enumerate(b):
            r[i + k] -= sb * lr * c
        r = trim(r[:-1])
    return trim(r)


def _primitive(p):
    g = 0
    for a in p:
        g = math.gcd(g, a)
    return [a // g for a in p] if g > 1 else p


def count_roots_01(p) -> int:
    """Number of distinct real roots of the integer polynomial `p` in the closed ``[0, 1]``.

    Sturm's theorem on ``p, p', -rem, ...`` with pseudo-remainders made primitive, so
    every coefficient stays an integer; repeated roots are counted once (the chain ends
    at ``gcd(p, p')``, a common factor that does not change the sign variations).
    Endpoints are tested directly. The zero polynomial raises ValueError.
    """
    p = trim(p)
    if not any(p):
        raise ValueError("the zero polynomial has infinitely many roots")
    # Sturm needs non-roots at the ends: count endpoint roots directly and
    # divide them out exactly (by t, and by t - 1 with synthetic division).
    n_end = 0
    if p[0] == 0:
        n_end += 1
        while p[0] == 0:
            p = p[1:]
    if sum(p) == 0:
        n_end += 1
        while len(p) > 1 and sum(p) == 0:
            q, acc = [], 0
            for a in reversed(p[1:]):
                acc += a
                q.append(acc)
            p = q[::-1]
    if len(p) == 1:
        return n_end
    chain = [_primitive(p), _primitive(deriv(p))]
    while len(chain[-1]) > 1:
        r = _prem_pos(chain[-2], chain[-1])
        if not any(r):
            break
        chain.append(_primitive(neg(r)))
    v0 = sign_changes([q[0] for q in chain])
    v1 = sign_changes([sum(q) for q in chain])
    return n_end + (v0 - v1)
