"""Broad phase: pairs of primitives whose swept, inflated axis-aligned boxes
overlap, found with a hierarchical loose grid in Numba.

Design (measured against sort-and-sweep and a plain uniform grid; figures in
the lead's report). Every box of the "grid" set B is entered ONCE, into the
cell of its centre, on the level whose cell size h_L = h_0 2^L is at least
the box's extent (h_0 from the 95th percentile of the extents). A box of set A finds every B
box that can overlap it on level L among the centres within h_L / 2 of A's
box, i.e. in a small block of cells. No pair is seen twice (no duplicate
removal), memory is one entry per box, and a few huge boxes (fast-moving
primitives) sit on a coarse level of their own instead of blowing up the
fine one. When a level's cell block is larger than the level itself, the
level is scanned linearly instead (huge query boxes). Each level's cell
table is dense while that is small, else hashed (an entry keeps its cell
key, so collisions cost time, never correctness).

Queries run in parallel over the rows of A in two passes (count, then fill
at prefix-summed offsets): the output comes out in row order without a
global sort, and memory is O(n + output), never O(n^2).

Boxes touching (equal bounds) count as overlapping. Primitives that share a
vertex index are adjacent and never paired.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..errors import InputError
from .distance import edge_edge_sq, point_edge_sq, point_triangle_sq
from .topology import as_positions, as_topology

#: Cell size of level 0: this factor times the `_CELL_QUANTILE` quantile of
#: the box extents (tuned on the 64K cloth and yarn scenes).
_CELL_FACTOR = 1.0
_CELL_QUANTILE = 0.95
#: Cell size ratio of consecutive levels.
_LEVEL_RATIO = 2
#: Cells per axis are capped so that a cell key fits int64 (2^20 ^ 3 = 2^60).
_MAX_DIM = 1 << 20
#: A level's cell table is dense (no hashing) while it has at most this many
#: cells per entry.
_DENSE_FACTOR = 8
#: Slack of the query block, relative to the cell size: centres are computed
#: in floating point, the block must contain them anyway.
_PAD_REL = 1e-6

MODE_COUNT, MODE_FILL, MODE_MIN = 0, 1, 2


@njit(cache=True)
def _boxes(V_t0, V_t1, T, inflation, lo, hi):
    # Serial: memory-bound and ~1 ms at 200K primitives; a parallel launch
    # costs more than that on a loaded machine.
    for i in range(T.shape[0]):
        for a in range(3):
            mn = np.inf
            mx = -np.inf
            for c in range(T.shape[1]):
                v = T[i, c]
                mn = min(mn, V_t0[v, a], V_t1[v, a])
                mx = max(mx, V_t0[v, a], V_t1[v, a])
            lo[i, a] = mn - inflation
            hi[i, a] = mx + inflation


def _box_arrays(V_t0, V_t1, T, inflation):
    lo = np.empty((T.shape[0], 3))
    hi = np.empty((T.shape[0], 3))
    _boxes(V_t0, V_t1, T, float(inflation), lo, hi)
    return lo, hi


@njit(cache=True)
def _box_stats(lo, hi):
    corners = np.empty((2, 3))
    corners[0] = np.inf
    corners[1] = -np.inf
    ext = np.empty(lo.shape[0])
    for i in range(lo.shape[0]):
        e = 0.0
        for a in range(3):
            corners[0, a] = min(corners[0, a], lo[i, a])
            corners[1, a] = max(corners[1, a], hi[i, a])
            e = max(e, hi[i, a] - lo[i, a])
        ext[i] = e
    return corners, ext


@njit(cache=True, inline="always")
def _bucket(key, bits):
    if bits < 0:
        # Dense table: the cell key is the bucket.
        return key
    return np.int64((np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(64 - bits))


@njit(cache=True)
def _centre_keys(lo, hi, idx, origin, h, keys):
    dims = np.zeros(3, dtype=np.int64)
    cells = np.empty((idx.shape[0], 3), dtype=np.int64)
    for k in range(idx.shape[0]):
        j = idx[k]
        for a in range(3):
            c = np.int64(np.floor((0.5 * (lo[j, a] + hi[j, a]) - origin[a]) / h))
            cells[k, a] = c
            dims[a] = max(dims[a], c + 1)
    for k in range(idx.shape[0]):
        keys[k] = cells[k, 0] + dims[0] * (cells[k, 1] + dims[1] * cells[k, 2])
    return dims


@njit(cache=True)
def _fill_level(lo, hi, idx, keys, bits, nb, boff, ent_id, ent_key, ent_box, e0):
    """Counting sort of one level's boxes by bucket into the entry arrays from e0 on."""
    count = np.zeros(nb + 1, dtype=np.int64)
    for k in range(idx.shape[0]):
        count[_bucket(keys[k], bits) + 1] += 1
    for b in range(nb):
        count[b + 1] += count[b]
    for b in range(nb + 1):
        boff[b] = e0 + count[b]
    for k in range(idx.shape[0]):
        b = _bucket(keys[k], bits)
        e = e0 + count[b]
        count[b] += 1
        j = idx[k]
        ent_id[e] = j
        ent_key[e] = keys[k]
        # A copy of each box in entry order: cells are scanned sequentially.
        for a in range(3):
            ent_box[e, a] = lo[j, a]
            ent_box[e, 3 + a] = hi[j, a]


@njit(cache=True, inline="always")
def _adjacent(TA, i, TB, j):
    for a in range(TA.shape[1]):
        for b in range(TB.shape[1]):
            if TA[i, a] == TB[j, b]:
                return True
    return False


@njit(cache=True, inline="always")
def _pair_sq(V, TA, i, TB, j):
    # The primitive kinds follow from the index widths (1 = vertex, 2 = edge,
    # 3 = face); only vertex-edge, vertex-face and edge-edge occur.
    if TA.shape[1] == 2:
        return edge_edge_sq(V[TA[i, 0]], V[TA[i, 1]], V[TB[j, 0]], V[TB[j, 1]])
    if TB.shape[1] == 3:
        return point_triangle_sq(V[TA[i, 0]], V[TB[j, 0]], V[TB[j, 1]], V[TB[j, 2]])
    return point_edge_sq(V[TA[i, 0]], V[TB[j, 0]], V[TB[j, 1]])


@njit(cache=True, inline="always")
def _try(mode, i, e, self_query, lx, ly, lz, hx, hy, hz, ent_id, ent_box, TA, TB, J, pos, V, dmin):
    """Test entry e against row i; record it per `mode`; return 1 if it is a pair."""
    j = ent_id[e]
    if self_query and j <= i:
        return 0
    if (lx > ent_box[e, 3] or ent_box[e, 0] > hx or ly > ent_box[e, 4]
            or ent_box[e, 1] > hy or lz > ent_box[e, 5] or ent_box[e, 2] > hz):
        return 0
    if _adjacent(TA, i, TB, j):
        return 0
    if mode == MODE_FILL:
        J[pos] = j
    elif mode == MODE_MIN:
        d = _pair_sq(V, TA, i, TB, j)
        for a in range(TA.shape[1]):
            v = TA[i, a]
            if d < dmin[v]:
                dmin[v] = d
        for b in range(TB.shape[1]):
            v = TB[j, b]
            if d < dmin[v]:
                dmin[v] = d
    return 1


@njit(cache=True, inline="always")
def _cell_span(lo, hi, o, h, dim):
    pad = 0.5 * h + _PAD_REL * h + 1e-15 * (abs(lo) + abs(hi) + abs(o))
    c0 = max(np.int64(np.floor((lo - pad - o) / h)), 0)
    c1 = min(np.int64(np.floor((hi + pad - o) / h)), dim - 1)
    return c0, c1, max(c1 - c0 + 1, 0)


@njit(cache=True)
def _visit_row(mode, i, self_query, loA, hiA, TA, TB, origin, lev_h, lev_dims, lev_bits,
               lev_boff, lev_ent, boff, ent_id, ent_key, ent_box, J, pos, V, dmin):
    """Visit the partners j of row i; return how many there are.

    MODE_COUNT only counts; MODE_FILL writes the partners j into J from `pos`
    on; MODE_MIN folds the squared pair distance into `dmin` (per vertex).
    """
    lx, ly, lz = loA[i, 0], loA[i, 1], loA[i, 2]
    hx, hy, hz = hiA[i, 0], hiA[i, 1], hiA[i, 2]
    n = np.int64(0)
    for L in range(lev_h.shape[0]):
        h = lev_h[L]
        dx, dy, dz = lev_dims[L, 0], lev_dims[L, 1], lev_dims[L, 2]
        bits = lev_bits[L]
        # The block of cells whose centres lie within h / 2 of the row's box
        # (plus slack for rounding), clipped to the level's grid.
        x0, x1, nx = _cell_span(lx, hx, origin[0], h, dx)
        y0, y1, ny = _cell_span(ly, hy, origin[1], h, dy)
        z0, z1, nz = _cell_span(lz, hz, origin[2], h, dz)
        ncell = nx * ny * nz
        if ncell == 0:
            continue
        if ncell >= lev_ent[L + 1] - lev_ent[L]:
            # Huge query box: scanning the whole level is cheaper than its cells.
            for e in range(lev_ent[L], lev_ent[L + 1]):
                n += _try(mode, i, e, self_query, lx, ly, lz, hx, hy, hz, ent_id, ent_box,
                          TA, TB, J, pos + n, V, dmin)
            continue
        b0 = lev_boff[L]
        for z in range(z0, z1 + 1):
            for y in range(y0, y1 + 1):
                for x in range(x0, x1 + 1):
                    key = x + dx * (y + dy * z)
                    b = b0 + _bucket(key, bits)
                    for e in range(boff[b], boff[b + 1]):
                        if bits >= 0 and ent_key[e] != key:
                            continue
                        n += _try(mode, i, e, self_query, lx, ly, lz, hx, hy, hz, ent_id, ent_box,
                                  TA, TB, J, pos + n, V, dmin)
    return n


@njit(cache=True, parallel=True)
def _count_rows(self_query, loA, hiA, TA, TB, origin, lev_h, lev_dims, lev_bits, lev_boff,
                lev_ent, boff, ent_id, ent_key, ent_box, counts):
    J = np.empty(0, dtype=np.int64)
    V = np.empty((0, 3))
    dmin = np.empty(0)
    for i in prange(loA.shape[0]):
        counts[i] = _visit_row(MODE_COUNT, i, self_query, loA, hiA, TA, TB, origin, lev_h,
                               lev_dims, lev_bits, lev_boff, lev_ent, boff, ent_id, ent_key,
                               ent_box, J, 0, V, dmin)


@njit(cache=True, parallel=True)
def _fill_rows(self_query, loA, hiA, TA, TB, origin, lev_h, lev_dims, lev_bits, lev_boff,
               lev_ent, boff, ent_id, ent_key, ent_box, offsets, I, J):
    V = np.empty((0, 3))
    dmin = np.empty(0)
    for i in prange(loA.shape[0]):
        pos = offsets[i]
        n = _visit_row(MODE_FILL, i, self_query, loA, hiA, TA, TB, origin, lev_h, lev_dims,
                       lev_bits, lev_boff, lev_ent, boff, ent_id, ent_key, ent_box, J, pos, V, dmin)
        I[pos:pos + n] = i
        _sort_segment(J, pos, pos + n)


@njit(cache=True, inline="always")
def _sort_segment(J, a, b):
    # Rows are short (a few to a few hundred partners): insertion sort in
    # place, no per-row allocation inside the parallel loop.
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


@njit(cache=True, parallel=True)
def _min_rows(self_query, loA, hiA, TA, TB, origin, lev_h, lev_dims, lev_bits, lev_boff,
              lev_ent, boff, ent_id, ent_key, ent_box, V, partial):
    # Chunk c owns rows [c m / C, (c + 1) m / C) and writes only partial[c]:
    # no shared writes, and min is exact, so any thread count gives the same.
    J = np.empty(0, dtype=np.int64)
    n_chunks = partial.shape[0]
    m = loA.shape[0]
    for c in prange(n_chunks):
        for i in range(c * m // n_chunks, (c + 1) * m // n_chunks):
            _visit_row(MODE_MIN, i, self_query, loA, hiA, TA, TB, origin, lev_h, lev_dims,
                       lev_bits, lev_boff, lev_ent, boff, ent_id, ent_key, ent_box, J, 0, V,
                       partial[c])


def _quantile(x, q):
    k = min(int(q * x.shape[0]), x.shape[0] - 1)
    return float(np.partition(x, k)[k])


class _Plan:
    """The B boxes on a hierarchical loose grid; see the module docstring."""

    def __init__(self, loA, hiA, TA, loB, hiB, TB, self_query):
        self.self_query = bool(self_query)
        self.loA, self.hiA, self.TA, self.TB = loA, hiA, TA, TB
        self.empty = loA.shape[0] == 0 or loB.shape[0] == 0
        if self.empty:
            return
        cornA, extA = _box_stats(loA, hiA)
        cornB, extB = (cornA, extA) if self_query else _box_stats(loB, hiB)
        origin = np.minimum(cornA[0], cornB[0])
        span = float((np.maximum(cornA[1], cornB[1]) - origin).max())
        h0 = _CELL_FACTOR * _quantile(extB, _CELL_QUANTILE)
        if not h0 > 0.0:
            h0 = _CELL_FACTOR * _quantile(extA, _CELL_QUANTILE)
        if not h0 > 0.0:
            h0 = span / np.cbrt(loA.shape[0] + loB.shape[0]) if span > 0.0 else 1.0
        h0 = max(h0, span / (_MAX_DIM - 2))
        # level of each B box: the smallest L with extent <= h0 R^L
        level = np.zeros(loB.shape[0], dtype=np.int64)
        big = extB > h0
        if big.any():
            R = float(_LEVEL_RATIO)
            level[big] = np.ceil(np.log(extB[big] / h0) / np.log(R)).astype(np.int64)
            level[big] += extB[big] > h0 * R ** level[big]
        order = np.argsort(level, kind="stable")
        bounds = np.searchsorted(level[order], np.arange(level.max() + 2))
        lev_h, lev_dims, lev_bits, lev_boff, lev_ent, parts = [], [], [], [0], [0], []
        n_ent = loB.shape[0]
        ent_id = np.empty(n_ent, dtype=np.int64)
        ent_key = np.empty(n_ent, dtype=np.int64)
        ent_box = np.empty((n_ent, 6))
        for L in range(level.max() + 1):
            idx = np.ascontiguousarray(order[bounds[L]:bounds[L + 1]])
            if idx.size == 0:
                continue
            h = h0 * float(_LEVEL_RATIO)**L
            keys = np.empty(idx.size, dtype=np.int64)
            dims = _centre_keys(loB, hiB, idx, origin, h, keys)
            n_dense = int(dims[0]) * int(dims[1]) * int(dims[2])
            if n_dense <= _DENSE_FACTOR * idx.size + 4096:
                bits, nb = -1, n_dense
            else:
                bits = max(1, int(np.ceil(np.log2(2 * idx.size))))
                nb = 1 << bits
            boff = np.empty(nb + 1, dtype=np.int64)
            _fill_level(loB, hiB, idx, keys, bits, nb, boff, ent_id, ent_key, ent_box, lev_ent[-1])
            parts.append(boff)
            lev_h.append(h)
            lev_dims.append(dims)
            lev_bits.append(bits)
            lev_boff.append(lev_boff[-1] + nb + 1)
            lev_ent.append(lev_ent[-1] + idx.size)
        self.grid = (origin, np.array(lev_h), np.array(lev_dims, dtype=np.int64),
                     np.array(lev_bits, dtype=np.int64), np.array(lev_boff[:-1], dtype=np.int64),
                     np.array(lev_ent, dtype=np.int64), np.concatenate(parts), ent_id, ent_key,
                     ent_box)

    def _args(self):
        return (self.self_query, self.loA, self.hiA, self.TA, self.TB, *self.grid)

    def pairs(self):
        """(K, 2) int64 rows (i, j), sorted lexicographically."""
        if self.empty:
            return np.zeros((0, 2), dtype=np.int64)
        counts = np.empty(self.loA.shape[0], dtype=np.int64)
        _count_rows(*self._args(), counts)
        offsets = np.zeros(counts.shape[0] + 1, dtype=np.int64)
        np.cumsum(counts, out=offsets[1:])
        I = np.empty(offsets[-1], dtype=np.int64)
        J = np.empty(offsets[-1], dtype=np.int64)
        _fill_rows(*self._args(), offsets, I, J)
        return np.ascontiguousarray(np.stack([I, J], axis=1))

    def min_sq_into(self, V, partial):
        """Fold squared pair distances into `partial` (C, N): per-vertex minima.

        Chunk c of the rows writes only partial[c]; reduce with min afterwards.
        """
        if not self.empty:
            _min_rows(*self._args(), V, partial)


# --- public functions ---------------------------------------------------------


def _check_motion(V_t0, V_t1, inflation):
    V_t0 = as_positions(V_t0, "V_t0")
    V_t1 = as_positions(V_t1, "V_t1")
    if V_t1.shape != V_t0.shape:
        raise InputError(f"V_t1 must have the shape of V_t0 {V_t0.shape}; got {V_t1.shape}")
    inflation = float(inflation)
    if not (inflation >= 0.0 and np.isfinite(inflation)):
        raise InputError(f"inflation must be finite and >= 0; got {inflation}")
    return V_t0, V_t1, inflation


def _check_vertices(vertices, n):
    if vertices is None:
        return np.arange(n, dtype=np.int64)[:, None]
    idx = np.asarray(vertices)
    if idx.ndim != 1 or not (np.issubdtype(idx.dtype, np.integer) or idx.size == 0):
        raise InputError(f"vertices must be a 1-D integer array; got {idx.dtype} {idx.shape}")
    idx = np.unique(idx.astype(np.int64))
    if idx.size and (idx[0] < 0 or idx[-1] >= n):
        raise InputError(f"vertices must lie in [0, {n}); got range [{idx[0]}, {idx[-1]}]")
    return np.ascontiguousarray(idx[:, None])


def edge_edge_candidates(V_t0, V_t1, E, inflation=0.0) -> np.ndarray:
    """Edge pairs of one edge set whose swept, inflated boxes overlap.

    Parameters
    ----------
    V_t0, V_t1 : (N, 3) float
        Positions at the start and the end of a linear motion (pass V_t1 =
        V_t0 for a static query).
    E : (M, 2) int
    inflation : float >= 0
        Every box grows by this much on every side (so pairs within
        2 * inflation of each other per axis are reported).

    Returns
    -------
    (K, 2) int64
        Rows (i, j), i < j, edge indices sharing no vertex, sorted
        lexicographically.

    Examples
    --------
    >>> V = np.array([[0.0, 0, 0], [1, 0, 0], [0.5, -1, 0.1], [0.5, 1, 0.1]])
    >>> edge_edge_candidates(V, V, [[0, 1], [2, 3]]).tolist()  # 0.1 apart in z
    []
    >>> edge_edge_candidates(V, V, [[0, 1], [2, 3]], inflation=0.05).tolist()
    [[0, 1]]
    """
    V_t0, V_t1, inflation = _check_motion(V_t0, V_t1, inflation)
    E = as_topology(E, 2, V_t0.shape[0], "E")
    lo, hi = _box_arrays(V_t0, V_t1, E, inflation)
    return _Plan(lo, hi, E, lo, hi, E, True).pairs()


def edge_edge_candidates_between(V_t0, V_t1, EA, EB, inflation=0.0) -> np.ndarray:
    """Pairs (i, j), edge i of EA and edge j of EB, whose swept, inflated boxes overlap.

    Same conventions as `edge_edge_candidates`; the two edge sets index one
    merged V (e.g. cloth and obstacle). Edges sharing a vertex index are
    skipped. Rows sorted lexicographically.
    """
    V_t0, V_t1, inflation = _check_motion(V_t0, V_t1, inflation)
    EA = as_topology(EA, 2, V_t0.shape[0], "EA")
    EB = as_topology(EB, 2, V_t0.shape[0], "EB")
    loA, hiA = _box_arrays(V_t0, V_t1, EA, inflation)
    loB, hiB = _box_arrays(V_t0, V_t1, EB, inflation)
    return _Plan(loA, hiA, EA, loB, hiB, EB, False).pairs()


def vertex_face_candidates(V_t0, V_t1, F, inflation=0.0, vertices=None) -> np.ndarray:
    """Vertex-face pairs whose swept, inflated boxes overlap.

    Parameters
    ----------
    V_t0, V_t1 : (N, 3) float
    F : (M, 3) int
    inflation : float >= 0
    vertices : (n,) int, optional
        Query vertices (default: all of 0..N-1); duplicates are ignored.

    Returns
    -------
    (K, 2) int64
        Rows (v, f), v not a vertex of face f, sorted lexicographically.

    Examples
    --------
    >>> V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, 0.0]])
    >>> vertex_face_candidates(V, V, [[0, 1, 2]]).tolist()
    [[3, 0]]
    """
    V_t0, V_t1, inflation = _check_motion(V_t0, V_t1, inflation)
    F = as_topology(F, 3, V_t0.shape[0], "F")
    Q = _check_vertices(vertices, V_t0.shape[0])
    loA, hiA = _box_arrays(V_t0, V_t1, Q, inflation)
    loB, hiB = _box_arrays(V_t0, V_t1, F, inflation)
    pairs = _Plan(loA, hiA, Q, loB, hiB, F, False).pairs()
    pairs[:, 0] = Q[pairs[:, 0], 0]
    return pairs


def vertex_face_candidates_between(V_t0, V_t1, vertices, F, inflation=0.0) -> np.ndarray:
    """Pairs (v, f) between a vertex set and a face set of a merged V.

    Identical to ``vertex_face_candidates(V_t0, V_t1, F, inflation, vertices)``
    with the vertex set required (e.g. cloth vertices against obstacle faces,
    or obstacle vertices against cloth faces). Rows sorted lexicographically.
    """
    if vertices is None:
        raise InputError("vertices must be given (a 1-D integer array); got None")
    return vertex_face_candidates(V_t0, V_t1, F, inflation, vertices)


# --- brute-force oracles (tests) ----------------------------------------------


def _brute(loA, hiA, TA, loB, hiB, TB, self_query):
    rows = []
    for s in range(0, loA.shape[0], 512):
        ov = np.all((loA[s:s + 512, None, :] <= hiB[None]) & (loB[None] <= hiA[s:s + 512, None, :]), axis=2)
        for a in range(TA.shape[1]):
            for b in range(TB.shape[1]):
                ov &= TA[s:s + 512, a, None] != TB[None, :, b]
        if self_query:
            ov &= np.arange(s, s + ov.shape[0])[:, None] < np.arange(loB.shape[0])[None]
        i, j = np.nonzero(ov)
        rows.append(np.stack([i + s, j], axis=1))
    if not rows:
        return np.zeros((0, 2), dtype=np.int64)
    return np.concatenate(rows).astype(np.int64)


def _np_boxes(V_t0, V_t1, T, inflation):
    lo = np.minimum(V_t0[T], V_t1[T]).min(axis=1) - inflation
    hi = np.maximum(V_t0[T], V_t1[T]).max(axis=1) + inflation
    return lo, hi


def edge_edge_candidates_brute(V_t0, V_t1, E, inflation=0.0) -> np.ndarray:
    """O(M^2) numpy oracle of `edge_edge_candidates`."""
    V_t0, V_t1, inflation = _check_motion(V_t0, V_t1, inflation)
    E = as_topology(E, 2, V_t0.shape[0], "E")
    lo, hi = _np_boxes(V_t0, V_t1, E, inflation)
    return _brute(lo, hi, E, lo, hi, E, True)


def edge_edge_candidates_between_brute(V_t0, V_t1, EA, EB, inflation=0.0) -> np.ndarray:
    """O(|EA| |EB|) numpy oracle of `edge_edge_candidates_between`."""
    V_t0, V_t1, inflation = _check_motion(V_t0, V_t1, inflation)
    EA = as_topology(EA, 2, V_t0.shape[0], "EA")
    EB = as_topology(EB, 2, V_t0.shape[0], "EB")
    return _brute(*_np_boxes(V_t0, V_t1, EA, inflation), EA,
                  *_np_boxes(V_t0, V_t1, EB, inflation), EB, False)


def vertex_face_candidates_brute(V_t0, V_t1, F, inflation=0.0, vertices=None) -> np.ndarray:
    """O(n M) numpy oracle of `vertex_face_candidates`."""
    V_t0, V_t1, inflation = _check_motion(V_t0, V_t1, inflation)
    F = as_topology(F, 3, V_t0.shape[0], "F")
    Q = _check_vertices(vertices, V_t0.shape[0])
    pairs = _brute(*_np_boxes(V_t0, V_t1, Q, inflation), Q,
                   *_np_boxes(V_t0, V_t1, F, inflation), F, False)
    pairs[:, 0] = Q[pairs[:, 0], 0]
    return pairs


def vertex_face_candidates_between_brute(V_t0, V_t1, vertices, F, inflation=0.0) -> np.ndarray:
    """O(n M) numpy oracle of `vertex_face_candidates_between`."""
    if vertices is None:
        raise InputError("vertices must be given (a 1-D integer array); got None")
    return vertex_face_candidates_brute(V_t0, V_t1, F, inflation, vertices)
