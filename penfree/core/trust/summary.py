"""Sequence-level figures from the per-step statistics, and the *projected* frame time
(SPEC section 7): the summary that `penfree report` and `penfree deform --stats` print."""

from __future__ import annotations

import math

import numpy as np

from ...constants import DEFAULT_CD_SHARE, DEFAULT_FRAME_MS
from ...errors import InputError
from .stats import STARTS, TARGETS

#: The *projected* frame time of `projected_frame_time`, as written into every report.
PROJECTED_FORMULA = "T' = T_frame ((1 - f) + f K_deformed / K_baseline) + t_fit, speedup = T_frame / T'"


def projected_frame_time(k_method, k_baseline, fit_ms=0.0, *, cd_share=DEFAULT_CD_SHARE,
                         frame_ms=DEFAULT_FRAME_MS) -> tuple:
    """*Projected* frame time and speedup (SPEC section 7).

    `T' = T_frame ((1 - f) + f K_method / K_baseline) + t_fit`, speedup `T_frame / T'`.

    Parameters
    ----------
    k_method, k_baseline : float
        CD passes per frame with and without the method (means over steps).
    fit_ms : float
        Mean per-step time of the method (fit + projection), milliseconds.
    cd_share : float
        Fraction `f` of the frame spent in CD, in [0, 1].
    frame_ms : float
        Frame time `T_frame` of the baseline simulator, milliseconds, > 0.

    Returns
    -------
    (float, float)
        ``(frame_ms_projected, speedup)``; NaN when a K is NaN.

    >>> projected_frame_time(1.0, 2.0, 0.0, cd_share=0.5, frame_ms=32.0)
    (24.0, 1.3333333333333333)
    """
    if not (0.0 <= cd_share <= 1.0):
        raise InputError(f"cd_share must be in [0, 1]; got {cd_share}")
    if not (frame_ms > 0 and math.isfinite(frame_ms)):
        raise InputError(f"frame_ms must be finite and > 0; got {frame_ms}")
    if not (k_baseline > 0):  # NaN or no baseline passes: nothing to project
        return math.nan, math.nan
    t = frame_ms * ((1.0 - cd_share) + cd_share * k_method / k_baseline) + fit_ms
    return float(t), float(frame_ms / t)


def finite_mean(a):
    """Mean of the finite entries of `a` (NaN when there are none)."""
    a = np.asarray(a, dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(a.mean()) if a.size else math.nan


def _sum(a):
    a = np.asarray(a, dtype=np.float64)
    return float(a[np.isfinite(a)].sum())


def _max(a):
    a = np.asarray(a, dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(a.max()) if a.size else math.nan


def summarize(stats, steps=None, cd_share=DEFAULT_CD_SHARE, frame_ms=DEFAULT_FRAME_MS) -> dict:
    """Sequence-level figures from `compute_stats` output, with the *projected* frame time.

    Parameters
    ----------
    stats : dict of str -> ndarray
        `compute_stats` output (or the ``stats/`` group of a result file).
    steps : dict of str -> ndarray, optional
        The result's ``steps/`` arrays; the median of ``time_fit_s`` is the per-step
        fit time added to the projected frame time (0 without it).
    cd_share, frame_ms : float
        CD share `f` of the frame and baseline frame time `T_frame` (milliseconds).

    Returns
    -------
    dict
        ``n_steps``, ``n_steps_next``, ``fit_ms_mean``, ``fit_ms_median``,
        ``hit_rate_gain_next`` /
        ``hit_rate_gain_pred`` (deformed minus baseline, fractions), and per start state
        (``baseline``, ``deformed``) for each target ``<t>``: ``hit_rate_<t>``,
        ``k_any_<t>``, ``k_1pct_<t>`` (means over steps), ``k_any_<t>_total``,
        ``k_1pct_<t>_total`` (sums), ``k_any_<t>_max``, ``k_1pct_<t>_max``,
        ``n_blocked_<t>`` (sum), ``r_max_<t>`` (max), ``residual_<t>_rms`` (RMS pooled
        over steps), ``residual_<t>_max`` (max), and with replay ``replay_k_any_<t>``,
        ``replay_k_1pct_<t>`` (means), ``replay_capped_<t>`` (count of capped steps).
        ``projected``: ``label`` ("projected"), ``cd_share``, ``frame_ms``, ``fit_ms``,
        ``fit_ms_statistic`` ("median"), ``target`` ("next"), and
        per rule (``k_1pct``, ``k_any``, with replay ``replay_k_1pct``,
        ``replay_k_any``) ``k_baseline``, ``k_deformed`` (mean passes over the steps
        with a next frame), ``frame_ms`` (projected T') and ``speedup``.

    Notes
    -----
    The mean K over steps is a ratio of totals (total CD passes of the sequence), so the
    projection compares whole-sequence CD cost. `T_frame` and `f` describe the
    simulator the numbers are projected onto, not this recording; the fit time is the
    one measured here, as the median over steps: the first step of a run can include
    Numba compilation (hundreds of ms), which a simulator pays once, not per frame.
    """
    S = int(np.asarray(stats["frame"]).shape[0])
    has_next = np.isfinite(np.asarray(stats["hit_rate_next_baseline"], dtype=np.float64))
    replay = "replay_k_any_next_baseline" in stats
    out = {"n_steps": S, "n_steps_next": int(has_next.sum())}
    for s in STARTS:
        block = {}
        for t in TARGETS:
            block[f"hit_rate_{t}"] = finite_mean(stats[f"hit_rate_{t}_{s}"])
            for k in ("k_any", "k_1pct"):
                block[f"{k}_{t}"] = finite_mean(stats[f"{k}_{t}_{s}"])
                block[f"{k}_{t}_total"] = _sum(stats[f"{k}_{t}_{s}"])
                block[f"{k}_{t}_max"] = _max(stats[f"{k}_{t}_{s}"])
            block[f"n_blocked_{t}"] = _sum(stats[f"n_blocked_{t}_{s}"])
            block[f"r_max_{t}"] = _max(stats[f"r_max_{t}_{s}"])
            rms = np.asarray(stats[f"residual_{t}_rms_{s}"], dtype=np.float64)
            block[f"residual_{t}_rms"] = math.sqrt(finite_mean(rms * rms))
            block[f"residual_{t}_max"] = _max(stats[f"residual_{t}_max_{s}"])
            if replay:
                block[f"replay_k_any_{t}"] = finite_mean(stats[f"replay_k_any_{t}_{s}"])
                block[f"replay_k_1pct_{t}"] = finite_mean(stats[f"replay_k_1pct_{t}_{s}"])
                block[f"replay_capped_{t}"] = _sum(stats[f"replay_capped_{t}_{s}"])
        out[s] = block
    for t in TARGETS:
        out[f"hit_rate_gain_{t}"] = out["deformed"][f"hit_rate_{t}"] - out["baseline"][f"hit_rate_{t}"]
    fit_ms = fit_mean = 0.0
    if steps is not None and "time_fit_s" in steps:
        t_fit = np.asarray(steps["time_fit_s"], dtype=np.float64)[:S]
        t_fit = t_fit[np.isfinite(t_fit)]
        if t_fit.size:
            fit_ms, fit_mean = float(np.median(t_fit)) * 1e3, float(t_fit.mean()) * 1e3
    out["fit_ms_mean"], out["fit_ms_median"] = fit_mean, fit_ms
    proj = {"label": "projected", "cd_share": float(cd_share), "frame_ms": float(frame_ms),
            "fit_ms": fit_ms, "fit_ms_statistic": "median", "target": "next"}
    rules = ["k_1pct", "k_any"] + (["replay_k_1pct", "replay_k_any"] if replay else [])
    for rule in rules:
        kb, km = out["baseline"][f"{rule}_next"], out["deformed"][f"{rule}_next"]
        t_ms, speedup = projected_frame_time(km, kb, fit_ms, cd_share=cd_share, frame_ms=frame_ms)
        proj[rule] = {"k_baseline": kb, "k_deformed": km, "frame_ms": t_ms, "speedup": speedup}
    out["projected"] = proj
    return out
