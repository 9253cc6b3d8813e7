"""The real-client section of ``penfree report`` (``--client ipctk``).

report.json gains, per file, ``client``: ``options`` (``client``, ``truncations``,
``radius_rules``, ``dhat``, ``every``, ``thickness``, ``obstacles``: the names of the
colliders in the client's collision mesh), ``summary`` (per truncation:
``baseline`` (rule step) and ``baseline_own`` (rule own), ``step``/``own`` passes
summed over the replayed steps, their ``..._change`` fractions against their own
rule's baseline and the iteration totals; `client_stats.summarize_counts`)
and ``steps`` (the per-step arrays of `client_stats.client_counts` as lists).
report.md gains a table per file and ``<stem>_client_passes.png``: passes per step,
baseline against deformed, per truncation and radius rule, with the steps where
``auto`` moved anything marked.
"""

from __future__ import annotations

import numpy as np

from ..core.trust.client_stats import (
    client_counts, expand, replayed_steps, resolve_dhat, rule_baseline, summarize_counts,
)
from ..core.trust.client import RADIUS_RULES, TRUNCATIONS


def client_section(result, *, client="ipctk", truncation="both", radius="both", dhat=None, every=1,
                   progress=None) -> dict:
    """Replay every `every`-th step of a deform result through the client (module doc)."""
    options = client_options(result.sequence, client=client, truncation=truncation, radius=radius, dhat=dhat,
                             every=every)
    return section_of(options, client_steps(result, options, progress=progress))


def client_options(seq, *, client="ipctk", truncation="both", radius="both", dhat=None, every=1) -> dict:
    """The section's ``options`` for a result of sequence `seq` (validated: truncations, radius
    rules and dhat resolved as the replay takes them)."""
    truncations = expand(truncation, TRUNCATIONS)
    radii = expand(radius, RADIUS_RULES)
    dhat = resolve_dhat(dhat, seq.contact_radius, seq.thickness)
    return {"client": client, "truncations": list(truncations), "radius_rules": list(radii),
            "dhat": dhat, "every": int(every), "thickness": float(seq.thickness),
            "obstacles": [ob.name for ob in seq.obstacles]}


def client_frames(frames, n_frames, every) -> np.ndarray:
    """The frames of the steps `client_counts` replays: those with a next frame among the
    `n_frames` of the recording, every `every`-th of them."""
    frames = np.asarray(frames, dtype=np.int64)
    return frames[replayed_steps(frames, n_frames, every)]


def client_steps(result, options, *, frames=None, progress=None) -> dict:
    """`client_counts` of `result`'s steps under `client_options` `options`: every
    ``every``-th step with a next frame, or with `frames` the steps of exactly those
    frames (a frame range of a long recording, the picks made over all its steps by
    `client_frames`, in the result's frame numbers)."""
    seq, steps = result.sequence, result.steps
    deformed, fr, models, every = steps["deformed"], steps["frame"], steps.get("model"), options["every"]
    if frames is not None:
        idx = np.flatnonzero(np.isin(np.asarray(fr), frames))
        deformed, fr, every = deformed[idx], np.asarray(fr)[idx], 1
        models = None if models is None else np.asarray(models)[idx]
    return client_counts(seq.positions, deformed, fr, edges=seq.edges, faces=seq.faces, dhat=options["dhat"],
                         thickness=seq.thickness, truncations=tuple(options["truncations"]),
                         radii=tuple(options["radius_rules"]), every=every, client=options["client"],
                         models=models, progress=progress, obstacles=seq.obstacles)


def section_of(options, counts) -> dict:
    """The section from its options and the per-step counts of all replayed steps (of one
    `client_steps` call, or of frame ranges concatenated in step order)."""
    return {
        "options": options,
        "summary": summarize_counts(counts),
        "steps": {k: np.asarray(v).tolist() for k, v in counts.items()},
    }


def client_headline(section) -> str:
    """One line of a `client_section`'s totals, for the report's headline: the passes the
    real client needs decide, not the static estimates (which `auto --client-model` does
    not optimise, and which can disagree with them)."""
    o, sm = section["options"], section["summary"]
    parts = []
    for tr in o["truncations"]:
        row = sm[tr]
        parts.append(f"{tr} " + ", ".join(f"rule {r} {_change(row, r)}" for r in o["radius_rules"]))
    return (f"real-client CD passes ({o['client']}, summed over {sm['n_steps']} steps), baseline -> deformed: "
            + "; ".join(parts))


def _change(row, rule) -> str:
    """``"base -> n (+x%)"`` of one rule of a `summarize_counts` row."""
    base = rule_baseline(row, rule)
    return f"{base} -> {row[rule]}" + (f" ({100 * row[f'{rule}_change']:+.0f}%)" if base else "")


def client_markdown(section) -> str:
    """The Markdown table of a `client_section`."""
    o, sm = section["options"], section["summary"]
    rules = o["radius_rules"]
    head = ["truncation"] + [f"passes, rule {r}: baseline -> x_def" for r in rules] + \
        [f"iterations, rule {r}: baseline -> x_def" for r in rules]
    rows = []
    for tr in o["truncations"]:
        row = sm[tr]
        rows.append([tr] + [_change(row, r) for r in rules]
                    + [f"{rule_baseline(row, r, 'iterations_baseline')} -> {row[f'iterations_{r}']}" for r in rules])
    lines = ["### Real-client CD passes\n",
             f"`{o['client']}` (`ipctk.ogc.TrustRegion` replay), dhat {o['dhat']:.4g}, min distance "
             f"{o['thickness']:.4g}, every {o['every']} step(s), {sm['n_steps']} steps, summed. Rule `step`: the "
             "simulator keeps the radius computed at x (the integration contract) and moves toward x_pred by the "
             "truncation's filter; rule `own`: ipctk's warm start (`warm_start_time_step`) recomputes it from "
             "x_def and moves isotropically within the radii. Each rule is compared with its own baseline "
             "(from x)." + (f" Obstacles in the client's collision mesh: {', '.join(o['obstacles'])}."
                            if o.get("obstacles") else "") + "\n",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def client_plot(section, title):
    """``fill(ax)`` drawing passes per step, baseline against deformed (plots.write_plots)."""
    st, o = section["steps"], section["options"]

    def fill(ax):
        frames = np.asarray(st["frame"])
        styles = {"isotropic": "-", "planar": "--"}
        for tr in o["truncations"]:
            ax.step(frames, st[f"passes_{tr}_baseline"], where="mid", color="0.4", ls=styles[tr], lw=4, alpha=0.4,
                    label=f"baseline rule step, {tr}")
            own = st.get(f"passes_{tr}_own_baseline")
            if own is not None and own != st[f"passes_{tr}_baseline"]:  # planar: another warm-start move
                ax.step(frames, own, where="mid", color="tab:red", ls=styles[tr], lw=4, alpha=0.25,
                        label=f"baseline rule own, {tr}")
            for rule, color in (("step", "tab:blue"), ("own", "tab:red")):
                if rule in o["radius_rules"]:
                    ax.step(frames, st[f"passes_{tr}_{rule}_deformed"], where="mid", color=color, ls=styles[tr],
                            label=f"x_def rule {rule}, {tr}")
        if "model" in st:
            moved = frames[np.asarray(st["model"]) != "none"]
            ax.plot(moved, np.zeros(len(moved)), "|", color="k", ms=10, label="auto moved")
        ax.set(xlabel="frame", ylabel="client CD passes", title=f"{title}: real-client CD passes")
        ax.set_ylim(bottom=-0.3)
        ax.legend(fontsize="small")

    return fill
