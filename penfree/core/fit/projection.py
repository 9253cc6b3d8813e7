"""Projection of a fitted ``D`` onto certified maps (SPEC section 5).

Modes: ``none`` (untouched), ``svd`` (the original recipe: reflection-free
SVD with clamped singular values, falling back to ``sym`` when not
certified), ``sym`` (Frobenius-nearest ``D`` with ``lambda_min(sym D) >= m - 1``,
always certified), ``auto`` (``D`` if certified, else the certified candidate
with the smaller residual to ``x_pred``).
"""

from __future__ import annotations

import numpy as np

from ... import constants as K
from ...errors import InputError
from .certificate import certify_map

_I3 = np.eye(3)


def is_certified(D, margin: float) -> bool:
    """``certify(I + D, margin)`` for the float64 ``A = I + D``; fast test first."""
    return certify_map(_I3 + np.asarray(D, dtype=np.float64), margin)


def _safety(S) -> float:
    return K.SYM_SAFETY_REL * (1.0 + float(np.linalg.norm(S)))


def project_sym(D, margin: float = 0.0) -> np.ndarray:
    """Frobenius-nearest ``D'`` with ``lambda_min(sym D') >= margin - 1`` (+ safety).

    Parameters
    ----------
    D : (3, 3) float64
    margin : float in [0, 1)

    Returns
    -------
    (3, 3) float64
        ``skew(D)`` kept, eigenvalues of ``sym(D)`` clamped from below at
        ``margin - 1 + SYM_SAFETY_REL (1 + ||sym D||_F)``; ``D`` itself when
        no eigenvalue needs clamping.

    Notes
    -----
    The set ``{D : sym D >= (m - 1) I}`` is convex and its Frobenius
    projection acts on ``sym D`` alone (``sym`` and ``skew`` are orthogonal).
    The safety keeps the rounded result above the fast test's rounding
    allowance, so ``fast_margin_bound(I + D') > margin``.
    """
    D = np.asarray(D, dtype=np.float64)
    S = 0.5 * (D + D.T)
    lam, V = np.linalg.eigh(S)
    lo = margin - 1.0 + _safety(S)
    if lam[0] >= lo:
        return D.copy()
    lam = np.maximum(lam, lo)
    return (V * lam) @ V.T + 0.5 * (D - D.T)


def project_svd(D, margin: float = 0.0) -> np.ndarray:
    """The original recipe: ``A = U S V^T`` made reflection-free, ``S`` clamped
    into ``[margin (+ safety), SVD_SMAX]``; returns ``D' = A' - I`` (not yet certified).

    A reflection (``det(U V^T) < 0``) flips the last singular vector pair so
    that ``det A' > 0``.
    """
    A = np.eye(3) + np.asarray(D, dtype=np.float64)
    U, s, Vt = np.linalg.svd(A)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        U[:, 2] = -U[:, 2]
    s = np.clip(s, margin + _safety(s), K.SVD_SMAX)
    return (U * s) @ Vt - np.eye(3)


def project(D, mode: str = "auto", margin: float = 0.0, residual=None, *, known_uncertified=False):
    """Project ``D`` so that ``I + D`` is certified for `margin`.

    Parameters
    ----------
    D : (3, 3) float64
    mode : {"none", "svd", "sym", "auto"}
    margin : float in [0, 1)
    residual : callable D -> float or None
        Residual to compare ``auto`` candidates (e.g. ``lambda D:
        fit.residual_gain(moments, D)``); default the Frobenius distance to `D`.
    known_uncertified : bool
        The caller already found ``I + D`` uncertified: ``auto`` skips re-testing it.

    Returns
    -------
    D_projected : (3, 3) float64
    mode_used : str
        ``"none"`` when ``D`` is returned untouched (mode ``none``, or ``auto``
        with a certified ``D``), else ``"svd"`` or ``"sym"``.

    Notes
    -----
    Mode ``none`` does not certify; the caller decides (`fit_step` falls back
    to the translation). The ``svd`` and ``sym`` results are certified
    (``sym`` by construction and the fast test).

    Examples
    --------
    >>> D, used = project(np.diag([0.0, 0.0, -1.5]), "sym")
    >>> used, bool(np.linalg.eigvalsh(D)[0] > -1.0)
    ('sym', True)
    """
    if mode not in K.PROJECTIONS:
        raise InputError(f"projection must be one of {K.PROJECTIONS}; got {mode!r}")
    D = np.asarray(D, dtype=np.float64)
    if mode == "none":
        return D.copy(), "none"
    if mode == "sym":
        return project_sym(D, margin), "sym"
    if mode == "auto" and not known_uncertified and is_certified(D, margin):
        return D.copy(), "none"
    D_svd = project_svd(D, margin)
    svd_ok = is_certified(D_svd, margin)
    if mode == "svd":
        return (D_svd, "svd") if svd_ok else (project_sym(D, margin), "sym")
    D_sym = project_sym(D, margin)
    if not svd_ok:
        return D_sym, "sym"
    if residual is None:
        def residual(X):
            return float(np.linalg.norm(X - D))
    return (D_svd, "svd") if residual(D_svd) < residual(D_sym) else (D_sym, "sym")
