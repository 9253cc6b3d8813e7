"""PNG plots of a report (optional: ``pip install penfree[plots]``).

matplotlib is imported lazily and only through its object-oriented API with the Agg
canvas (no pyplot, no global backend switch), so a report works headless and inside
a researcher's own process. Without matplotlib the plots are skipped and the report
says so.

Per input file (``<stem>`` is the file name without extension, made unique):
``<stem>_hit_rate.png`` (per-step hit rate, baseline vs deformed),
``<stem>_cd_passes.png`` (per-step K_1pct and K_any, and the replay counts when
present), ``<stem>_r_hist.png`` (histogram of r_v pooled over the steps) and, with the
model ladder, ``<stem>_ladder.png`` (fit time against residual to the next frame).
"""

from __future__ import annotations

import os
import re

import numpy as np

#: Figure size (inches) and resolution of every plot.
FIG_SIZE = (6.4, 3.6)
FIG_DPI = 110
COLORS = {"baseline": "tab:gray", "deformed": "tab:blue"}


def load_matplotlib():
    """``(Figure, FigureCanvasAgg)`` or raise ImportError when matplotlib is missing."""
    import matplotlib  # noqa: F401  (fails first, with a clear name, when not installed)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    return Figure, FigureCanvasAgg


def _stems(reports):
    seen, out = {}, []
    for rep in reports:
        stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", os.path.splitext(rep["name"])[0]) or "file"
        n = seen.get(stem, 0) + 1
        seen[stem] = n
        out.append(stem if n == 1 else f"{stem}-{n}")
    return out


def _target(steps):
    return "next" if np.isfinite(np.asarray(steps["hit_rate_next_baseline"], dtype=float)).any() else "pred"


def _save(lib, fill, path):
    Figure, Canvas = lib
    fig = Figure(figsize=FIG_SIZE, dpi=FIG_DPI, layout="constrained")
    Canvas(fig)
    fill(fig.add_subplot())
    fig.savefig(path)


def _integer_frames(ax):
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(integer=True))


def _hit_rate(rep):
    st, t = rep["steps"], _target(rep["steps"])

    def fill(ax):
        for s in ("baseline", "deformed"):
            ax.plot(st["frame"], 100 * np.asarray(st[f"hit_rate_{t}_{s}"], dtype=float), ".-",
                    color=COLORS[s], label=s)
        ax.set(xlabel="frame", ylabel="hit rate (%)", ylim=(0, 102), title=f"{rep['name']}: hit rate vs x_{t}")
        _integer_frames(ax)
        ax.legend(loc="lower right")

    return fill


def _cd_passes(rep):
    st, t = rep["steps"], _target(rep["steps"])

    def fill(ax):
        for s in ("baseline", "deformed"):
            ax.step(st["frame"], st[f"k_1pct_{t}_{s}"], where="mid", color=COLORS[s], label=f"K_1pct {s}")
            ax.step(st["frame"], st[f"k_any_{t}_{s}"], where="mid", color=COLORS[s], ls=":", label=f"K_any {s}")
            if f"replay_k_1pct_{t}_{s}" in st:
                ax.plot(st["frame"], st[f"replay_k_1pct_{t}_{s}"], "x", color=COLORS[s], label=f"replay K_1pct {s}")
        ax.set(xlabel="frame", ylabel="CD passes", title=f"{rep['name']}: CD passes vs x_{t}")
        _integer_frames(ax)
        ax.set_ylim(bottom=0)
        ax.legend(fontsize="small")

    return fill


def _r_hist(rep):
    h, t = rep["r_hist"], _target(rep["steps"])
    edges = np.asarray(h["edges"], dtype=float)

    def fill(ax):
        # Finite log bins only; r = 0 (no motion) and blocked vertices go into the legend.
        lo, hi = edges[1:-2], edges[2:-1]
        for s in ("baseline", "deformed"):
            c = np.asarray(h[f"{t}_{s}"], dtype=float)
            ax.stairs(c[1:-1], np.r_[lo, hi[-1]], color=COLORS[s],
                      label=f"{s} (r=0: {c[0]:.0f}, r>=1e4 or blocked: {c[-1]:.0f})")
        ax.axvline(1.0, color="k", lw=0.8, ls="--")
        occupied = np.flatnonzero(sum(np.nan_to_num(np.asarray(h[f"{t}_{s}"], dtype=float))[1:-1]
                                      for s in ("baseline", "deformed")))
        if occupied.size:  # zoom on the occupied decades (and r = 1)
            ax.set_xlim(min(lo[occupied[0]], 0.5) / 2, max(hi[occupied[-1]], 2.0) * 2)
        ax.set(xscale="log", xlabel="r_v = |y - x_s| / b_v", ylabel="vertices (pooled over steps)",
               title=f"{rep['name']}: trust-region ratio vs x_{t}")
        ax.legend(fontsize="small")

    return fill


def _ladder(rep):
    rows = rep["ladder"]["rows"]

    def fill(ax):
        for r in rows:
            x, y = r.get("fit_ms_median"), r["residual_next_rms"]
            if x is None or y is None or not np.isfinite([x, y]).all():
                continue
            ax.plot(x, y, "o", color=COLORS["baseline" if r["model"] == "baseline" else "deformed"])
            ax.annotate(r["model"], (x, y), textcoords="offset points", xytext=(4, 4), fontsize="small")
        ax.set(xlabel="fit time per step, median (ms)", ylabel="residual RMS to x_next",
               title=f"{rep['name']}: model ladder, speed against error")

    return fill


def write_plots(outdir, reports) -> dict:
    """Write the PNG plots of every file report into `outdir`.

    Returns
    -------
    dict
        ``status`` (``written`` or ``skipped``), ``reason`` (why skipped, else None),
        ``files`` (names relative to `outdir`) and ``per_file`` (one list per report).
    """
    try:
        lib = load_matplotlib()
    except ImportError as exc:
        return {"status": "skipped", "reason": f"matplotlib is not installed ({exc}); pip install penfree[plots]",
                "files": [], "per_file": [[] for _ in reports]}
    per_file = []
    for rep, stem in zip(reports, _stems(reports)):
        names = []
        kinds = [("hit_rate", _hit_rate), ("cd_passes", _cd_passes), ("r_hist", _r_hist)]
        if rep.get("ladder"):
            kinds.append(("ladder", _ladder))
        if rep.get("client"):
            from .client import client_plot

            kinds.append(("client_passes", lambda r: client_plot(r["client"], r["name"])))
        for kind, make in kinds:
            name = f"{stem}_{kind}.png"
            _save(lib, make(rep), os.path.join(outdir, name))
            names.append(name)
        per_file.append(names)
    return {"status": "written", "reason": None, "files": [n for f in per_file for n in f], "per_file": per_file}
