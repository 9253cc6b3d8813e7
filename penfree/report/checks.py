"""CI checks over file reports: thresholds, regression against a baseline report, and the
re-check of every stored map through the one certification gate."""

from __future__ import annotations

import math

import numpy as np


def recheck_certificates(steps, groups=None) -> np.ndarray:
    """Re-run the one certification gate on every stored map: (S,) bool, never trusting stored claims.

    Step k is certified when ``certify_map(steps/A[k], m)`` holds with m its
    ``margin_required`` (0 where the file has none; m >= 1 means no margin was
    possible and only the identity is accepted, as in verify). A per-component
    step (``steps/A`` all NaN) needs every map ``component_maps/A[k]`` certified.
    A NaN, infinite or negative margin, a partly NaN map or missing component maps
    count as not certified.
    """
    from ..core.fit.certificate import certify_map

    A = np.asarray(steps["A"], dtype=np.float64)
    S = A.shape[0]
    req = np.asarray(steps.get("margin_required", np.zeros(S)), dtype=np.float64).reshape(-1)
    comp = (groups or {}).get("component_maps")
    comp_A = np.asarray(comp["A"], dtype=np.float64) if isinstance(comp, dict) and "A" in comp else None
    if comp_A is not None and (comp_A.ndim != 4 or comp_A.shape[0] != S or comp_A.shape[2:] != (3, 3)):
        comp_A = None
    ok = np.zeros(S, dtype=bool)
    for k in range(S):
        m = req[k] if req.size == S else np.nan
        if not np.isfinite(m) or m < 0:
            continue
        if np.isfinite(A[k]).all():
            maps = [A[k]]
        elif np.isnan(A[k]).all() and comp_A is not None and np.isfinite(comp_A[k]).all() and len(comp_A[k]):
            maps = list(comp_A[k])
        else:
            continue
        if m >= 1.0:
            ok[k] = all(np.array_equal(M, np.eye(3)) for M in maps)
        else:
            ok[k] = all(certify_map(M, m) for M in maps)
    return ok


def _started_dirty(steps, seq, frames):
    if "start_intersections" in steps:
        return int(np.count_nonzero(np.asarray(steps["start_intersections"]) > 0))
    if seq is None:
        return None
    from ..core.pipeline.deform import start_state_intersections

    return int(np.count_nonzero(start_state_intersections(seq, np.asarray(frames, dtype=np.int64)) > 0))


def certificate_summary(steps, rechecked=None, seq=None) -> dict:
    """Min margin, all certified yes/no, models and projections used, from ``steps/``.

    A step counts as certified when its ``certificate_margin`` is finite and at least
    its ``margin_required`` (0 where the file has none) and, when `rechecked` (from
    `recheck_certificates`) is given, its map passes the certificate again. The steps
    that started dirty come from ``steps/start_intersections``, else are counted on
    `seq` when given.
    """
    frames = np.asarray(steps.get("frame", np.arange(np.size(steps.get("certificate_margin", [])))))
    # No stored margin claims nothing: every step counts as not certified.
    cm = np.asarray(steps.get("certificate_margin", np.full(frames.size, np.nan)), dtype=np.float64)
    req = np.asarray(steps.get("margin_required", np.zeros_like(cm)), dtype=np.float64)
    ok = np.isfinite(cm) & (cm >= np.where(np.isfinite(req), req, 0.0))
    if rechecked is not None:
        ok = ok & rechecked if ok.shape == rechecked.shape else np.asarray(rechecked, dtype=bool)

    def counts(key):
        names, n = np.unique(np.asarray(steps.get(key, []), dtype=str), return_counts=True)
        return {str(a): int(b) for a, b in zip(names, n)}

    return {
        "min_margin": float(np.nanmin(cm)) if cm.size and not np.all(np.isnan(cm)) else math.nan,
        "all_certified": bool(ok.all()) if ok.size else False,
        "n_uncertified": int(np.count_nonzero(~ok)),
        "uncertified_frames": frames[~ok].tolist(),
        "n_started_dirty": _started_dirty(steps, seq, frames),
        "models": counts("model"),
        "projections": counts("projection"),
    }


#: Figures compared against a baseline report: (dotted path in ``summary``, True if
#: higher is better).
REGRESSION_FIGURES = (
    ("deformed.k_1pct_next", False),
    ("projected.k_1pct.speedup", True),
    ("deformed.hit_rate_next", True),
)


def _dig(d, dotted):
    for part in dotted.split("."):
        if not isinstance(d, dict) or part not in d:
            return None
        d = d[part]
    return None if d is None or (isinstance(d, float) and math.isnan(d)) else float(d)


def _check(name, file, passed, value, threshold, message):
    return {"name": name, "file": file, "passed": bool(passed), "value": value, "threshold": threshold,
            "message": message}


def run_checks(reports, *, fail_if_uncertified=False, min_speedup=None, min_hit_rate_gain=None,
               baseline=None, max_regression=None) -> list:
    """CI checks over the file reports; a check that cannot be evaluated fails.

    Parameters
    ----------
    reports : list of dict
        `build_file_report` entries.
    fail_if_uncertified : bool
        Every step's certificate margin must be finite and >= its required margin.
    min_speedup : float, optional
        Minimum *projected* speedup (K_1pct rule, against the next frame).
    min_hit_rate_gain : float, optional
        Minimum gain of the hit rate against the next frame, deformed minus baseline,
        in *percentage points* (5 means from e.g. 60 % to at least 65 %).
    baseline : dict, optional
        A stored report.json (`load_report_json`); files are matched by ``name``
        (a single file on each side is matched whatever its name).
    max_regression : float, optional
        Largest allowed regression against `baseline`, in percent of the baseline
        value, of each figure of `REGRESSION_FIGURES` (lower K_1pct, higher speedup and
        hit rate are better).

    Returns
    -------
    list of dict
        {``name``, ``file``, ``passed``, ``value``, ``threshold``, ``message``}.
    """
    checks = []
    for rep in reports:
        name, sm = rep["name"], rep["summary"]
        if fail_if_uncertified:
            c = rep["certificate"]
            checks.append(_check("certified", name, c["all_certified"] and c["n_uncertified"] == 0,
                                 c["n_uncertified"], 0,
                                 f"{c['n_uncertified']} uncertified step(s)" + (
                                     f", frames {c['uncertified_frames'][:10]}" if c["n_uncertified"] else "")))
        if min_speedup is not None:
            v = _dig(sm, "projected.k_1pct.speedup")
            checks.append(_check("min_speedup", name, v is not None and v >= min_speedup, v, min_speedup,
                                 "no step with a next frame" if v is None else
                                 f"projected speedup {v:.3f} (minimum {min_speedup:g})"))
        if min_hit_rate_gain is not None:
            v = _dig(sm, "hit_rate_gain_next")
            v = None if v is None else 100.0 * v
            checks.append(_check("min_hit_rate_gain", name, v is not None and v >= min_hit_rate_gain, v,
                                 min_hit_rate_gain, "no step with a next frame" if v is None else
                                 f"hit-rate gain {v:+.2f} points (minimum {min_hit_rate_gain:+g})"))
        if baseline is not None:
            checks.extend(_regression_checks(rep, baseline, max_regression, single=len(reports) == 1))
    return checks


def _regression_checks(rep, baseline, max_regression, single):
    name = rep["name"]
    old_files = baseline.get("files", [])
    match = [f for f in old_files if f.get("name") == name]
    if not match and single and len(old_files) == 1:
        match = old_files
    if not match:
        return [_check("regression", name, False, None, max_regression, f"no entry for {name} in the baseline report")]
    old_sm, out = match[0].get("summary", {}), []
    for path, higher_better in REGRESSION_FIGURES:
        old, new = _dig(old_sm, path), _dig(rep["summary"], path)
        if old is None:
            out.append(_check(f"regression:{path}", name, True, new, max_regression, "no baseline value; not compared"))
            continue
        if new is None:
            out.append(_check(f"regression:{path}", name, False, None, max_regression,
                              f"baseline {old:g}, now missing"))
            continue
        worse = (old - new) if higher_better else (new - old)
        pct = 100.0 * worse / abs(old) if old != 0 else (math.inf if worse > 0 else 0.0)
        out.append(_check(f"regression:{path}", name, pct <= max_regression, new, max_regression,
                          f"{old:g} -> {new:g} ({'+' if pct > 0 else ''}{pct:.2f}% regression, "
                          f"maximum {max_regression:g}%)" if pct > 0 else f"{old:g} -> {new:g} (no regression)"))
    return out


# ---------------------------------------------------------------- Markdown
