"""A file's report from the library's results, and the ``penfree report`` output files.

A file's entry is built from the per-step figures of its steps (`penfree.report.entry`:
of a whole read, or of a long recording's frame ranges joined in step order, with the
same entry). The CI checks and the certificate re-check are in `penfree.report.checks`,
report.md in `penfree.report.markdown`, the PNG plots in `penfree.report.plots`.

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
from ..constants import DEFAULT_CD_SHARE, DEFAULT_FRAME_MS
from ..core.trust.summary import PROJECTED_FORMULA
from ..errors import InputError
from ..formats.atomic import atomic_dir, check_output_dir
from .baseline import read_baseline
from .entry import (  # noqa: F401  (the report's public names, re-exported for callers of build)
    WORST_STEPS, FileDecisions, assemble_entry, concat_parts, decide, file_part, path_verdicts, stored_stats,
    stored_stats_checked, worst_steps,
)
from .markdown import render_markdown

REPORT_SCHEMA = 1


#: Per-step datasets a report needs beyond those every reader needs.
REPORT_REQUIRES = ("certificate_margin",)


def _check_is_result(path):
    from ..formats.result import is_result_file

    if not os.path.isfile(path):
        raise InputError(f"no such file: {path} (expected a penfree deform output)")
    if not is_result_file(path):
        raise InputError(f"{path} is not a penfree deform output (no dataset steps/frame in {path}:/steps/frame); "
                         f"run `penfree deform {path} -o deformed.h5` and report on its output")


def _no_steps(path):
    return InputError(f"{path} holds no steps to report (steps/frame is empty in {path}:/steps/frame)")


def open_result(path):
    """Read a ``penfree deform`` output; InputError naming the file if it is not one.

    A damaged HDF5 file, or a result missing a dataset the report needs
    (`REPORT_REQUIRES`), is a FormatError naming ``file:/dataset``; a result without
    steps is an InputError (a report about nothing would claim too much).
    """
    from ..formats.result import read_result

    path = os.fspath(path)
    _check_is_result(path)
    res = read_result(path, require=REPORT_REQUIRES)
    if not res.n_steps:
        raise _no_steps(path)
    return res


def open_tables(path) -> tuple:
    """``(result, n_frames)``: a ``penfree deform`` output's per-step tables and groups without
    its frames (`penfree.formats.result.read_result_tables`), checked as `open_result`
    checks a whole read: a long recording's report plans its frame ranges from them
    (`penfree.scaleout.report_many`), whose tasks read their frames (`read_range`)."""
    from ..formats.result import read_result_tables

    path = os.fspath(path)
    _check_is_result(path)
    res, n_frames = read_result_tables(path, require=REPORT_REQUIRES)
    if not res.n_steps:
        raise _no_steps(path)
    return res, n_frames


def read_range(path, lo, hi) -> tuple:
    """``(result, first)``: the steps of frames ``lo .. hi - 1`` of a ``penfree deform`` output,
    read with the frames they use (``lo - 1 .. hi``: a step at frame s reads s - 1, s and
    s + 1) and nothing else; frame numbers are the window's, whose frame 0 is the file's
    frame `first` (`entry.file_part` takes them back to the file's)."""
    from ..formats.result import read_result

    first = int(lo) - 1
    res = read_result(os.fspath(path), require=REPORT_REQUIRES, window=(first, int(hi) + 1))
    return select_steps(res, (int(lo) - first, int(hi) - first)), first


def select_steps(result, frames=None, n_frames=None):
    """The result restricted to the steps whose frame lies in the ``(start, stop)`` slice.

    Per-step arrays of ``steps`` and of the ``stats`` group (rows = steps) are subset
    alike; InputError when the slice selects no step. `n_frames`: the recording's frame
    count when ``result.sequence`` holds fewer (`open_tables`).
    """
    if frames is None:
        return result
    fr = np.asarray(result.steps["frame"])
    T = result.sequence.n_frames if n_frames is None else int(n_frames)
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
    rows = None if result.rows is None else np.asarray(result.rows)[keep]  # a window's: the file's rows
    return dataclasses.replace(result, steps=sub(result.steps), groups=groups, rows=rows)


def make_file_report(path, result, *, cd_share=DEFAULT_CD_SHARE, frame_ms=DEFAULT_FRAME_MS, replay=False,
                     ladder=True, progress=None, client=None, use_stored_stats=True, verify_paths=False) -> dict:
    """Statistics (read or computed), model ladder and the report entry of one result.

    `entry.assemble_entry` of the `entry.file_part` of `result`: a long recording is
    reported a frame range at a time through the same two functions
    (`penfree.scaleout.report_many`), with the same entry.

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
        Called once per step of each computing phase (statistics, ladder, client).
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
    part = file_part(result, replay=replay, ladder=ladder, client=client, use_stored_stats=use_stored_stats,
                     verify_paths=verify_paths, progress=progress)
    return assemble_entry(path, result, part, cd_share=cd_share, frame_ms=frame_ms)


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
        `make_file_report` entries, one per input file.
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
