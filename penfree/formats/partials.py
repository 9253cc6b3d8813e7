"""Partial deform results of frame ranges (`penfree.scaleout`): each range's ``steps``
and ``groups`` written as one NPZ into a folder of the run's own (created by the run,
never a user's name), and merged back in frame order into the layout of a serial run
(`penfree.formats.result`)."""

from __future__ import annotations

import os

import numpy as np

from .frames import Frames

_DEFORMED = "steps/deformed"


def _flatten(prefix, d, out):
    for k, v in d.items():
        if isinstance(v, dict):
            _flatten(f"{prefix}{k}/", v, out)
        else:
            out[f"{prefix}{k}"] = np.asarray(v)
    return out


def _unflatten(flat):
    out = {}
    for key, v in flat.items():
        node = out
        *heads, leaf = key.split("/")
        for h in heads:
            node = node.setdefault(h, {})
        node[leaf] = v
    return out


def write_partial(parts, steps, groups) -> str:
    """Write one frame range's `steps` and `groups` into the folder `parts`; its path.

    `parts` must exist (the run that owns it made it): a folder removed meanwhile (the
    run stopped) is not created again.
    """
    flat = _flatten("steps/", steps, {})
    _flatten("groups/", groups, flat)
    if not os.path.isdir(parts):
        raise FileNotFoundError(f"the folder of partial results {parts} is gone (the run stopped)")
    name = os.path.join(parts, f"part-{int(steps['frame'][0]):010d}.npz")
    tmp = name + f".tmp-{os.getpid()}.npz"
    np.savez(tmp, **flat)
    os.replace(tmp, name)
    return name


def merge_partials(parts, stream_deformed=False) -> tuple:
    """``(steps, groups)`` of a serial run from partial results in frame order.

    `stream_deformed`: ``steps["deformed"]`` is a `PartialFrames` (one partial's states in
    memory at a time, for `result.write_result`) instead of one array of every step.
    """
    loaded = []
    skip = _DEFORMED if stream_deformed else None
    for p in parts:
        with np.load(p, allow_pickle=False) as z:
            loaded.append(_unflatten({k: z[k] for k in z.files if k != skip}))
    steps = {k: np.concatenate([d["steps"][k] for d in loaded]) for k in loaded[0]["steps"]}
    if stream_deformed:
        steps["deformed"] = PartialFrames(parts, [len(d["steps"]["frame"]) for d in loaded])
    groups = {}
    for g in loaded[0].get("groups", {}):
        tables = [d["groups"][g] for d in loaded]
        groups[g] = _merge_selection(tables) if g == "selection" else _merge_group(tables)
    return steps, groups


class PartialFrames(Frames):
    """The deformed states of partial results, in frame order; one partial's in memory at a time."""

    def __init__(self, parts, counts):
        self._parts, self._ends = list(parts), np.cumsum(counts)
        self._loaded, self._states = -1, None
        first = self._load(0)
        super().__init__((int(self._ends[-1]),) + first.shape[1:], first.dtype, self._parts[0], _DEFORMED)

    def _load(self, i):
        if i != self._loaded:
            with np.load(self._parts[i], allow_pickle=False) as z:
                self._states = z[_DEFORMED]
            self._loaded = i
        return self._states

    def _read(self, t):
        i = int(np.searchsorted(self._ends, t, side="right"))
        return self._load(i)[t - (int(self._ends[i - 1]) if i else 0)]


def _merge_group(tables):
    out = {}
    for k, v in tables[0].items():
        if k == "labels":  # per vertex, not per step
            out[k] = v
        else:
            out[k] = np.concatenate([t[k] for t in tables])
    return out


def _merge_selection(tables):
    # Columns in order of first appearance across the steps, as `selection_arrays` makes them.
    names = []
    for t in tables:
        for n in t["candidates"].tolist():
            if n not in names:
                names.append(n)
    out = {"candidates": np.array(names, dtype=str)}
    chosen = []
    for t in tables:
        col = np.array([names.index(n) for n in t["candidates"].tolist()], dtype=np.int64)
        ch = np.asarray(t["chosen"])
        chosen.append(np.where(ch >= 0, col[np.maximum(ch, 0)] if col.size else -1, -1))
    out["chosen"] = np.concatenate(chosen).astype(np.int64)
    for k in tables[0]:
        if not k.startswith("predicted_"):
            continue
        rows = []
        for t in tables:
            a = np.full((t[k].shape[0], len(names)), np.nan)
            for j, n in enumerate(t["candidates"].tolist()):
                a[:, names.index(n)] = t[k][:, j]
            rows.append(a)
        out[k] = np.concatenate(rows)
    return out
