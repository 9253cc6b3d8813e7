"""Inputs and partitioning of the scale-out path: files from specs, output names, and
the tasks (a file, or a range of its steps) that `penfree.scaleout` runs."""

from __future__ import annotations

import glob
import math
import os
from dataclasses import dataclass

import numpy as np

from ..errors import InputError

#: Extensions a directory input expands to (the primary format).
DIRECTORY_PATTERNS = ("*.h5", "*.hdf5")
#: An ``-o`` ending so names a result file, never a directory of results.
FILE_EXTENSIONS = (".h5", ".hdf5")
#: Tasks per worker the partitioner aims for (balance without tiny tasks).
TASKS_PER_WORKER = 2
#: A frame range holds at least this many steps.
MIN_STEPS_PER_TASK = 4
#: A deform or verify task holds its frames and their deformed states (two ``(steps, N, 3)``
#: arrays, one to verify a raw sequence); a file whose steps need more is cut into ranges
#: of at most this many bytes of them, however many workers and files there are (a
#: recording of tens of thousands of frames), and on a serial run too (`InProcess`).
MAX_TASK_BYTES = 1 << 30


def expand_inputs(specs, missing_ok=False) -> list:
    """Input files from files, directories and glob patterns, in a stable order.

    A directory expands to its ``*.h5`` / ``*.hdf5`` files (sorted); a directory
    without any is itself one input (a numbered mesh-file sequence). A pattern
    expands to its sorted matches. Duplicates are dropped, first occurrence kept.
    A path that does not exist is an InputError, or passed on with `missing_ok`
    (for the reader to report in its own words).
    """
    out = []
    for spec in specs:
        spec = os.fspath(spec)
        if os.path.isdir(spec):
            found = sorted({p for pat in DIRECTORY_PATTERNS for p in glob.glob(os.path.join(glob.escape(spec), pat))})
            out.extend(found or [spec])
        elif os.path.exists(spec) or (missing_ok and not glob.has_magic(spec)):
            out.append(spec)
        elif glob.has_magic(spec):
            found = sorted(glob.glob(spec))
            if not found:
                raise InputError(f"no file matches the pattern {spec!r}")
            out.extend(found)
        else:
            raise InputError(f"no such file or directory: {spec}")
    seen, unique = set(), []
    for p in out:
        key = os.path.realpath(p)
        if key not in seen:
            seen.add(key)
            unique.append(p)
    return unique


def is_scaleout(specs, workers=None, scheduler=None) -> bool:
    """True when the command should take the scale-out path."""
    if workers is not None or scheduler is not None or len(specs) != 1:
        return True
    spec = os.fspath(specs[0])
    if os.path.isdir(spec):
        return any(glob.glob(os.path.join(glob.escape(spec), pat)) for pat in DIRECTORY_PATTERNS)
    return not os.path.exists(spec) and glob.has_magic(spec)


def is_long(path, kind="sequence", fmt=None) -> bool:
    """True when `path` is an HDF5 file whose frames take more than `MAX_TASK_BYTES`: a
    serial run goes through it in frame ranges (`cluster.InProcess`), as a worker would."""
    if fmt not in (None, "hdf5"):
        return False
    T, steps, frame_bytes = _steps_of(path, kind)
    return steps is not None and T * frame_bytes > MAX_TASK_BYTES


def one_input(specs, inputs) -> bool:
    """True when `specs` name one input as such: one file (or mesh sequence), not a
    directory of recordings or a pattern, which stand for several inputs."""
    return len(specs) == 1 and inputs == [os.fspath(specs[0])]


def deform_outputs(specs, inputs, output) -> list:
    """The result file of each input of ``deform``: `output` itself for one input (as a
    serial run), ``<output>/<stem>.h5`` for several (`output_paths`).

    Raises
    ------
    InputError
        One input and `output` is a directory; several and `output` is an existing
        file, or a name ending in ``.h5`` / ``.hdf5`` that is not an existing directory.
    """
    output = os.fspath(output)
    if one_input(specs, inputs):
        if os.path.isdir(output) or output.endswith(("/", os.sep)):
            raise InputError(f"-o {output} is a directory; with one input -o names the result file (a directory "
                             f"only with several inputs)")
        return [output]
    many = f"{len(inputs)} inputs" if len(specs) > 1 or len(inputs) > 1 else f"{specs[0]} (a directory or pattern)"
    if os.path.lexists(output) and not os.path.isdir(output):
        raise InputError(f"-o {output}: {many} need an output directory (<dir>/<stem>.h5 each); "
                         f"got an existing file")
    if not os.path.isdir(output) and output.lower().endswith(FILE_EXTENSIONS):
        raise InputError(f"-o {output}: {many} need an output directory (<dir>/<stem>.h5 each); got a result "
                         f"file name (give one input file to write one result file)")
    return output_paths(inputs, output)


def output_paths(inputs, outdir) -> list:
    """``<outdir>/<input stem>.h5`` per input; InputError when two stems collide."""
    outs = [os.path.join(outdir, os.path.splitext(os.path.basename(os.path.normpath(p)))[0] + ".h5") for p in inputs]
    if len(set(outs)) != len(outs):
        dup = sorted({o for o in outs if outs.count(o) > 1})[0]
        raise InputError(f"two inputs would write the same output {dup}; rename one of them")
    return outs


# --- partitioning ----------------------------------------------------------------------


@dataclass(frozen=True)
class Task:
    """One unit of work: a file and a half-open range ``[lo, hi)`` of its steps (None: all).

    Steps are numbered as the library does: for a raw sequence and `deform`, step `s`
    (1 <= s < T) goes from frame s - 1 to s (``kind="sequence"``); for `verify` of a raw
    sequence, step `s` goes from frame s to s + 1 (``kind="path"``); for a result, `s` is
    its ``steps/frame`` (``kind="result"``).
    """

    path: str
    lo: int | None = None
    hi: int | None = None
    kind: str = "sequence"

    def label(self) -> str:
        return self.path if self.lo is None else f"{self.path} frames {self.lo}:{self.hi}"

    def frames(self):
        """The library's ``frames=(start, stop)`` slice selecting exactly these steps."""
        if self.kind == "path":  # s -> s + 1 needs frame s + 1 selected too
            return (self.lo, self.hi + 1)
        return (self.lo, self.hi)


def _steps_of(path, kind):
    """(T, steps, bytes of a frame) of a file, or (None, None, 0) when it is not HDF5 (one
    task then)."""
    try:
        import h5py

        with h5py.File(path, "r") as f:
            ds = f["positions"]
            T, frame_bytes = int(ds.shape[0]), int(np.prod(ds.shape[1:])) * 8  # read as float64 at most
            if kind == "result":
                frame = f["steps/frame"]
                if frame.dtype.kind not in "iu":  # the real reader names what is wrong
                    return None, None, 0
                return T, np.unique(np.asarray(frame[()], dtype=np.int64)), frame_bytes
    except Exception:  # not HDF5 (or unreadable here): the real reader reports it in the task
        return None, None, 0
    return T, (np.arange(1, T) if kind == "sequence" else np.arange(0, T - 1)), frame_bytes


def _ranges(n, n_parts):
    """Split range(n) into <= n_parts contiguous ranges of >= MIN_STEPS_PER_TASK."""
    n_parts = max(1, min(n_parts, n // MIN_STEPS_PER_TASK))
    cuts = [(k * n) // n_parts for k in range(n_parts + 1)]
    return [(a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]


def plan(paths, n_workers, frames=None, kind="sequence") -> list:
    """Tasks for `paths`: one per file, plus step ranges within a file when there are
    fewer files than ``TASKS_PER_WORKER * n_workers`` (see `Task` for the kinds). A file
    whose frames take more than `MAX_TASK_BYTES` always goes in ranges, each holding at
    most about that much of frames and deformed states (a whole-file task would read it
    whole; a range task reads only the frames of its steps).

    With a user frame slice, ranges are cut inside the selected steps (of a raw sequence to
    verify, the steps whose two frames are selected).
    """
    want = TASKS_PER_WORKER * max(1, n_workers)
    per_file = max(1, math.ceil(want / max(1, len(paths))))
    tasks = []
    for p in paths:
        T, steps, frame_bytes = _steps_of(p, kind)
        if steps is not None and frames is not None:
            sel = np.arange(T)[slice(*frames)]
            # a raw sequence's step s -> s + 1 needs both frames selected
            steps = steps[np.isin(steps, sel) & (np.isin(steps + 1, sel) if kind == "path" else True)]
        # a whole-file task reads every frame: a large file goes in ranges of bounded size
        big = steps is not None and T * frame_bytes > MAX_TASK_BYTES
        parts = per_file
        if big:  # a step holds a frame, and a deformed state unless it verifies a raw sequence
            per_step = frame_bytes * (1 if kind == "path" else 2)
            parts = max(parts, math.ceil((steps.size + 1) * per_step / MAX_TASK_BYTES))
        if steps is None or not steps.size or (not big and (steps.size < 2 * MIN_STEPS_PER_TASK or parts == 1)):
            tasks.append(Task(p, kind=kind))
            continue
        for a, b in _ranges(steps.size, parts):
            tasks.append(Task(p, int(steps[a]), int(steps[b - 1]) + 1, kind))
    return tasks
