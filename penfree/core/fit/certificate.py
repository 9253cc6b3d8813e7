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


def _check_A(A) -> np.ndarray:
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


def _fast_bound(A: np.ndarray) -> float:
    """`fast_margin_bound` without argument checks, for (3, 3) float64 `A`."""
    return float(_fast_bound_kernel(A, K.FAST_CERT_ROUNDING_C * _EPS))


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


# --- exact polynomial arithmetic over the integers (coefficients low order first)


def _trim(p):
    while len(p) > 1 and p[-1] == 0:
        p = p[:-1]
    return p


def _add(p, q):
    n = max(len(p), len(q))
    return _trim([(p[i] if i < len(p) else 0) + (q[i] if i < len(q) else 0) for i in range(n)])


def _mul(p, q):
    r = [0] * (len(p) + len(q) - 1)
    for i, a in enumerate(p):
        if a:
            for j, b in enumerate(q):
                r[i + j] += a * b
    return _trim(r)


def _neg(p):
    return [-a for a in p]


def _det3(M):
    """Determinant of a 3x3 matrix of polynomials (cofactor expansion)."""
    def minor(i, j, k, l):
        return _add(_mul(M[i][k], M[j][l]), _neg(_mul(M[i][l], M[j][k])))

    t0 = _mul(M[0][0], minor(1, 2, 1, 2))
    t1 = _mul(M[0][1], minor(1, 2, 0, 2))
    t2 = _mul(M[0][2], minor(1, 2, 0, 1))
    return _add(_add(t0, _neg(t1)), t2)


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
    LM = [[_trim(e) for e in row] for row in LM]
    if m == 0.0:
        return _det3(LM)
    mn, md = m.as_integer_ratio()
    # md^2 (LM)^T (LM) - L^2 mn^2 I  =  (L md)^2 (M^T M - m^2 I)
    N = [[None] * 3 for _ in range(3)]
    for i in range(3):
        for j in range(3):
            s = [0]
            for k in range(3):
                s = _add(s, _mul(LM[k][i], LM[k][j]))
            s = [md * md * a for a in s]
            if i == j:
                s = _add(s, [-(L * L * mn * mn)])
            N[i][j] = s
    return _det3(N)


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
        r = _trim(r[:-1]) if len(r) > 1 else [0]
    return _trim(r)


def _primitive(p):
    g = 0
    for a in p:
        g = math.gcd(g, a)
    return [a // g for a in p] if g > 1 else p


def _variations(values):
    signs = [v > 0 for v in values if v != 0]
    return sum(1 for a, b in zip(signs, signs[1:]) if a != b)


def count_roots_01(p) -> int:
    """Number of distinct real roots of the integer polynomial `p` in the closed ``[0, 1]``.

    Sturm's theorem on ``p, p', -rem, ...``; repeated roots are counted once
    (the chain ends at ``gcd(p, p')``, a common factor that does not change
    the sign variations). Endpoints are tested directly. The zero polynomial
    raises ValueError.
    """
    p = _trim(list(p))
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
    chain = [_primitive(p), _primitive(_trim([i * a for i, a in enumerate(p)][1:]))]
    while len(chain[-1]) > 1:
        r = _prem_pos(chain[-2], chain[-1])
        if not any(r):
            break
        chain.append(_primitive(_neg(r)))
    v0 = _variations([q[0] for q in chain])
    v1 = _variations([sum(q) for q in chain])
    return n_end + (v0 - v1)


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
    if not np.isfinite(A).all():
        return False
    return _fast_bound(A) > m or count_roots_01(certificate_polynomial(A, m)) == 0


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
