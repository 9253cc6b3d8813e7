"""One mesh file through meshio (or penfree's OBJ reader): points, edges and faces.

Shared by the numbered mesh sequences (``meshseq``) and meshio's XDMF time series
(``xdmf``): cell blocks become edges and triangles, and a cell type that would
otherwise be dropped (a volume cell, a type meshio skips with a warning) is refused,
since dropping it would read a mesh as bare points.
"""

from __future__ import annotations

import contextlib
import io
import re

import numpy as np

from ..errors import FormatError
from .obj import read_obj

#: What :func:`topology_from_cells` reads; every other cell type is refused.
SUPPORTED_CELLS = "triangle, quad, polygon, line, line3 or vertex cells"
#: VTK cell types that meshio 5.3 skips with a warning instead of reading them.
VTK_SKIPPED = {2: "VTK_POLY_VERTEX", 4: "VTK_POLY_LINE", 6: "VTK_TRIANGLE_STRIP", 11: "VTK_VOXEL"}
#: Nodes per cell of the fixed-size types; quads and polygons ("polygon", "polygon5") are fanned.
CELL_NODES = {"triangle": 3, "quad": 4, "line": 2, "line3": 3}
MESHIO_SKIPPED = re.compile(r"cells that meshio cannot handle \(types? ([\d, ]+)\)")


def fan(cells: np.ndarray) -> np.ndarray:
    """``(C, k)`` polygons -> ``(C * (k - 2), 3)`` fan triangles, each polygon's triangles together, winding kept."""
    k = cells.shape[1]
    corners = np.array([[0, j, j + 1] for j in range(1, k - 1)], dtype=np.int64).ravel()
    return cells[:, corners].reshape(-1, 3)


def topology_from_cells(cells, n_points: int, path: str):
    """meshio cell blocks -> ``edges (E, 2)`` and ``faces (F, 3)`` int64, each None if empty.

    Triangles are faces, quads and polygons fan triangles (:func:`fan`), lines
    edges, ``line3`` (nodes end0, end1, mid) the two edges end0-mid, mid-end1;
    vertex cells carry nothing. Any other type is refused: dropping it would
    read a mesh as bare points.

    Raises
    ------
    FormatError
        Naming `path`, the cell type or the out-of-range index, and what was expected.
    """
    edges, faces = [], []
    for block in cells:
        kind = block.type
        if kind == "vertex":
            continue
        polygon = kind == "quad" or kind.startswith("polygon")
        try:
            data = np.asarray(block.data, dtype=np.int64)
        except (TypeError, ValueError):
            data = None  # ragged
        if data is None or data.ndim != 2 or kind not in CELL_NODES and not polygon:
            nodes = f"{data.shape[1]} nodes" if data is not None and data.ndim == 2 else "varying nodes"
            raise FormatError(f"cells of type {kind} ({nodes}) in {path}; penfree reads {SUPPORTED_CELLS} "
                              f"(surfaces and curves, not volumes or higher-order cells)")
        if data.shape[1] != CELL_NODES.get(kind, max(data.shape[1], 3)):
            raise FormatError(f"cells of type {kind} in {path} have {data.shape[1]} nodes; expected "
                              f"{CELL_NODES.get(kind, 'at least 3')}")
        if data.size and (data.min() < 0 or data.max() >= n_points):
            bad = int(data.min()) if data.min() < 0 else int(data.max())
            raise FormatError(f"cells of type {kind} in {path} refer to vertex {bad}; expected indices in "
                              f"[0, {n_points - 1}] for the file's {n_points} vertices")
        if kind == "triangle":
            faces.append(data)
        elif polygon:
            faces.append(fan(data))
        elif kind == "line":
            edges.append(data)
        else:  # line3: end0, end1, mid
            edges.append(data[:, [0, 2, 2, 1]].reshape(-1, 2))
    e = np.concatenate(edges) if edges else None
    f = np.concatenate(faces) if faces else None
    return e, f


def read_mesh(path: str):
    """One frame: ``points (N, 3)``, ``edges (E, 2)`` or None, ``faces (F, 3)`` or None."""
    if path.lower().endswith(".obj"):
        return read_obj(path)
    import meshio

    sink = io.StringIO()
    try:
        # meshio prints to the console and may call sys.exit on unreadable files.
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
            mesh = meshio.read(path)
    except (Exception, SystemExit) as exc:
        msg = " ".join((str(exc) if not isinstance(exc, SystemExit) else sink.getvalue()).split())[:120]
        raise FormatError(f"cannot read mesh file {path} ({type(exc).__name__}: {msg})") from None
    pts = np.asarray(mesh.points)
    if pts.ndim != 2 or pts.shape[1] not in (2, 3):
        raise FormatError(f"points must be (N, 3); got {pts.shape} in {path}")
    if pts.shape[1] == 2:
        pts = np.column_stack([pts, np.zeros(len(pts), pts.dtype)])
    # meshio warns and skips VTK cell types it has no name for (VTU, VTK 5.1): that would be lost geometry.
    skipped = MESHIO_SKIPPED.search(" ".join(sink.getvalue().split()))
    if skipped:
        types = [int(t) for t in skipped.group(1).replace(",", " ").split()]
        names = ", ".join(f"{VTK_SKIPPED.get(t, 'VTK cell type')} ({t})" for t in types)
        raise FormatError(f"cells of type {names} in {path} cannot be read (meshio skips them); expected "
                          f"{SUPPORTED_CELLS} (save polylines as VTK_LINE segments or as OBJ 'l' records)")
    e, f = topology_from_cells(mesh.cells, len(pts), path)
    return pts, e, f
