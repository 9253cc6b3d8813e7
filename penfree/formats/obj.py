"""A small Wavefront OBJ reader/writer for ``v``, ``l`` and ``f`` records.

meshio 5.3 drops ``l`` (polyline) records, which is how rods, yarn and hair are
exported, so OBJ frames are read here. Polylines become consecutive edges;
faces with more than three corners are split into a fan of triangles.
Texture/normal indices (``f 1/1/1``) are ignored; negative (relative) indices
are resolved.

OBJ is text and has no dtype: the writer records it in a comment
(``# penfree dtype float32``) that the reader honours, so float32 frames
round-trip as float32; other files read as float64.
"""

from __future__ import annotations

import numpy as np

from ..errors import FormatError

DTYPE_TAG = "# penfree dtype "


def _index(token: str, n_seen: int, path: str, lineno: int) -> int:
    try:
        i = int(token.split("/", 1)[0])
    except ValueError:
        raise FormatError(f"bad vertex index {token!r} on line {lineno} of {path}; expected an integer") from None
    if i == 0:
        raise FormatError(f"vertex index 0 on line {lineno} of {path}; OBJ indices start at 1")
    if i < -n_seen:
        above = f"-1 .. -{n_seen} (relative to the {n_seen} vertices above it)" if n_seen else "a 'v' line above it"
        raise FormatError(f"vertex index {i} on line {lineno} of {path} points before the first vertex; expected {above}")
    return i - 1 if i > 0 else n_seen + i


def read_obj(path: str):
    """Read one OBJ file.

    Returns
    -------
    points : (N, 3) float64 (float32 if the file says so)
    edges : (E, 2) int64 or None
        From ``l`` records (consecutive pairs of each polyline).
    faces : (F, 3) int64 or None
        From ``f`` records (fan-triangulated).
    """
    points, edges, faces = [], [], []
    dtype = np.float64
    try:
        fh = open(path, encoding="utf-8", errors="replace")
    except OSError as exc:
        raise FormatError(f"cannot read {path}: {exc.strerror}") from None
    with fh:
        for lineno, line in enumerate(fh, 1):
            if line.startswith(DTYPE_TAG):
                dtype = np.float32 if line[len(DTYPE_TAG):].strip() == "float32" else np.float64
                continue
            parts = line.split()
            if not parts:
                continue
            tag = parts[0]
            if tag == "v":
                try:
                    points.append([float(t) for t in parts[1:4]])
                except ValueError:
                    raise FormatError(f"bad vertex on line {lineno} of {path}; expected 'v x y z'") from None
                if len(points[-1]) != 3:
                    raise FormatError(f"bad vertex on line {lineno} of {path}; expected 'v x y z'")
            elif tag == "l":
                idx = [_index(t, len(points), path, lineno) for t in parts[1:]]
                edges.extend(zip(idx[:-1], idx[1:]))
            elif tag == "f":
                idx = [_index(t, len(points), path, lineno) for t in parts[1:]]
                if len(idx) < 3:
                    raise FormatError(f"face with {len(idx)} corners on line {lineno} of {path}; expected >= 3")
                faces.extend((idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1))
    if not points:
        raise FormatError(f"{path} holds no vertices ('v x y z' lines); expected an OBJ mesh")
    pts = np.array(points, dtype=np.float64).astype(dtype)
    e = np.array(edges, dtype=np.int64).reshape(-1, 2) if edges else None
    f = np.array(faces, dtype=np.int64).reshape(-1, 3) if faces else None
    # A positive index may name a vertex defined further down, so the range is checked once all are read.
    if max((a.max() for a in (e, f) if a is not None), default=-1) >= len(pts):
        _raise_out_of_range(path, len(pts))
    return pts, e, f


def _raise_out_of_range(path: str, n: int):
    """Name the first ``l``/``f`` index beyond the last vertex, as written (1-based) and with its line."""
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            parts = line.split()
            if parts and parts[0] in ("l", "f"):
                for t in parts[1:]:
                    if int(t.split("/", 1)[0]) > n:
                        raise FormatError(f"vertex index {t.split('/', 1)[0]} on line {lineno} of {path} is out of "
                                          f"range; expected 1 .. {n} (the file has {n} vertices)")
    raise FormatError(f"a vertex index in {path} is out of range; expected 1 .. {n}")  # not reached


def write_obj(path: str, points, edges=None, faces=None) -> None:
    """Write ``v`` / ``l`` / ``f`` records; coordinates with round-trip precision."""
    points = np.asarray(points)
    # 9 (float32) and 17 (float64) significant digits read back bit-identically.
    fmt = "%.9g" if points.dtype == np.float32 else "%.17g"
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("# written by penfree\n")
        fh.write(f"{DTYPE_TAG}{'float32' if points.dtype == np.float32 else 'float64'}\n")
        np.savetxt(fh, points, fmt=f"v {fmt} {fmt} {fmt}")
        if edges is not None and len(edges):
            np.savetxt(fh, np.asarray(edges, dtype=np.int64) + 1, fmt="l %d %d")
        if faces is not None and len(faces):
            np.savetxt(fh, np.asarray(faces, dtype=np.int64) + 1, fmt="f %d %d %d")
