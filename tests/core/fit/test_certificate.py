"""Exact certificate and its fast sufficient test against exact and sampling oracles."""

from fractions import Fraction

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from penfree.core.fit.certificate import (
    certificate_polynomial,
    certified_margin,
    certify,
    fast_margin_bound,
)
from penfree.errors import InputError

from _geom import rot


T_DENSE = np.linspace(0.0, 1.0, 4001)


def sigma_min_path(A, t=T_DENSE):
    """Oracle: sigma_min(I + t (A - I)) on a grid of t."""
    M = np.eye(3) + t[:, None, None] * (np.asarray(A) - np.eye(3))
    return np.linalg.svd(M, compute_uv=False)[:, -1]


def refined_min(A):
    """Oracle: global min of sigma_min over [0, 1]: dense grid, then a bounded 1-D search."""
    s = sigma_min_path(A)
    i = int(np.argmin(s))
    lo, hi = T_DENSE[max(i - 1, 0)], T_DENSE[min(i + 1, len(T_DENSE) - 1)]
    r = minimize_scalar(lambda t: sigma_min_path(A, np.array([t]))[0], bounds=(lo, hi),
                        method="bounded", options={"xatol": 1e-14})
    return min(float(s.min()), float(r.fun))


RNG_SEED = 20261121  # seed of the shared `rng` fixture (tests/conftest.py)


# --- the polynomial itself is exact --------------------------------------------------


@pytest.mark.parametrize("margin", [0.0, 0.25, 0.7])
def test_polynomial_is_positive_multiple_of_exact_q(rng, margin):
    A = np.eye(3) + 0.7 * rng.standard_normal((3, 3))
    p = certificate_polynomial(A, margin)
    Af = [[Fraction(float(a)) for a in row] for row in A]
    m2 = Fraction(margin) ** 2

    def exact_q(t):
        M = [[(1 if i == j else 0) + t * (Af[i][j] - (1 if i == j else 0)) for j in range(3)] for i in range(3)]
        if margin:
            M = [[sum(M[k][i] * M[k][j] for k in range(3)) - (m2 if i == j else 0) for j in range(3)]
                 for i in range(3)]
        return (M[0][0] * (M[1][1] * M[2][2] - M[1][2] * M[2][1])
                - M[0][1] * (M[1][0] * M[2][2] - M[1][2] * M[2][0])
                + M[0][2] * (M[1][0] * M[2][1] - M[1][1] * M[2][0]))

    ratios = set()
    for k in range(8):
        t = Fraction(k, 7)
        ratios.add(sum(c * t**i for i, c in enumerate(p)) / exact_q(t))
    assert len(ratios) == 1 and next(iter(ratios)) > 0
    assert len(p) - 1 <= (6 if margin else 3)


# --- named facts ------------------------------------------------------------------------


def test_rotation_170_with_stretch_is_not_certified():
    # det > 0 and all singular values positive, yet M(t) is singular half-way.
    A = rot([0, 0, 1], 170) @ np.diag([2.0, 0.5, 1.0])
    assert np.linalg.det(A) > 0
    assert np.linalg.svd(A, compute_uv=False).min() > 0.4
    assert refined_min(A) < 1e-6
    assert not certify(A, 0.0)
    assert fast_margin_bound(A) < 0


@pytest.mark.parametrize(
    "A, margin, expected",
    [
        (np.eye(3), 0.0, True),
        (np.eye(3), 0.999, True),
        (np.diag([1.0, 1.0, -0.5]), 0.0, False),  # reflection
        (np.diag([1.0, 1.0, 0.0]), 0.0, False),  # singular at t = 1: root on the closed end
        (np.diag([1.0, 1.0, 0.5]), 0.5, False),  # sigma_min(1) == margin exactly
        (np.diag([1.0, 1.0, 0.5]), 0.4999999, True),
        (rot([1, 1, 0], 100), 0.0, True),  # rotations are never singular on the path ...
        (np.diag([-1.0, -1.0, 1.0]), 0.0, False),  # ... except an exact half turn (t = 1/2)
        (rot([0, 0, 1], 90), 0.70, True),  # sigma_min = cos 45 = 0.7071
        (rot([0, 0, 1], 90), 0.71, False),
    ],
    ids=["identity", "identity-high-margin", "reflection", "singular-end", "margin-at-end",
         "margin-below-end", "rotation-100", "half-turn", "rotation-90-below", "rotation-90-above"],
)
def test_certify_named(A, margin, expected):
    assert certify(A, margin) is expected


def test_nonfinite_is_false_and_bad_input_raises():
    A = np.eye(3)
    A[0, 1] = np.nan
    assert certify(A) is False
    assert fast_margin_bound(A) == -np.inf
    for m in (1.0, -0.1, np.nan, 2.0):
        with pytest.raises(InputError):
            certify(np.eye(3), m)
    with pytest.raises(InputError):
        certify(np.eye(2))


# --- exact test against dense sampling -------------------------------------------------


@pytest.mark.parametrize("scale", [0.3, 0.8, 1.5])
def test_certify_against_sampling(rng, scale):
    n_true = n_false = 0
    for _ in range(60):
        A = np.eye(3) + scale * rng.standard_normal((3, 3))
        m = float(rng.choice([0.0, rng.uniform(0, 0.9)]))
        ok = certify(A, m)
        smin = refined_min(A)
        if ok:
            # Certified: no sample may fall below the margin.
            assert smin >= m - 1e-12
            n_true += 1
        else:
            # Not certified: an exact root exists, so sigma_min reaches m somewhere.
            assert smin <= m + 1e-6
            n_false += 1
        if smin < m - 1e-9:
            assert not ok
    assert n_true > 5 and n_false > 5  # both verdicts exercised


def test_certify_m0_matches_real_eigenvalue_criterion(rng):
    # m = 0: certified iff A has no real eigenvalue in (-inf, 0] (SPEC section 5).
    checked = 0
    for _ in range(300):
        A = np.eye(3) + 1.2 * rng.standard_normal((3, 3))
        ev = np.linalg.eigvals(A)
        real = ev[np.abs(ev.imag) < 1e-12].real
        if np.any(np.abs(real) < 1e-8):
            continue  # too close to call in floating point
        assert certify(A, 0.0) == (not np.any(real < 0))
        checked += 1
    assert checked > 250


# --- the fast test is rigorous ------------------------------------------------------------


def test_fast_implies_exact_random(rng):
    passed = 0
    for _ in range(400):
        A = np.eye(3) + float(rng.choice([0.05, 0.3, 1.0])) * rng.standard_normal((3, 3))
        m = float(rng.uniform(0, 0.95))
        fb = fast_margin_bound(A)
        # a lower bound of the true minimum, hence of any sample
        assert fb <= sigma_min_path(A, T_DENSE[::10]).min() + 1e-12
        if fb > m:
            passed += 1
            assert certify(A, m)
    assert passed > 50


@pytest.mark.parametrize("delta", [-1e-13, -1e-15, 0.0, 1e-15, 1e-14, 1e-13, 1e-12, 1e-10])
@pytest.mark.parametrize("margin", [0.0, 0.5])
def test_fast_implies_exact_at_the_boundary(rng, delta, margin):
    # sym(D) with lambda_min placed within rounding of margin - 1: the fast test
    # may say no, but whenever it says yes the exact test must agree.
    for _ in range(60):
        Q = np.linalg.qr(rng.standard_normal((3, 3)))[0]
        lam = np.array([margin - 1 + delta, rng.uniform(-0.3, 0.5), rng.uniform(-0.3, 0.5)])
        K = rng.standard_normal((3, 3)) * float(rng.choice([0.0, 0.3]))
        D = (Q * lam) @ Q.T + 0.5 * (K - K.T)
        A = np.eye(3) + D
        if fast_margin_bound(A) > margin:
            assert certify(A, margin)


def test_certified_margin_exact_only_case():
    A = rot([0, 1, 1], 100)  # fast bound < 0 (sym D has 1 + cos 100 - 1 < 0), exact passes
    assert fast_margin_bound(A) < 0
    v = certified_margin(A, 0.0)
    assert v > 0.6  # true minimum: cos(50 deg) = 0.643
    assert certify(A, v)
    assert np.isnan(certified_margin(np.diag([-1.0, -1.0, 1.0]), 0.0))
