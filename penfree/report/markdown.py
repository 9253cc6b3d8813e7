"""report.md from the report.json content."""

from __future__ import annotations

import math

from ..core.trust.summary import PROJECTED_FORMULA
from .checks import entry_labels


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


def _file_md(rep, label):
    sc, sm, cert = rep["scene"], rep["summary"], rep["certificate"]
    p = sm["projected"]
    out = [f"## {label}\n",
           f"File `{rep['file']}`: {sc['kind']} scene, {sc['n_vertices']} vertices, {sc['n_frames']} frames, "
           f"{sc['n_steps']} steps ({sm['n_steps_next']} with a next frame), thickness {_f(sc['thickness'])}. "
           f"Statistics {'read from the file' if rep['stats_source'] == 'file' else 'computed by this report'}.\n"]
    if rep.get("stats_note"):
        out.append(f"Note: {rep['stats_note']}.\n")
    opts = dict(rep.get("deform_options") or {})
    if isinstance(opts.get("options"), dict):  # deform's own options, one level down
        opts.update({f"options.{k}": v for k, v in opts.pop("options").items()})
    if opts:
        out.append("Deform result attributes: " + ", ".join(f"`{k}={v}`" for k, v in sorted(opts.items())) + ".\n")
    if rep.get("client"):
        from .client import client_headline

        line = client_headline(rep["client"])
        out.append(f"**{line[:1].upper() + line[1:]}** (table below). These are the passes "
                   "IPC Toolkit's trust region needs; the static estimates that follow hold the bounds fixed and "
                   "can disagree with them.\n")
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
               + (f"- steps whose stored deformed state is not the image of the stored map: "
                  f"{cert['n_not_applied']} (frames {cert['not_applied_frames'][:10]})\n"
                  if cert.get("n_not_applied") else "") +
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
    for i, (rep, label) in enumerate(zip(doc["files"], entry_labels(doc["files"]))):
        out.append(_file_md(rep, label))
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
