"""Real-client CD passes of a deformed sequence: every step replayed from `x` and `x_def`.

Per-step keys of `client_counts` (``(S,)`` arrays over the replayed steps; ``<tr>``
is a truncation, ``<rule>`` a radius rule):

=====================================  =============================================
``frame``                              the step's frame index ``s`` (int64)
``passes_<tr>_baseline``               CD passes from the recorded ``x`` under rule
``iterations_<tr>_baseline``           ``step`` (the simulator's warm start, filtered
                                       by the truncation)
``passes_<tr>_own_baseline``           the same under rule ``own`` (ipctk's
``iterations_<tr>_own_baseline``       ``warm_start_time_step``, whose move is
                                       isotropic): with rule ``own`` only
``passes_<tr>_<rule>_deformed``        CD passes from ``x_def`` under the radius rule
``iterations_<tr>_<rule>_deformed``
``model``                              the map `deform` applied (``none`` = x_def is x)
=====================================  =============================================

Each rule is compared with its own baseline. From ``x`` both rules take the radius of
``x``; under isotropic truncation their warm starts are the same move, under planar
truncation they are not (rule ``step`` moves by the planar filter): on the cables
sample, doing nothing needs 63 passes under rule step and 116 under rule own.

Only steps with a next frame are replayed (the iterations go to ``x_next``), every
``every``-th of them.
"""

from __future__ import annotations

import numpy as np

from ...errors import InputError
from .client import RADIUS_RULES, TRUNCATIONS, ClientQuery, load_ipctk, replay_step


def resolve_dhat(dhat, contact_radius, thickness) -> float:
    """`dhat` if given, else the contact radius, else the thickness; InputError when all are 0."""
    for v in (dhat, contact_radius, thickness):
        if v is not None and float(v) > 0:
            return float(v)
    raise InputError("the client replay needs a contact offset dhat > 0: give --dhat "
                     "(the sequence has neither contact_radius nor thickness)")


def expand(choice, options) -> tuple:
    """``"both"`` -> all options; a single name -> a 1-tuple (validated)."""
    if choice == "both":
        return tuple(options)
    if choice not in options:
        raise InputError(f"expected one of {options} or 'both'; got {choice!r}")
    return (choice,)


def replayed_steps(frames, n_frames, every) -> np.ndarray:
    """Indices of the steps `client_counts` replays: every `every`-th of the steps (of
    frames `frames`) with a next frame among the `n_frames` of the recording."""
    if int(every) < 1:
        raise InputError(f"--every must be >= 1; got {every}")
    return np.flatnonzero(np.asarray(frames, dtype=np.int64) + 1 < n_frames)[::int(every)]


def client_counts(positions, deformed, frames, *, edges=None, faces=None, dhat, thickness=0.0,
                  truncations=TRUNCATIONS, radii=RADIUS_RULES, every=1, client="ipctk", models=None,
                  progress=None, obstacles=()) -> dict:
    """Replay every `every`-th step with a next frame through the client (module doc).

    Parameters
    ----------
    positions : (T, N, 3) float
    deformed : (S, N, 3) float
        ``x_def`` per step of `frames`.
    frames : (S,) int
    edges, faces : topology
    dhat, thickness : float
    truncations, radii : tuple of str
    every : int >= 1
    client : {"ipctk", "own"}
    models : (S,) str, optional
        The applied model per step (copied into the output).
    progress : callable, optional
        Called once per replayed step.
    obstacles : sequence of Obstacle, optional
        The recording's colliders, in the client's collision mesh (`client.replay_step`);
        `positions`' frame numbers index their frames.

    Returns
    -------
    dict of str -> ndarray
    """
    if client == "ipctk":
        load_ipctk()
    frames = np.asarray(frames, dtype=np.int64)
    pick = replayed_steps(frames, positions.shape[0], every)
    out = {"frame": frames[pick].copy()}
    if models is not None:
        out["model"] = np.asarray(models)[pick].astype(str)
    for tr in truncations:
        for key in ("passes", "iterations"):
            out[f"{key}_{tr}_baseline"] = np.zeros(len(pick), np.int64)
            if "own" in radii:
                out[f"{key}_{tr}_own_baseline"] = np.zeros(len(pick), np.int64)
            for rule in radii:
                out[f"{key}_{tr}_{rule}_deformed"] = np.zeros(len(pick), np.int64)
    # the own client's queries shared by all replays (both truncations start from the same states)
    query = ClientQuery(positions[0], edges, faces, obstacles) if client == "own" and len(pick) else None
    for k, i in enumerate(pick):
        s = frames[i]
        x = np.asarray(positions[s], dtype=np.float64)
        x_pred = 2.0 * x - np.asarray(positions[s - 1], dtype=np.float64)
        x_next = np.asarray(positions[s + 1], dtype=np.float64)
        x_def = np.asarray(deformed[i], dtype=np.float64)
        same = np.array_equal(x_def, x)
        for tr in truncations:
            kw = dict(edges=edges, faces=faces, dhat=dhat, thickness=thickness, truncation=tr, client=client,
                      query=query, obstacles=obstacles, frame=int(s))
            base = {"step": replay_step(x, x, x_pred, x_next, radius="step", **kw)}
            if "own" in radii:  # the same warm-start move as rule step's under isotropic truncation
                base["own"] = base["step"] if tr == "isotropic" else replay_step(x, x, x_pred, x_next, radius="own",
                                                                                 **kw)
            for rule, b in base.items():
                key = "baseline" if rule == "step" else "own_baseline"
                out[f"passes_{tr}_{key}"][k], out[f"iterations_{tr}_{key}"][k] = b["passes"], b["iterations"]
            for rule in radii:
                r = base[rule] if same else replay_step(x_def, x, x_pred, x_next, radius=rule, **kw)
                out[f"passes_{tr}_{rule}_deformed"][k] = r["passes"]
                out[f"iterations_{tr}_{rule}_deformed"][k] = r["iterations"]
        if progress is not None:
            progress()
    return out


def summarize_counts(counts) -> dict:
    """Totals over the replayed steps: ``{tr: {"baseline": n, "baseline_own": n, rule: n,
    rule + "_change": fraction}}``, each rule's change against its own baseline
    (``baseline`` is rule step's; ``baseline_own`` with rule own only)."""
    out = {"n_steps": int(len(counts["frame"]))}
    for tr in TRUNCATIONS:
        if f"passes_{tr}_baseline" not in counts:
            continue
        row = {"baseline": int(counts[f"passes_{tr}_baseline"].sum()),
               "iterations_baseline": int(counts[f"iterations_{tr}_baseline"].sum())}
        if f"passes_{tr}_own_baseline" in counts:
            row["baseline_own"] = int(counts[f"passes_{tr}_own_baseline"].sum())
            row["iterations_baseline_own"] = int(counts[f"iterations_{tr}_own_baseline"].sum())
        for rule in RADIUS_RULES:
            k = f"passes_{tr}_{rule}_deformed"
            if k in counts:
                base = rule_baseline(row, rule)
                row[rule] = int(counts[k].sum())
                row[f"{rule}_change"] = (row[rule] - base) / base if base else float("nan")
                row[f"iterations_{rule}"] = int(counts[f"iterations_{tr}_{rule}_deformed"].sum())
        out[tr] = row
    return out


def rule_baseline(row, rule, key="baseline") -> int:
    """The baseline total a rule's change in a `summarize_counts` row is measured against
    (`key` ``"iterations_baseline"``: its iterations)."""
    return row[key if rule == "step" else f"{key}_own"]
