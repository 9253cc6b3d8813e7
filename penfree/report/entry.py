"""A file's report entry in parts: the per-step figures of a result's steps (`file_part`),
their concatenation in step order (`concat_parts`) and the entry built from them
(`assemble_entry`).

`penfree.report.build.make_file_report` is `assemble_entry` of the `file_part` of the
whole result. A long recording is reported a frame range at a time
(`penfree.scaleout.report_many`): each range reads only its frames, its `file_part` holds
its steps' figures, and the parts are joined in step order and assembled once, with the
decisions that need every step made beforehand on the file's tables (`FileDecisions`):
whether a stored ``stats/`` group serves, whether verify can check the paths, which steps
the client replays.

Every figure of the entry is computed from the joined per-step arrays by the same code in
the same order as from a whole read (sums, means, medians, histograms, counts): an entry
assembled from ranges equals the whole read's. A step at frame s reads frames s - 1, s
and s + 1 (statistics, ladder, client) and its ``steps/`` rows (the certificate checks).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .. import constants as K
from ..constants import DEFAULT_CD_SHARE, DEFAULT_FRAME_MS
from ..core.pipeline.ladder import concat_ladder_steps, ladder_steps, ladder_summary
from ..core.trust.stats import R_HIST_EDGES, STARTS, TARGETS, compute_stats, stats_keys
from ..core.trust.summary import summarize
from ..errors import InputError
from .checks import applied_maps, certificate_summary, recheck_certificates, started_dirty

#: Rows of the worst-steps table.
WORST_STEPS = 10
#: The ``steps/`` arrays of a result an entry uses (those present are kept per step).
PART_STEPS = ("frame", "certificate_margin", "margin_required", "model", "projection", "time_fit_s")


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

    frames = np.asarray(result.steps["frame"])
    try:
        ok = {st.frame: st.ok for st in verify_result(result).steps}
    except InputError as exc:
        return np.zeros(frames.size, dtype=bool), str(exc)
    return np.array([ok.get(int(f), False) for f in frames], dtype=bool), None


# --- stored statistics ------------------------------------------------------------------


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
    return _stored_rows(st, replay), None


def _stored_rows(st, replay):
    return {k: np.asarray(st[k]) for k in stats_keys(replay)}


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


def _ignored(note):
    return None if note is None else f"stored statistics ignored and recomputed: {note}"


# --- parts -------------------------------------------------------------------------------


@dataclass(frozen=True)
class FileDecisions:
    """What a frame range's part takes from its whole file (all its selected steps), decided
    once on the file's tables (`decide`).

    Attributes
    ----------
    stats_usable : bool
        The stored ``stats/`` group serves (`stored_stats_checked` of all steps).
    stats_note : str or None
        Why a complete stored group was ignored.
    path_error : str or None
        verify's message when it cannot check the paths of the file (its per-component
        maps), with ``verify_paths``.
    client_frames : (R,) int64 or None
        The frames of the steps the client replays (`client.client_frames`).
    """

    stats_usable: bool
    stats_note: str | None = None
    path_error: str | None = None
    client_frames: np.ndarray | None = None


def decide(result, n_frames, *, replay=False, verify_paths=False, client=None) -> FileDecisions:
    """`FileDecisions` of `result`'s steps (the per-step tables of all selected steps, e.g.
    `penfree.formats.result.read_result_tables`) in a recording of `n_frames` frames;
    InputError for client options that cannot serve, before any work."""
    stored, note = stored_stats_checked(result, replay)
    path_error = None
    if verify_paths:
        from ..core.pipeline.verification import check_component_maps

        try:
            check_component_maps(result)
        except InputError as exc:
            path_error = str(exc)
    frames = None
    if client:
        from .client import client_frames, client_options

        client_options(result.sequence, **client)  # its errors before any range runs
        frames = client_frames(result.steps["frame"], n_frames, client.get("every", 1))
    return FileDecisions(stored is not None, _ignored(note), path_error, frames)


def file_part(result, *, replay=False, ladder=True, client=None, use_stored_stats=True, verify_paths=False,
              decisions=None, first=0, progress=None) -> dict:
    """The per-step figures of a result's steps, for `assemble_entry` (see `make_file_report`
    for the options).

    Parameters
    ----------
    result : DeformResult
        A whole result (possibly restricted by `select_steps`), or a frame range's
        (`penfree.report.build.read_range`) whose frame 0 is the file's frame `first`.
    decisions : FileDecisions, optional
        A frame range's: the whole file's. None decides on `result` itself.
    first : int
        Added to every frame number of the part (the file's numbers).
    progress : callable, optional
        Called once per step of each computing phase (statistics, ladder, client).

    Returns
    -------
    dict
        ``steps`` (the `PART_STEPS` arrays present), ``stats`` (`compute_stats` output or
        the stored rows), ``stats_source``, ``stats_ignored`` (note or None),
        ``stats_differ`` (stored keys that differ from the computed ones, or None),
        ``applied``, ``rechecked``, ``dirty`` ((S,) bool), ``path_ok`` ((S,) bool or None),
        ``path_error``, ``ladder`` (`ladder_steps` output or None), ``client``
        (``options`` and per-step ``counts``, or None).
    """
    seq, steps = result.sequence, result.steps
    if decisions is None:
        stored, ignored = stored_stats_checked(result, replay)
        ignored = _ignored(ignored)
    else:
        stored = _stored_rows(result.groups["stats"], replay) if decisions.stats_usable else None
        ignored = decisions.stats_note
    stats, source, differ = stored, "file", None
    if stored is None or not use_stored_stats:
        stats, source = compute_stats(result, replay=replay, progress=progress), "computed"
        differ = None if stored is None else _stats_differ(stored, stats)
    lad = None
    if ladder:
        opts = result.attrs.get("options")
        # Re-fit with the projection mode deform used, so the affine row matches the file.
        projection = opts.get("projection", "auto") if isinstance(opts, dict) else "auto"
        lad = ladder_steps(seq.positions, steps["frame"], edges=seq.edges, faces=seq.faces,
                           thickness=seq.thickness, weights=seq.weights, margins=steps.get("margin_required"),
                           projection=projection, replay=replay, progress=progress,
                           contact_radius=seq.contact_radius)
    applied = applied_maps(steps, result.groups, seq)
    rechecked = recheck_certificates(steps, result.groups, seq, applied)
    path_ok = why = None
    if verify_paths and decisions is not None and decisions.path_error is not None:
        path_ok, why = np.zeros(len(steps["frame"]), dtype=bool), decisions.path_error
    elif verify_paths:
        path_ok, why = path_verdicts(result)
    part = {"steps": {k: np.asarray(steps[k]) for k in PART_STEPS if k in steps}, "stats": stats,
            "stats_source": source, "stats_ignored": ignored, "stats_differ": differ, "applied": applied,
            "rechecked": rechecked, "dirty": started_dirty(steps, seq), "path_ok": path_ok, "path_error": why,
            "ladder": lad, "client": None}
    if client:
        from .client import client_options, client_steps

        options = client_options(seq, **client)
        frames = None if decisions is None or decisions.client_frames is None else decisions.client_frames - first
        part["client"] = {"options": options, "counts": client_steps(result, options, frames=frames,
                                                                     progress=progress)}
    if first:
        for d in (part["steps"], part["stats"], *(() if part["client"] is None else (part["client"]["counts"],))):
            d["frame"] = np.asarray(d["frame"], dtype=np.int64) + first
    return part


def _cat(dicts) -> dict:
    return {k: np.concatenate([np.asarray(d[k]) for d in dicts]) for k in dicts[0]}


def concat_parts(parts) -> dict:
    """`file_part` outputs of consecutive frame ranges of one file joined in step order (one
    part is returned as it is). A path-check error of any range is the file's: verify
    cannot check it, and no step's path counts as checked."""
    if len(parts) == 1:
        return parts[0]
    p0 = parts[0]
    differ = None
    if p0["stats_differ"] is not None:
        seen = {k for p in parts for k in p["stats_differ"]}
        differ = [k for k in p0["stats"] if k in seen]  # the order of a whole comparison
    why = next((p["path_error"] for p in parts if p["path_error"] is not None), None)
    path_ok = None if p0["path_ok"] is None else np.concatenate([p["path_ok"] for p in parts])
    if why is not None:
        path_ok = np.zeros(path_ok.size, dtype=bool)
    return {
        "steps": _cat([p["steps"] for p in parts]),
        "stats": _cat([p["stats"] for p in parts]),
        "stats_source": p0["stats_source"],
        "stats_ignored": p0["stats_ignored"],
        "stats_differ": differ,
        "applied": np.concatenate([p["applied"] for p in parts]),
        "rechecked": np.concatenate([p["rechecked"] for p in parts]),
        "dirty": None if any(p["dirty"] is None for p in parts) else np.concatenate([p["dirty"] for p in parts]),
        "path_ok": path_ok,
        "path_error": why,
        "ladder": None if p0["ladder"] is None else concat_ladder_steps([p["ladder"] for p in parts]),
        "client": None if p0["client"] is None else {
            "options": p0["client"]["options"], "counts": _cat([p["client"]["counts"] for p in parts])},
    }


def assemble_entry(path, result, part, *, n_frames=None, cd_share=DEFAULT_CD_SHARE,
                   frame_ms=DEFAULT_FRAME_MS) -> dict:
    """The report entry of one result file (`penfree.report.build` key reference) from the
    `file_part` of its steps (`concat_parts` of its frame ranges).

    `result` gives the scene, the attributes and the file name (the whole result, or its
    tables); `n_frames` the recording's frame count (default ``result.sequence``'s).
    """
    seq = result.sequence
    stats, steps = part["stats"], part["steps"]
    per_step = {k: v for k, v in stats.items() if not k.startswith("r_hist_")}
    for k in ("certificate_margin", "model", "projection", "time_fit_s"):
        if k in steps:
            per_step[k] = np.asarray(steps[k])
    hist = {"edges": R_HIST_EDGES}
    for t in TARGETS:
        for s in STARTS:
            h = np.asarray(stats[f"r_hist_{t}_{s}"], dtype=np.float64)
            hist[f"{t}_{s}"] = np.nansum(h, axis=0) if h.size else np.zeros(R_HIST_EDGES.size - 1)
    lad = None
    if part["ladder"] is not None:
        lad = {k: v for k, v in ladder_summary(part["ladder"]).items() if k != "steps"}
    applied, rechecked, path_ok, why = part["applied"], part["rechecked"], part["path_ok"], part["path_error"]
    certificate = certificate_summary(steps, rechecked if path_ok is None else rechecked & path_ok,
                                      applied=applied, dirty=part["dirty"])
    if path_ok is not None:
        certificate.update(path_checked=True, n_path_failed=int(np.count_nonzero(~path_ok)),
                           path_failed_frames=np.asarray(steps["frame"])[~path_ok].tolist())
        if why is not None:
            certificate["path_check_error"] = why
    rep = {
        "file": os.fspath(path),
        "name": os.path.basename(os.fspath(path)),
        "scene": {"kind": seq.kind, "n_vertices": seq.n_vertices,
                  "n_frames": seq.n_frames if n_frames is None else int(n_frames),
                  "n_steps": int(len(stats["frame"])), "thickness": seq.thickness,
                  "contact_radius": seq.contact_radius, "dtype": str(seq.dtype)},
        "deform_options": dict(result.attrs),
        "stats_source": part["stats_source"],
        "summary": summarize(stats, steps, cd_share=cd_share, frame_ms=frame_ms),
        "certificate": certificate,
        "worst_steps": worst_steps(stats),
        "steps": per_step,
        "r_hist": hist,
        "ladder": lad,
    }
    note, differ = part["stats_ignored"], part["stats_differ"]
    if note is None and differ:
        note = (f"stored statistics differ from those computed from the positions and steps/deformed "
                f"({', '.join(differ[:4])}{', ...' if len(differ) > 4 else ''} in {result.origin}:/stats); "
                f"the computed ones are used")
    if note is not None:
        rep["stats_note"] = note
    if part["client"] is not None:
        from .client import section_of

        rep["client"] = section_of(part["client"]["options"], part["client"]["counts"])
    return rep
