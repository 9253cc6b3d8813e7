"""The ``penfree report`` output: ``report.md``, ``report.json`` and PNG plots.

Longer than the ~400-line guideline for now: its Markdown section (from ``_f`` on) is
to move to ``penfree/report/markdown.py`` once the open branches that edit it are merged
(moving it now would turn their edits into conflicts).

Frame times and speedups are *projected* (SPEC section 7): they assume a simulator
that spends a share `f` of a frame of `T_frame` in CD and needs K CD passes per frame;
both assumptions are written into every output.

report.json key reference (schema ``penfree_report`` = 1; NaN and inf are written as
``null`` so that the file is strict JSON):

- ``penfree_report``: schema version (1); ``penfree_version``; ``projected_formula``.
- ``options``: ``cd_share`` (f), ``frame_ms`` (T_frame), ``replay``, ``ladder``,
  ``frames`` (the ``--frames`` slice or null), ``gamma``; with ``--client``: ``client``,
  ``truncation``, ``radius``, ``dhat``, ``every``.
- ``plots``: ``status`` (``written`` | ``skipped`` | ``disabled``), ``reason``,
  ``files`` (PNG names in the report directory), ``per_file`` (the same, one list
  per entry of ``files`` below).
- ``checks``: list of {``name``, ``file``, ``passed``, ``value``, ``threshold``,
  ``message``}; ``all_checks_passed``.
- ``files``: one entry per input file:

  - ``file`` (path as given), ``name`` (base name; the key used to match a baseline);
  - ``scene``: ``kind``, ``n_vertices``, ``n_frames``, ``n_steps``, ``thickness``,
    ``dtype``; ``deform_options``: the result file's attributes;
  - ``stats_source``: ``file`` (its ``stats/`` group) or ``computed``;
  - ``summary``: `penfree.core.trust.summary.summarize` output: ``n_steps``, ``n_steps_next``,
    ``fit_ms_mean``, ``fit_ms_median``, ``hit_rate_gain_next``, ``hit_rate_gain_pred``
    (fractions),
    ``baseline`` / ``deformed`` blocks (``hit_rate_<t>``, ``k_any_<t>``,
    ``k_1pct_<t>`` (means), ``..._total``, ``..._max``, ``n_blocked_<t>``,
    ``r_max_<t>``, ``residual_<t>_rms``, ``residual_<t>_max``, with replay
    ``replay_k_any_<t>``, ``replay_k_1pct_<t>``, ``replay_capped_<t>``; ``<t>`` is
    ``next`` or ``pred``) and ``projected`` (``label``, ``cd_share``, ``frame_ms``,
    ``fit_ms`` (median per-step fit time), ``fit_ms_statistic``, ``target``, and per
    rule ``k_1pct`` / ``k_any`` / ``replay_*``:
    ``k_baseline``, ``k_deformed``, ``frame_ms``, ``speedup``);
  - ``certificate``: ``min_margin``, ``all_certified``, ``n_uncertified``,
    ``uncertified_frames``, ``n_started_dirty`` (steps whose start state already held
    intersections, kept as they were), ``models`` and ``projections`` ({name: steps});
  - ``worst_steps``: up to 10 rows {``frame``, ``target``, ``k_1pct_baseline``,
    ``k_1pct_deformed``, ``k_any_baseline``, ``k_any_deformed``,
    ``hit_rate_baseline``, ``hit_rate_deformed``, ``k_1pct_gain``};
  - ``steps``: every per-step array of `penfree.core.trust.stats.compute_stats` (except
    the histograms) plus ``certificate_margin``, ``model``, ``projection``,
    ``time_fit_s``, as lists;
  - ``r_hist``: ``edges`` and pooled counts ``<t>_<s>`` over all steps;
  - ``ladder``: null or `penfree.core.pipeline.ladder.model_ladder` output without the per-step
    arrays: ``models`` (``baseline``, the ladder, ``auto``, ``x_pred``: the unsafe
    ideal), ``n_steps``, ``n_steps_next``, ``rows`` (per model: ``fit_ms_mean``,
    ``fit_ms_median``, ``residual_next_rms``, ``residual_pred_rms``, ``k_1pct_next``,
    ``k_1pct_next_sum``, ``k_any_next``, ``hit_rate_next``, ``replay_k_1pct_next``,
    ``replay_k_any_next`` (null without ``--replay``), ``certificate_margin_mean``,
    ``certificate_margin_min``, ``models_used``), ``auto_best_rate`` (fraction of
    steps on which ``auto``'s actual K_1pct was the best of baseline and fixed models);
  - ``client`` (only with ``--client ipctk``): the real-client replay,
    `penfree.report.client` (``options``, ``summary``, ``steps``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os

import numpy as np

from .._version import __version__
from ..formats._json import json_safe
from ..constants import DEFAULT_CD_SHARE, DEFAULT_FRAME_MS
from ..core.pipeline.ladder import model_ladder
from ..core.trust.stats import R_HIST_EDGES, STARTS, TARGETS, compute_stats, stats_keys
from ..core.trust.summary import summarize
from ..errors import InputError
from ..formats.atomic import atomic_dir, check_output_dir

REPORT_SCHEMA = 1
#: Rows of the worst-steps table.
WORST_STEPS = 10
PROJECTED_FORMULA = "T' = T_frame ((1 - f) + f K_deformed / K_baseline) + t_fit, speedup = T_frame / T'"


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
    cm = np.asarray(steps.get("certificate_margin", []), dtype=np.float64)
    req = np.asarray(steps.get("margin_required", np.zeros_like(cm)), dtype=np.float64)
    ok = np.isfinite(cm) & (cm >= np.where(np.isfinite(req), req, 0.0))
    if rechecked is not None:
        ok = ok & rechecked if ok.shape == rechecked.shape else np.asarray(rechecked, dtype=bool)
    frames = np.asarray(steps.get("frame", np.arange(cm.size)))

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


def worst_steps(stats, n=WORST_STEPS) -> list:
    """The `n` steps with the most deformed CD passes (K_1pct), then the smallest gain."""
    t = "next" if np.isfinite(np.asarray(stats["k_1pct_next_deformed"], dtype=float)).any() else "pred"
    kd = np.asarray(stats[f"k_1pct_{t}_deformed"], dtype=float)
    kb = np.asarray(stats[f"k_1pct_{t}_baseline"], dtype=float)
    frames = np.asarray(stats["frame"])
    idx = [i for i in np.lexsort((frames, kb - kd, -kd)) if np.isfinite(kd[i])][:n]
    rows = []
    for i in idx:
        row = {"frame": int(frames[i]), "target": t}
        for k in ("k_1pct", "k_any", "hit_rate"):
            for s in STARTS:
                row[f"{k}_{s}"] = float(stats[f"{k}_{t}_{s}"][i])
        row["k_1pct_gain"] = float(kb[i] - kd[i])
        rows.append(row)
    return rows


def build_file_report(path, result, stats, *, ladder=None, cd_share=DEFAULT_CD_SHARE, frame_ms=DEFAULT_FRAME_MS,
                      stats_source="computed") -> dict:
    """The report entry of one result file (see the module key reference)."""
    seq, steps = result.sequence, result.steps
    per_step = {k: v for k, v in stats.items() if not k.startswith("r_hist_")}
    for k in ("certificate_margin", "model", "projection", "time_fit_s"):
        if k in steps:
            per_step[k] = np.asarray(steps[k])
    hist = {"edges": R_HIST_EDGES}
    for t in TARGETS:
        for s in STARTS:
            h = np.asarray(stats[f"r_hist_{t}_{s}"], dtype=np.float64)
            hist[f"{t}_{s}"] = np.nansum(h, axis=0) if h.size else np.zeros(R_HIST_EDGES.size - 1)
    lad = None if ladder is None else {k: v for k, v in ladder.items() if k != "steps"}
    return {
        "file": os.fspath(path),
        "name": os.path.basename(os.fspath(path)),
        "scene": {"kind": seq.kind, "n_vertices": seq.n_vertices, "n_frames": seq.n_frames,
                  "n_steps": int(len(stats["frame"])), "thickness": seq.thickness,
                  "contact_radius": seq.contact_radius, "dtype": str(seq.dtype)},
        "deform_options": dict(result.attrs),
        "stats_source": stats_source,
        "summary": summarize(stats, steps, cd_share=cd_share, frame_ms=frame_ms),
        "certificate": certificate_summary(steps, recheck_certificates(steps, result.groups), seq),
        "worst_steps": worst_steps(stats),
        "steps": per_step,
        "r_hist": hist,
        "ladder": lad,
    }


def open_result(path):
    """Read a ``penfree deform`` output; InputError naming the file if it is not one."""
    from ..formats.result import is_result_file, read_result

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError(f"no such file: {path} (expected a penfree deform output)")
    if not is_result_file(path):
        raise InputError(f"{path} is not a penfree deform output (no dataset steps/frame in {path}:/steps/frame); "
                         f"run `penfree deform {path} -o deformed.h5` and report on its output")
    return read_result(path)


def select_steps(result, frames=None):
    """The result restricted to the steps whose frame lies in the ``(start, stop)`` slice.

    Per-step arrays of ``steps`` and of the ``stats`` group (rows = steps) are subset
    alike; InputError when the slice selects no step.
    """
    if frames is None:
        return result
    fr = np.asarray(result.steps["frame"])
    T = result.sequence.n_frames
    keep = np.isin(fr, np.arange(T)[slice(*frames)])
    if not keep.any():
        raise InputError(f"--frames {frames[0] if frames[0] is not None else ''}:"
                         f"{frames[1] if frames[1] is not None else ''} selects none of the {fr.size} steps "
                         f"(frames {fr.min()}..{fr.max()}) of {result.origin}")

    def sub(d):
        return {k: (v[keep] if isinstance(v, np.ndarray) and v.ndim and v.shape[0] == fr.size else v)
                for k, v in d.items()}

    groups = dict(result.groups)
    if isinstance(groups.get("stats"), dict):
        groups["stats"] = sub(groups["stats"])
    if isinstance(groups.get("component_maps"), dict):  # per-step maps; labels are per vertex
        groups["component_maps"] = {k: (sub({k: v})[k] if k != "labels" else v)
                                    for k, v in groups["component_maps"].items()}
    return dataclasses.replace(result, steps=sub(result.steps), groups=groups)


def stored_stats(result, replay=False):
    """The file's ``stats/`` group if it holds every key `compute_stats` would give, else None."""
    st = result.groups.get("stats")
    if not isinstance(st, dict) or not set(stats_keys(replay)) <= set(st):
        return None
    if np.shape(st["frame"]) != np.shape(result.steps["frame"]) or np.any(st["frame"] != result.steps["frame"]):
        return None
    return {k: np.asarray(st[k]) for k in stats_keys(replay)}


def make_file_report(path, result, *, cd_share=DEFAULT_CD_SHARE, frame_ms=DEFAULT_FRAME_MS, replay=False,
                     ladder=True, progress=None, client=None) -> dict:
    """Statistics (read or computed), model ladder and the report entry of one result.

    Parameters
    ----------
    path : str
        The file name shown in the report.
    result : DeformResult
        `open_result` output, possibly restricted by `select_steps`.
    cd_share, frame_ms : float
        Assumptions of the *projected* frame time.
    replay : bool
        Include the replay estimate (computes the statistics if the file lacks it).
    ladder : bool
        Re-fit every step with every model of the ladder.
    progress : callable, optional
        Called once per step of each computing phase (statistics, ladder).
    client : dict, optional
        Options of the real-client replay (`penfree.report.client.client_section`); its
        section is stored under ``client``.
    """
    stats = stored_stats(result, replay)
    source = "file"
    if stats is None:
        stats, source = compute_stats(result, replay=replay, progress=progress), "computed"
    lad = None
    if ladder:
        seq, steps = result.sequence, result.steps
        opts = result.attrs.get("options")
        # Re-fit with the projection mode deform used, so the affine row matches the file.
        projection = opts.get("projection", "auto") if isinstance(opts, dict) else "auto"
        lad = model_ladder(seq.positions, steps["frame"], edges=seq.edges, faces=seq.faces,
                           thickness=seq.thickness, weights=seq.weights, margins=steps.get("margin_required"),
                           projection=projection, replay=replay, progress=progress,
                           contact_radius=seq.contact_radius)
    rep = build_file_report(path, result, stats, ladder=lad, cd_share=cd_share, frame_ms=frame_ms,
                            stats_source=source)
    if client:
        from .client import client_section

        rep["client"] = client_section(result, progress=progress, **client)
    return rep


def load_report_json(path) -> dict:
    """Read a stored report.json (e.g. a CI baseline); InputError if it is not one."""
    path = os.fspath(path)
    if os.path.isdir(path):
        path = os.path.join(path, "report.json")
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read baseline report {path}: {exc}") from None
    if not isinstance(data, dict) or data.get("penfree_report") != REPORT_SCHEMA or "files" not in data:
        raise InputError(f"{path} is not a penfree report.json (expected penfree_report = {REPORT_SCHEMA})")
    files = data["files"]
    if not isinstance(files, list) or not all(isinstance(f, dict) for f in files):
        raise InputError(f"{path}: files must be a list of objects in a penfree report.json")
    for k, f in enumerate(files):
        if not isinstance(f.get("name", ""), str) or not isinstance(f.get("summary", {}), dict):
            raise InputError(f"{path}: files[{k}] needs a string name and an object summary")
        for dotted, _ in REGRESSION_FIGURES:
            d = f.get("summary", {})
            for part in dotted.split("."):
                d = d.get(part) if isinstance(d, dict) else None
            if d is not None and (isinstance(d, bool) or not isinstance(d, (int, float))):
                raise InputError(f"{path}: files[{k}].summary.{dotted} must be a number or null; got {d!r}")
    return data


def report_names(outdir):
    """``name -> bool``: True for the entries of an existing report directory that penfree wrote.

    Those are ``report.md``, ``report.json`` and the plots that report.json lists; a
    directory without a penfree report.json owns nothing.
    """
    try:
        with open(os.path.join(os.fspath(outdir), "report.json"), encoding="utf-8") as fh:
            doc = json.load(fh)
        plots = doc.get("plots", {}).get("files", []) if doc.get("penfree_report") == REPORT_SCHEMA else None
    except (OSError, ValueError, AttributeError):
        plots = None
    if not isinstance(plots, list):
        return lambda name: False
    owned = {"report.md", "report.json"} | {p for p in plots if isinstance(p, str) and p.endswith(".png")}
    return owned.__contains__


def check_report_dir(outdir, overwrite=False, inputs=()) -> None:
    """Refuse a report directory that holds an input, the working directory, or files penfree did not write.

    Raises
    ------
    InputError, OutputExistsError
    """
    check_output_dir(outdir, overwrite, inputs=inputs, owned=report_names(outdir))


def write_report(outdir, reports, overwrite=False, *, options=None, checks=None, plots=True) -> dict:
    """Write ``report.md``, ``report.json`` and the PNG plots into `outdir`, atomically.

    Parameters
    ----------
    outdir : str or os.PathLike
        Report directory (created; an existing one is replaced only with `overwrite`).
    reports : list of dict
        `build_file_report` entries, one per input file.
    overwrite : bool
    options : dict, optional
        Report options recorded under ``options`` (cd_share, frame_ms, ...).
    checks : list of dict, optional
        `run_checks` results.
    plots : bool
        Try the PNG plots (skipped with a note when matplotlib is missing).

    Returns
    -------
    dict
        The report.json content, as written (strict JSON values).
    """
    from .plots import write_plots

    checks = list(checks or [])
    doc = {
        "penfree_report": REPORT_SCHEMA,
        "penfree_version": __version__,
        "projected_formula": PROJECTED_FORMULA,
        "options": dict(options or {}),
        "plots": {"status": "disabled", "reason": "plots not requested", "files": [],
                  "per_file": [[] for _ in reports]},
        "checks": checks,
        "all_checks_passed": all(c["passed"] for c in checks),
        "files": list(reports),
    }
    check_report_dir(outdir, overwrite, inputs=[r["file"] for r in reports])
    with atomic_dir(outdir, overwrite) as tmp:
        if plots:
            doc["plots"] = write_plots(tmp, reports)
        doc = json_safe(doc)
        with open(os.path.join(tmp, "report.json"), "w", encoding="utf-8") as fh:
            json.dump(doc, fh, indent=1, allow_nan=False)
            fh.write("\n")
        with open(os.path.join(tmp, "report.md"), "w", encoding="utf-8") as fh:
            fh.write(render_markdown(doc))
    return doc


# ---------------------------------------------------------------- CI checks

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


def _f(v, spec=".3g", suffix=""):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    return f"{v:{spec}}{suffix}"


def _pct(v):
    return _f(None if v is None else 100.0 * v, ".1f", " %")


def _table(header, rows):
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def _summary_rows(sm):
    b, d = sm["baseline"], sm["deformed"]
    rows = []

    def ratio(key):
        x, y = b.get(key), d.get(key)
        return "n/a" if x in (None, 0) or y is None else f"x{y / x:.3g}"

    for t, label in (("next", "x_next"), ("pred", "x_pred")):
        rows.append([f"hit rate vs {label}", _pct(b[f"hit_rate_{t}"]), _pct(d[f"hit_rate_{t}"]),
                     _f(None if b[f"hit_rate_{t}"] is None or d[f"hit_rate_{t}"] is None else
                        100 * (d[f"hit_rate_{t}"] - b[f"hit_rate_{t}"]), "+.1f", " pts")])
        for k, what in (("k_any", "K_any"), ("k_1pct", "K_1pct"), ("replay_k_any", "replay K_any"),
                        ("replay_k_1pct", "replay K_1pct")):
            if f"{k}_{t}" in b:
                rows.append([f"{what} vs {label} (mean CD passes)", _f(b[f"{k}_{t}"]), _f(d[f"{k}_{t}"]),
                             ratio(f"{k}_{t}")])
        rows.append([f"residual RMS to {label}", _f(b[f"residual_{t}_rms"]), _f(d[f"residual_{t}_rms"]),
                     ratio(f"residual_{t}_rms")])
        rows.append([f"residual max to {label}", _f(b[f"residual_{t}_max"]), _f(d[f"residual_{t}_max"]),
                     ratio(f"residual_{t}_max")])
        rows.append([f"blocked vertices vs {label} (total)", _f(b[f"n_blocked_{t}"], ".0f"),
                     _f(d[f"n_blocked_{t}"], ".0f"), ""])
    p = sm["projected"]
    for rule in ("k_1pct", "k_any", "replay_k_1pct", "replay_k_any"):
        if rule in p:
            rows.append([f"*projected* frame time ({rule} rule)", _f(p["frame_ms"], ".2f", " ms"),
                         _f(p[rule]["frame_ms"], ".2f", " ms"),
                         "speedup " + _f(p[rule]["speedup"], ".3f") + " *projected*"])
    rows.append(["fit time per step (median / mean)", "",
                 _f(sm.get("fit_ms_median"), ".3g", " ms") + " / " + _f(sm["fit_ms_mean"], ".3g", " ms"), ""])
    return rows


def _file_md(rep):
    sc, sm, cert = rep["scene"], rep["summary"], rep["certificate"]
    p = sm["projected"]
    out = [f"## {rep['name']}\n",
           f"File `{rep['file']}`: {sc['kind']} scene, {sc['n_vertices']} vertices, {sc['n_frames']} frames, "
           f"{sc['n_steps']} steps ({sm['n_steps_next']} with a next frame), thickness {_f(sc['thickness'])}. "
           f"Statistics {'read from the file' if rep['stats_source'] == 'file' else 'computed by this report'}.\n"]
    opts = dict(rep.get("deform_options") or {})
    if isinstance(opts.get("options"), dict):  # deform's own options, one level down
        opts.update({f"options.{k}": v for k, v in opts.pop("options").items()})
    if opts:
        out.append("Deform result attributes: " + ", ".join(f"`{k}={v}`" for k, v in sorted(opts.items())) + ".\n")
    out.append("### Summary: baseline vs deformed\n")
    out.append(f"*Projected* figures assume a CD share f = {_f(p['cd_share'])} of a baseline frame of "
               f"T_frame = {_f(p['frame_ms'])} ms, plus the median per-step fit time measured by deform "
               f"({_f(p['fit_ms'], '.3g')} ms): {PROJECTED_FORMULA}. K is the mean over the steps with a next "
               f"frame; K_1pct uses the 99th percentile of r_v (method 'higher').\n")
    out.append(_table(["figure", "baseline", "deformed", "change"], _summary_rows(sm)))
    out.append("### Certificate\n")
    out.append(f"- minimum certificate margin: {_f(cert['min_margin'], '.6g')}\n"
               f"- all steps certified: {'yes' if cert['all_certified'] else 'NO'} "
               f"({cert['n_uncertified']} uncertified)\n"
               f"- steps that started with pre-existing intersections (kept as they were): "
               f"{_f(cert.get('n_started_dirty'), 'd')}\n"
               f"- models: {', '.join(f'{k} x{v}' for k, v in cert['models'].items()) or 'n/a'}\n"
               f"- projections: {', '.join(f'{k} x{v}' for k, v in cert['projections'].items()) or 'n/a'}\n")
    ws = rep["worst_steps"]
    if ws:
        t = ws[0]["target"]
        out.append(f"### Worst steps (by deformed K_1pct vs x_{t}, then smallest gain)\n")
        out.append(_table(["frame", "K_1pct base", "K_1pct def", "K_any base", "K_any def", "hit base", "hit def"],
                          [[r["frame"], _f(r["k_1pct_baseline"]), _f(r["k_1pct_deformed"]), _f(r["k_any_baseline"]),
                            _f(r["k_any_deformed"]), _pct(r["hit_rate_baseline"]), _pct(r["hit_rate_deformed"])]
                           for r in ws]))
    lad = rep.get("ladder")
    if lad:
        out.append("### Model ladder: speed against error\n")
        out.append("Every step re-fitted with each model; CD-pass figures are *actual*: bounds recomputed at "
                   "each model's deformed state, target the simulator's next frame. `K_1pct sum` is summed "
                   "over the steps. `x_pred` is the unsafe ideal (the prediction itself, uncertified), a "
                   "ceiling, not an option.\n")
        replay = any(r.get("replay_k_1pct_next") == r.get("replay_k_1pct_next") and r.get("replay_k_1pct_next")
                     is not None for r in lad["rows"])
        head = ["model", "fit ms/step (median)", "residual RMS x_next", "residual RMS x_pred", "K_1pct x_next",
                "K_1pct sum", *(["replay K_1pct"] if replay else []), "hit rate x_next", "min margin",
                "models used"]
        out.append(_table(head, [[r["model"], _f(r.get("fit_ms_median")), _f(r["residual_next_rms"]),
                                  _f(r["residual_pred_rms"]), _f(r["k_1pct_next"]), _f(r.get("k_1pct_next_sum")),
                                  *([_f(r.get("replay_k_1pct_next"))] if replay else []),
                                  _pct(r["hit_rate_next"]), _f(r["certificate_margin_min"]),
                                  ", ".join(f"{k} x{v}" for k, v in (r["models_used"] or {}).items())]
                                 for r in lad["rows"]]))
        rate = lad.get("auto_best_rate")
        if rate is not None and rate == rate:
            out.append(f"\n`auto` chose a map whose actual K_1pct was the best of baseline and the fixed "
                       f"models on {_pct(rate)} of the steps.\n")
    return "\n".join(out)


def render_markdown(doc) -> str:
    """report.md from the report.json content (`write_report`'s document)."""
    o = doc["options"]
    out = ["# penfree report\n",
           f"penfree {doc['penfree_version']}. Inputs: " + ", ".join(f"`{r['file']}`" for r in doc["files"]) + ". "
           f"Options: " + ", ".join(f"`{k}={v}`" for k, v in sorted(o.items())) + ".\n",
           f"Frame times and speedups are *projected*, not measured: {PROJECTED_FORMULA}.\n"]
    for i, rep in enumerate(doc["files"]):
        out.append(_file_md(rep))
        if rep.get("client"):
            from .client import client_markdown

            out.append(client_markdown(rep["client"]))
        files = (doc["plots"].get("per_file") or [[]] * len(doc["files"]))[i]
        if files:
            out.append("### Plots\n")
            out += [f"![{f}]({f})\n" for f in files]
    pl = doc["plots"]
    if pl["status"] != "written":
        out.append(f"Plots {pl['status']}: {pl['reason']}.\n")
    if doc["checks"]:
        out.append("## Checks\n")
        out.append(_table(["check", "file", "result", "detail"],
                          [[c["name"], c["file"], "pass" if c["passed"] else "**FAIL**", c["message"]]
                           for c in doc["checks"]]))
        out.append(f"All checks passed: {'yes' if doc['all_checks_passed'] else 'NO'}.\n")
    return "\n".join(out)
