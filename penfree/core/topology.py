"""Topology helpers: unique edges of a triangle mesh, vertex -> primitive
incidence (CSR), and the one-time validation of positions and index arrays
that the public functions of the proximity stages share.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..errors import InputError


def as_positions(V, name: str = "V") -> np.ndarray:
    """Validate and convert positions once.

    Parameters
    ----------
    V : (N, 3) array_like of float
        Any float (or integer) dtype; converted to float64.
    name : str
        Name used in the error message.

    Returns
    -------
    (N, 3) float64, C-contiguous (a copy only if a conversion was needed).

    Raises
    ------
    InputError
        If the shape is not (N, 3) or a value is not finite.
    """
    V = np.asarray(V)
    if V.ndim != 2 or V.shape[1] != 3:
        raise InputError(f"{name} must be (N, 3); got {V.shape}")
    if not (np.issubdtype(V.dtype, np.floating) or np.issubdtype(V.dtype, np.integer)):
        raise InputError(f"{name} must be a float array; got dtype {V.dtype}")
    V = np.ascontiguousarray(V, dtype=np.float64)
    if not np.isfinite(V).all():
        raise InputError(f"{name} must be finite; got NaN or inf")
    return V


def as_topology(T, k: int, n_vertices: int, name: str = "E") -> np.ndarray:
    """Validate and convert an index array of k-vertex primitives once.

    Parameters
    ----------
    T : (M, k) array_like of int, or None
        Edges (k = 2) or faces (k = 3). None gives an empty (0, k) array.
    k : int
    n_vertices : int
        Indices must lie in ``[0, n_vertices)``.
    name : str
        Name used in the error message.

    Returns
    -------
    (M, k) int64, C-contiguous.

    Raises
    ------
    InputError
        On a wrong shape, a non-integer dtype, or an index out of range.
    """
    if T is None:
        return np.zeros((0, k), dtype=np.int64)
    T = np.asarray(T)
    if T.size == 0 and not (T.ndim == 2 and T.shape[0] > 0):  # (0,), (0, k): none; (3, 0) is rows without indices
        return np.zeros((0, k), dtype=np.int64)
    if T.ndim != 2 or T.shape[1] != k:
        raise InputError(f"{name} must be (M, {k}); got {T.shape}")
    if not np.issubdtype(T.dtype, np.integer):
        raise InputError(f"{name} must be an integer array; got dtype {T.dtype}")
    lo, hi = int(T.min()), int(T.max())  # before the int64 cast: a uint64 2**64 - 1 would read as -1
    if lo < 0 or hi >= n_vertices:
        raise InputError(f"{name} indices must lie in [0, {n_vertices}); got range [{lo}, {hi}]")
    return np.ascontiguousarray(T, dtype=np.int64)


def edges_from_faces(F) -> np.ndarray:
    """Unique undirected edges of a triangle mesh.

    Parameters
    ----------
    F : (F, 3) array_like of int
        Non-negative vertex indices.

    Returns
    -------
    E : (E, 2) int64
        Each row sorted (``E[:, 0] < E[:, 1]``), rows sorted lexicographically.
        Edges of degenerate faces that repeat a vertex (``i == j``) are dropped:
        they are not edges.

    Examples
    --------
    >>> edges_from_faces([[0, 1, 2], [2, 1, 3]]).tolist()
    [[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]]
    """
    F = np.asarray(F)
    if F.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    if F.ndim != 2 or F.shape[1] != 3:
        raise InputError(f"faces must be (F, 3); got {F.shape}")
    if not np.issubdtype(F.dtype, np.integer):
        raise InputError(f"faces must be an integer array; got dtype {F.dtype}")
    F = F.astype(np.int64, copy=False)
    if F.min() < 0:
        raise InputError(f"faces indices must be >= 0; got {int(F.min())}")
    return _unique_face_edges(np.ascontiguousarray(F), int(F.max()) + 1)


@njit(cache=True, inline="always")
def sort_segment(J, a, b):
    """Sort ``J[a:b]`` in place: insertion sort for the short runs of adjacency and
    candidate rows (no allocation inside parallel loops), `np.sort` above 64 entries."""
    if b - a > 64:
        J[a:b] = np.sort(J[a:b])
        return
    for k in range(a + 1, b):
        v = J[k]
        m = k - 1
        while m >= a and J[m] > v:
            J[m + 1] = J[m]
            m -= 1
        J[m + 1] = v


@njit(cache=True)
def _unique_face_edges(F, n):
    # Counting sort of the 3F half-edges (lo, hi) by lo, then per lo the few hi sorted
    # (insertion) and deduplicated: O(F), rows sorted lexicographically. (np.unique
    # on a 1-D key took 30-70 ms at 130K faces, a fifth of the certificate path.)
    count = np.zeros(n + 1, dtype=np.int64)
    for f in range(F.shape[0]):
        for c in range(3):
            a, b = F[f, c], F[f, (c + 1) % 3]
            if a != b:
                count[min(a, b) + 1] += 1
    for v in range(n):
        count[v + 1] += count[v]
    fill = count[:-1].copy()
    hi = np.empty(count[n], dtype=np.int64)
    for f in range(F.shape[0]):
        for c in range(3):
            a, b = F[f, c], F[f, (c + 1) % 3]
            if a != b:
                lo = min(a, b)
                hi[fill[lo]] = max(a, b)
                fill[lo] += 1
    out = np.empty((count[n], 2), dtype=np.int64)
    m = 0
    for v in range(n):
        s, e = count[v], count[v + 1]
        sort_segment(hi, s, e)
        for k in range(s, e):
            if k == s or hi[k] != hi[k - 1]:
                out[m, 0] = v
                out[m, 1] = hi[k]
                m += 1
    return out[:m].copy()


def scene_edges(E, F) -> np.ndarray:
    """The edge set of a scene: its segments merged with the edges of its faces.

    The one place that decides which edges a scene has (verification, trust regions).

    Parameters
    ----------
    E : (M, 2) int64
        Segments, validated (`as_topology`); may be empty.
    F : (K, 3) int64
        Faces, validated; may be empty.

    Returns
    -------
    E : (M', 2) int64, C-contiguous
        Without faces, the segments in their given order; with faces, the union of
        the segments (each row sorted) and `edges_from_faces`, sorted and unique.
        Degenerate segments ``(i, i)`` are dropped either way: they have no extent
        and are no primitive.

    Examples
    --------
    >>> scene_edges(np.array([[3, 3], [4, 0]]), np.array([[0, 1, 2]])).tolist()
    [[0, 1], [0, 2], [0, 4], [1, 2]]
    """
    E = np.asarray(E, dtype=np.int64).reshape(-1, 2)
    if not len(F):
        # `compress` or a plain copy: a boolean index of the rows took ~0.9 ms for 65K
        # segments, once per `verify_step` (a 64K rods step takes ~15 ms).
        keep = E[:, 0] != E[:, 1]
        return np.array(E, order="C", copy=True) if keep.all() else np.compress(keep, E, axis=0)
    F = np.asarray(F)
    for cE, cF, res in _SCENE_EDGES_SEEN:
        if cE.shape == E.shape and cF.shape == F.shape and np.array_equal(cF, F) and np.array_equal(cE, E):
            return res.copy()
    FE = edges_from_faces(F)
    E_in = E.copy()
    E = np.unique(np.concatenate([np.sort(E, axis=1), FE]), axis=0) if len(E) else FE
    res = np.ascontiguousarray(E[E[:, 0] != E[:, 1]])
    _SCENE_EDGES_SEEN.append((E_in, np.array(F, copy=True), res.copy()))
    del _SCENE_EDGES_SEEN[:max(0, len(_SCENE_EDGES_SEEN) - _SCENE_EDGES_KEEP)]
    return res


#: The last few (segments, faces, edge set) of `scene_edges` with faces: the same mesh is
#: asked for once per step by every pass over a recording, and deriving a 130K-triangle
#: mesh's edges (a sort of 390K keys) costs ~0.1-0.2 s each time; comparing the
#: topology with a remembered one costs ~1 ms. Matched by content, never by identity.
_SCENE_EDGES_KEEP = 4
_SCENE_EDGES_SEEN: list = []


def vertex_incidence(T, n_vertices: int):
    """CSR map from each vertex to the primitives that contain it.

    Parameters
    ----------
    T : (M, k) int64
        Validated primitives (edges or faces).
    n_vertices : int

    Returns
    -------
    offsets : (n_vertices + 1,) int64
    prims : (sum of degrees,) int64
        The primitives containing vertex ``v`` are
        ``prims[offsets[v]:offsets[v + 1]]``, in increasing order; a primitive
        repeating a vertex is listed once per occurrence.
    """
    T = np.asarray(T, dtype=np.int64)
    flat = T.ravel()
    prim = np.repeat(np.arange(T.shape[0], dtype=np.int64), T.shape[1])
    order = np.argsort(flat, kind="stable")
    counts = np.bincount(flat, minlength=n_vertices).astype(np.int64)
    offsets = np.zeros(n_vertices + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    return offsets, np.ascontiguousarray(prim[order])


def referenced_vertices(n_vertices: int, *topologies) -> np.ndarray:
    """(n_vertices,) bool: True where a vertex belongs to at least one primitive."""
    used = np.zeros(n_vertices, dtype=bool)
    for T in topologies:
        if T is not None and np.size(T):
            _mark(used, np.ascontiguousarray(T, dtype=np.int64).reshape(-1))
    return used


def separation_vertices(n_vertices: int, F, E) -> np.ndarray:
    """(n_vertices,) bool: the vertices that can have a separation term (SPEC section 7).

    Every vertex of a triangle scene (a vertex in no primitive still has its nearest
    face, and is a face's nearest vertex: ipctk counts such points too); the edges'
    vertices of a segment scene, whose terms are edge-edge only.
    """
    if F is not None and np.size(F):
        return np.ones(n_vertices, dtype=bool)
    return referenced_vertices(n_vertices, F, E)


@njit(cache=True)
def _mark(used, idx):
    # used[idx] = True without numpy's fancy-index machinery (0.9 -> ~0.2 ms for a 64K
    # cloth's faces and edges, a few calls per step); negative indices wrap as numpy's.
    n = used.shape[0]
    for k in range(idx.shape[0]):
        i = idx[k]
        if i < 0:
            i += n
        if i < 0 or i >= n:
            raise IndexError("vertex index out of range")
        used[i] = True
