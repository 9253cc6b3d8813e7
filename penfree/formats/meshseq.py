"""Numbered mesh-file sequences (``frame_0001.ply``, ``out/A%08d.ply``, ``frames/*.obj``).

A sequence is named by a printf pattern (``out/A%08d.ply``), a glob
(``frames/frame_*.obj``), a directory holding one numbered series, or one
numbered file whose siblings share its name pattern (``frame_0001.ply`` ->
every ``frame_NNNN.ply``). Frames are sorted by number, not by name. Files are
read through meshio, OBJ through :mod:`penfree.formats.obj` (meshio drops
``l`` polylines). Triangles become faces, lines/polylines edges, quads and
polygons a fan of triangles; any other cell type, and cells that meshio
itself skips (VTK_POLY_LINE), are refused, never dropped. Every frame must
have the vertex count and the topology of the first.

Frame numbers may be negative (Houdini's ``cloth.-002.ply``: a ``-`` right
after a non-alphanumeric character is a sign, ``cloth-0002.ply`` is frame 2)
and must follow one constant stride (every frame or every k-th): the steps
are taken to be equal in time, so a missing frame is refused.

Mesh files carry no thickness, dt, weights or obstacles: they are not written
and read back as absent. Two files with one frame number are refused. Writing
replaces only the frame files it writes (with ``overwrite``) and refuses a
directory that holds other frames of the same series: they would read back as
extra frames, and penfree never removes a file it did not write.

>>> seq = read_sequence("out/A%08d.ply")                          # doctest: +SKIP
>>> write_sequence("frames/", seq)  # frames/frame_0000.ply ...  # doctest: +SKIP
"""

from __future__ import annotations

import contextlib
import glob
import io
import os
import re
import shutil
import tempfile

import numpy as np

from ..errors import FormatError, InputError, OutputExistsError
from ..sequence import Sequence
from ._registry import FORMATS, register
from .atomic import PRINTF_DIRECTIVE, TMP_PREFIX, TMP_SUFFIX, atomic_dir, on_commit, printf_to_glob, write_phase
from ._mesh_file import read_mesh
from .obj import write_obj

MESH_EXTENSIONS = (".ply", ".obj", ".vtk", ".vtu", ".off", ".stl")
DEFAULT_PATTERN = "frame_%04d.ply"
#: A frame number: digits, with a minus sign only right after a non-alphanumeric
#: character (``cloth.-002.ply`` is -2, ``cloth-0002.ply`` is 2).
NUMBER = r"((?:(?<![A-Za-z0-9])-)?\d+)"
#: The last run of digits in a file name is its frame number.
NUMBERED = re.compile(r"^(.*?)" + NUMBER + r"(\D*)$")
#: Output names count as numbered only with the digits right before the extension.
NUMBERED_FILE = re.compile(r"^(.*?)(\d+)(\.[^.]+)$")
GLOB_CHARS = re.compile(r"[*?\[]")


# --- finding the files ----------------------------------------------------------

def _pattern_regex(basename: str) -> re.Pattern:
    parts = PRINTF_DIRECTIVE.split(basename)
    # split() with 2 groups yields [text, zero, width, text, ...]
    pieces = [re.escape(parts[0])]
    for k in range(1, len(parts), 3):
        pieces.append(r"(-?\d+)")  # printf writes -2 as "-002" for %04d
        pieces.append(re.escape(parts[k + 2]))
    return re.compile("^" + "".join(pieces) + "$")


def _from_pattern(path: str) -> list:
    d, base = os.path.split(path)
    if len(PRINTF_DIRECTIVE.findall(base)) != 1:
        raise InputError(f"pattern {path} must hold exactly one %d directive (e.g. A%08d.ply)")
    rx = _pattern_regex(base)
    found = []
    for name in _listdir(d or ".", path):
        m = rx.match(name)
        if m and base % int(m.group(1)) == name:
            found.append((int(m.group(1)), os.path.join(d, name)))
    return [p for _, p in sorted(found)]


def _listdir(d: str, path: str) -> list:
    try:
        return sorted(os.listdir(d))
    except OSError:
        raise InputError(f"no such directory {d or '.'} for {path}") from None


def _number_key(p: str):
    m = NUMBERED.match(os.path.basename(p))
    return (0, int(m.group(2)), p) if m else (1, 0, p)


def _from_siblings(path: str) -> list:
    d, base = os.path.split(path)
    m = NUMBERED.match(base)
    if not m:
        raise InputError(f"{path} has no frame number in its name; expected e.g. frame_0001.ply, a pattern or a directory")
    prefix, suffix = m.group(1), m.group(3)
    rx = re.compile("^" + re.escape(prefix) + NUMBER + re.escape(suffix) + "$")
    return sorted((os.path.join(d, n) for n in _listdir(d or ".", path) if rx.match(n)), key=_number_key)


def _from_directory(path: str) -> list:
    groups = {}
    for name in _listdir(path, path):
        full = os.path.join(path, name)
        m = NUMBERED.match(name)
        if name.startswith(".") or not m or os.path.splitext(name)[1].lower() not in MESH_EXTENSIONS:
            continue
        if os.path.isfile(full):
            groups.setdefault((m.group(1), m.group(3)), []).append(full)
    if not groups:
        raise InputError(f"directory {path} holds no numbered mesh files; expected e.g. frame_0001.ply ({' '.join(MESH_EXTENSIONS)})")
    if len(groups) > 1:
        names = ", ".join(f"{p}*{s}" for p, s in sorted(groups))
        raise InputError(f"directory {path} holds several numbered series ({names}); pass a pattern such as {path}/frame_%04d.ply")
    return sorted(next(iter(groups.values())), key=_number_key)


def frame_files(path: str) -> list:
    """The frame files named by `path`, sorted by frame number."""
    base = os.path.basename(path)
    if PRINTF_DIRECTIVE.search(base):
        files = _from_pattern(path)
    elif os.path.isdir(path):
        files = _from_directory(path)
    elif GLOB_CHARS.search(path) and not os.path.exists(path):
        files = sorted((p for p in glob.glob(path) if os.path.isfile(p)), key=_number_key)
    elif os.path.isfile(path):
        files = _from_siblings(path)
    else:
        raise InputError(f"no such file or directory: {path}")
    if len(files) < 2:
        raise InputError(f"{path} names {len(files)} mesh file(s); a sequence needs at least 2 frames")
    _check_unique_numbers(files, path)
    _check_stride(files, path)
    return files


def _check_unique_numbers(files: list, path: str) -> None:
    """Two files with one frame number (``frame_3.ply``, ``frame_0003.ply``) are a conflict, not two frames."""
    seen = {}
    for p in files:
        m = NUMBERED.match(os.path.basename(p))
        if m is None:
            continue
        n = int(m.group(2))
        if n in seen:
            raise InputError(f"{seen[n]} and {p} have the same frame number {n} in {path}; "
                             f"expected one file per frame (remove or rename one)")
        seen[n] = p


def _check_stride(files: list, path: str) -> None:
    """Frame numbers must follow one stride: a step of the prediction is one frame-to-frame time step."""
    matches = [NUMBERED.match(os.path.basename(p)) for p in files]
    if len(files) < 3 or not all(matches):  # a glob may add unnumbered files: their order is the caller's
        return
    numbers = [int(m.group(2)) for m in matches]
    steps = np.diff(numbers)
    values, counts = np.unique(steps, return_counts=True)
    stride = int(values[np.argmax(counts)])  # the most common step; ties go to the smallest
    if (steps == stride).all():
        return
    k = int(np.flatnonzero(steps != stride)[0])
    a, b, pa, pb = numbers[k], numbers[k + 1], files[k], files[k + 1]
    d = path if os.path.isdir(path) else (os.path.dirname(pa) or ".")
    gap = (f"frame {a + stride} is missing from" if (b - a) % stride == 0 and b > a + stride
           else f"frames {a} and {b} are {b - a} apart in")
    raise InputError(f"{gap} {d}: {os.path.basename(pa)} is followed by {os.path.basename(pb)} while the other "
                     f"frames are {stride} apart; expected one constant stride of frame numbers (penfree assumes "
                     f"equal time steps between frames)")


# --- reading -----------------------------------------------------------------

def _same(a, b) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return a.shape == b.shape and np.array_equal(a, b)


def read_meshseq(path: str) -> Sequence:
    files = frame_files(path)
    pts0, edges, faces = read_mesh(files[0])
    # float32 stays float32 whatever its byte order (legacy VTK is big-endian).
    dtype = np.dtype(np.float32) if pts0.dtype.kind == "f" and pts0.dtype.itemsize == 4 else np.dtype(np.float64)
    positions = np.empty((len(files), len(pts0), 3), dtype=dtype)
    positions[0] = pts0
    for s, name in enumerate(files[1:], 1):
        pts, e, f = read_mesh(name)
        if pts.shape != pts0.shape:
            raise InputError(f"frame {s} has {len(pts)} vertices, frame 0 ({files[0]}) has {len(pts0)}; in {name}")
        if not (_same(e, edges) and _same(f, faces)):
            raise InputError(f"frame {s} has a different topology (edges/faces) than frame 0 ({files[0]}); in {name}")
        positions[s] = pts
        if not np.isfinite(positions[s]).all():
            raise InputError(f"positions must be finite; frame {s} holds NaN or Inf in {name}")
    if not np.isfinite(positions[0]).all():
        raise InputError(f"positions must be finite; frame 0 holds NaN or Inf in {files[0]}")
    return Sequence(positions=positions, edges=edges, faces=faces, origin=path)


# --- writing -----------------------------------------------------------------

def output_pattern(path: str) -> str:
    """The printf pattern that writing to `path` uses."""
    base = os.path.basename(path)
    if PRINTF_DIRECTIVE.search(base):
        return path
    ext = os.path.splitext(base)[1].lower()
    if path.endswith(os.sep) or os.path.isdir(path) or ext not in MESH_EXTENSIONS:
        return os.path.join(path, DEFAULT_PATTERN)
    m = NUMBERED_FILE.match(base)
    if m:  # frame_0001.ply -> frame_%04d.ply
        return os.path.join(os.path.dirname(path), f"{m.group(1)}%0{len(m.group(2))}d{m.group(3)}")
    stem, ext = os.path.splitext(base)
    return os.path.join(os.path.dirname(path), f"{stem}_%04d{ext}")


def _write_mesh(path: str, points, edges, faces) -> None:
    if path.lower().endswith(".obj"):
        write_obj(path, points, edges, faces)
        return
    import meshio

    cells = []
    # int32: PLY cannot hold int64 (meshio would print a warning and cast anyway).
    if faces is not None and len(faces):
        cells.append(("triangle", np.asarray(faces, dtype=np.int32)))
    if edges is not None and len(edges):
        cells.append(("line", np.asarray(edges, dtype=np.int32)))
    if not cells and not path.lower().endswith(".ply"):
        # VTK/VTU files without cells cannot be read back; one vertex cell per point can.
        cells.append(("vertex", np.arange(len(points), dtype=np.int32)[:, None]))
    sink = io.StringIO()
    with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
        meshio.write(path, meshio.Mesh(np.asarray(points), cells))


def _write_frames(directory: str, base: str, seq: Sequence) -> list:
    names = []
    for s in range(seq.n_frames):
        names.append(base % s)
        _write_mesh(os.path.join(directory, names[-1]), seq.positions[s], seq.edges, seq.faces)
    return names


#: What each mesh format can hold: "faces" (triangles), "edges" (lines), "points" (no cells).
CAN_HOLD = {".ply": ("faces", "edges", "points"), ".obj": ("faces", "edges", "points"),
            ".vtk": ("faces", "edges", "points"), ".vtu": ("faces", "edges", "points"),
            ".off": ("faces", "points"), ".stl": ("faces",)}


def check_writable(pattern: str, seq: Sequence) -> None:
    """Refuse to write less than was read: topology the format cannot hold, obstacles, weights, labels.

    Raises
    ------
    InputError
        Naming the output, the format and what it cannot hold.
    """
    ext = os.path.splitext(pattern)[1].lower()
    if ext not in MESH_EXTENSIONS:
        raise InputError(f"mesh sequence output {pattern} must end in one of {' '.join(MESH_EXTENSIONS)}")
    holds = CAN_HOLD[ext]
    has = {"faces": seq.faces is not None and len(seq.faces), "edges": seq.edges is not None and len(seq.edges)}
    lost = [k for k, v in has.items() if v and k not in holds]
    if not any(has.values()) and "points" not in holds:
        lost.append("points without cells")
    lost += [f"obstacles ({', '.join(ob.name for ob in seq.obstacles)})"] if seq.obstacles else []
    lost += [k for k in ("weights", "components") if getattr(seq, k) is not None]
    if lost:
        raise InputError(f"{ext} mesh files cannot hold the {', '.join(lost)} of {seq.origin}; nothing written to "
                         f"{pattern}; choose a format that can (.h5, .npz, .xdmf{', .ply, .vtu, .obj' if lost[0] == 'edges' else ''})")


def output_files(path: str, n_frames: int) -> list:
    """Every file writing `n_frames` frames to `path` creates or replaces (it never removes one)."""
    pattern = output_pattern(path)
    return [pattern % s for s in range(n_frames)]


def _series_regex(base: str) -> re.Pattern:
    """Names of the series of `base` (``frame_%04d.ply``) whatever their padding:
    ``frame_3.ply``, ``frame_00003.ply``."""
    parts = PRINTF_DIRECTIVE.split(base)
    return re.compile("^" + re.escape(parts[0]) + r"(-?\d+)" + re.escape(parts[3]) + "$")


def check_frames_replaceable(pattern: str, n_frames: int) -> None:
    """Refuse a write that would leave frames of its series beside its own, or replace a non-file.

    Writing frames 0..n-1 replaces exactly those names. Another frame file of the
    series (``frame_0009.ply``, ``frame_9.ply``) may be anyone's: penfree cannot tell
    that it wrote it, so it is never removed, and left in place it would read back
    as part of the sequence (an extra or a duplicate frame).

    Raises
    ------
    InputError
        Naming the first such file, the pattern and the frame count.
    """
    d, base = os.path.split(pattern)
    d = d or "."
    if not os.path.isdir(d):
        return
    ours = {base % s for s in range(n_frames)}
    rx = _series_regex(base)
    try:
        names = os.listdir(d)
    except OSError as exc:
        raise InputError(f"cannot read output directory {d}: {exc.strerror or exc}") from None
    for name in sorted(ours.intersection(names)):
        full = os.path.join(d, name)
        if os.path.islink(full) or not os.path.isfile(full):
            raise InputError(f"output {full} exists and is not a regular file; penfree replaces only frame files "
                             f"it writes; choose another output")
    foreign = sorted((n for n in names if n not in ours and rx.match(n)), key=lambda n: (int(rx.match(n).group(1)), n))
    if foreign:
        more = f" and {len(foreign) - 1} more" if len(foreign) > 1 else ""
        raise InputError(f"output directory {d} holds {foreign[0]!r}{more}, a frame file that this write ({n_frames} "
                         f"frames of {base}) would not replace; --overwrite replaces only the frames penfree writes and "
                         f"never removes a file it did not write (left there, it would read back as an extra frame); "
                         f"move it away or choose another output")


def write_meshseq(path: str, seq: Sequence, overwrite: bool = False) -> None:
    pattern = output_pattern(path)
    d, base = os.path.split(pattern)
    d = d or "."
    if len(PRINTF_DIRECTIVE.findall(base)) != 1:
        raise InputError(f"output pattern {pattern} must hold exactly one %d directive (e.g. A%08d.ply)")
    check_writable(pattern, seq)
    if not os.path.isdir(d):  # a fresh directory: swap in the whole tree at once
        with atomic_dir(d) as tmp:
            _write_frames(tmp, base, seq)
        return
    check_frames_replaceable(pattern, seq.n_frames)
    old = glob.glob(printf_to_glob(pattern))
    if old and not overwrite:
        raise OutputExistsError(f"output {pattern} exists ({len(old)} files); pass --overwrite (overwrite=True) to replace it")
    with write_phase():
        try:
            tmp = tempfile.mkdtemp(prefix=TMP_PREFIX, suffix=TMP_SUFFIX, dir=d)
        except OSError as exc:
            raise InputError(f"cannot create output {pattern}: {exc.strerror or exc}") from None
        names = []

        def commit():
            if not overwrite and glob.glob(printf_to_glob(pattern)):
                raise OutputExistsError(f"output {pattern} exists; pass --overwrite (overwrite=True) to replace it")
            check_frames_replaceable(pattern, len(names))  # again: files may have appeared meanwhile
            for name in names:
                os.replace(os.path.join(tmp, name), os.path.join(d, name))
            shutil.rmtree(tmp, ignore_errors=True)
            return pattern

        on_commit(commit, lambda: shutil.rmtree(tmp, ignore_errors=True))
        names += _write_frames(tmp, base, seq)


def _sniff(path: str, writing: bool = False) -> bool:
    base = os.path.basename(path)
    if PRINTF_DIRECTIVE.search(base) or path.endswith(os.sep):
        return True
    if writing:
        # An existing directory receives frames, unless its name says which file to write (d.h5):
        # then the extension decides, and that writer refuses the directory.
        return os.path.isdir(path) and os.path.splitext(base)[1].lower() not in _known_extensions()
    return os.path.isdir(path) or (bool(GLOB_CHARS.search(path)) and not os.path.exists(path))


def _known_extensions() -> set:
    return {ext for spec in FORMATS.values() for ext in spec.extensions}


register("meshseq", MESH_EXTENSIONS, read_meshseq, write_meshseq, sniff=_sniff,
         input_files=frame_files, output_files=output_files)
