"""CI checks over file reports: thresholds, regression against a baseline report, and the
re-check of every stored map: through the one certification gate, and as the map whose
image the stored deformed state is (`applied_maps`)."""

from __future__ import annotations

import math

import numpy as np

from ..constants import UNIT_ROUNDOFF
from .baseline import REGRESSION_FIGURES, match_baseline

#: Vertex rows per block of the applied-map check: its temporaries stay bounded whatever N.
APPLIED_BLOCK_ROWS = 1 << 15
#: Float64 error of deform's x_def against the stored map, in units of UNIT_ROUNDOFF per
#: unit of the magnitudes summed in `applied_maps` (at most 20 are needed; see there).
APPLIED_F64_ROUNDINGS = 32.0
#: Roundings of the stored dtype allowed per unit of ``|x_def| + |x|`` (2 are needed, for a
#: shortened step; see `applied_maps`).
APPLIED_DTYPE_ROUNDINGS = 2.5
#: A map whose terms in `applied_maps`' bound exceed the coordinates involved by more than
#: this factor (they cancel) makes that bound loose: its step needs verify's path check too.
APPLIED_CANCELLATION_MAX = 64.0


def _component_arrays(groups, S, N, seq):
    """``(A (S, C, 3, 3), b (S, C, 3), labels (N,))`` float64 / int64 of ``component_maps/``,
    or None when it cannot serve. Labels are deform's own (`component_labels` of the
    sequence); stored ``labels`` that differ make the maps unusable."""
    comp = (groups or {}).get("component_maps")
    if not isinstance(comp, dict):
        return None
    A, b, labels = comp.get("A"), comp.get("b"), comp.get("labels")
    if A is None or b is None or isinstance(A, dict) or isinstance(b, dict) or isinstance(labels, dict):
        return None
    A, b = np.asarray(A), np.asarray(b)
    if (seq is None or A.dtype.kind not in "iuf" or b.dtype.kind not in "iuf" or A.ndim != 4 or A.shape[0] != S
            or A.shape[2:] != (3, 3) or b.shape != A.shape[:2] + (3,)):
        return None
    from ..core.pipeline.components import component_labels

    # deform's components of the scene; stored labels must be those (a finer partition,
    # e.g. one label per vertex, would let any state be "the image" of per-vertex maps)
    own = component_labels(N, seq.edges, seq.faces, seq.components)
    if labels is not None and not (np.shape(labels) == (N,) and np.array_equal(np.asarray(labels), own)):
        return None
    if N and own.max() >= A.shape[1]:
        return None
    return A.astype(np.float64), b.astype(np.float64), own


def _is_image(x, x_def, A, b, labels=None) -> tuple:
    """``(image, loose)``: every coordinate of `x_def` lies within the bound of `applied_maps`
    of the exact ``A[l] x + b[l]`` (``l`` the vertex's label, 0 without `labels`); the map
    terms of that bound exceed ``APPLIED_CANCELLATION_MAX`` times the coordinates."""
    # One rounding to the stored dtype, which SPEC section 8 makes the input's: a
    # stored dtype coarser than the positions' earns no more room than theirs.
    fi = min((np.finfo(np.dtype(x_def.dtype)), np.finfo(np.dtype(x.dtype))), key=lambda f: f.eps)
    u_d, eta = float(fi.eps) / 2.0, float(fi.smallest_subnormal)
    n = x.shape[0]
    X = np.zeros(3)
    for lo in range(0, n, APPLIED_BLOCK_ROWS):
        X = np.maximum(X, np.abs(np.asarray(x[lo:lo + APPLIED_BLOCK_ROWS], dtype=np.float64)).max(axis=0))
    absA = np.abs(A)
    # deform's centre terms, per map: |D| = |A - I| (deform takes D = A - I back) and |c_j| <= X_j
    centre = 2.0 * np.einsum("cij,j->ci", np.abs(A - np.eye(3)), X) + np.abs(b)
    loose = False
    for lo in range(0, n, APPLIED_BLOCK_ROWS):
        xb = np.asarray(x[lo:lo + APPLIED_BLOCK_ROWS], dtype=np.float64)
        vb = np.asarray(x_def[lo:lo + APPLIED_BLOCK_ROWS], dtype=np.float64)
        ax, av = np.abs(xb), np.abs(vb)
        if labels is None:
            y = xb @ A[0].T + b[0]
            mag = ax @ absA[0].T + centre[0]
        else:
            lab = labels[lo:lo + APPLIED_BLOCK_ROWS]
            y = np.einsum("nij,nj->ni", A[lab], xb) + b[lab]
            mag = np.einsum("nij,nj->ni", absA[lab], ax) + centre[lab]
        tol = (APPLIED_F64_ROUNDINGS * UNIT_ROUNDOFF * (mag + ax + av)
               + APPLIED_DTYPE_ROUNDINGS * u_d * (av + ax) + 2.0 * eta)
        if not (np.abs(vb - y) <= tol).all():  # NaN fails too
            return False, loose
        loose = loose or bool((mag > APPLIED_CANCELLATION_MAX * (ax + av + X)).any())
    return True, loose


def _path_passes(seq, s, x_def) -> bool:
    """verify's check of the path from ``positions[s]`` to `x_def` at the result's thickness."""
    from ..core.pipeline.verification import verify_deformed_path

    return verify_deformed_path(seq, s, x_def, seq.thickness).ok


def applied_maps(steps, groups=None, seq=None) -> np.ndarray:
    """(S,) bool: ``steps/deformed[k]`` is the image ``A x + b`` of step k's stored map(s)
    (x = ``positions[frame]``) up to the rounding of forming and writing it.

    A per-component step (``steps/A`` all NaN) checks each vertex against its
    component's map (``component_maps/A``, ``component_maps/b``; the components are
    deform's own, `component_labels`, which stored labels must equal). Without `seq`,
    with unusable component maps or a non-finite map, a step is not applied.

    Notes
    -----
    Per vertex and coordinate i, with ``v`` the stored value, ``X_j = max_v |x_vj|`` over
    the step's start state and ``u`` the float64 unit roundoff, the check is

        |v_i - (A x + b)_i| <= 32 u (|x_i| + sum_j |A_ij| |x_j| + 2 sum_j |A_ij - delta_ij| X_j
                                     + |b_i| + |v_i|)
                               + 2.5 u_d (|v_i| + |x_i|) + 2 eta_d

    (``u_d``, ``eta_d``: unit roundoff and smallest subnormal of the stored dtype, or of the
    positions' dtype where that is finer: SPEC section 8 stores the input's).

    Why every genuine result passes: deform (`penfree.core.fit.models.apply_map`) forms
    ``x_def = x + D (x - c) + u`` in float64, in any order, fused or not (error at most
    gamma_6 of ``|x_i| + sum_j |D_ij| (|x_j| + |c_j|) + |u_i|``), and stores ``A = I + D``
    with ``D = A - I`` taken back (u |A - I| |x|) and ``b = fl(u - D c)`` (gamma_4 of
    ``|u| + |D| |c|``); ``|D| = |A - I|``, ``|c_j| <= X_j`` (a weighted mean) and
    ``|u| <= |b| + |D| |c|``. This check's own float64 evaluation of ``A x + b`` adds
    gamma_4 of ``sum_j |A_ij x_j| + |b_i|`` (the bound of
    `penfree.core.verify.gate.deviation_bound`). In all at most 20 u of the magnitudes
    summed above; 32 u leaves room. Writing rounds once to the stored dtype (``u_d |v|``);
    a shortened step (``x + alpha (x_def - x)``, alpha < 1, of a map's own rounded
    ``x_def``, `penfree.core.pipeline.strategy.shortened`) carries alpha times that map's
    rounding, at most ``u_d (2 |x| + |v|)``: 2 u_d (|v| + |x|) in all, 2.5 with room.
    Doing nothing is exact, and per-component steps are per-group `fit_step` maps. The
    bound is a few ulps of the coordinates (float32) or about 100 (float64, far from
    the origin), far below any vertex spacing.

    Unless the map's terms cancel: a map with a huge entry along a direction in which
    the start state does not extend (a flat sheet's normal, say ``A_zz = 1e15`` with
    ``b_z = -1e15 z``) is the same map on the data, but its terms, and so the bound,
    are huge. Where they exceed ``APPLIED_CANCELLATION_MAX`` times the coordinates
    involved (deform's maps, near the identity, stay far below it), the step counts as
    applied only if the path to the stored state also passes verify's check
    (`verify_step`, obstacles at the step's frame): an edit hidden in that room cannot
    carry a penetration. Per-component labels must be deform's own (`component_labels`
    of the scene): the file's are compared with them.
    """
    frames = np.asarray(steps["frame"])
    S = frames.size
    ok = np.zeros(S, dtype=bool)
    deformed = steps.get("deformed")
    if seq is None or deformed is None or np.dtype(deformed.dtype).kind != "f":
        return ok
    N = seq.n_vertices
    if np.shape(deformed) != (S, N, 3):
        return ok
    A_all = np.asarray(steps["A"], dtype=np.float64)
    b_all = np.asarray(steps["b"], dtype=np.float64)
    comp = False  # not looked up yet
    for k in range(S):
        x = seq.positions[int(frames[k])]
        if np.isfinite(A_all[k]).all() and np.isfinite(b_all[k]).all():
            image, loose = _is_image(x, deformed[k], A_all[k][None], b_all[k][None])
        elif np.isnan(A_all[k]).all():
            if comp is False:
                comp = _component_arrays(groups, S, N, seq)
            if comp is None or not (np.isfinite(comp[0][k]).all() and np.isfinite(comp[1][k]).all()):
                continue
            image, loose = _is_image(x, deformed[k], comp[0][k], comp[1][k], comp[2])
        else:
            continue
        ok[k] = image and (not loose or _path_passes(seq, int(frames[k]), deformed[k]))
    return ok


def recheck_certificates(steps, groups=None, seq=None, applied=None) -> np.ndarray:
    """(S,) bool: step k's map(s) pass the one certification gate again *and* its stored
    deformed state is their image (`applied_maps`); never trusting stored claims.

    Step k's maps are certified when ``certify_map(A, m)`` holds for each with m its
    ``margin_required`` (0 where the file has none), and at least the margin of the
    result's thickness (`gate.margin_rule`, which deform never goes below; m >= 1 means
    no margin was possible and only the identity is accepted, as in verify). A per-component step (``steps/A``
    all NaN) needs every map ``component_maps/A[k]`` certified. A NaN, infinite or
    negative margin, a partly NaN map, missing component maps or a missing `seq` (the
    start states) count as not certified. `applied`: `applied_maps` output when the
    caller has it already.
    """
    from ..core.fit.certificate import certify_map

    A = np.asarray(steps["A"], dtype=np.float64)
    S = A.shape[0]
    req = np.asarray(steps.get("margin_required", np.zeros(S)), dtype=np.float64).reshape(-1)
    if seq is not None:  # a stored margin below the thickness's rule claims less than deform proves
        from ..core.verify.gate import margin_rule

        req = np.maximum(req, margin_rule(seq.thickness))  # NaN stays NaN
    # Without `seq` no step is certified (its deformed state cannot be checked): no maps needed.
    comp = None if seq is None else _component_arrays(groups, S, seq.n_vertices, seq)
    comp_A = None if comp is None else comp[0]
    ok = np.zeros(S, dtype=bool)
    for k in range(S):
        m = req[k] if req.size == S else np.nan
        if not np.isfinite(m) or m < 0:
            continue
        if np.isfinite(A[k]).all():
            maps = [A[k]]
        elif np.isnan(A[k]).all() and comp_A is not None and np.isfinite(comp_A[k]).all() and len(comp_A[k]):
            maps = list(np.unique(comp_A[k], axis=0))
        else:
            continue
        if m >= 1.0:
            ok[k] = all(np.array_equal(M, np.eye(3)) for M in maps)
        else:
            ok[k] = all(certify_map(M, m) for M in maps)
    return ok & (applied_maps(steps, groups, seq) if applied is None else np.asarray(applied, dtype=bool))


def started_dirty(steps, seq=None):
    """(S,) bool: the steps whose start state already held intersections, from
    ``steps/start_intersections``, else counted on `seq` (`start_state_intersections`);
    None without either."""
    if "start_intersections" in steps:
        return np.asarray(steps["start_intersections"]) > 0
    if seq is None:
        return None
    from ..core.pipeline.deform import start_state_intersections

    frames = np.asarray(steps.get("frame", ()), dtype=np.int64)
    return start_state_intersections(seq, frames) > 0


def certificate_summary(steps, rechecked=None, seq=None, applied=None, dirty=None) -> dict:
    """Min margin, all certified yes/no, models and projections used, from ``steps/``.

    A step counts as certified when its ``certificate_margin`` is finite and at least
    its ``margin_required`` (0 where the file has none) and, when `rechecked` (from
    `recheck_certificates`) is given, its map passes the certificate again and the
    stored deformed state is its image. `applied` (from `applied_maps`) adds
    ``n_not_applied`` and ``not_applied_frames``: the steps whose ``steps/deformed`` is
    not the image of the stored map. The steps that started dirty come from
    ``steps/start_intersections``, else are counted on `seq` when given (`started_dirty`),
    or are `dirty` ((S,) bool, `started_dirty` output) when given.
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

    out = {
        "min_margin": float(np.nanmin(cm)) if cm.size and not np.all(np.isnan(cm)) else math.nan,
        "all_certified": bool(ok.all()) if ok.size else False,
        "n_uncertified": int(np.count_nonzero(~ok)),
        "uncertified_frames": frames[~ok].tolist(),
        "n_started_dirty": _count(started_dirty(dict(steps, frame=frames), seq) if dirty is None else dirty),
        "models": counts("model"),
        "projections": counts("projection"),
    }
    if applied is not None:
        bad = ~np.asarray(applied, dtype=bool)
        out["n_not_applied"] = int(np.count_nonzero(bad))
        out["not_applied_frames"] = frames[bad].tolist() if bad.shape == frames.shape else frames.tolist()
    return out


def _count(flags):
    return None if flags is None else int(np.count_nonzero(flags))


def entry_labels(reports) -> list:
    """How each report entry is named in checks, report.md and the CLI: its base name where
    that is unique among the entries, else its path as given (numbered if that repeats too)."""
    names = [r["name"] for r in reports]
    paths = [r.get("file", r["name"]) for r in reports]
    out = []
    for k, (name, path) in enumerate(zip(names, paths)):
        if names.count(name) == 1:
            out.append(name)
        elif paths.count(path) == 1:
            out.append(path)
        else:
            out.append(f"{path} #{paths[:k + 1].count(path)}")
    return out


def _dig(d, dotted):
    for part in dotted.split("."):
        if not isinstance(d, dict) or part not in d:
            return None
        d = d[part]
    if d is None or isinstance(d, bool) or not isinstance(d, (int, float, np.integer, np.floating)):
        return None
    return float(d) if math.isfinite(d) else None


def shown_alike(value, limit, spec="") -> tuple:
    """`value` and `limit` formatted alike with the fewest significant digits (6 or more)
    that tell them apart, so that a check's message never shows a failing value equal to
    its threshold: ``shown_alike(1.0828291, 1.08283) == ("1.082829", "1.08283")``."""
    for p in range(6, 18):
        a, b = format(value, f"{spec}.{p}g"), format(limit, f"{spec}.{p}g")
        if a != b or value == limit:
            return a, b
    return repr(value), repr(limit)


def _check(name, file, passed, value, threshold, message):
    return {"name": name, "file": file, "passed": bool(passed), "value": value, "threshold": threshold,
            "message": message}


def _certified_message(c):
    msg = f"{c['n_uncertified']} uncertified step(s)"
    if c["n_uncertified"]:
        msg += f", frames {c['uncertified_frames'][:10]}"
    if c.get("n_not_applied"):
        msg += (f"; steps/deformed is not the image A x + b of the stored map at {c['n_not_applied']} step(s), "
                f"frames {c['not_applied_frames'][:10]}")
    if c.get("path_check_error"):
        msg += f"; verify cannot check the paths: {c['path_check_error']}"
    elif c.get("n_path_failed"):
        msg += (f"; verify's check of the path fails at {c['n_path_failed']} step(s), frames "
                f"{c['path_failed_frames'][:10]} (penfree verify names the pairs)")
    return msg


def run_checks(reports, *, fail_if_uncertified=False, min_speedup=None, min_hit_rate_gain=None,
               baseline=None, max_regression=None, baseline_name="the baseline") -> list:
    """CI checks over the file reports; a check that cannot be evaluated fails.

    Parameters
    ----------
    reports : list of dict
        `make_file_report` entries.
    fail_if_uncertified : bool
        Every step's certificate margin must be finite and >= its required margin, its
        map(s) must pass the certificate again and its deformed state must be their image.
    min_speedup : float, optional
        Minimum *projected* speedup (K_1pct rule, against the next frame).
    min_hit_rate_gain : float, optional
        Minimum gain of the hit rate against the next frame, deformed minus baseline,
        in *percentage points* (5 means from e.g. 60 % to at least 65 %).
    baseline : dict, optional
        A stored report.json (`load_report_json`); entries are matched by
        `penfree.report.baseline.match_baseline` (the path as given, else an
        unambiguous base name; a single file on each side whatever its name).
    max_regression : float, optional
        Largest allowed regression against `baseline`, in percent of the baseline
        value, of each figure of `REGRESSION_FIGURES` (lower K_1pct, higher speedup and
        hit rate are better). A figure missing (null) on either side fails.
    baseline_name : str
        The baseline's file name, for messages.

    Returns
    -------
    list of dict
        {``name``, ``file``, ``passed``, ``value``, ``threshold``, ``message``}; ``file``
        is the entry's label (`entry_labels`).

    Raises
    ------
    InputError
        A baseline entry match that is ambiguous (`match_baseline`).
    """
    checks = []
    labels = entry_labels(reports)
    matches = None
    if baseline is not None:
        matches = match_baseline([r.get("file", r["name"]) for r in reports], baseline, baseline_name)
    for j, (rep, name) in enumerate(zip(reports, labels)):
        sm = rep["summary"]
        if fail_if_uncertified:
            c = rep["certificate"]
            checks.append(_check("certified", name, c["all_certified"] and c["n_uncertified"] == 0,
                                 c["n_uncertified"], 0, _certified_message(c)))
        if min_speedup is not None:
            v = _dig(sm, "projected.k_1pct.speedup")
            checks.append(_check("min_speedup", name, v is not None and v >= min_speedup, v, min_speedup,
                                 "no step with a next frame" if v is None else
                                 "projected speedup {} (minimum {})".format(*shown_alike(v, min_speedup))))
        if min_hit_rate_gain is not None:
            v = _dig(sm, "hit_rate_gain_next")
            v = None if v is None else 100.0 * v
            checks.append(_check("min_hit_rate_gain", name, v is not None and v >= min_hit_rate_gain, v,
                                 min_hit_rate_gain, "no step with a next frame" if v is None else
                                 "hit-rate gain {} points (minimum {})".format(
                                     *shown_alike(v, min_hit_rate_gain, "+"))))
        if baseline is not None:
            m = matches[j]
            old = None if m is None else baseline["files"][m[0]]
            checks.extend(_regression_checks(rep, name, old, max_regression))
    return checks


def _regression_checks(rep, name, old_entry, max_regression):
    if old_entry is None:
        return [_check("regression", name, False, None, max_regression,
                       f"no entry for {rep.get('file', rep['name'])} in the baseline report")]
    old_sm, out = old_entry.get("summary", {}), []
    for path, higher_better in REGRESSION_FIGURES:
        old, new = _dig(old_sm, path), _dig(rep["summary"], path)
        if old is None or new is None:  # cannot be compared: fails
            what = ("no baseline value (null in the baseline)" if old is None else f"baseline {old:g}") + ", " + (
                "now missing" if new is None else f"now {new:g}")
            out.append(_check(f"regression:{path}", name, False, new, max_regression, f"{what}; not comparable"))
            continue
        worse = (old - new) if higher_better else (new - old)
        pct = 100.0 * worse / abs(old) if old != 0 else (math.inf if worse > 0 else 0.0)
        if pct > 0:
            a, b = shown_alike(old, new)
            p, mx = shown_alike(pct, max_regression)
            msg = f"{a} -> {b} (+{p}% regression, maximum {mx}%)"
        else:
            msg = "{} -> {} (no regression)".format(*shown_alike(old, new))
        out.append(_check(f"regression:{path}", name, pct <= max_regression, new, max_regression, msg))
    return out
