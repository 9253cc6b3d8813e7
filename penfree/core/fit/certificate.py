"""Certificate that the straight path ``x + t (x_def - x)`` keeps every gap (SPEC section 5).

The path is ``c + M(t) P + t u`` with ``M(t) = I + t D``, ``A = I + D``. It is
penetration-free, with gaps shrinking by at most a factor ``m``, iff
``sigma_min(M(t)) > m`` for all ``t in [0, 1]``.

Two tests:

- `certify` decides this exactly from the float64 entries of ``A`` with
  integer (dyadic-rational) arithmetic and a Sturm sequence;
- `fast_margin_bound` is a cheap, rigorous sufficient test: whenever its bound
  exceeds ``m``, `certify(A, m)` is True.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ... import constants as K
from ...errors import InputError
from ..polynomial import add, count_roots_01, mul, sub, trim


def _check_A(A) -> np.ndarray:
    if type(A) is np.ndarray and A.dtype == np.float64 and A.shape == (3, 3):
        return A  # the common case, read only below (fit_step calls this per candidate)
    arr = np.asarray(A)
    if arr.shape != (3, 3):
        raise InputError(f"A must be (3, 3); got shape {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise InputError(f"A must be a float array; got dtype {arr.dtype}")
    return arr.astype(np.float64)


def _check_margin(margin) -> float:
    m = float(margin)
    if not 0.0 <= m < 1.0:
        raise InputError(f"margin must be in [0, 1); got {margin!r}")
    return m


def fast_margin_bound(A) -> float:
    """Rigorous lower bound of ``min_{t in [0,1]} sigma_min(I + t D)``, ``D = A - I``.

    Parameters
    ----------
    A : (3, 3) float64

    Returns
    -------
    float
        ``min(1, 1 + lambda_min(sym D)) - FAST_CERT_ROUNDING_C * eps * (1 + ||sym D||_F)``;
        ``-inf`` for non-finite ``A``.

    Notes
    -----
    For unit ``v``, ``|M(t) v| >= v^T M(t) v = 1 + t v^T sym(D) v``, hence
    ``sigma_min(M(t)) >= min(1, 1 + lambda_min(sym D))`` on ``[0, 1]`` (field of
    values). The subtracted term bounds all floating-point error (Weyl's
    inequality for the rounding of ``A - I`` and of the symmetrisation, whose
    entrywise relative errors are <= eps/2, plus LAPACK's backward error for a
    3x3 symmetric eigenproblem and the final additions). So
    ``fast_margin_bound(A) > m`` implies ``certify(A, m)``.

    Examples
    --------
    >>> fast_margin_bound(np.eye(3)) > 0.999
    True
    """
    return _fast_bound(_check_A(A))


_I3 = np.eye(3)
_EPS = float(np.finfo(np.float64).eps)
#: The fast bound's rounding allowance per unit of ``1 + ||sym D||_F``.
FAST_BOUND_ALLOWANCE = K.FAST_CERT_ROUNDING_C * _EPS


def _fast_bound(A: np.ndarray) -> float:
    """`fast_margin_bound` without argument checks, for (3, 3) float64 `A`."""
    return float(_fast_bound_kernel(A, FAST_BOUND_ALLOWANCE))


@njit(cache=True)
def _fast_bound_kernel(A, allowance):
    # No fastmath: the rounding budget assumes IEEE arithmetic as written.
    S = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            dij = A[i, j] - (1.0 if i == j else 0.0)
            dji = A[j, i] - (1.0 if i == j else 0.0)
            S[i, j] = 0.5 * (dij + dji)
    if not np.isfinite(S).all():
        return -np.inf
    lam_min = np.linalg.eigvalsh(S)[0]
    return min(1.0, 1.0 + lam_min) - allowance * (1.0 + np.sqrt(np.sum(S * S)))


# --- the certificate polynomial over the integers (coefficients low order first)


def _det3(M):
    """Determinant of a 3x3 matrix of polynomials (cofactor expansion)."""
    def minor(i, j, k, l):
        return sub(mul(M[i][k], M[j][l]), mul(M[i][l], M[j][k]))

    t0 = mul(M[0][0], minor(1, 2, 1, 2))
    t1 = mul(M[0][1], minor(1, 2, 0, 2))
    t2 = mul(M[0][2], minor(1, 2, 0, 1))
    return add(sub(t0, t1), t2)


def certificate_polynomial(A, margin: float = 0.0) -> list:
    """Integer coefficients (low order first) of a positive multiple of ``q(t)``.

    ``q(t) = det(M(t))`` for ``margin == 0`` (degree <= 3), else
    ``det(M(t)^T M(t) - margin^2 I)`` (degree <= 6), ``M(t) = I + t (A - I)``,
    both scaled by a positive power of two so that the float64 entries of
    ``A`` and ``margin`` enter exactly as integers.
    """
    A = _check_A(A)
    m = _check_margin(margin)
    ratios = [[float(A[i, j]).as_integer_ratio() for j in range(3)] for i in range(3)]
    L = max(den for row in ratios for _, den in row)  # all powers of two
    # L * M(t) = L I + t Dn with Dn = L (A - I): exact integers.
    LM = [[[L if i == j else 0, (num - (den if i == j else 0)) * (L // den)]
           for j, (num, den) in enumerate(row)] for i, row in enumerate(ratios)]
    LM = [[trim(e) for e in row] for row in LM]
    if m == 0.0:
        return _det3(LM)
    mn, md = m.as_integer_ratio()
    # md^2 (LM)^T (LM) - L^2 mn^2 I  =  (L md)^2 (M^T M - m^2 I)
    N = [[None] * 3 for _ in range(3)]
    for i in range(3):
        for j in range(3):
            s = []
            for k in range(3):
                s = add(s, mul(LM[k][i], LM[k][j]))
            s = [md * md * a for a in s]
            if i == j:
                s = add(s, [-(L * L * mn * mn)])
            N[i][j] = s
    return _det3(N)


def certify(A, margin: float = 0.0) -> bool:
    """Exact test that ``sigma_min(I + t D) > margin`` for every ``t in [0, 1]``, ``D = A - I``.

    Parameters
    ----------
    A : (3, 3) float64
        The map; its float64 entries are taken as exact rationals.
    margin : float in [0, 1)

    Returns
    -------
    bool
        True iff ``q(t)`` (see `certificate_polynomial`) has no root in the
        closed interval ``[0, 1]``. False for non-finite ``A``.

    Raises
    ------
    InputError
        `A` not (3, 3) or `margin` outside ``[0, 1)``.

    Notes
    -----
    ``q(0) = (1 - m^2)^3 > 0``; each singular value of ``M(t)`` is continuous,
    so no root on ``[0, 1]`` means every singular value stays above ``m``.
    ``det(A) > 0`` is not sufficient: a 170 degree rotation composed with an
    anisotropic stretch has ``det > 0`` and a singular ``M(t)`` half-way.

    Examples
    --------
    >>> certify(np.eye(3))
    True
    >>> certify(np.diag([1.0, 1.0, -0.5]))
    False
    """
    A = _check_A(A)
    m = _check_margin(margin)
    if not np.isfinite(A).all():
        return False
    return count_roots_01(certificate_polynomial(A, m)) == 0


def certify_map(A, margin: float = 0.0) -> bool:
    """The one certification gate: ``True`` iff `A` provably keeps ``sigma_min(I + tD) > margin``.

    The cheap rigorous bound decides first (``fast_margin_bound(A) > margin`` implies
    ``certify(A, margin)``); the exact rational test decides the rest. Every path that
    writes or proposes a map goes through this function.

    >>> certify_map(np.eye(3))
    True
    """
    A = _check_A(A)
    m = _check_margin(margin)
    if _fast_bound(A) > m:  # -inf unless A is finite
        return True
    return bool(np.isfinite(A).all()) and count_roots_01(certificate_polynomial(A, m)) == 0


def _sampled_sigma_min(A, n: int = 65) -> float:
    t = np.linspace(0.0, 1.0, n)
    M = np.eye(3) + t[:, None, None] * (A - np.eye(3))
    return float(np.linalg.svd(M, compute_uv=False).min())


def certified_margin(A, margin: float = 0.0, *, exact_known: bool = False) -> float:
    """Best certified lower bound of ``sigma_min(M(t))`` over ``[0, 1]`` found cheaply.

    Returns the fast bound when it exceeds `margin`; else, if the exact test
    passes, a larger value certified exactly near a sampled estimate, or
    `margin` itself; ``nan`` when `A` is not certified for `margin`.
    Every returned finite value ``v >= margin`` satisfies ``certify(A, v)``.
    ``exact_known=True`` means the caller has already seen ``certify(A, margin)``
    pass (it is not repeated).
    """
    A = _check_A(A)
    m = _check_margin(margin)
    fb = _fast_bound(A)
    if fb > m:
        return fb
    if not exact_known and not certify(A, m):
        return math.nan
    est = _sampled_sigma_min(A)
    for f in (0.999, 0.9):
        cand = est * f
        if m < cand < 1.0 and certify(A, cand):
            return cand
    return m
