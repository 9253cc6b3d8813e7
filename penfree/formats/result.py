"""The ``deform`` output file (SPEC section 8).

A result file is an HDF5 layout-v1 sequence file (every input dataset copied,
so ``read_sequence`` reads it as its input) plus the group ``steps/`` (one
row per step) and optional groups such as ``stats/`` and ``selection/``.

=============================  ==================================================
``steps/frame`` (S,) int       frame index s of each step, 1 <= s <= T - 1
``steps/A`` (S, 3, 3) float64  the map applied: x_def = A x + b up to rounding
``steps/b`` (S, 3) float64
``steps/deformed`` (S, N, 3)   x_def in the input dtype, one step per chunk
``steps/model`` (S,) str       variable-length UTF-8 in the file, numpy str in memory
any other ``steps/<name>``     (S, ...) per-step arrays
=============================  ==================================================

Attributes are str, int, float, bool or JSON-able values (dicts, lists, None are
stored as ``"json:..."`` strings and decoded on read); ``penfree_format`` and
``penfree_version`` are always written.

>>> res = read_result("deformed.h5")                   # doctest: +SKIP
>>> res.steps["A"].shape, res.sequence.n_frames          # doctest: +SKIP
((39, 3, 3), 40)
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace

import h5py
import numpy as np

from .._version import __version__
from ..constants import FORMAT_VERSION
from ..errors import FormatError, InputError
from ..sequence import Sequence
from .atomic import atomic_file
from .frames import Frames, StepRows
from .chunks import read_frames, write_positions
from .hdf5 import frame_window, has_h5_magic, new_h5, open_h5, read_attrs, read_from_h5, write_attrs, write_to_h5

#: Per-step datasets that every reader needs (SPEC section 8); others may require more
#: (`read_result`'s `require`, e.g. ``certificate_margin`` for ``report``).
REQUIRED_STEPS = ("frame", "A", "b", "deformed")
#: Per-step datasets that must be numeric when present (``A`` may be NaN: per-component steps).
NUMERIC_STEPS = ("A", "b", "deformed", "certificate_margin", "margin_required", "start_gap", "time_fit_s", "rank",
                 "start_intersections")
#: Prefixes of further numeric per-step datasets (residual summaries, SPEC section 8).
NUMERIC_PREFIXES = ("residual_", "baseline_")
#: Per-step datasets of names (str).
TEXT_STEPS = ("model", "projection")
#: Top-level names a result file uses for the sequence itself; extra groups must avoid them.
SEQUENCE_NAMES = ("positions", "edges", "faces", "weights", "components", "obstacles", "steps")


@dataclass
class DeformResult:
    """A deform result read back.

    Attributes
    ----------
    sequence : Sequence
        The input sequence (validated, ``origin`` = the result file).
    steps : dict of str -> ndarray
        ``frame (S,) int64``, ``A (S, 3, 3)``, ``b (S, 3)``, ``deformed (S, N, 3)``
        (input dtype), ``model``/``projection`` (S,) str, and the other per-step arrays.
    attrs : dict
        File attributes (decoded; includes ``penfree_format``, ``penfree_version``).
    groups : dict of str -> dict of str -> ndarray
        Further groups (``stats``, ``selection``, ...); nested groups become nested dicts.
    origin : str
    rows : (S,) int64 or None
        A frame window's read (`read_result`): each step's row in the file, for messages.
    """

    sequence: Sequence
    steps: dict
    attrs: dict = field(default_factory=dict)
    groups: dict = field(default_factory=dict)
    origin: str = "<memory>"
    rows: np.ndarray | None = None

    @property
    def n_steps(self) -> int:
        return int(len(self.steps["frame"]))


# --- writing -----------------------------------------------------------------

def _is_text(a: np.ndarray) -> bool:
    return a.dtype.kind in "USO"


def _write_array(g, name, value, deformed_dtype=None):
    if isinstance(value, dict):
        sub = g.create_group(name)
        for k, v in value.items():
            _write_array(sub, k, v)
        return
    if deformed_dtype is not None:
        write_positions(g, name, value, deformed_dtype)
        return
    if isinstance(value, StepRows):  # a merge's per-vertex rows, one range at a time: as `data=` lays them out
        ds = g.create_dataset(name, shape=value.shape, dtype=value.dtype)
        start = 0
        for block in value.blocks():
            ds[start:start + len(block)] = block
            start += len(block)
        return
    a = np.asarray(value)
    if _is_text(a):
        data = np.array([str(x) for x in a.ravel()], dtype=object).reshape(a.shape)
        g.create_dataset(name, data=data, dtype=h5py.string_dtype("utf-8"))
    else:
        g.create_dataset(name, data=a)


def _kind(value) -> str:
    return "a group" if isinstance(value, dict) else f"{np.shape(value)} {np.asarray(value).dtype}"


def _check_steps(steps: dict, T: int, N: int, where: str, require=()) -> int:
    """Presence, shapes, dtypes and ranges of the per-step arrays; returns S.

    Messages name ``where:/steps/<name>`` and, for a bad value, the step's frame.
    """
    for key in (*REQUIRED_STEPS, *require):
        if key not in steps:
            raise FormatError(f"missing dataset steps/{key} in {where}:/steps/{key}")
    for key, value in steps.items():
        if isinstance(value, dict) and (key in (*REQUIRED_STEPS, *NUMERIC_STEPS, *TEXT_STEPS)
                                        or key.startswith(NUMERIC_PREFIXES)):
            raise FormatError(f"steps/{key} must be a dataset; got a group in {where}:/steps/{key}")
    frame = np.asarray(steps["frame"])
    if frame.ndim != 1 or (frame.size and frame.dtype.kind not in "iu"):
        raise FormatError(f"steps/frame must be (S,) integer; got {frame.shape} {frame.dtype} in {where}:/steps/frame")
    S = len(frame)
    if S and (frame.min() < 1 or frame.max() > T - 1):
        bad = int(frame.min() if frame.min() < 1 else frame.max())
        raise FormatError(f"steps/frame must be in [1, {T - 1}] for {T} frames; found {bad} in {where}:/steps/frame")
    if S > 1 and not (np.diff(frame.astype(np.int64)) > 0).all():
        k = int(np.flatnonzero(np.diff(frame.astype(np.int64)) <= 0)[0])
        raise FormatError(f"steps/frame must be strictly increasing; found {int(frame[k])} then {int(frame[k + 1])} "
                          f"in {where}:/steps/frame")
    expect = {"A": (S, 3, 3), "b": (S, 3), "deformed": (S, N, 3)}
    for key, shape in expect.items():
        got = np.shape(steps[key])
        if got != shape:
            raise FormatError(f"steps/{key} must be {shape}; got {got} in {where}:/steps/{key}")
    for key, value in steps.items():
        if key in NUMERIC_STEPS or key.startswith(NUMERIC_PREFIXES):
            dtype = value.dtype if isinstance(value, (Frames, StepRows, h5py.Dataset)) else np.asarray(value).dtype
            if dtype.kind not in "iuf":
                raise FormatError(f"steps/{key} must be numeric; got {dtype} in {where}:/steps/{key}")
        elif key in TEXT_STEPS and np.asarray(value).dtype.kind not in "USO":
            raise FormatError(f"steps/{key} must be (S,) strings; got {np.asarray(value).dtype} "
                              f"in {where}:/steps/{key}")
    for key, value in steps.items():
        shape = np.shape(value)
        if not isinstance(value, dict) and (len(shape) < 1 or shape[0] != S):
            raise FormatError(f"steps/{key} must have one row per step ({S}); got {shape} in {where}:/steps/{key}")
    _check_maps(np.asarray(steps["A"], dtype=np.float64), np.asarray(steps["b"], dtype=np.float64), frame, where)
    return S


def _check_maps(A, b, frame, where) -> None:
    """Each step's map is finite, or ``A`` is all NaN (a per-component step: its maps are in
    ``component_maps/``, SPEC section 8) with ``b`` finite or all NaN."""
    for k in range(len(frame)):
        fin_a, fin_b = np.isfinite(A[k]).all(), np.isfinite(b[k]).all()
        if fin_a and fin_b:
            continue
        if np.isnan(A[k]).all() and (fin_b or np.isnan(b[k]).all()):
            continue
        key = "b" if fin_a or np.isnan(A[k]).all() else "A"
        raise FormatError(f"steps/{key} must be finite (steps/A all NaN marks a per-component step); "
                          f"step {k} (frame {int(frame[k])}) holds NaN or Inf in {where}:/steps/{key}")


def _check_groups(groups: dict, S: int, where: str) -> None:
    """The optional groups that index into something: ``selection/chosen`` (S,) in [-1, C - 1]."""
    sel = groups.get("selection")
    if not isinstance(sel, dict) or "chosen" not in sel:
        return
    chosen = sel["chosen"]
    if isinstance(chosen, dict) or np.shape(chosen) != (S,) or (S and np.asarray(chosen).dtype.kind not in "iu"):
        raise FormatError(f"selection/chosen must be ({S},) integer; got {_kind(chosen)} in {where}:/selection/chosen")
    cand = sel.get("candidates")
    C = None if cand is None or isinstance(cand, dict) else int(np.size(cand))
    chosen = np.asarray(chosen, dtype=np.int64)
    bad = (chosen < -1) | (chosen >= C if C is not None else False)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        hi = f"{C - 1}] ({C} candidates)" if C is not None else "...]"
        raise FormatError(f"selection/chosen must be in [-1, {hi}; found {int(chosen[k])} at step {k} "
                          f"in {where}:/selection/chosen")


def write_result(path, seq: Sequence, steps: dict, attrs: dict, groups: dict | None = None,
                 overwrite: bool = False) -> None:
    """Write a deform result atomically (temporary name beside `path`, renamed at the end).

    Parameters
    ----------
    path : str or os.PathLike
    seq : Sequence
        The input sequence; copied into the file (positions, topology, weights, obstacles, attrs).
        Its positions (and a mesh obstacle's per-frame positions) may be `frames.Frames`,
        read and checked one frame at a time; the caller has validated the rest (a
        header read with a frame window), and `seq.validate` is not run.
    steps : dict of str -> array_like
        Per-step arrays, see the module docstring; ``deformed`` is cast to the input dtype
        and may be a `frames.Frames` too, any other a `frames.StepRows` (written block by
        block).
    attrs : dict
        Options, input name, ...; written over the sequence's own attributes (so a
        ``thickness``, ``dt`` or ``source`` key here replaces the sequence's value
        when the file is read back; ``penfree_format`` and ``penfree_version`` are
        always set by this function).
    groups : dict of str -> dict of str -> array_like, optional
        Extra groups (``stats``, ``selection``).
    overwrite : bool
        Replace an existing `path`; otherwise OutputExistsError.

    Raises
    ------
    OutputExistsError, FormatError
    """
    where = str(path)
    streamed = [a for a in (seq.positions, *(ob.positions for ob in seq.obstacles)) if isinstance(a, Frames)]
    if not isinstance(seq.positions, Frames):
        seq.validate()
    _check_steps(steps, seq.n_frames, seq.n_vertices, where)
    for name in groups or {}:
        if name in SEQUENCE_NAMES or "/" in name:
            raise InputError(f"result group name {name!r} is reserved or not a plain name in {where}")
    with atomic_file(path, overwrite) as tmp:
        with new_h5(tmp, path) as f:
            write_to_h5(f, seq)
            write_attrs(f, attrs)
            f.attrs["penfree_format"] = FORMAT_VERSION
            f.attrs["penfree_version"] = __version__
            g = f.create_group("steps")
            for key, value in steps.items():
                _write_array(g, key, value, deformed_dtype=seq.dtype if key == "deformed" else None)
            for name, content in (groups or {}).items():
                _write_array(f, name, content)
        for a in streamed:  # each input frame was checked finite as it was read; now their range
            a.check_scale()


# --- reading -----------------------------------------------------------------

def _read_group(g, where, skip_deformed=False, lazy=None) -> dict:
    """The datasets of `g` as arrays (nested groups as dicts); `lazy(ds)` True keeps a
    dataset open, unread (a frame window's read takes its rows later)."""
    out = {}
    for key, obj in g.items():
        if obj is None:
            raise FormatError(f"{key} is a link to nothing in {where}:{g.name}/{key}")
        if isinstance(obj, h5py.Group):
            out[key] = _read_group(obj, where)
        elif skip_deformed and key == "deformed":
            continue
        elif lazy is not None and lazy(obj):
            out[key] = obj
        elif h5py.check_string_dtype(obj.dtype) is not None:
            out[key] = np.asarray(obj.asstr()[()]).astype(str)
        else:
            out[key] = obj[()]
    return out


def _check_deformed(ds, where) -> np.dtype:
    """The native dtype of a stored ``steps/deformed``; FormatError unless (S, N, 3) float."""
    if not isinstance(ds, h5py.Dataset):
        raise FormatError(f"steps/deformed must be a dataset; got a group in {where}:/steps/deformed")
    dt = np.dtype(ds.dtype)
    if dt.kind != "f" or ds.ndim != 3:
        raise FormatError(f"steps/deformed must be (S, N, 3) float; got {ds.shape} {dt} in {where}:/steps/deformed")
    return dt.newbyteorder("=")


def _read_deformed(ds, where, frame=None, rows=None) -> np.ndarray:
    """The stored deformed states (the steps `rows` of them, all by default), each checked finite."""
    dtype = _check_deformed(ds, where)  # before its shape is used
    rows = range(ds.shape[0]) if rows is None else rows
    out = np.empty((len(rows),) + ds.shape[1:], dtype=dtype)
    pooled = read_frames(ds, rows, out)  # else frame by frame below
    for i, k in enumerate(rows):
        if not pooled:
            out[i] = ds[k]
        if not np.isfinite(out[i]).all():
            at = f" (frame {int(frame[k])})" if frame is not None and k < np.size(frame) else ""
            raise FormatError(f"steps/deformed must be finite; step {k}{at} holds NaN or Inf in {where}:/steps/deformed")
    return out


def _per_vertex(N):
    """Whether a per-step dataset is per vertex, ``(S, N, ...)`` (``--per-vertex`` residuals):
    a frame window's read takes only its rows, a tables read none. ``A`` ``(S, 3, 3)`` of
    a 3-vertex scene is not one."""
    return lambda ds: ds.ndim >= 2 and ds.shape[1] == N and ds.size > 9 * ds.shape[0]


def _steps_of(f, where):
    """The ``steps`` group of an open result file; FormatError when it is not one."""
    link = f.get("steps", getlink=True)
    if link is None:
        raise FormatError(f"{where} is not a deform result; missing dataset steps/frame in {where}:/steps/frame")
    g = f.get("steps")
    if not isinstance(g, h5py.Group):
        got = "a broken link" if g is None else "a dataset"
        raise FormatError(f"steps must be a group of per-step datasets; got {got} in {where}:/steps")
    if g.get("frame", getlink=True) is None:
        raise FormatError(f"{where} is not a deform result; missing dataset steps/frame in {where}:/steps/frame")
    return g


def read_result(path, require=(), window=None) -> DeformResult:
    """Read and validate a deform result file.

    Parameters
    ----------
    path : str or os.PathLike
    require : iterable of str
        Per-step datasets needed beyond ``frame``, ``A``, ``b`` and ``deformed``
        (e.g. ``("certificate_margin",)`` for a report).
    window : (start, stop), optional
        Read only the frames ``start .. stop - 1`` (at least 2) and the steps whose frame
        lies among them, with their rows of the per-step groups (``component_maps``,
        ``stats``, ``selection``): a frame range of a long recording (`penfree.scaleout`).
        The per-step tables are validated whole first; frame numbers are then those of
        the window (``steps/frame`` less `start`), messages name the file's.

    Raises
    ------
    FormatError
        Not a result file (no ``steps/frame``), a missing required dataset, or a
        per-step dataset with the wrong shape, dtype, range or non-finite values;
        the message names ``file:/steps/<name>`` (and the step's frame for a bad value).
    """
    where = str(path)
    with open_h5(path) as f:
        g = _steps_of(f, where)
        seq = read_from_h5(f, where, window)
        seq.validate()
        # a window's read leaves the per-vertex datasets (S, N, ...) to take their rows
        lazy = None if window is None else _per_vertex(seq.n_vertices)
        steps = _read_group(g, where, skip_deformed=True, lazy=lazy)
        frame = steps.get("frame")
        usable = frame is not None and np.ndim(frame) == 1 and np.asarray(frame).dtype.kind in "iu"
        attrs = read_attrs(f, where)
        groups = {k: _read_group(obj, where) for k, obj in f.items()
                  if isinstance(obj, h5py.Group) and k not in SEQUENCE_NAMES}
        if window is None:
            if "deformed" in g:
                steps["deformed"] = _read_deformed(g["deformed"], where, frame if usable else None)
            S = _check_steps(steps, seq.n_frames, seq.n_vertices, where, require=tuple(require))
            _check_groups(groups, S, where)
        else:
            steps, groups, rows = _window_steps(f, g, steps, groups, window, where, tuple(require), seq.n_vertices)
    steps["frame"] = steps["frame"].astype(np.int64)
    return DeformResult(sequence=seq, steps=steps, attrs=attrs, groups=groups, origin=where,
                        rows=None if window is None else rows)


def _check_tables(f, g, steps, groups, where, require, N) -> int:
    """The whole per-step tables and groups validated, the stored ``deformed`` by shape and
    dtype only (`steps` then holds it unread); returns S."""
    if "deformed" in g:
        _check_deformed(g["deformed"], where)
        steps["deformed"] = g["deformed"]
    S = _check_steps(steps, f["positions"].shape[0], N, where, require=require)
    _check_groups(groups, S, where)
    return S


def _window_steps(f, g, steps, groups, window, where, require, N):
    """The steps of `read_result`'s frame window: the whole tables validated (the stored
    ``deformed`` by shape and dtype), then the window's rows, ``frame`` less its start."""
    T = f["positions"].shape[0]
    S = _check_tables(f, g, steps, groups, where, require, N)
    start, stop = frame_window(window, T, where)
    frame = np.asarray(steps["frame"], dtype=np.int64)
    rows = np.flatnonzero((frame >= start) & (frame < stop))
    # (h5py reads the rows of an open dataset only: `rows` ascend)
    out = {k: v[rows] if isinstance(v, h5py.Dataset) else np.asarray(v)[rows]
           for k, v in steps.items() if k != "deformed" and not isinstance(v, dict)}
    out["frame"] = frame[rows] - start
    if "deformed" in steps:
        out["deformed"] = _read_deformed(steps["deformed"], where, frame, rows)
    groups = {name: _step_rows(content, rows, S) for name, content in groups.items()}
    stats = groups.get("stats")
    if isinstance(stats, dict) and isinstance(stats.get("frame"), np.ndarray) and stats["frame"].dtype.kind in "iu":
        stats["frame"] = stats["frame"].astype(np.int64) - start
    return out, groups, rows


def read_result_tables(path, require=()) -> tuple:
    """``(result, n_frames)``: a result file's per-step tables, groups and attributes without
    its frames, validated as `read_result` validates them.

    ``result.sequence`` holds the first two frames only (topology, thickness, obstacles
    and dtype are the file's), ``result.steps`` every per-step dataset whole except
    ``deformed`` and the per-vertex ones (``(S, N, ...)``, e.g. ``--per-vertex``
    residuals), ``result.groups`` every group whole; `n_frames` is the file's frame count.
    What a report of a long recording plans its frame ranges from, before a range task
    reads its frames (`read_result` with a window). Raises as `read_result` does.
    """
    where = str(path)
    with open_h5(path) as f:
        g = _steps_of(f, where)
        ds = f.get("positions")
        T = int(ds.shape[0]) if isinstance(ds, h5py.Dataset) and ds.ndim >= 1 else None
        # fewer than two frames hold no valid step: the whole (tiny) read names what is wrong
        seq = read_from_h5(f, where, None if T is None or T < 2 else (0, 2))
        seq.validate()
        N = seq.n_vertices
        steps = _read_group(g, where, skip_deformed=True, lazy=_per_vertex(N))  # those unread, then dropped
        attrs = read_attrs(f, where)
        groups = {k: _read_group(obj, where) for k, obj in f.items()
                  if isinstance(obj, h5py.Group) and k not in SEQUENCE_NAMES}
        _check_tables(f, g, steps, groups, where, tuple(require), N)
        steps = {k: v for k, v in steps.items() if not isinstance(v, h5py.Dataset)}  # none stays open
    steps["frame"] = steps["frame"].astype(np.int64)
    return DeformResult(sequence=seq, steps=steps, attrs=attrs, groups=groups, origin=where), int(T)


def _step_rows(content, rows, S):
    """The `rows` of a group's per-step arrays (leading dimension S; ``selection/candidates``
    names the candidates, not steps), nested groups alike."""
    if isinstance(content, dict):
        return {k: v if k == "candidates" else _step_rows(v, rows, S) for k, v in content.items()}
    a = np.asarray(content)
    return a[rows] if a.ndim >= 1 and a.shape[0] == S else a


def is_result_file(path) -> bool:
    """True if `path` is an HDF5 file with a top-level ``steps`` member: a result, or a broken one.

    False for a missing file, a directory or a file without the HDF5 signature (the
    sequence readers report those). A file with ``steps`` that is no valid result is
    still True, so that `read_result` names what is wrong instead of the file being
    read as a raw sequence.

    Raises
    ------
    FormatError
        A truncated or damaged HDF5 file (as `open_h5` reports it).
    """
    if not os.path.isfile(path) or not has_h5_magic(path):
        return False
    with open_h5(path) as f:
        return f.get("steps", getlink=True) is not None


def deformed_sequence(result: DeformResult) -> Sequence:
    """The deformed states of a result as a sequence (one frame per step), e.g. for ParaView.

    Frame k is ``steps/deformed[k]``, the deformed state of step ``steps/frame[k]``;
    topology, thickness and dt are the input's. The step frames are kept in
    ``attrs["deformed_from_frames"]``.
    """
    seq = result.sequence
    deformed = result.steps["deformed"]
    if deformed.shape[0] < 2:
        raise InputError(f"--deformed needs at least 2 steps to make a sequence; got {deformed.shape[0]} "
                         f"in {result.origin}:/steps/deformed")
    frames = np.asarray(result.steps["frame"], dtype=np.int64)
    obstacles = [ob if ob.is_half_space else
                 replace(ob, positions=ob.positions if np.ndim(ob.positions) == 2 else ob.positions[frames],
                         shape=None if ob.shape is None else ob.shape.take(frames))
                 for ob in seq.obstacles]
    out = Sequence(positions=deformed, edges=seq.edges, faces=seq.faces, weights=seq.weights,
                   components=seq.components, thickness=seq.thickness, contact_radius=seq.contact_radius,
                   dt=seq.dt, obstacles=obstacles,
                   source=f"deformed states of {result.origin}", origin=f"{result.origin}:/steps/deformed",
                   attrs={"deformed_from_frames": ",".join(str(int(f)) for f in result.steps["frame"])})
    return out.validate()
