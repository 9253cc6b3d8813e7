"""Partial deform results of frame ranges (`penfree.scaleout`): each range's ``steps``
and ``groups`` written as one NPZ into a folder of the run's own (created by the run,
never a user's name), and merged back in frame order into the layout of a serial run
(`penfree.formats.result`)."""

from __future__ import annotations

import os

import numpy as np

from .frames import Frames, StepRows

_DEFORMED = "steps/deformed"


def is_per_vertex(name) -> bool:
    """Whether per-step dataset `name` (``steps/<name>`` or ``<name>``) holds a row per
    vertex, ``(S, N)``: the ``--per-vertex`` residuals, nearly as large as the recording."""
    return name.endswith("_per_vertex")


def _streamed(key) -> bool:
    """A dataset that `merge_partials` streams: the deformed states and the per-vertex rows."""
    return key == _DEFORMED or (key.startswith("steps/") and is_per_vertex(key))


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


def merge_partials(parts, stream=False) -> tuple:
    """``(steps, groups)`` of a serial run from partial results in frame order.

    `stream`: ``steps["deformed"]`` is a `PartialFrames` and each per-vertex dataset
    (``steps/*_per_vertex``) a `PartialRows` (one partial's rows in memory at a time, for
    `result.write_result`) instead of one array of every step.
    """
    loaded, names = [], []
    for p in parts:
        with np.load(p, allow_pickle=False) as z:
            names = z.files
            loaded.append(_unflatten({k: z[k] for k in z.files if not (stream and _streamed(k))}))
    steps = {k: np.concatenate([d["steps"][k] for d in loaded]) for k in loaded[0]["steps"]}
    if stream:
        counts = [len(d["steps"]["frame"]) for d in loaded]
        for key in names:  # every range of a run holds the same datasets
            if key == _DEFORMED:
                steps["deformed"] = PartialFrames(parts, counts)
            elif _streamed(key):
                steps[key[len("steps/"):]] = PartialRows(parts, counts, key)
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


class PartialRows(StepRows):
    """Dataset `key` of partial results (per-step rows, `counts` of them in each), in frame
    order; one partial's rows in memory at a time."""

    def __init__(self, parts, counts, key):
        self._parts, self._key = list(parts), key
        with np.load(self._parts[0], allow_pickle=False) as z, z.zip.open(f"{key}.npy") as f:
            version = np.lib.format.read_magic(f)  # the member's header, not its data
            header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, _, dtype = header(f)
        super().__init__((int(sum(counts)),) + tuple(shape[1:]), dtype)

    def blocks(self):
        for p in self._parts:
            with np.load(p, allow_pickle=False) as z:
                yield z[self._key]


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
