"""Exact polynomials and Sturm counting (shared by the certificate and the exact CCD),
against polynomials built from known rational roots and against numpy's products."""

from fractions import Fraction

import numpy as np
import pytest

from penfree.core.polynomial import (
    add,
    count_roots,
    count_roots_01,
    evaluate,
    gcd,
    mul,
    squarefree,
    sturm,
    sub,
    trim,
)


# --- Sturm root counting against polynomials with known rational roots ------------


def poly_from_roots(roots, lead=1):
    p = [lead]
    for r in roots:
        r = Fraction(r)
        f = [-r.numerator, r.denominator]  # den * t - num
        q = [0] * (len(p) + 1)
        for i, a in enumerate(p):
            q[i] += a * f[0]
            q[i + 1] += a * f[1]
        p = q
    return p


@pytest.mark.parametrize(
    "roots, lead, expected",
    [
        ([], 5, 0),
        ([Fraction(1, 2)], 1, 1),
        ([Fraction(1, 2), Fraction(1, 2)], 1, 1),  # double root touches zero, no sign change
        ([Fraction(1, 3)] * 3 + [Fraction(2, 3)] * 2, -7, 2),
        ([0], 1, 1),
        ([1], 1, 1),
        ([0, 0, 1, 1, 1], 3, 2),
        ([-1, 2, Fraction(3, 2)], 1, 0),
        ([Fraction(-1, 10**30), Fraction(10**30 + 1, 10**30)], 1, 0),  # just outside
        ([Fraction(1, 10**30), Fraction(10**30 - 1, 10**30)], 1, 2),  # just inside
    ],
    ids=["constant", "simple", "double", "triple-and-double", "at-0", "at-1",
         "multiple-at-ends", "outside", "just-outside", "just-inside"],
)
def test_count_roots_named(roots, lead, expected):
    assert count_roots_01(poly_from_roots(roots, lead)) == expected


def test_count_roots_random(rng):
    for _ in range(200):
        k = int(rng.integers(0, 7))
        roots = [Fraction(int(rng.integers(-20, 41)), 20) for _ in range(k)]  # in [-1, 2]
        p = poly_from_roots(roots, int(rng.choice([-3, -1, 1, 2])))
        p = p + [0] * int(rng.integers(0, 2))  # a zero leading term must be harmless
        assert count_roots_01(p) == len({r for r in roots if 0 <= r <= 1})


def test_zero_polynomial_raises():
    with pytest.raises(ValueError):
        count_roots_01([0, 0])


# --- rational Sturm sequences (the exact CCD's root isolation) -----------------------


def test_ring_operations_match_numpy(rng):
    for _ in range(50):
        p = [int(v) for v in rng.integers(-9, 10, size=int(rng.integers(1, 6)))]
        q = [int(v) for v in rng.integers(-9, 10, size=int(rng.integers(1, 6)))]
        want = trim(np.polynomial.polynomial.polymul(p, q).astype(int).tolist())
        assert mul(p, q) == want
        assert sub(add(p, q), q) == trim(p)
        x = Fraction(int(rng.integers(-5, 6)), 3)
        assert evaluate(mul(p, q), x) == evaluate(p, x) * evaluate(q, x)


def test_zero_polynomial_is_empty():
    assert trim([0, 0]) == [] and mul([], [1, 2]) == [] and add([1, -1], [-1, 1]) == []


@pytest.mark.parametrize("roots, a, b, expected", [
    ([Fraction(1, 3), Fraction(1, 2)], Fraction(0), Fraction(1), 2),
    ([Fraction(1, 3), Fraction(1, 2)], Fraction(1, 3), Fraction(1, 2), 1),  # (a, b]: a excluded
    ([Fraction(1, 4)] * 3 + [Fraction(3, 4)], Fraction(0), Fraction(1), 2),  # squarefree first
    ([Fraction(-1), Fraction(2)], Fraction(0), Fraction(1), 0),
], ids=["two-inside", "half-open", "repeated", "outside"])
def test_sturm_counts_distinct_roots(roots, a, b, expected):
    p = [Fraction(c) for c in poly_from_roots(roots)]
    assert count_roots(sturm(squarefree(p)), a, b) == expected


def test_gcd_is_the_common_factor():
    common = poly_from_roots([Fraction(1, 2), Fraction(-3)])
    p = [Fraction(c) for c in mul(common, poly_from_roots([Fraction(5)]))]
    q = [Fraction(c) for c in mul(common, poly_from_roots([Fraction(7, 3)]))]
    g = gcd(p, q)
    assert g[-1] == 1 and len(g) == 3
    assert evaluate(g, Fraction(1, 2)) == 0 and evaluate(g, Fraction(-3)) == 0
