"""A file's report from the library's results, and the ``penfree report`` output files.

The CI checks and the certificate re-check are in `penfree.report.checks`, report.md in
`penfree.report.markdown`, the PNG plots in `penfree.report.plots`.

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

  - ``file`` (path as given; the key used to match a baseline entry), ``name`` (base name;
    matched when the path is not and the name is unambiguous; checks and report.md name
    an entry by it where it is unique among the inputs, else by ``file``);
  - ``scene``: ``kind``, ``n_vertices``, ``n_frames``, ``n_steps``, ``thickness``,
    ``dtype``; ``deform_options``: the result file's attributes;
  - ``stats_source``: ``file`` (its ``stats/`` group) or ``computed`` (always when a CI check
    is requested: the statistics are computed from the positions and deformed states);
    ``stats_note`` (only when a complete ``stats/`` group was unusable, e.g. not numeric,
    or differs from the computed statistics): why it was not used;
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
    ``uncertified_frames`` (a step is certified when its stored margin claims it, its
    map(s) pass the certificate again and ``steps/deformed`` is their image),
    ``n_not_applied``, ``not_applied_frames`` (steps whose ``steps/deformed`` is not the
    image ``A x + b`` of the stored map up to rounding, `checks.applied_maps`),
    ``n_started_dirty`` (steps whose start state already held intersections, kept as
    they were), ``models`` and ``projections`` ({name: steps});
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
import os
import re

import numpy as np

from .._version import __version__
from ..formats._json import json_safe
from .. import constants as K
from ..constants import DEFAULT_CD_SHARE, DEFAULT_FRAME_MS
from ..core.pipeline.ladder import model_ladder
from ..core.trust.stats import R_HIST_EDGES, STARTS, TARGETS, compute_stats, stats_keys
from ..core.trust.summary import PROJECTED_FORMULA, summarize
from ..errors import InputError
from ..formats.atomic import atomic_dir, check_output_dir
from .baseline import read_baseline
from .checks import applied_maps, certificate_summary, recheck_certificates
from .markdown import render_markdown

REPORT_SCHEMA = 1
#: Rows of the worst-steps table.
WORST_STEPS = 10


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
                      stats_source="computed", verify_paths=False) -> dict:
    """The report entry of one result file (see the module key reference); with
    `verify_paths`, a step counts as certified only if verify's check of its path passes
    too (`path_verdicts`)."""
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
    applied = applied_maps(steps, result.groups, seq)
    rechecked = recheck_certificates(steps, result.groups, seq, applied)
    path_ok, why = path_verdicts(result) if verify_paths else (None, None)
    certificate = certificate_summary(steps, rechecked if path_ok is None else rechecked & path_ok, seq,
                                      applied=applied)
    if path_ok is not None:
        certificate.update(path_checked=True, n_path_failed=int(np.count_nonzero(~path_ok)),
                           path_failed_frames=np.asarray(steps["frame"])[~path_ok].tolist())
        if why is not None:
            certificate["path_check_error"] = why
    return {
        "file": os.fspath(path),
        "name": os.path.basename(os.fspath(path)),
        "scene": {"kind": seq.kind, "n_vertices": seq.n_vertices, "n_frames": seq.n_frames,
                  "n_steps": int(len(stats["frame"])), "thickness": seq.thickness,
                  "contact_radius": seq.contact_radius, "dtype": str(seq.dtype)},
        "deform_options": dict(result.attrs),
        "stats_source": stats_source,
        "summary": summarize(stats, steps, cd_share=cd_share, frame_ms=frame_ms),
        "certificate": certificate,
        "worst_steps": worst_steps(stats),
        "steps": per_step,
        "r_hist": hist,
        "ladder": lad,
    }


def path_verdicts(result) -> tuple:
    """``(ok (S,) bool, error)``: verify's verdict on each step's path (`verify_result`,
    mode auto, the result's thickness and obstacles), or all False and verify's message
    when it cannot check the file (e.g. per-component steps without usable maps).

    A certificate proves one map's path free of new intersections within the scene only:
    obstacles, the pairs between components that per-component maps move apart or
    together, and at a thickness the pairs that start within ``thickness / m`` are
    verify's to check (a map that is the identity plus a translation through the ground
    is certified)."""
    from ..core.pipeline.verification import verify_result
    from ..errors import InputError

    frames = np.asarray(result.steps["frame"])
    try:
        ok = {st.frame: st.ok for st in verify_result(result).steps}
    except InputError as exc:
        return np.zeros(frames.size, dtype=bool), str(exc)
    return np.array([ok.get(int(f), False) for f in frames], dtype=bool), None


#: Per-step datasets a report needs beyond those every reader needs.
REPORT_REQUIRES = ("certificate_margin",)


def open_result(path):
    """Read a ``penfree deform`` output; InputError naming the file if it is not one.

    A damaged HDF5 file, or a result missing a dataset the report needs
    (`REPORT_REQUIRES`), is a FormatError naming ``file:/dataset``; a result without
    steps is an InputError (a report about nothing would claim too much).
    """
    from ..formats.result import is_result_file, read_result

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError(f"no such file: {path} (expected a penfree deform output)")
    if not is_result_file(path):
        raise InputError(f"{path} is not a penfree deform output (no dataset steps/frame in {path}:/steps/frame); "
                         f"run `penfree deform {path} -o deformed.h5` and report on its output")
    res = read_result(path, require=REPORT_REQUIRES)
    if not res.n_steps:
        raise InputError(f"{path} holds no steps to report (steps/frame is empty in {path}:/steps/frame)")
    return res


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


def _stats_problem(st, key, S) -> str | None:
    """Why the stored ``stats/<key>`` cannot be used (None if it can)."""
    v = st[key]
    if isinstance(v, dict):
        return f"stats/{key} is a group, expected a dataset"
    a = np.asarray(v)
    if a.dtype.kind not in "biuf":
        return f"stats/{key} must be numeric; got {a.dtype}"
    want = 2 if key.startswith("r_hist_") else 1
    if a.ndim != want or a.shape[0] != S or (want == 2 and a.shape[1] != R_HIST_EDGES.size - 1):
        shape = f"({S}, {R_HIST_EDGES.size - 1})" if want == 2 else f"({S},)"
        return f"stats/{key} must be {shape}; got {a.shape}"
    return None


def stored_stats_checked(result, replay=False) -> tuple:
    """``(stats, note)``: the file's ``stats/`` group if complete and usable, else None.

    `note` says why a complete ``stats/`` group was ignored (a non-numeric value, a
    wrong length, frames other than ``steps/frame``), so that the report can say the
    statistics were recomputed; None when there was nothing to ignore.
    """
    st = result.groups.get("stats")
    keys = stats_keys(replay)
    if not isinstance(st, dict) or not set(keys) <= set(st):
        return None, None
    S = int(np.size(result.steps["frame"]))
    for k in keys:
        problem = _stats_problem(st, k, S)
        if problem is not None:
            return None, f"{problem} in {result.origin}:/stats/{k}"
    if np.any(np.asarray(st["frame"]) != np.asarray(result.steps["frame"])):
        return None, f"stats/frame differs from steps/frame in {result.origin}:/stats/frame"
    return {k: np.asarray(st[k]) for k in keys}, None


def stored_stats(result, replay=False):
    """The file's ``stats/`` group if it holds every key `compute_stats` would give, each
    numeric with one row per step and the same frames as ``steps/frame``; else None."""
    return stored_stats_checked(result, replay)[0]


def _stats_differ(stored, computed) -> list:
    """Keys of `stored` whose values differ from `computed` (NaN equals NaN)."""
    out = []
    for k, v in stored.items():
        a, b = np.asarray(v, dtype=np.float64), np.asarray(computed.get(k), dtype=np.float64)
        if a.shape != b.shape or not np.allclose(a, b, rtol=K.STORED_STATS_RTOL, atol=0.0, equal_nan=True):
            out.append(k)
    return out


def make_file_report(path, result, *, cd_share=DEFAULT_CD_SHARE, frame_ms=DEFAULT_FRAME_MS, replay=False,
                     ladder=True, progress=None, client=None, use_stored_stats=True, verify_paths=False) -> dict:
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
    use_stored_stats : bool
        Take a usable ``stats/`` group as a cache. False (whenever a CI check is asked
        for: a forged group must not pass it) computes the statistics from the positions
        and deformed states, and notes a stored group that differs.
    verify_paths : bool
        A step is certified only if verify's check of its path passes too
        (`path_verdicts`; ``--fail-if-uncertified``).
    """
    stats, note = stored_stats_checked(result, replay)
    if note is not None:
        note = f"stored statistics ignored and recomputed: {note}"
    source = "file"
    if stats is None or not use_stored_stats:
        stored, stats, source = stats, compute_stats(result, replay=replay, progress=progress), "computed"
        differ = [] if stored is None else _stats_differ(stored, stats)
        if differ:
            note = (f"stored statistics differ from those computed from the positions and steps/deformed "
                    f"({', '.join(differ[:4])}{', ...' if len(differ) > 4 else ''} in {result.origin}:/stats); "
                    f"the computed ones are used")
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
                            stats_source=source, verify_paths=verify_paths)
    if note is not None:
        rep["stats_note"] = note
    if client:
        from .client import client_section

        rep["client"] = client_section(result, progress=progress, **client)
    return rep


def load_report_json(path) -> dict:
    """Read a stored report.json (e.g. a CI baseline), validated for comparison
    (`penfree.report.baseline.read_baseline`); InputError if it cannot serve."""
    return read_baseline(path, REPORT_SCHEMA)


#: The plots `penfree.report.plots.write_plots` names: ``<stem>_<kind>.png``.
PLOT_NAME = re.compile(r"[A-Za-z0-9_.-]+_(hit_rate|cd_passes|r_hist|ladder|client_passes)\.png")


def report_names(outdir):
    """``name -> bool``: True for the entries of an existing report directory that penfree wrote.

    Those are ``report.md``, ``report.json`` and the plots that report.json lists *and*
    that are named as penfree names its plots (`PLOT_NAME`): a name taken from the
    file's contents alone never makes a file penfree's to delete. A directory without
    a penfree report.json owns nothing.
    """
    try:
        with open(os.path.join(os.fspath(outdir), "report.json"), encoding="utf-8") as fh:
            doc = json.load(fh)
        plots = doc.get("plots", {}).get("files", []) if doc.get("penfree_report") == REPORT_SCHEMA else None
    except (OSError, ValueError, AttributeError):
        plots = None
    if not isinstance(plots, list):
        return lambda name: False
    owned = {"report.md", "report.json"} | {p for p in plots if isinstance(p, str) and PLOT_NAME.fullmatch(p)}
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
