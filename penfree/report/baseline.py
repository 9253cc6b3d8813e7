"""A stored report.json as a CI baseline: read and validate it, match its entries to the
inputs, and name what differs from the run it is compared with.

A baseline that cannot be compared is unusable input (InputError, exit 2), never a
silent pass: strict JSON only (no NaN or Infinity), every compared figure present,
``null`` or a number in its real range (`FIGURE_RANGES`). Entries are matched by the
path as given (normalised); by base name only when that is unambiguous.
"""

from __future__ import annotations

import json
import math
import os

from .. import constants as K
from .._version import __version__
from ..errors import InputError

#: Figures compared against a baseline report: (dotted path in ``summary``, True if
#: higher is better).
REGRESSION_FIGURES = (
    ("deformed.k_1pct_next", False),
    ("projected.k_1pct.speedup", True),
    ("deformed.hit_rate_next", True),
)
#: Report options whose difference changes the compared figures (warned about, not failed).
COMPARED_OPTIONS = ("cd_share", "frame_ms", "frames", "gamma")


def _figure_range(path, summary):
    """``(low, low_open, high, what)`` of a compared figure. A projected speedup is
    ``1 / ((1 - f) + f K_def / K_base + t_fit / T)`` with K_def >= 1, so at most
    ``1 / (1 - f)`` and at most K_base; a hit rate is a fraction; K a count >= 1."""
    if path.endswith("hit_rate_next"):
        return 0.0, False, 1.0, "a hit rate in [0, 1]"
    if path.endswith("k_1pct_next"):
        return 1.0, False, K.BASELINE_K_MAX, "a mean CD-pass count in [1, 2^53]"
    proj = summary.get("projected")
    f = proj.get("cd_share") if isinstance(proj, dict) else None
    high = K.BASELINE_K_MAX
    if _is_number(f) and 0.0 <= f < 1.0:
        high = min(high, (1.0 / (1.0 - f)) * (1.0 + 1e-9))  # room for the rounding of the quotient
    return 0.0, True, high, (f"a projected speedup in (0, {high:.6g}]" + (f" (1 / (1 - f), f = {f:g})"
                                                                           if high < K.BASELINE_K_MAX else ""))


class _NonFinite:
    """What ``NaN``, ``Infinity`` and ``-Infinity`` parse to: found and named by `_walk`."""

    def __init__(self, name):
        self.name = name


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _walk(obj, where, dotted=""):
    """InputError at the first NaN / Infinity (or a number too large for a float) in `obj`."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            _walk(v, where, f"{dotted}.{k}" if dotted else str(k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            _walk(v, where, f"{dotted}[{i}]")
    elif isinstance(obj, _NonFinite) or (isinstance(obj, float) and not math.isfinite(obj)):
        got = obj.name if isinstance(obj, _NonFinite) else "a number beyond the float range"
        raise InputError(f"baseline {where}: {dotted} is {got}; a penfree report.json holds finite numbers or null "
                         f"(strict JSON)")


def read_baseline(path, schema) -> dict:
    """Read and validate a stored report.json (or a report directory holding one).

    Raises
    ------
    InputError
        Unreadable, not strict JSON, not a penfree report of schema `schema`, or a
        compared figure missing, of the wrong type or outside its range; one line
        naming the file, the key and what was expected.
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        path = os.path.join(path, "report.json")
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh, parse_constant=_NonFinite)
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read baseline report {path}: {exc}") from None
    if not isinstance(data, dict) or data.get("penfree_report") != schema or isinstance(
            data.get("penfree_report"), bool) or "files" not in data:
        raise InputError(f"{path} is not a penfree report.json (expected penfree_report = {schema})")
    _walk(data, path)
    validate_baseline(data, path)
    return data


_MISSING = object()


def _need(cond, where, key, expected, got):
    if not cond:
        shown = "nothing (missing)" if got is _MISSING else json.dumps(got)[:60]
        raise InputError(f"baseline {where}: {key} must be {expected}; got {shown}")


def validate_baseline(data, where) -> None:
    """The parts of a report.json a comparison reads, each present and in range (`read_baseline`)."""
    files = data["files"]
    _need(isinstance(files, list) and len(files) > 0 and all(isinstance(f, dict) for f in files), where, "files",
          "a non-empty list of objects", files if not isinstance(files, list) else len(files))
    _need(isinstance(data.get("penfree_version"), str), where, "penfree_version", "a string",
          data.get("penfree_version", _MISSING))
    _need(isinstance(data.get("options"), dict), where, "options", "an object", data.get("options", _MISSING))
    for k, f in enumerate(files):
        for key in ("name", "file"):
            _need(isinstance(f.get(key), str) and f.get(key), where, f"files[{k}].{key}", "a non-empty string",
                  f.get(key, _MISSING))
        for key in ("scene", "deform_options"):
            _need(isinstance(f.get(key, {}), dict), where, f"files[{k}].{key}", "an object", f.get(key))
        sm = f.get("summary", _MISSING)
        _need(isinstance(sm, dict), where, f"files[{k}].summary", "an object", sm)
        proj = sm.get("projected")
        if isinstance(proj, dict) and "cd_share" in proj:
            f_ = proj["cd_share"]
            _need(_is_number(f_) and 0.0 <= f_ <= 1.0, where, f"files[{k}].summary.projected.cd_share",
                  "a number in [0, 1]", f_)
        for dotted, _ in REGRESSION_FIGURES:
            d, key = sm, f"files[{k}].summary"
            parts = dotted.split(".")
            for part in parts[:-1]:
                d, key = d.get(part, _MISSING), f"{key}.{part}"
                _need(isinstance(d, dict), where, key, "an object", d)
            lo, lo_open, hi, what = _figure_range(dotted, sm)
            v, key = d.get(parts[-1], _MISSING), f"{key}.{parts[-1]}"
            if v is None:  # a report writes null where a figure does not exist (no next frame)
                continue
            _need(_is_number(v) and (v > lo if lo_open else v >= lo) and v <= hi, where, key, f"null or {what}", v)


def _norm(path) -> str:
    return os.path.normpath(os.fspath(path))


def _path_of(entry) -> str:
    """An entry's path as given (its base name where it has none, as in hand-made baselines)."""
    return entry.get("file") or entry.get("name") or ""


def match_baseline(files, baseline, where) -> list:
    """The baseline entry of each input: ``(index, how)`` or None (no entry).

    `how` is ``path`` (the path as given, normalised, is the baseline's), ``single``
    (one file on each side, whatever its name) or ``name`` (the base name, where that
    is unambiguous: entries matched by path to another input are not candidates).

    Raises
    ------
    InputError
        Two baseline entries for one input path, or a base-name match that is
        ambiguous (two baseline entries, or two inputs, of that name); names both.
    """
    old = baseline["files"]
    by_path = {}
    for i, f in enumerate(old):
        by_path.setdefault(_norm(_path_of(f)), []).append(i)
    out, claimed = [None] * len(files), set()
    for j, p in enumerate(files):
        ix = by_path.get(_norm(p), [])
        if len(ix) > 1:
            raise InputError(f"baseline {where} holds two entries for {p}: files[{ix[0]}] and files[{ix[1]}] "
                             f"(expected one per file)")
        if ix:
            out[j] = (ix[0], "path")
            claimed.add(ix[0])
    if len(files) == 1 and len(old) == 1:
        return [out[0] or (0, "single")]
    open_ = [j for j in range(len(files)) if out[j] is None]
    for j in open_:
        name = os.path.basename(_norm(files[j]))
        ix = [i for i, f in enumerate(old) if i not in claimed and os.path.basename(_norm(_path_of(f))) == name]
        if len(ix) > 1:
            raise InputError(f"baseline {where}: {files[j]} matches no entry by path and two by base name {name}: "
                             f"{_path_of(old[ix[0]])} and {_path_of(old[ix[1]])}; give the inputs as the baseline "
                             f"names them")
        rivals = [files[q] for q in open_ if q != j and os.path.basename(_norm(files[q])) == name]
        if ix and rivals:
            raise InputError(f"baseline {where}: both {files[j]} and {rivals[0]} match the entry "
                             f"{_path_of(old[ix[0]])} by base name only; give the inputs as the baseline names them")
        if ix:
            out[j] = (ix[0], "name")
    return out


def _fmt(v) -> str:
    return json.dumps(v) if not isinstance(v, str) else v


def baseline_warnings(baseline, where, options, reports, matches) -> list:
    """One-line warnings (str) naming what differs from the baseline's run: penfree
    version and report options (`COMPARED_OPTIONS`), and per matched entry the file,
    the deform input and the scene. Differences are reported, not failed."""
    out, diffs = [], []
    if baseline.get("penfree_version") != __version__:
        diffs.append(f"penfree_version {_fmt(baseline.get('penfree_version'))} (now {__version__})")
    old_opts = baseline.get("options", {})
    for key in COMPARED_OPTIONS:
        if old_opts.get(key) != options.get(key):
            diffs.append(f"option {key} {_fmt(old_opts.get(key))} (now {_fmt(options.get(key))})")
    if diffs:
        out.append(f"warning: baseline {where} comes from another run: " + ", ".join(diffs))
    for rep, m in zip(reports, matches):
        if m is None:
            continue
        f, diffs = baseline["files"][m[0]], []
        if m[1] != "path":
            diffs.append(f"file {_path_of(f)} (now {rep['file']})")
        old_in = f.get("deform_options", {}).get("input")
        new_in = (rep.get("deform_options") or {}).get("input")
        if old_in != new_in:
            diffs.append(f"deform input {_fmt(old_in)} (now {_fmt(new_in)})")
        for key in ("kind", "n_vertices", "n_frames", "dtype"):
            old_v, new_v = f.get("scene", {}).get(key), (rep.get("scene") or {}).get(key)
            if old_v != new_v:
                diffs.append(f"scene {key} {_fmt(old_v)} (now {_fmt(new_v)})")
        if diffs:
            out.append(f"warning: baseline {where} entry {_path_of(f)} differs for {rep['file']}: " + ", ".join(diffs))
    return out
