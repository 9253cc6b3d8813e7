"""Broad phase: pairs of primitives whose swept, inflated axis-aligned boxes
overlap, found with a uniform grid (dense or hashed) in Numba.

Design. The boxes of the "grid" set B are entered into a uniform grid of cubic
cells, twice the median box extent along the axis where that median is largest,
doubled while a few huge boxes would cost too much; a min fold may instead take
per-axis sizes, twice the median extent along each axis, or slabs, thick across the
scene's thinnest axis and smaller along the others, where a sampled scan cost says
they pay (`choose_cells`: per-axis cells for a dense bundle of yarns, whose cubes,
sized by the long axis, hold many strands each; slabs for a draped sheet, whose cubes
hold more entries that a row scans in vain). The cell table is dense while
it has at most `_DENSE_FACTOR` cells per entry, else hashed (each entry keeps its
cell key, so collisions cost time, never correctness). Each entry carries a copy of
its box, so a cell is scanned sequentially. The key's fastest axis, called x below, is
the axis along which consecutive boxes change cells most often (a rod's own axis, a
sheet's row direction), then the next (`_AXIS_ORDER`: the plan permutes its boxes'
axes once). Two layouts:

- Lower corner (every query but a listed self query): each box is entered once, in
  the cell of its lower corner, and the rows of the query set A scan their own cells
  and `reach` layers below them, the largest span (in cells beyond the first) of the
  grid's boxes along each axis, so each partner is found once. On a dense table a
  row of cells along x is one run of entries, so the min folds' plans cut their cells
  along x into `_RUN_SPLIT` (fewer entries per run, no more runs), and a run starts
  after the leading cells whose boxes all end below the row's box along x (each cell's
  largest upper x, `_build_grid`'s `cmax`). In the min folds
  of a self query a row scans only the cells from its own on in key order: each pair
  is folded from the row whose lower corner's cell comes first. Boxes spanning more
  than `_MAX_REACH` cells (or one, when few do) stay out of the grid.
- Covering (listed self queries, `_Plan(listing=True)`): each box is entered in every
  cell it covers, each row visits its own cells from its first id above its own, and
  a pair that overlaps in several cells is emitted only from the cell holding the
  lower corner of the two boxes' intersection. Boxes covering more than `_BIG_CELLS`
  cells stay out of the grid.

Boxes kept out of the grid (fast-moving or huge primitives) are tested against every
box of the other set, so they cannot blow up the grid's memory. Issue 13, A/B in one
process each, 64K cloth: the lower-corner layout enters 130K face boxes instead of
296K (their plan 9.4 -> 6.6 ms) and its rows scan no more entries (the edge-face pass
14.8 -> 12.9 ms, the edges' self fold 10.1 -> 7.9 ms); a covering grid stays faster for
listed self queries, whose rows skip half of each cell by id (rods: the lower-corner
scan with its reach layer was 1.1-1.3x slower).

The grid is a counting sort laid out as one serial pass in id order: counted in
parallel over chunks of the boxes, filled in parallel over ranges of buckets, each
bucket by one thread (`_build_grid`).

Queries run in parallel over chunks of the rows of A in one
pass: each chunk writes its rows' partners into its own slots of a buffer sized
from a sample of the rows (a chunk that runs out only counts from there on and
is refilled at exact offsets), then the chunks are gathered in row order. The
output is the same for any number of threads, needs no global sort, and memory
is O(n + output), never O(n^2). Two passes (count, then fill) cost 2-4x more
(64K scenes, issue 13). The same row visit folds pair distances into minima
without storing pairs (`fold_min_sq`, `min_pair_sq`) and filters edge-face pairs
through certified orientation signs (`edge_face_candidates`); there each worker (a row
of minima, one per thread) claims chunk after chunk of the rows (`parallel.claim`), so
a descheduled thread leaves its share to the others. A built grid can be
queried by a second set of rows (`_Plan.with_rows`): the certificate path's edge-face
candidates and vertex-face fold share the faces' grid (`start_pass`). On a triangle
mesh the certificate path's start pass is one visit: every edge-face box hit (adjacent
ones too) folds the edge-edge and vertex-face pairs it owns (`_Plan.start_pairs`,
`_start_owners`: each such pair is reached through exactly one hit, since a face's box
holds its edges' and an edge's its vertices'), so neither fold builds a grid or visits
rows of its own. Those pairs' boxes overlap, so the box bound below cannot skip them;
a projection gap (`distance._ee_gap`, `_pt_gap`) can, and the certificate path starts
the minimum at a cap twice the distance it asks about (`start_pass`), far below a
mesh's own spacing, so almost no pair is evaluated (64K cloth: 1.13-1.15x for the
whole certificate path, with its grid's cells cut along x as a fold's).

Row scan (issue 13, A/B in one process against the previous version, same bits):
the covering grid's emit-once rule compares stored lower cell corners (`ent_clo`, the
same `_cell` values: floor is monotone, so cell(max(a, b)) = max(cell(a), cell(b)))
instead of three divisions per overlapping pair; a self query starts each bucket at
its first id above the row (`_first_above`: entries are filled in id order); the box
test is branch-free. Measured together: the scan alone 1.1-1.3x (64K yarn and cloth).

Pruned folds. Before evaluating a pair, the min folds bound its squared distance
from below by its boxes (`_gap_sq`: per-axis gaps of the primitives, the boxes less
the inflation on both sides; the fused start pass by a projection gap instead,
`_fold_owned`) and skip it when the bound, times ``1 - 1e-9``, exceeds
every minimum the pair could lower (the worker's current minima of its vertices, or
the worker's global one). The result is bit for bit the unpruned one: such a pair's
computed distance is above those minima, and min is exact. Rounding: the boxes and
the gap arithmetic err by a few ulps (the projection gap by ~100) of the largest box
coordinate M, and the distance kernels by at most ~1e-12 relative plus ~1e-13 of the pair's extent
(<= 2 M; `distance` module, tested against exact arithmetic); each gap is therefore
reduced by 1e-9 M (`_PRUNE_SLACK`) before squaring, ~1e4x what the kernels need.
`per_vertex_separation` starts its minima at the cap radius**2 (not inf), so pairs
beyond the radius are skipped from the first pair on.

Cell shape (measured, one process, 1 thread, loaded 2-core machine, 64K scenes):
cubes against per-axis sizes (2x the median extent along each axis: tiny cells
across a yarn or a sheet, sparse hashed grids) 42 vs 87 ms rods, 147 vs 164 ms
cloth edge-edge, 974 vs 1214 ms trust-region bounds of the draped, folded cloth;
never slower.

Earlier (per-axis cells, edge-edge, swept, 1 thread, loaded 2-core machine): 16K-vertex
cloth (49K edges) grid 52 ms for the sorted pairs vs sort-and-sweep along
the widest axis 51 ms just to count them; 64K cloth (196K edges) 165 vs
528 ms (a sheet's x-interval overlaps a whole strip, sweep grows ~n^1.5);
16K / 65K-segment rod bundles 8 vs 14 ms and 54 vs 211 ms. A loose
(centre-binned, multi-level) grid scanned fewer entries but visited ~6x
more cells and was 2-4x slower.

Inlining and compile time. Helpers that take arrays are inlined by Numba
(``inline="always"``): out of line, every call pays a reference count update per array
argument (the row visit out of line was 1.2-1.4x slower). Numba copies an inlined body
at every call site, and deep-copying the IR was 70% of a cold compile, so each kernel
calls `_visit_row` once, `_visit_row` calls `_scan` once and `_record` twice (once in
`_scan`, once for the boxes outside the grid), and helpers on scalars only (`_cell`,
`_gap_sq`, the orientation and projection-gap arithmetic of `orient` and `distance`) are
``forceinline=True``: compiled once and inlined by LLVM, with no IR copy. Issue 13,
fresh Numba cache, quiet machine: the first `per_vertex_separation`, edge-edge listing
and `start_pass` compiled in 28 + 40 + 24 s instead of 129 + 209 + 180 s, and the folds
ran within noise of the old code (64K cloth, 1 and 2 threads).

Boxes touching (equal bounds) count as overlapping. Primitives that share a
vertex index are adjacent and never paired.

Longer than the ~400-line guideline on purpose: the grid build, the chunked row
queries and the plan that sizes them share their array layout and invariants (the
emit-once rule above); split apart, each piece would be unreadable alone. The
brute-force oracles live in ``tests/oracles.py``.
"""

from __future__ import annotations

import copy
import types
from typing import NamedTuple

import numba
import numpy as np
from numba import njit, prange

from ...errors import InputError
from .distance import _ee, _ee_gap, _pe, _pt, _pt_gap, ee_sq_columns, pt_sq_columns
from .orient import segment_may_meet_triangle_at
from ..parallel import chunk_count, claim, claim_next, parallel_kernel, range_counter, use_parallel, work_counter
from ..topology import as_positions, as_topology, sort_segment

#: A grid box spanning more than this many cells beyond its first along an axis is
#: "big": kept out of the grid and tested by brute force. Every row scans `reach`
#: cell layers below its own along each axis, the largest span of the grid's boxes.
_MAX_REACH = 2
#: The folds' plans (`_Plan(listing=False)`, `start_pass`'s too) split each cell along
#: x, the axis of a dense table's runs, into this many: a row's cells along x are one
#: contiguous run of entries whatever their number, so finer cells there cut the entries a row scans
#: (its span plus the reach along x) without adding runs. Rows then scan up to
#: `_SPLIT_MAX_REACH` layers along x, and fewer boxes stay out of the grid
#: (`_SPLIT_BIG_SHARE` of the brute-force budget). A table that would be hashed, whose
#: cells are visited one by one, keeps unsplit cells. 64K cloth at its separations'
#: reach, one thread, alternating in one process, same bits: edge-edge fold 80 -> 58 ms,
#: vertex-face 32 -> 21 ms at 4 (2: 70 / 24 ms; 3: 59 / 23 ms); 64K yarn 88 -> 81 ms.
_RUN_SPLIT = 4
_SPLIT_MAX_REACH = 4
_SPLIT_BIG_SHARE = 1.0 / 16.0
#: A query box whose scan region (its cells and the reach) holds more cells than this
#: is tested against every grid box instead.
_BIG_ROW_CELLS = 512
#: A covering grid (listed self queries) keeps a box covering more cells than this out
#: (3 x 3 x 3 = 27 cells is the worst case of a box twice the cell size; 64 leaves room
#: for moderately elongated boxes).
_BIG_CELLS = 64
#: Row scans in blocks of this many entries (the compacted scan's scratch, `_scan`).
_SCAN_BLOCK = 256
#: MODE_MIN's deferred pairs (`_deferred_py`): a worker lists up to `_DEFER_CAP` pairs of
#: its rows and evaluates them once `_DEFER_FLUSH` are listed. 64K cloth, edge-edge fold,
#: one thread, same bits: a throwaway prototype of the fold ran 32.7 ms evaluating each
#: pair at once and 22.2 / 20.9 / 20.4 ms listing batches of 64 / 128 / 256 pairs.
_DEFER_CAP = 512
_DEFER_FLUSH = 256
#: The (row, partner) widths whose MODE_MIN folds defer: edge-edge and vertex-face.
_DEFERRED_WIDTHS = ((2, 2), (1, 3))
#: The fused start pass's scratch for one row's box hits (`_start_chunks`); a row with
#: more is visited again into a scratch twice its count.
_ROW_HITS = 256
#: Cell shapes of a plan: cubes at the largest axis's size, per-axis sizes, or slabs:
#: cells `_SLAB_ACROSS` times the cube's size along the axis where the scene spans
#: least, `_SLAB_ALONG` times it along the other two (a sheet: one or two layers of cells
#: across it, so a row visits few cells, each holding a patch of the sheet).
CELL_SHAPES = ("cube", "axis", "slab")
_SLAB_ACROSS = 8.0
_SLAB_ALONG = 0.75
#: `choose_cells`: a visited cell costs about as much as this many scanned entries, and
#: other cells than cubes are chosen only when their estimated scan costs less than this
#: fraction of the cubes' (the estimate is a sample; a near tie keeps the cubes).
_CELL_VISIT_ENTRIES = 2.0
_SHAPE_GAIN = 0.8
#: Boxes sampled (strided) for the median extents that size the cells: the cell size
#: sets the speed, never the pairs, and a median of 4K boxes is within ~2% of all of
#: theirs (a 64K-box median took 0.9 ms per axis, per plan).
_STAT_SAMPLE = 4096
#: Cells per axis are capped so that a cell key fits int64 (2^20 ^ 3 = 2^60).
_MAX_DIM = 1 << 20
#: Brute-force budget for big boxes, in box tests per box of the scene, before
#: the cell size is doubled.
_BIG_WORK_PER_BOX = 64

#: A dense cell table (no hashing) is used while it has at most this many
#: cells per grid entry.
_DENSE_FACTOR = 8
#: Cell size per axis in units of the median box extent along that axis
#: (1.5 .. 3 measured within ~15% of each other on 64K cloth and yarn scenes;
#: 1 is ~1.5x slower: more cells per box).
_CELL_FACTOR = 2.0

MODE_COUNT, MODE_FILL, MODE_MIN, MODE_GLOBAL_MIN, MODE_FILL_EF, MODE_FILL_ALL = 0, 1, 2, 3, 4, 5
#: `_defer_rows`' own mode, MODE_MIN of edge-edge or vertex-face pairs deferred: a row's
#: pairs that pass the box bound are listed, and their distances evaluated later in
#: batches (`_fold_deferred`).
MODE_MIN_DEFER = 6

#: The grid's key orders the axes by how often consecutive boxes (in id order) change
#: cells along them, the most often first (`_axis_order`; the plan permutes its boxes'
#: axes once, so every kernel keeps "x" as the key's fastest axis): the grid fill then
#: writes, and rows in id order visit, nearby buckets. The order changes the time, never
#: the pairs or the minima. Issue 13, A/B in one process, same outputs: 64K rods
#: `verify_step`, gentle step, 18 -> 13.5 ms (the rods run along z; boxes 2,070 buckets
#: apart in x-first order), fast step unchanged; 64K cloth `deform --model auto`
#: 1.08x; yarn, trust-region bounds and cloth `verify_step` within noise.
_AXIS_ORDER = True

#: Query rows below which the row passes run serially: a row costs ~0.3-1 us (a few
#: cells scanned), so 2048 rows are ~1 ms of serial work.
_PARALLEL_MIN_ROWS = 2048
#: Row chunks of the one-pass pair enumeration (each fills its own buffer slots),
#: at least this many rows each; rows sampled to size the buffer.
_PAIR_CHUNKS = 256
_PAIR_CHUNK_MIN_ROWS = 256
#: Row chunks of the min folds, claimed by the workers one at a time (`_min_rows_py`),
#: at least this many rows each: small enough that a thread descheduled for a few
#: milliseconds leaves its share to the others, large enough that claiming costs nothing.
_MIN_CHUNKS = 256
_MIN_CHUNK_ROWS = 256
_SAMPLE_ROWS = 512
_SAMPLE_MIN_STEP = 8
#: Buffer slots per chunk: the sampled pairs per row times this, plus a pad.
_CAP_SLACK = 1.25
_CAP_PAD = 64
#: The row scan compacts its box hits first (`_visit_row`) when fewer than
#: `_COMPACT_HIT_RATE` of the scanned entries overlap the row's box and a row scans at
#: least `_COMPACT_MISSES` entries that do not, decided on a sample of the rows of plans
#: with at least `_COMPACT_MIN_ROWS` rows. The deferred folds of the 64K scenes (issue 13,
#: Zen 4, one process; misses a row, hit rate, compacted / plain): yarn 70, 12%: 15.6 /
#: 19.9 ms; shuffled yarn 51, 15%: 15.6 / 23.6; cloth vertex-face 30, 17%: 5.5 / 4.6;
#: shuffled cloth vertex-face 39, 17%: 7.2-7.7 / 6.9-7.3; cloth edge-edge 29, 20%: 15.3 /
#: 13.1. (An earlier host: yarn ~10%: 1.3-1.5x faster; cloth ~30%: 0.9x.)
_COMPACT_HIT_RATE = 0.2
_COMPACT_MISSES = 45
_COMPACT_MIN_ROWS = 4096
#: Box chunks of the plan's reductions (corners, cell ranges).
_STAT_CHUNKS = 16
#: Row chunks of `min_pair_sq` (each keeps its own minimum; min is exact).
_GLOBAL_MIN_CHUNKS = 64
#: The min folds skip a pair whose box bound, times `_PRUNE_REL`, exceeds every minimum
#: it could lower; the bound's per-axis gaps are reduced by `_PRUNE_SLACK` times the
#: largest box coordinate. Both are ~1e6x the roundings they cover (module docstring).
_PRUNE_SLACK = 1e-9
_PRUNE_REL = 1.0 - 1e-9


def _boxes_py(V_t0, V_t1, T, inflation, axes, lo, hi, corners, counter):
    # Chunk c of corners.shape[0] makes the boxes [c m / C, (c + 1) m / C) and keeps their
    # bounding corners as `_corners_py` does (`_box_arrays`' corners, which `_Plan` would
    # otherwise read the boxes again for). Each box writes its own rows and min / max are
    # exact: both builds give the same bits. Memory-bound, ~1 ms at 200K primitives
    # serially; below PARALLEL_MIN_WORK boxes the serial build runs (a parallel launch
    # would cost more on a loaded machine).
    # A NaN or infinite coordinate makes its box NaN (min and max would pass a NaN
    # by; the sum of the coordinates does not, nor does it overflow below ~1e307):
    # the chunk's flag (`corners[c, 2, 0]`) is then NaN, and `_checked_corners` refuses it
    # before any grid is sized. The workers claim the chunks one after another
    # (`parallel.claim`): a late thread leaves its share to the others. Box axis k is
    # coordinate axes[k] (a plan's key order, `_Plan.axes`; (0, 1, 2) for the natural one).
    m = T.shape[0]
    C = corners.shape[0]
    x0, x1, x2 = axes[0], axes[1], axes[2]
    for w in prange(min(C, counter[1])):
        c = claim(counter)
        while c < C:
            # the chunk's corners in registers (stores into `corners` per box, which may
            # alias the boxes for all LLVM knows, made the 64K cloth's pass 1.2-1.5x slower)
            c0, c1, c2 = np.inf, np.inf, np.inf
            d0, d1, d2 = -np.inf, -np.inf, -np.inf
            bad = 0.0
            for i in range(c * m // C, (c + 1) * m // C):
                mn0, mn1, mn2 = np.inf, np.inf, np.inf
                mx0, mx1, mx2 = -np.inf, -np.inf, -np.inf
                acc = 0.0
                for k in range(T.shape[1]):
                    v = T[i, k]
                    p0, p1, p2 = V_t0[v, x0], V_t0[v, x1], V_t0[v, x2]
                    q0, q1, q2 = V_t1[v, x0], V_t1[v, x1], V_t1[v, x2]
                    mn0, mn1, mn2 = min(mn0, p0, q0), min(mn1, p1, q1), min(mn2, p2, q2)
                    mx0, mx1, mx2 = max(mx0, p0, q0), max(mx1, p1, q1), max(mx2, p2, q2)
                    acc += (p0 + q0) + (p1 + q1) + (p2 + q2)
                l0, l1, l2 = mn0 - inflation, mn1 - inflation, mn2 - inflation
                h0, h1, h2 = mx0 + inflation, mx1 + inflation, mx2 + inflation
                lo[i, 0], lo[i, 1], lo[i, 2] = l0, l1, l2
                hi[i, 0], hi[i, 1], hi[i, 2] = h0, h1, h2
                c0, c1, c2 = min(c0, l0), min(c1, l1), min(c2, l2)
                d0, d1, d2 = max(d0, h0), max(d1, h1), max(d2, h2)
                if not (acc - acc == 0.0):
                    lo[i, 0] = np.nan
                    bad = np.nan
            corners[c, 0, 0], corners[c, 0, 1], corners[c, 0, 2] = c0, c1, c2
            corners[c, 1, 0], corners[c, 1, 1], corners[c, 1, 2] = d0, d1, d2
            corners[c, 2, 0] = bad
            c = claim(counter)


_boxes = parallel_kernel(_boxes_py, "_bp_boxes")


_NATURAL_AXES = np.arange(3, dtype=np.int64)


def _box_arrays(V_t0, V_t1, T, inflation, corners=False, axes=None):
    """``(lo, hi)``: the boxes of primitives T over V_t0 -> V_t1, inflated; with
    `corners`, ``(lo, hi, (2, 3) bounding corners)`` (`_box_corners`' value and checks,
    made in the same pass). `axes`: the boxes' axes are the coordinates in this order
    (a plan's key order, `_Plan.axes`), natural without."""
    lo = np.empty((T.shape[0], 3))
    hi = np.empty((T.shape[0], 3))
    parts = np.empty((_STAT_CHUNKS, 3, 3))
    axes = _NATURAL_AXES if axes is None else np.ascontiguousarray(axes, dtype=np.int64)
    _boxes(T.shape[0], V_t0, V_t1, T, float(inflation), axes, lo, hi, parts, work_counter())
    return (lo, hi, _checked_corners(parts)) if corners else (lo, hi)


@njit(cache=True, forceinline=True)
def _cell(x, o, inv_h):
    # One formula everywhere: the reference-cell rule needs cells computed
    # identically in the box ranges and in the pair test. Monotone in x (a product by
    # a positive constant rounds monotonically), which is all the grid needs; times the
    # cell size's reciprocal rather than over the size: six divisions a box were most
    # of the range pass (issue 13).
    return np.int64(np.floor((x - o) * inv_h))


@njit(cache=True, forceinline=True)
def _bucket(key, bits):
    if bits < 0:
        # Dense table: the cell key is the bucket (no hashing, cache-friendly).
        return key
    return np.int64((np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(64 - bits))


def _cell_ranges_py(lo, hi, origin, h, clo, chi, top, reach, n_over, counter):
    # Cell ranges of the boxes. Chunk c of STAT_CHUNKS keeps its largest chi per axis in
    # top[c]; for r = 1 .. R - 1 (slot 0 unused: the reach is at least 1), the number of
    # its boxes spanning more than r cells beyond their first along some axis in
    # n_over[c, r], and the largest span per axis of the others in reach[c, r] (integer
    # max and sum: exact, so any thread count).
    m = lo.shape[0]
    C = top.shape[0]
    R = n_over.shape[1]
    o0, o1, o2 = origin[0], origin[1], origin[2]
    h0, h1, h2 = 1.0 / h[0], 1.0 / h[1], 1.0 / h[2]  # (reciprocals: `_cell`)
    for w in prange(min(C, counter[1])):  # chunks claimed (`parallel.claim`)
        c = claim(counter)
        while c < C:
            t0 = t1 = t2 = np.int64(0)
            # Histogram of the boxes by their largest span (capped at R), with the largest
            # per-axis spans in each bin, in locals: reach and n_over follow from it (the
            # per-box updates of the shared arrays could not stay in registers).
            rr = np.zeros((R + 1, 3), dtype=np.int64)
            nn = np.zeros(R + 1, dtype=np.int64)
            for i in range(c * m // C, (c + 1) * m // C):
                a0 = _cell(lo[i, 0], o0, h0)
                a1 = _cell(lo[i, 1], o1, h1)
                a2 = _cell(lo[i, 2], o2, h2)
                b0 = _cell(hi[i, 0], o0, h0)
                b1 = _cell(hi[i, 1], o1, h1)
                b2 = _cell(hi[i, 2], o2, h2)
                clo[i, 0], clo[i, 1], clo[i, 2] = a0, a1, a2
                chi[i, 0], chi[i, 1], chi[i, 2] = b0, b1, b2
                t0 = max(t0, b0)
                t1 = max(t1, b1)
                t2 = max(t2, b2)
                s0, s1, s2 = b0 - a0, b1 - a1, b2 - a2
                s = min(max(s0, s1, s2), R)
                nn[s] += 1
                rr[s, 0] = max(rr[s, 0], s0)
                rr[s, 1] = max(rr[s, 1], s1)
                rr[s, 2] = max(rr[s, 2], s2)
            top[c, 0] = max(top[c, 0], t0)
            top[c, 1] = max(top[c, 1], t1)
            top[c, 2] = max(top[c, 2], t2)
            for r in range(1, R):
                for k in range(R + 1):
                    if k > r:
                        n_over[c, r] += nn[k]
                    else:
                        for a in range(3):
                            reach[c, r, a] = max(reach[c, r, a], rr[k, a])
            c = claim(counter)


_cell_ranges_k = parallel_kernel(_cell_ranges_py, "_bp_cell_ranges")


def _cell_ranges(lo, hi, origin, h, clo, chi, max_reach=_MAX_REACH):
    """Cell ranges of the boxes into clo, chi; returns (largest chi per axis (3,),
    reach (R, 3), n_over (R,)) for R = max_reach + 1: for r >= 1, n_over[r] boxes span
    more than r cells beyond their first along some axis, and reach[r] is the others'
    largest span (row 0 unused)."""
    top = np.zeros((_STAT_CHUNKS, 3), dtype=np.int64)
    reach = np.zeros((_STAT_CHUNKS, max_reach + 1, 3), dtype=np.int64)
    n_over = np.zeros((_STAT_CHUNKS, max_reach + 1), dtype=np.int64)
    _cell_ranges_k(lo.shape[0], lo, hi, origin, h, clo, chi, top, reach, n_over, work_counter())
    return top.max(axis=0), reach.max(axis=0), n_over.sum(axis=0)


def _small_rows_py(clo, chi, reach, max_span, max_cells, small, n_big, n_cells, counter):
    # small[i]: box i spans at most max_span cells beyond its first along every axis and
    # its scan region (its cells, `reach` more below) has at most max_cells cells; chunk c
    # of STAT_CHUNKS counts the others in n_big[c] and the small ones' cells in n_cells[c].
    m = clo.shape[0]
    C = n_big.shape[0]
    for w in prange(min(C, counter[1])):  # chunks claimed (`parallel.claim`)
        c = claim(counter)
        while c < C:
            # counts in locals: workers interleave chunks, and per-box updates of
            # n_big[c] shared a cache line with the other worker's chunk (3x slower)
            big = np.int64(0)
            total = np.int64(0)
            for i in range(c * m // C, (c + 1) * m // C):
                ok = True
                cells = np.int64(1)
                for a in range(3):
                    span = chi[i, a] - clo[i, a]
                    ok &= span <= max_span
                    cells *= min(span + 1 + reach[a], max_cells + 1)  # capped: no overflow
                ok &= cells <= max_cells
                small[i] = ok
                big += not ok
                total += cells if ok else 0
            n_big[c] += big
            n_cells[c] += total
            c = claim(counter)


_small_rows_k = parallel_kernel(_small_rows_py, "_bp_small_rows")


def _small_rows(clo, chi, reach, max_span, max_cells):
    """((M,) bool, count of False, cells of the True ones): the boxes within `max_span`
    and `max_cells` (`_small_rows_py`)."""
    small = np.empty(clo.shape[0], dtype=np.bool_)
    n_big = np.zeros(_STAT_CHUNKS, dtype=np.int64)
    n_cells = np.zeros(_STAT_CHUNKS, dtype=np.int64)
    _small_rows_k(clo.shape[0], clo, chi, np.asarray(reach, dtype=np.int64), np.int64(max_span),
                  np.int64(max_cells), small, n_big, n_cells, work_counter())
    return small, int(n_big.sum()), int(n_cells.sum())


def _grid_count_py(clo, chi, small, covering, dims, bits, bounds, counts, bkt, counter):
    # Chunk c counts the entries of boxes [bounds[c], bounds[c + 1]) per bucket into its
    # own row of `counts` (C, nb): each box in every cell it covers (`covering`), else
    # once, in the cell of its lower corner, whose bucket it keeps in `bkt` (-1: a big
    # box, not entered) for the fill. (A row per chunk: with a column per chunk, both
    # threads' counters of a bucket shared a cache line.)
    d0 = dims[0]
    d01 = dims[0] * dims[1]
    C = bounds.shape[0] - 1
    for w in prange(min(C, counter[1])):  # chunks claimed (`parallel.claim`)
        c = claim(counter)
        while c < C:
            for j in range(bounds[c], bounds[c + 1]):
                if not small[j]:
                    if not covering:
                        bkt[j] = -1
                    continue
                if not covering:
                    b = _bucket(d0 * clo[j, 1] + d01 * clo[j, 2] + clo[j, 0], bits)
                    bkt[j] = b
                    counts[c, b] += 1
                    continue
                for z in range(clo[j, 2], chi[j, 2] + 1):
                    for y in range(clo[j, 1], chi[j, 1] + 1):
                        base = d0 * y + d01 * z
                        for x in range(clo[j, 0], chi[j, 0] + 1):
                            counts[c, _bucket(base + x, bits)] += 1
            c = claim(counter)


@njit(cache=True, inline="always")
def _enter(f, j, lo, hi, ent_id, ent_box):
    # Grid entry f holds box j: its id and a copy of the box (lo x, y, z, hi x, y, z).
    ent_id[f] = j
    for a in range(3):
        ent_box[f, a] = lo[j, a]
        ent_box[f, 3 + a] = hi[j, a]


def _grid_fill_py(clo, chi, small, covering, dims, bits, lo, hi, splits, slots, bkt, cmax, ent_key, ent_id,
                  ent_box, ent_clo, counter):
    # Range r enters the boxes whose bucket lies in [splits[r], splits[r + 1]), each at
    # its bucket's next slot (`slots`, from the bucket offsets), going through every box
    # in id order (its bucket from `bkt`, or each cell of a covering grid's): a bucket is
    # filled by one range, in id order, so the layout is that of one serial pass, and the
    # ranges write disjoint runs of the entry arrays. (Chunks of the boxes, each writing
    # its own slots of every bucket, had both threads writing neighbouring slots of the
    # same buckets at once wherever their chunks cover the same region, as the 64K
    # cloth's two families of faces do: 2.8x slower than one thread.)
    d0 = dims[0]
    d01 = dims[0] * dims[1]
    n = clo.shape[0]
    R = splits.shape[0] - 1
    for w in prange(min(R, counter[1])):  # ranges claimed (`parallel.claim`)
        r = claim(counter)
        while r < R:
            b0, b1 = splits[r], splits[r + 1]
            for j in range(n if b1 > b0 else 0):
                if not covering:
                    b = bkt[j]
                    if b < b0 or b >= b1:  # (-1 for a big box)
                        continue
                    f = slots[b]
                    slots[b] = f + 1
                    if bits >= 0:
                        ent_key[f] = d0 * clo[j, 1] + d01 * clo[j, 2] + clo[j, 0]
                    else:  # a dense table's largest upper x per cell (`_visit_row` skips by it)
                        cmax[b] = max(cmax[b], hi[j, 0])
                    _enter(f, j, lo, hi, ent_id, ent_box)
                    continue
                if not small[j]:
                    continue
                for z in range(clo[j, 2], chi[j, 2] + 1):
                    for y in range(clo[j, 1], chi[j, 1] + 1):
                        base = d0 * y + d01 * z
                        for x in range(clo[j, 0], chi[j, 0] + 1):
                            key = base + x
                            b = _bucket(key, bits)
                            if b < b0 or b >= b1:
                                continue
                            f = slots[b]
                            slots[b] = f + 1
                            if bits >= 0:
                                ent_key[f] = key
                            _enter(f, j, lo, hi, ent_id, ent_box)
                            for a in range(3):
                                ent_clo[f, a] = clo[j, a]
            r = claim(counter)


_grid_count = parallel_kernel(_grid_count_py, "_bp_grid_count")
_grid_fill = parallel_kernel(_grid_fill_py, "_bp_grid_fill")


def _check_box_count(n):
    """Grid entries store int32 box ids: at most 2^31 - 1 boxes (~100 GB of boxes)."""
    if n >= (1 << 31):
        raise InputError(f"a broad-phase grid holds at most 2^31 - 1 boxes; got {n}")


def _build_grid(clo, chi, small, covering, dims, bits, nb, lo, hi, chunks=None):
    """Counting sort of the small boxes' (box, cell) entries by bucket, in id order within
    a bucket: (boff, cmax, ent_key, ent_id, ent_box, ent_clo). A covering grid enters each
    box in every cell it covers and keeps its lower cell corner (`ent_clo`), else each box
    is entered once, in the cell of its lower corner (and `ent_clo` is empty). A dense
    table (one cell per bucket) keeps in `cmax` its cells' largest box upper x (-inf for
    an empty cell; a covering grid's stay -inf): a row's run skips the leading cells whose
    boxes all end below its own lower x (`_visit_row`; the 64K cloth's vertex-face rows
    scanned 26% fewer entries, its edge-edge rows 13%).

    Counted in parallel over contiguous chunks of the boxes, one per thread, each into
    its own row of counts; filled in parallel over ranges of buckets holding about as
    many entries each, one per thread, each range going through every box in id order
    and entering those in its buckets (`_grid_fill_py`): the arrays are those of one
    serial pass for any number of chunks (issue 13: the serial sort was ~40% of a 64K
    rods `verify_step`; filling by chunks of boxes, each into its own slots of every
    bucket, was 2.8x slower than one thread on the 64K cloth's faces, 1.4-3.5x slower
    than by ranges of buckets on its edges and faces).
    """
    n = clo.shape[0]
    _check_box_count(n)
    C = chunks if chunks is not None else (numba.get_num_threads() if use_parallel(n) else 1)
    bounds = (np.arange(C + 1, dtype=np.int64) * n) // C
    counts = np.zeros((C, nb), dtype=np.int64)
    bkt = np.empty(0 if covering else n, dtype=np.int64)  # a lower-corner grid's box buckets
    _grid_count(n, clo, chi, small, covering, dims, bits, bounds, counts, bkt, work_counter())
    boff = np.zeros(nb + 1, dtype=np.int64)
    np.cumsum(counts.sum(axis=0), out=boff[1:])
    m = int(boff[nb])
    # Keys only for a hashed table: a dense one has one cell per bucket.
    ent_key = np.empty(m if bits >= 0 else 0, dtype=np.int64)
    # int32 ids and cell corners (cells per axis <= _MAX_DIM = 2^20): less to write and scan.
    ent_id = np.empty(m, dtype=np.int32)
    # A copy of each box in entry order: the query scans entries sequentially instead
    # of gathering boxes by index (measured 1.5-2x faster), one box per row (lo x, y, z,
    # hi x, y, z): a box test and its hit's bound read one cache line, and the fill
    # writes one. Six coordinate rows were meant for vectorised box tests, but a row's
    # runs are too short for them to pay; one box per row measured 1.12x on the 64K
    # cloth's folds at 2 threads, ~1.02x on the yarn's (issue 13, 2026-12-03).
    ent_box = np.empty((m, 6))
    # A covering grid's lower cell corners, for its emit-once rule without a division per pair.
    ent_clo = np.empty((m if covering else 0, 3), dtype=np.int32)
    # C ranges of buckets holding about m / C entries each
    splits = np.searchsorted(boff, (np.arange(C + 1, dtype=np.int64) * m) // C)
    splits[0], splits[-1] = 0, nb
    # A dense table's largest upper x of each cell's boxes, -inf for none (a covering
    # grid's stays -inf: its rows do not skip by it, unless it is empty and they may).
    cmax = np.full(nb if bits < 0 else 0, -np.inf)
    _grid_fill(n, clo, chi, small, covering, dims, bits, lo, hi, splits, boff[:-1].copy(), bkt, cmax, ent_key,
               ent_id, ent_box, ent_clo, work_counter())
    return boff, cmax, ent_key, ent_id, ent_box, ent_clo


@njit(cache=True, inline="always")
def _first_above(ids, a, b, i):
    """The first e in [a, b) with ids[e] > i (ids ascending there), else b."""
    while a < b:
        mid = (a + b) >> 1
        if ids[mid] <= i:
            a = mid + 1
        else:
            b = mid
    return a


@njit(cache=True, inline="always")
def _entry_overlaps(ent_box, e, lx, ly, lz, hx, hy, hz):
    """Whether grid entry e's box overlaps the box (lx..hx, ly..hy, lz..hz); branch-free
    (`&`, not `or`: one branch for the caller instead of up to six unpredictable ones).
    The index unsigned: no negative-index wraparound per load (the 64K cloth's compacted
    vertex-face fold up to 1.05x faster)."""
    u = np.uint64(e)
    return ((lx <= ent_box[u, 3]) & (ent_box[u, 0] <= hx) & (ly <= ent_box[u, 4])
            & (ent_box[u, 1] <= hy) & (lz <= ent_box[u, 5]) & (ent_box[u, 2] <= hz))


@njit(cache=True, inline="always")
def _overlap(loA, hiA, i, loB, hiB, j):
    for a in range(3):
        if loA[i, a] > hiB[j, a] or loB[j, a] > hiA[i, a]:
            return False
    return True


@njit(cache=True, inline="always")
def _adjacent(TA, i, TB, j):
    # Whether the primitives share a vertex. The widths that occur are written out
    # branch-free (`|`, not `or`): the loops over runtime widths compiled to a branch
    # per vertex pair, mispredicted on the ~10 adjacent hits of a mesh edge's row.
    ka, kb = TA.shape[1], TB.shape[1]
    if ka == 2 and kb == 2:
        a0, a1, b0, b1 = TA[i, 0], TA[i, 1], TB[j, 0], TB[j, 1]
        return (a0 == b0) | (a0 == b1) | (a1 == b0) | (a1 == b1)
    if ka == 1 and kb == 3:
        a0 = TA[i, 0]
        return (a0 == TB[j, 0]) | (a0 == TB[j, 1]) | (a0 == TB[j, 2])
    for a in range(ka):
        for b in range(kb):
            if TA[i, a] == TB[j, b]:
                return True
    return False


@njit(cache=True, inline="always")
def _pair_sq(V, TA, i, TB, j):
    # The primitive kinds follow from the index widths (1 = vertex, 2 = edge,
    # 3 = face); only vertex-edge, vertex-face and edge-edge occur.
    # Coordinates, not (3,) views of V: the scalar kernels are the same arithmetic, and
    # a view per argument cost a reference count update each (the serial build of the
    # folds ran 1.6-3.7x slower than the parallel one's loop body, issue 13).
    if TA.shape[1] == 2:
        a, b, c, d = TA[i, 0], TA[i, 1], TB[j, 0], TB[j, 1]
        return _ee(V[a, 0], V[a, 1], V[a, 2], V[b, 0], V[b, 1], V[b, 2],
                   V[c, 0], V[c, 1], V[c, 2], V[d, 0], V[d, 1], V[d, 2])
    if TB.shape[1] == 3:
        p, a, b, c = TA[i, 0], TB[j, 0], TB[j, 1], TB[j, 2]
        return _pt(V[p, 0], V[p, 1], V[p, 2], V[a, 0], V[a, 1], V[a, 2],
                   V[b, 0], V[b, 1], V[b, 2], V[c, 0], V[c, 1], V[c, 2])
    p, a, b = TA[i, 0], TB[j, 0], TB[j, 1]
    return _pe(V[p, 0], V[p, 1], V[p, 2], V[a, 0], V[a, 1], V[a, 2], V[b, 0], V[b, 1], V[b, 2])


@njit(cache=True, forceinline=True)
def _gap_sq(lx, ly, lz, hx, hy, hz, m0, m1, m2, M0, M1, M2, gap_off):
    # Per-axis gaps of the primitives (their boxes, less the inflation on both sides
    # and a rounding slack: gap_off = 2 inflation - slack), squared and summed.
    s = 0.0
    g = max(m0 - hx, lx - M0) + gap_off
    if g > 0.0:
        s += g * g
    g = max(m1 - hy, ly - M1) + gap_off
    if g > 0.0:
        s += g * g
    g = max(m2 - hz, lz - M2) + gap_off
    if g > 0.0:
        s += g * g
    return s


@njit(cache=True, forceinline=True)
def _min_mode(mode):
    # The modes that fold minima, which bound pairs by their boxes and visit half the
    # region of a self query.
    return mode == MODE_MIN or mode == MODE_GLOBAL_MIN or mode == MODE_MIN_DEFER


@njit(cache=True, inline="always")
def _big_gap_sq(loA, hiA, i, loB, hiB, j, mode, gap_off):
    if not _min_mode(mode):
        return 0.0
    return _gap_sq(loA[i, 0], loA[i, 1], loA[i, 2], hiA[i, 0], hiA[i, 1], hiA[i, 2],
                   loB[j, 0], loB[j, 1], loB[j, 2], hiB[j, 0], hiB[j, 1], hiB[j, 2], gap_off)


@njit(cache=True, inline="always")
def _record(mode, i, j, TA, TB, J, pos, lim, V, dmin, lb_sq):
    """Record the hit (i, j); return 1 if it counts, 0 if the filter of MODE_FILL_EF drops it.

    `lb_sq` (the min modes only): a lower bound of the pair's squared distance from its
    boxes (`_gap_sq`); a pair that provably cannot lower a minimum is not evaluated.
    """
    # Inlined (Numba IR), like `_visit_row`: out of line, each call passes its array
    # arguments; inlining measured 1.08x on the certificate path (~450K hits), and
    # 1.2-1.4x for `_visit_row` (issue 13, A/B in one process).
    if mode == MODE_FILL_EF:
        # (edge i, face j): kept unless the closed segment provably misses the triangle
        if not segment_may_meet_triangle_at(V, TA[i, 0], TA[i, 1], TB[j, 0], TB[j, 1], TB[j, 2]):
            return 0
        if pos < lim:
            J[pos] = j
    elif mode == MODE_FILL or mode == MODE_FILL_ALL:
        if pos < lim:  # beyond `lim` a full chunk only counts (see _pairs_pass)
            J[pos] = j
    elif mode == MODE_GLOBAL_MIN:
        _fold_global_min(V, TA, i, TB, j, dmin, lb_sq)
    elif mode == MODE_MIN:
        fold_pair_min(V, TA, i, TB, j, dmin, lb_sq)
    elif mode == MODE_MIN_DEFER:
        # listed for `_fold_deferred` unless its bound proves it cannot lower a minimum
        if lb_sq * _PRUNE_REL > _pair_top(TA, i, TB, j, dmin):
            return 0
        if pos < lim:
            J[pos] = j
    return 1


@njit(cache=True, inline="always")
def _fold_global_min(V, TA, i, TB, j, dmin, lb_sq):
    # Lower ``dmin[0]`` by the pair's squared distance, unless its lower bound `lb_sq`
    # (times `_PRUNE_REL`) proves that the computed distance cannot lower it.
    if lb_sq * _PRUNE_REL > dmin[0]:
        return
    d = _pair_sq(V, TA, i, TB, j)
    if d < dmin[0]:
        dmin[0] = d


@njit(cache=True, inline="always")
def _pair_top(TA, i, TB, j, dmin):
    # The largest minimum of the pair's vertices: the pair matters only below it (the
    # widths of the folds written out, as in `_adjacent`).
    ka, kb = TA.shape[1], TB.shape[1]
    if ka == 2 and kb == 2:
        return max(dmin[TA[i, 0]], dmin[TA[i, 1]], dmin[TB[j, 0]], dmin[TB[j, 1]])
    if ka == 1 and kb == 3:
        return max(dmin[TA[i, 0]], dmin[TB[j, 0]], dmin[TB[j, 1]], dmin[TB[j, 2]])
    top = 0.0
    for a in range(TA.shape[1]):
        top = max(top, dmin[TA[i, a]])
    for b in range(TB.shape[1]):
        top = max(top, dmin[TB[j, b]])
    return top


@njit(cache=True, inline="always")
def fold_pair_min(V, TA, i, TB, j, dmin, lb_sq):
    """Lower the per-vertex minima `dmin` of the pair's vertices by its squared distance,
    unless its lower bound `lb_sq` (times `_PRUNE_REL`) proves that it cannot lower any."""
    if lb_sq * _PRUNE_REL > _pair_top(TA, i, TB, j, dmin):
        return
    d = _pair_sq(V, TA, i, TB, j)
    for a in range(TA.shape[1]):
        v = TA[i, a]
        if d < dmin[v]:
            dmin[v] = d
    for b in range(TB.shape[1]):
        v = TB[j, b]
        if d < dmin[v]:
            dmin[v] = d


@njit(cache=True, inline="always")
def _scan(mode, i, box, TA, TB, bits, key, ent_key, ent_id, ent_box, ent_clo, compact, gap_off, e0, e1,
          J, pos, lim, V, dmin, buf, above, corner, cell):
    """Visit the grid entries [e0, e1) for row i (`box`: lo x, y, z, hi x, y, z); return
    how many partners it found (`_visit_row`). Only ids above `above` count (-1: all),
    on a hashed table (bits >= 0) only entries of cell `key`, and on a covering grid
    only the pairs whose boxes' intersection has its lower corner in `cell` (`corner`:
    the row's lower cell corner)."""
    lx, ly, lz, hx, hy, hz = box
    n = np.int64(0)
    s = e0
    while s < e1:
        # `compact`: the box tests over a block first, branch-free, their hits compacted
        # into `buf`. Where few entries hit, this avoids one unpredictable branch per
        # entry; where many do, the extra pass costs more: see `_Plan`.
        t = min(e1, s + buf.shape[0]) if compact else e1
        nq = t - s
        if compact:
            nq = 0
            if above < 0:  # (loop-invariant: the id load only where it decides)
                for e in range(s, t):
                    buf[nq] = e
                    nq += _entry_overlaps(ent_box, e, lx, ly, lz, hx, hy, hz)
            else:
                for e in range(s, t):
                    buf[nq] = e
                    nq += _entry_overlaps(ent_box, e, lx, ly, lz, hx, hy, hz) & (ent_id[e] > above)
        for q in range(nq):
            e = buf[q] if compact else s + q
            # (the id load only where an id bound applies: `above` is loop-invariant)
            if not compact and (not _entry_overlaps(ent_box, e, lx, ly, lz, hx, hy, hz)
                                or (above >= 0 and ent_id[np.uint64(e)] <= above)):
                continue
            if bits >= 0 and ent_key[e] != key:
                continue
            # Covering grid: emit only from the cell holding the intersection's lower
            # corner. _cell is monotone, so cell(max(a, b)) = max(cell(a), cell(b)), both
            # cells computed by the same formula (cloA, ent_clo).
            if ent_clo.shape[0] and (max(corner[0], ent_clo[e, 0]) != cell[0]
                                     or max(corner[1], ent_clo[e, 1]) != cell[1]
                                     or max(corner[2], ent_clo[e, 2]) != cell[2]):
                continue
            j = ent_id[e]
            if mode != MODE_FILL_ALL and _adjacent(TA, i, TB, j):
                continue
            lb_sq = 0.0
            if _min_mode(mode):
                u = np.uint64(e)  # (unsigned: no negative-index wraparound per load)
                lb_sq = _gap_sq(lx, ly, lz, hx, hy, hz, ent_box[u, 0], ent_box[u, 1], ent_box[u, 2],
                                ent_box[u, 3], ent_box[u, 4], ent_box[u, 5], gap_off)
            n += 1 if mode == MODE_COUNT else _record(mode, i, j, TA, TB, J, pos + n, lim, V, dmin, lb_sq)
        s = t
    return n


@njit(cache=True, inline="always")
def _visit_row(mode, i, self_query, loA, hiA, TA, cloA, chiA, smallA, loB, hiB, TB, dims, bits, reach,
               boff, cmax, ent_key, ent_id, ent_box, ent_clo, compact, bigB, gap_off, J, pos, lim, V, dmin, buf):
    # At most 30 parameters (CPython's limit for a plain call): with more, the callers'
    # calls compile through a tuple (CALL_FUNCTION_EX), which Numba's inliner refuses
    # ("closure with *args").
    """Visit the partners j of row i; return how many there are.

    MODE_COUNT only counts; MODE_FILL writes the partners j into J from `pos` on
    (below `lim`; the count goes on beyond it), MODE_FILL_ALL likewise with the
    adjacent ones (every box hit: the certificate path's fused start pass);
    MODE_MIN folds the squared pair distance into `dmin` (per vertex), MODE_GLOBAL_MIN
    into ``dmin[0]``; MODE_MIN_DEFER writes, as MODE_FILL does, the partners whose box
    bound does not rule them out against `dmin`, for `_fold_deferred`.

    Two grid layouts (`_Plan`). A covering grid (``ent_clo`` not empty, reach 0) holds
    each box in every cell it covers: the row visits its own cells, and a pair is
    emitted from the cell of its boxes' intersection's lower corner only. Otherwise each
    grid box is stored once, in the cell of its lower corner, and spans at most
    ``reach[a]`` cells beyond it along axis a; a box meeting row i's therefore has its
    lower corner's cell in [cloA - reach, chiA] per axis (cells are monotone in the
    coordinate), the region scanned. In a self query (the grid boxes are the small rows)
    a pair of grid boxes is found from one row only: on a covering grid or when pairs
    are listed, the smaller id's (rows i < j); in the min folds on a lower-corner grid,
    whose order does not matter, the row whose lower corner's cell comes first in key
    order (the smaller id in a shared cell), so that a row scans only the cells from its
    own on, about half the region.
    """
    n = np.int64(0)
    brute = not smallA[i]  # a row too big for the grid: every B box is a candidate
    if not brute:
        box = (loA[i, 0], loA[i, 1], loA[i, 2], hiA[i, 0], hiA[i, 1], hiA[i, 2])
        corner = (cloA[i, 0], cloA[i, 1], cloA[i, 2])
        cx, cy, cz = corner
        x0, x1 = max(cx - reach[0], 0), min(chiA[i, 0], dims[0] - 1)
        y0, y1 = max(cy - reach[1], 0), min(chiA[i, 1], dims[1] - 1)
        z0, z1 = max(cz - reach[2], 0), min(chiA[i, 2], dims[2] - 1)
        covering = ent_clo.shape[0] > 0
        dense = bits < 0 and not covering
        half = self_query and not covering and _min_mode(mode)
        above = self_query and not half  # only ids above i
        for z in range(cz if half else z0, z1 + 1):
            for y in range(cy if half and z == cz else y0, y1 + 1):
                row = dims[0] * (y + dims[1] * z)
                own = half and z == cz and y == cy  # this run starts at row i's own cell
                xs = cx if own else x0
                if dense:  # leading cells whose boxes all end below this box's lower x: skipped
                    while xs <= x1 and cmax[row + xs] < box[0]:
                        xs += 1
                    own = own and xs == cx
                # Dense table: the cells xs..x1 are consecutive buckets, one run of entries
                # (a cell's entries are in ascending id, filled in id order); else cell by cell.
                # One `_scan` call site (Numba copies an inlined body per site: compile time).
                for x in range(xs, xs + 1 if dense else x1 + 1):
                    if dense:
                        key = 0
                        e0 = _first_above(ent_id, boff[row + xs], boff[row + xs + 1], i) if own else boff[row + xs]
                        e1 = boff[row + x1 + 1]
                        skip = i if above else -1
                    else:
                        key = row + x
                        b = _bucket(key, bits)  # a dense table's bucket is its key
                        e0 = _first_above(ent_id, boff[b], boff[b + 1], i) if above or (own and x == xs) else boff[b]
                        e1 = boff[b + 1]
                        skip = -1
                    cell = (cx if dense else x, cy if dense else y, cz if dense else z)
                    n += _scan(mode, i, box, TA, TB, bits, key, ent_key, ent_id, ent_box, ent_clo, compact, gap_off,
                               e0, e1, J, pos + n, lim, V, dmin, buf, skip, corner, cell)
    return n + _visit_big(mode, i, brute, self_query, loA, hiA, TA, loB, hiB, TB, bigB, gap_off, J, pos + n, lim,
                          V, dmin)


@njit(cache=True, inline="always")
def _visit_big(mode, i, brute, self_query, loA, hiA, TA, loB, hiB, TB, bigB, gap_off, J, pos, lim, V, dmin):
    """Row i's partners among the B boxes outside the grid's scan (`_visit_row`): all of
    them for a big row (`brute`), else the big grid boxes; recorded from `pos` on, their
    count returned (one `_record` call site for both)."""
    n = np.int64(0)
    j0 = i + 1 if self_query else 0
    for t in range(loB.shape[0] - j0 if brute else bigB.shape[0]):
        j = j0 + t if brute else bigB[t]
        if self_query and j <= i:
            continue
        if _overlap(loA, hiA, i, loB, hiB, j) and (mode == MODE_FILL_ALL or not _adjacent(TA, i, TB, j)):
            n += 1 if mode == MODE_COUNT else _record(mode, i, j, TA, TB, J, pos + n, lim, V, dmin,
                                                      _big_gap_sq(loA, hiA, i, loB, hiB, j, mode, gap_off))
    return n


@njit(cache=True, inline="always")
def _visit_dense(mode, i, self_query, loA, hiA, TA, cloA, chiA, smallA, loB, hiB, TB, dims, bits, reach,
                 boff, cmax, ent_key, ent_id, ent_box, ent_clo, compact, bigB, gap_off, J, pos, lim, V, dmin, buf):
    """`_visit_row` in MODE_MIN_DEFER on a dense lower-corner grid (`_defer_dense`): the
    same partners listed in the same order, by a row visit with none of the other
    layouts' and modes' tests. It takes `_visit_row`'s arguments, so that either can be
    a deferred kernel's visit (`_with_visit`); `mode` (MODE_MIN_DEFER), `bits`, `ent_key`
    and `ent_clo` (a dense lower-corner grid has no hash bits, no keys and no covered
    cells) go unused. The 64K cloth's folds against `_defer_rows`, one thread,
    the same compaction, same bits: edge-edge 25.9 -> 25.4 ms, vertex-face 9.6 -> 9.0 ms
    (issue 13). (Compiled twice, once for each value of `compact`, the edge-edge fold ran
    1.05x faster still, but the first query of a fresh install compiled for 44-50 s
    instead of 28 s.)"""
    n = np.int64(0)
    brute = not smallA[i]
    if not brute:
        lx, ly, lz = loA[i, 0], loA[i, 1], loA[i, 2]
        hx, hy, hz = hiA[i, 0], hiA[i, 1], hiA[i, 2]
        cx, cy, cz = cloA[i, 0], cloA[i, 1], cloA[i, 2]
        x0, x1 = max(cx - reach[0], 0), min(chiA[i, 0], dims[0] - 1)
        y0, y1 = max(cy - reach[1], 0), min(chiA[i, 1], dims[1] - 1)
        z0, z1 = max(cz - reach[2], 0), min(chiA[i, 2], dims[2] - 1)
        for z in range(cz if self_query else z0, z1 + 1):
            for y in range(cy if self_query and z == cz else y0, y1 + 1):
                row = dims[0] * (y + dims[1] * z)
                own = self_query and z == cz and y == cy  # the run starts at row i's own cell
                xs = cx if own else x0
                while xs <= x1 and cmax[row + xs] < lx:  # cells whose boxes all end below lx
                    xs += 1
                e0 = _first_above(ent_id, boff[row + xs], boff[row + xs + 1], i) if own and xs == cx else boff[row + xs]
                e1 = boff[row + x1 + 1]
                s = e0
                while s < e1:
                    t = min(e1, s + buf.shape[0]) if compact else e1
                    nq = t - s
                    if compact:
                        nq = 0
                        for e in range(s, t):
                            buf[nq] = e
                            nq += _entry_overlaps(ent_box, e, lx, ly, lz, hx, hy, hz)
                    for q in range(nq):
                        e = buf[q] if compact else s + q
                        if not compact and not _entry_overlaps(ent_box, e, lx, ly, lz, hx, hy, hz):
                            continue
                        j = ent_id[e]
                        if _adjacent(TA, i, TB, j):
                            continue
                        u = np.uint64(e)
                        lb_sq = _gap_sq(lx, ly, lz, hx, hy, hz, ent_box[u, 0], ent_box[u, 1], ent_box[u, 2],
                                        ent_box[u, 3], ent_box[u, 4], ent_box[u, 5], gap_off)
                        n += _record(MODE_MIN_DEFER, i, j, TA, TB, J, pos + n, lim, V, dmin, lb_sq)
                    s = t
    return n + _visit_big(MODE_MIN_DEFER, i, brute, self_query, loA, hiA, TA, loB, hiB, TB, bigB, gap_off, J,
                          pos + n, lim, V, dmin)


@njit(cache=True, inline="always")
def _close_row(J, pos, n, lim, over):
    """After a row wrote its n partners into J from `pos`: the next row's `pos`, and
    whether the chunk's slots (below `lim`) ran out; a chunk that ran out only counts
    from there on (`_pairs_pass` refills it). A row that fits is sorted in place."""
    if over:
        return pos, True
    if pos + n > lim:
        return pos, True
    sort_segment(J, pos, pos + n)
    return pos + n, False


def _fill_chunks_py(self_query, loA, hiA, TA, cloA, chiA, smallA, loB, hiB, TB,
                    dims, bits, reach, boff, cmax, ent_key, ent_id, ent_box, ent_clo, compact, bigB, gap_off,
                    starts, todo, bstart, blim, counts, J, full, mode, V, counter):
    """One pass over the rows of the chunks marked in `todo`, filling and counting.

    Chunk c owns rows [starts[c], starts[c + 1]) and the slots [bstart[c], blim[c])
    of J, where it writes each row's partners (sorted) one row after another and
    each row's count into `counts`. When its slots run out it only counts from
    there on and sets full[c]: the caller refills it at exact offsets. A chunk
    writes only its own slots, so the bits depend neither on the threads nor on which
    worker takes which chunk: the workers claim them by ranges (`parallel.claim_next` on
    `counter`, a `range_counter`), so a late thread's chunks are taken by the others.
    `mode` is MODE_FILL, or MODE_FILL_EF (edge-face pairs through the filter, positions `V`).
    """
    dmin = np.empty(0)
    for w in prange(counter[-1]):
        buf = np.empty(_SCAN_BLOCK, dtype=np.int64)
        c, k = claim_next(counter, w, 0)
        while c >= 0:
            if todo[c]:  # (not a `continue`: with one, LLVM made the rows 1.16x slower)
                pos = bstart[c]
                lim = blim[c]
                over = False
                for i in range(starts[c], starts[c + 1]):
                    # once full, the same mode only counts (no slot below a limit of -1)
                    n = _visit_row(mode, i, self_query, loA, hiA, TA, cloA, chiA, smallA, loB, hiB, TB, dims, bits,
                                   reach, boff, cmax, ent_key, ent_id, ent_box, ent_clo, compact, bigB, gap_off,
                                   J, pos, -1 if over else lim, V, dmin, buf)
                    counts[i] = n
                    pos, over = _close_row(J, pos, n, lim, over)
                full[c] = over
            c, k = claim_next(counter, w, k)


def _min_rows_py(self_query, loA, hiA, TA, cloA, chiA, smallA, loB, hiB, TB,
              dims, bits, reach, boff, cmax, ent_key, ent_id, ent_box, ent_clo, compact, bigB, gap_off, V,
              partial, mode, n_chunks, counter):
    # Worker w (one per row of `partial`) claims chunk after chunk of the rows, chunk c
    # being rows [c m / C, (c + 1) m / C) (`parallel.claim` on `counter`), and folds them
    # into partial[w] only: no shared writes. min is exact, so which worker takes which
    # chunk changes the time only, never a bit, at any thread count; a worker whose
    # thread is descheduled takes fewer chunks instead of holding the region up (a static
    # split waited for it: 1.07x on the 64K cloth's folds, their slow tail 1.25x).
    J = np.empty(0, dtype=np.int64)
    m = loA.shape[0]
    for w in prange(partial.shape[0]):
        buf = np.empty(_SCAN_BLOCK, dtype=np.int64)
        c = claim(counter)
        while c < n_chunks:
            for i in range(c * m // n_chunks, (c + 1) * m // n_chunks):
                _visit_row(mode, i, self_query, loA, hiA, TA, cloA, chiA, smallA, loB, hiB, TB,
                           dims, bits, reach, boff, cmax, ent_key, ent_id, ent_box, ent_clo, compact, bigB, gap_off,
                           J, 0, 0, V, partial[w], buf)
            c = claim(counter)


def _deferred_py(self_query, loA, hiA, TA, cloA, chiA, smallA, loB, hiB, TB,
                 dims, bits, reach, boff, cmax, ent_key, ent_id, ent_box, ent_clo, compact, bigB, gap_off, V,
                 partial, n_chunks, counter, cap, flush):
    # `_min_rows_py` in MODE_MIN for edge-edge or vertex-face pairs, with the distances
    # deferred: each row lists its pairs that pass the box bound (MODE_MIN_DEFER), and
    # `_fold_deferred` evaluates the list once `flush` pairs are listed, with branch-free
    # kernels over gathered coordinates: the same bits (min is exact; a pair the bound
    # would have skipped against minima lowered since is evaluated, and lowers nothing). A
    # row whose pairs do not fit in the room left of the list's `cap` is visited again,
    # after the list is emptied, into the list or, with more than `cap` pairs, into a list
    # of its own (`_listed_row`; `_DEFER_CAP`, `_DEFER_FLUSH`; the tests pass smaller ones).
    # `_DEFERRED_VISIT` is not a global of this module: each of the two kernels compiled
    # from this source binds it to its own row visit (`_with_visit`): `_defer_rows` to
    # `_visit_row` (MODE_MIN_DEFER, a constant here, so the visit is compiled for it
    # alone), any grid; `_defer_dense` to `_visit_dense`, a dense lower-corner grid only
    # (`_Plan.min_sq_into` picks it). One kernel choosing its visit at run time compiled
    # for 82 s instead of 44 on a fresh install.
    m = loA.shape[0]
    for w in prange(partial.shape[0]):
        buf, J, rows, starts, G, dist = _defer_buffers(cap)
        dmin = partial[w]
        pos = nr = own = 0
        c = claim(counter)
        while c < n_chunks:
            i = c * m // n_chunks
            end = (c + 1) * m // n_chunks
            while i < end:
                Jr, at, lim = (np.empty(own, dtype=np.int64), 0, own) if own else (J, pos, cap)
                n = _DEFERRED_VISIT(MODE_MIN_DEFER, i, self_query, loA, hiA, TA, cloA, chiA, smallA,  # noqa: F821
                                    loB, hiB, TB, dims, bits, reach, boff, cmax, ent_key, ent_id, ent_box, ent_clo,
                                    compact, bigB, gap_off, Jr, at, lim, V, dmin, buf)
                pos, nr, own, done = _listed_row(i, n, own, Jr, pos, nr, J, rows, starts, G, dist, cap, flush, V, TA,
                                                 TB, dmin)
                i += done
            c = claim(counter)
        if nr:
            _fold_deferred(V, TA, TB, rows, starts, nr, pos, J, G, dist, dmin)


def _with_visit(fn, name, visit):
    """A copy of `fn` named `name` whose global ``_DEFERRED_VISIT`` is `visit`: Numba
    freezes a kernel's globals when it compiles it, so each copy compiles with its own
    row visit inlined and no test of which one it is."""
    f = types.FunctionType(fn.__code__, dict(fn.__globals__, _DEFERRED_VISIT=visit), name, fn.__defaults__,
                           fn.__closure__)
    f.__qualname__ = name  # Numba's cache is keyed by it (`parallel.named`)
    return f


@njit(cache=True, inline="always")
def _defer_buffers(cap):
    """A deferred fold's worker scratch: the scan block, the listed pairs' partners (row
    after row), the listed rows and where their pairs start, the gathered coordinates
    and the distances (`_fold_deferred`)."""
    # (rows of cap + 8: at 512 the twelve rows of a column lay 4 KiB apart, in one L1
    # set, and the gather ran 2.2x slower)
    return (np.empty(_SCAN_BLOCK, dtype=np.int64), np.empty(cap, dtype=np.int64), np.empty(cap, dtype=np.int64),
            np.empty(cap, dtype=np.int64), np.empty((12, cap + 8)), np.empty(cap))


@njit(cache=True, inline="always")
def _listed_row(i, n, own, Jr, pos, nr, J, rows, starts, G, dist, cap, flush, V, TA, TB, dmin):
    """After row i listed its `n` pairs (into `Jr`: the list `J` from `pos` on, or with
    `own` > 0 a list of its own): ``(pos, nr, own, done)``, the list's state and whether
    the row is done (0: visit it again, after the list was emptied because the row's
    pairs did not fit; `own` > 0 then when they exceed the whole list)."""
    if own:
        _fold_deferred(V, TA, TB, np.full(1, i, dtype=np.int64), np.zeros(1, dtype=np.int64), 1, n, Jr,
                       np.empty((12, n + 8)), np.empty(n), dmin)
        return pos, nr, 0, 1
    if pos + n > cap:
        _fold_deferred(V, TA, TB, rows, starts, nr, pos, J, G, dist, dmin)
        return 0, 0, n if n > cap else 0, 0
    if n:
        rows[nr] = i
        starts[nr] = pos
        nr += 1
        pos += n
        if pos >= flush:
            _fold_deferred(V, TA, TB, rows, starts, nr, pos, J, G, dist, dmin)
            return 0, 0, 0, 1
    return pos, nr, 0, 1


@njit(cache=True)
def _fold_deferred(V, TA, TB, rows, starts, nr, total, J, G, dist, dmin):
    """Fold the `total` listed pairs into the minima `dmin`: listed row ``rows[r]``'s
    partners are ``J[starts[r]:starts[r + 1]]`` (the last row's end at `total`). Edge-edge
    pairs (TA, TB of width 2) or vertex-face pairs (widths 1 and 3): their coordinates
    gathered into the columns of `G` in `_pair_sq`'s argument order, their distances
    evaluated without branches (`distance.ee_sq_columns`, `pt_sq_columns`: `_ee`'s and
    `_pt`'s bits), then each folded into the pair's four vertices."""
    edges = TA.shape[1] == 2
    for r in range(nr):
        i = rows[r]
        for q in range(starts[r], starts[r + 1] if r + 1 < nr else total):
            a, b, c, d = _deferred_vertices(edges, TA, i, TB, J[q])
            G[0, q], G[1, q], G[2, q] = V[a, 0], V[a, 1], V[a, 2]
            G[3, q], G[4, q], G[5, q] = V[b, 0], V[b, 1], V[b, 2]
            G[6, q], G[7, q], G[8, q] = V[c, 0], V[c, 1], V[c, 2]
            G[9, q], G[10, q], G[11, q] = V[d, 0], V[d, 1], V[d, 2]
    if edges:
        ee_sq_columns(G, dist, total)
    else:
        pt_sq_columns(G, dist, total)
    for r in range(nr):
        i = rows[r]
        for q in range(starts[r], starts[r + 1] if r + 1 < nr else total):
            a, b, c, d = _deferred_vertices(edges, TA, i, TB, J[q])
            x = dist[q]
            if x < dmin[a]:
                dmin[a] = x
            if x < dmin[b]:
                dmin[b] = x
            if x < dmin[c]:
                dmin[c] = x
            if x < dmin[d]:
                dmin[d] = x


@njit(cache=True, forceinline=True)
def _deferred_vertices(edges, TA, i, TB, j):
    # The four vertices of a deferred pair in `_pair_sq`'s argument order: edge i's two
    # and edge j's two, or vertex i and face j's three.
    if edges:
        return TA[i, 0], TA[i, 1], TB[j, 0], TB[j, 1]
    return TA[i, 0], TB[j, 0], TB[j, 1], TB[j, 2]


# Serial and parallel builds of the row passes (each row / chunk writes only its own
# slots, so both give the same bits), chosen per call by the number of rows: a small
# query never waits for a descheduled thread (penfree.core.parallel).
_fill_chunks = parallel_kernel(_fill_chunks_py, "_bp_fill_chunks", _PARALLEL_MIN_ROWS)
_min_rows = parallel_kernel(_min_rows_py, "_bp_min_rows", _PARALLEL_MIN_ROWS)
_defer_rows = parallel_kernel(_with_visit(_deferred_py, "_defer_rows_py", _visit_row), "_bp_defer_rows",
                              _PARALLEL_MIN_ROWS)
_defer_dense = parallel_kernel(_with_visit(_deferred_py, "_defer_dense_py", _visit_dense), "_bp_defer_dense",
                               _PARALLEL_MIN_ROWS)


@njit(cache=True, forceinline=True)
def _gap_bound_sq(gap, slack):
    # A projection gap (`distance._ee_gap`, `_pt_gap`) less the rounding slack, squared.
    g = gap - slack
    return g * g if g > 0.0 else 0.0


@njit(cache=True, inline="always")
def _fold_owned(V, E, i, F, j, face_edges, owner_face, owner_edge, loE, hiE, loF, hiF, inflation, slack, dmin):
    """Fold into ``dmin[0]`` the edge-edge and vertex-face pairs that the box hit (edge i,
    face j) owns (`_start_owners`): each edge b > i of face j whose owner face is j, and
    each end v of edge i whose owner edge is i; a pair counts when its inflated boxes
    overlap and it shares no vertex, as in `min_pair_sq`.

    A pair is skipped when its projection gap (`distance._ee_gap`, `_pt_gap`, less
    `slack`, squared, times `_PRUNE_REL`) exceeds ``dmin[0]``, as the min folds skip by
    their box bound: its computed distance could not lower the minimum. The boxes of
    these pairs overlap, so their box bound is 0; a start pass capped far below the
    pairs' distances (`start_pass`) skips almost every pair this way."""
    for k in range(3):
        b = face_edges[j, k]  # -1 for a repeated vertex: never above i
        if b > i and owner_face[b] == j and _overlap(loE, hiE, i, loE, hiE, b) and not _adjacent(E, i, E, b):
            p, q, r, s = E[i, 0], E[i, 1], E[b, 0], E[b, 1]
            _fold_global_min(V, E, i, E, b, dmin, _gap_bound_sq(_ee_gap(
                V[p, 0], V[p, 1], V[p, 2], V[q, 0], V[q, 1], V[q, 2],
                V[r, 0], V[r, 1], V[r, 2], V[s, 0], V[s, 1], V[s, 2]), slack))
    for a in range(2):
        v = E[i, a]
        if owner_edge[v] != i or v == F[j, 0] or v == F[j, 1] or v == F[j, 2]:
            continue
        meets = True
        for ax in range(3):  # the vertex's box as `_boxes` makes it: x - inflation, x + inflation
            if V[v, ax] - inflation > hiF[j, ax] or loF[j, ax] > V[v, ax] + inflation:
                meets = False
        if meets:
            p, q, r = F[j, 0], F[j, 1], F[j, 2]
            lb_sq = _gap_bound_sq(_pt_gap(V[v, 0], V[v, 1], V[v, 2], V[p, 0], V[p, 1], V[p, 2],
                                          V[q, 0], V[q, 1], V[q, 2], V[r, 0], V[r, 1], V[r, 2]), slack)
            if lb_sq * _PRUNE_REL > dmin[0]:
                continue
            d = _pt(V[v, 0], V[v, 1], V[v, 2], V[p, 0], V[p, 1], V[p, 2],
                    V[q, 0], V[q, 1], V[q, 2], V[r, 0], V[r, 1], V[r, 2])
            if d < dmin[0]:
                dmin[0] = d


def _start_chunks_py(self_query, loA, hiA, TA, cloA, chiA, smallA, loB, hiB, TB,
                     dims, bits, reach, boff, cmax, ent_key, ent_id, ent_box, ent_clo, compact, bigB, gap_off,
                     starts, todo, bstart, blim, counts, J, full, V,
                     face_edges, owner_face, owner_edge, loE, hiE, loF, hiF, inflation, slack, partial, counter):
    """`_fill_chunks` of MODE_FILL_EF for the rows A = edges, B = faces, fused with the
    edge-edge and vertex-face folds (`_Plan.start_pairs`): each row lists all its box
    hits (adjacent faces too) in a scratch, folds the pairs each hit owns into its
    chunk's ``partial[c, 0]`` (`_fold_owned`) and keeps the non-adjacent hits that the
    float filter cannot clear, as MODE_FILL_EF does. A refilled chunk folds again: min
    is exact, so the minimum does not change, and no chunk writes another's slots. The
    workers claim the chunks by ranges, as `_fill_chunks`' do."""
    none = np.empty(0)
    for w in prange(counter[-1]):
        buf = np.empty(_SCAN_BLOCK, dtype=np.int64)
        hits = np.empty(_ROW_HITS, dtype=np.int64)
        c, k = claim_next(counter, w, 0)
        while c >= 0:
            if todo[c]:  # (not a `continue`: with one, LLVM made `_fill_chunks`' rows 1.16x slower)
                pos = bstart[c]
                lim = blim[c]
                over = False
                dmin = partial[c]
                for i in range(starts[c], starts[c + 1]):
                    n = np.int64(0)
                    for _ in range(2):  # a row with more hits than the scratch: visit it again (one call site)
                        n = _visit_row(MODE_FILL_ALL, i, self_query, loA, hiA, TA, cloA, chiA, smallA, loB, hiB,
                                       TB, dims, bits, reach, boff, cmax, ent_key, ent_id, ent_box, ent_clo, compact,
                                       bigB, gap_off, hits, 0, hits.shape[0], V, none, buf)
                        if n <= hits.shape[0]:
                            break
                        hits = np.empty(2 * n, dtype=np.int64)
                    kept = 0
                    for q in range(n):
                        j = hits[q]
                        _fold_owned(V, TA, i, TB, j, face_edges, owner_face, owner_edge, loE, hiE, loF, hiF,
                                    inflation, slack, dmin)
                        if not _adjacent(TA, i, TB, j) and segment_may_meet_triangle_at(
                                V, TA[i, 0], TA[i, 1], TB[j, 0], TB[j, 1], TB[j, 2]):
                            if not over and pos + kept < lim:
                                J[pos + kept] = j
                            kept += 1
                    counts[i] = kept
                    pos, over = _close_row(J, pos, kept, lim, over)
                full[c] = over
            c, k = claim_next(counter, w, k)


_start_chunks = parallel_kernel(_start_chunks_py, "_bp_start_chunks", _PARALLEL_MIN_ROWS)


@njit(cache=True)
def _start_owners(E, F, vertices, n):
    """The owners of the fused start pass (`_Plan.start_pairs`).

    Returns (face_edges (K, 3), owner_face (M,), owner_edge (n,), ok): face_edges[f, c]
    is the row of E of face f's edge (F[f, c], F[f, c + 1]) (-1 where the two repeat a
    vertex); an edge's owner face is the first face that has it; a vertex's owner edge
    is the first edge that has it, -1 for a vertex not in `vertices`. ok is False
    (the separate folds are needed) unless E is sorted as `scene_edges` makes it (rows
    ascending, each ``E[r, 0] < E[r, 1]``), every edge is some face's, and every vertex
    of `vertices` some edge's: then every pair of the two folds is owned by a box hit.
    """
    M, K = E.shape[0], F.shape[0]
    face_edges = np.full((K, 3), -1, dtype=np.int64)
    owner_face = np.full(M, -1, dtype=np.int64)
    owner_edge = np.full(n, -1, dtype=np.int64)
    first = np.zeros(n + 1, dtype=np.int64)  # the rows of E with E[r, 0] = v: first[v]..first[v + 1]
    for r in range(M):
        after_last = r == 0 or E[r - 1, 0] < E[r, 0] or (E[r - 1, 0] == E[r, 0] and E[r - 1, 1] < E[r, 1])
        if E[r, 0] >= E[r, 1] or not after_last:
            return face_edges, owner_face, owner_edge, False
        first[E[r, 0] + 1] += 1
    for v in range(n):
        first[v + 1] += first[v]
    for f in range(K):
        for c in range(3):
            a, b = F[f, c], F[f, (c + 1) % 3]
            if a == b:
                continue
            lo, hi = min(a, b), max(a, b)
            for r in range(first[lo], first[lo + 1]):
                if E[r, 1] == hi:
                    face_edges[f, c] = r
                    if owner_face[r] < 0:
                        owner_face[r] = f
                    break
    for r in range(M):
        if owner_face[r] < 0:
            return face_edges, owner_face, owner_edge, False
    wanted = np.zeros(n, dtype=np.bool_)
    for v in vertices:
        wanted[v] = True
    for r in range(M):
        for a in range(2):
            v = E[r, a]
            if wanted[v] and owner_edge[v] < 0:
                owner_edge[v] = r
    for v in vertices:
        if owner_edge[v] < 0:
            return face_edges, owner_face, owner_edge, False
    return face_edges, owner_face, owner_edge, True


def _corners_py(lo, hi, corners):
    # Chunk c of STAT_CHUNKS keeps its lower and upper corners in corners[c, :2]
    # (min and max are exact: any thread count gives the same bits), and in
    # corners[c, 2, 0] a sum that is NaN when a box has a NaN or infinite bound: min
    # and max pass NaN by, and a cell index of NaN would address outside the grid.
    m = lo.shape[0]
    C = corners.shape[0]
    for c in prange(C):
        for a in range(3):
            corners[c, 0, a] = np.inf
            corners[c, 1, a] = -np.inf
        bad = 0.0
        for i in range(c * m // C, (c + 1) * m // C):
            for a in range(3):
                lo_a = lo[i, a]
                hi_a = hi[i, a]
                corners[c, 0, a] = min(corners[c, 0, a], lo_a)
                corners[c, 1, a] = max(corners[c, 1, a], hi_a)
                bad += (lo_a - lo_a) + (hi_a - hi_a)
        corners[c, 2, 0] = bad


_corners = parallel_kernel(_corners_py, "_bp_corners")


def _box_corners(lo, hi):
    """(2, 3): the boxes' lower and upper bounding corners; `InputError` when a box
    has a NaN or infinite bound (every grid is sized from these corners)."""
    parts = np.empty((_STAT_CHUNKS, 3, 3))
    _corners(lo.shape[0], lo, hi, parts)
    return _checked_corners(parts)


def _checked_corners(parts):
    """The corners (2, 3) of per-chunk corners `parts` (`_corners_py`), refusing NaN."""
    if not np.all(parts[:, 2, 0] == 0.0):
        raise InputError("broad phase: a primitive has a NaN or infinite coordinate (positions must be finite)")
    return np.stack([parts[:, 0].min(axis=0), parts[:, 1].max(axis=0)])


def _box_stats(lo, hi, corners=None):
    """``(corners (2, 3), ext)``: the boxes' bounding corners (`corners` when the caller
    has them, `_box_arrays`') and the extents of a strided sample of <= `_STAT_SAMPLE`
    of them (all that `_median_extents` reads)."""
    step = max(1, -(-lo.shape[0] // _STAT_SAMPLE))
    return _box_corners(lo, hi) if corners is None else corners, hi[::step] - lo[::step]


def _median_extents(sample):
    """(3,) per-axis median of the sampled box extents (`_box_stats`)."""
    k = sample.shape[0] // 2
    return np.array([np.partition(sample[:, a], k)[k] for a in range(3)])


@njit(cache=True)
def _hit_rate(rows, self_query, loA, hiA, cloA, chiA, smallA, dims, bits, reach, boff, ent_id, ent_box):
    """(entries scanned, entries whose box overlaps the row's) over the scan regions of
    the sampled `rows`, as `_visit_row` scans them to list pairs (the key check of a
    hashed table left out)."""
    scanned = 0
    hits = 0
    for i in rows:
        if not smallA[i]:
            continue
        cx, cy, cz = cloA[i, 0], cloA[i, 1], cloA[i, 2]
        x0, x1 = max(cx - reach[0], 0), min(chiA[i, 0], dims[0] - 1)
        y0, y1 = max(cy - reach[1], 0), min(chiA[i, 1], dims[1] - 1)
        z0, z1 = max(cz - reach[2], 0), min(chiA[i, 2], dims[2] - 1)
        for z in range(z0, z1 + 1):
            for y in range(y0, y1 + 1):
                row = dims[0] * (y + dims[1] * z)
                for x in range(x0, x1 + 1):
                    b = _bucket(row + x, bits)
                    e0 = _first_above(ent_id, boff[b], boff[b + 1], i) if self_query else boff[b]
                    for e in range(e0, boff[b + 1]):
                        scanned += 1
                        hits += _entry_overlaps(ent_box, e, loA[i, 0], loA[i, 1], loA[i, 2],
                                                hiA[i, 0], hiA[i, 1], hiA[i, 2])
    return scanned, hits


@njit(cache=True)
def _sample_counts(rows, mode, V, self_query, loA, hiA, TA, cloA, chiA, smallA, loB, hiB, TB,
                   dims, bits, reach, boff, cmax, ent_key, ent_id, ent_box, ent_clo, compact, bigB, gap_off):
    """(len(rows),) int64: the partner count of each sampled row."""
    J = np.empty(0, dtype=np.int64)
    dmin = np.empty(0)
    buf = np.empty(_SCAN_BLOCK, dtype=np.int64)
    out = np.empty(rows.shape[0], dtype=np.int64)
    for k in range(rows.shape[0]):
        out[k] = _visit_row(mode, rows[k], self_query, loA, hiA, TA, cloA, chiA, smallA, loB, hiB, TB,
                            dims, bits, reach, boff, cmax, ent_key, ent_id, ent_box, ent_clo, compact, bigB, gap_off,
                            J, 0, -1, V, dmin, buf)
    return out


def _gather_chunks_py(J_buf, bstart, J_buf2, bstart2, starts, counts, offsets, full, P):
    # Chunk c copies its rows' partners (from the first pass's buffer, or from the
    # refill's when it overflowed) to rows offsets[i].. of P: disjoint writes.
    for c in prange(starts.shape[0] - 1):
        src = J_buf2 if full[c] else J_buf
        k = bstart2[c] if full[c] else bstart[c]
        for i in range(starts[c], starts[c + 1]):
            for q in range(offsets[i], offsets[i + 1]):
                P[q, 0] = i
                P[q, 1] = src[k]
                k += 1


_gather_chunks = parallel_kernel(_gather_chunks_py, "_bp_gather_chunks")


def _pair_chunks(n):
    """The row chunks of `_pairs_pass` over n rows."""
    return chunk_count(n, _PAIR_CHUNKS, _PAIR_CHUNK_MIN_ROWS)


def _pairs_pass(args, n, mode=MODE_FILL, V=None, fold=None):
    """(K, 2) pairs (i, j) in row order, in one pass over the rows (see `_Plan.pairs`).

    `fold` (with MODE_FILL_EF): the arguments of `_start_chunks` after `V` (owners,
    boxes, inflation, and ``partial`` with a row per chunk), whose kernel then fills
    (it always keeps edge-face pairs as MODE_FILL_EF does).
    """
    V = np.empty((0, 3)) if V is None else V
    n_chunks = _pair_chunks(n)
    starts = (np.arange(n_chunks + 1, dtype=np.int64) * n) // n_chunks

    def fill(todo, bstart_, blim_, counts_, J_, full_):
        if fold is None:
            _fill_chunks(n, *args, starts, todo, bstart_, blim_, counts_, J_, full_, mode, V,
                         range_counter(n_chunks))
        else:
            _start_chunks(n, *args, starts, todo, bstart_, blim_, counts_, J_, full_, V, *fold,
                          range_counter(n_chunks))

    # Capacity from a sample of rows (a stride over all of them), with slack; a chunk
    # that still runs out is refilled at exact offsets, so the guess only costs time.
    # At most 1 row in _SAMPLE_MIN_STEP is sampled: a small dense query (every row with
    # hundreds of partners) would otherwise sample most of its rows before the real
    # pass. Each chunk's rows are sized by the mean of all sampled rows, or of those
    # inside it where that is larger (densities differ between parts of a scene: with
    # the global mean alone every dense chunk refilled; with few samples per chunk
    # alone, the chunks of a uniform scene did).
    step = max(_SAMPLE_MIN_STEP, n // _SAMPLE_ROWS)
    sample = np.arange(0, n, step, dtype=np.int64)
    found = _sample_counts(sample, mode, V, *args).astype(np.float64)
    owner = np.searchsorted(starts, sample, side="right") - 1
    hits = np.bincount(owner, weights=found, minlength=n_chunks)
    seen = np.bincount(owner, minlength=n_chunks)
    per_row = np.maximum(found.mean(), np.where(seen > 0, hits / np.maximum(seen, 1), 0.0))
    caps = np.ceil((starts[1:] - starts[:-1]) * (_CAP_SLACK * per_row + 0.5 * _CAP_SLACK)).astype(np.int64) + _CAP_PAD
    bstart = np.zeros(n_chunks + 1, dtype=np.int64)
    np.cumsum(caps, out=bstart[1:])
    counts = np.empty(n, dtype=np.int64)
    full = np.zeros(n_chunks, dtype=np.bool_)
    J_buf = np.empty(bstart[-1], dtype=np.int64)
    fill(np.ones(n_chunks, dtype=np.bool_), bstart[:-1], bstart[1:], counts, J_buf, full)
    offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    bstart2 = np.zeros(n_chunks + 1, dtype=np.int64)
    if full.any():
        need = np.where(full, offsets[starts[1:]] - offsets[starts[:-1]], 0)
        np.cumsum(need, out=bstart2[1:])
        J_buf2 = np.empty(bstart2[-1], dtype=np.int64)
        fill(full.copy(), bstart2[:-1], bstart2[1:], counts, J_buf2, np.zeros(n_chunks, dtype=np.bool_))
    else:
        J_buf2 = np.empty(0, dtype=np.int64)
    P = np.empty((offsets[-1], 2), dtype=np.int64)
    _gather_chunks(offsets[-1], J_buf, bstart, J_buf2, bstart2, starts, counts, offsets, full, P)
    return P


@njit(cache=True)
def _cell_changes(lo, origin, h, step):
    """(3,) int64: per axis, how many of the consecutive box pairs (j, j + 1), j = 0,
    step, 2 step, ..., have their lower corners in different cells."""
    out = np.zeros(3, dtype=np.int64)
    inv_h = 1.0 / h
    for j in range(0, lo.shape[0] - 1, step):
        for a in range(3):
            out[a] += _cell(lo[j, a], origin[a], inv_h[a]) != _cell(lo[j + 1, a], origin[a], inv_h[a])
    return out


def _axis_order(lo, origin, h):
    """Axis order (3,) of the grid's key, fastest first, or None for the natural order:
    the axes along which consecutive boxes change cells most often come first, so that
    boxes in id order fill, and rows in id order visit, nearby buckets."""
    m = lo.shape[0]
    if m < 2:
        return None
    changes = _cell_changes(lo, origin, h, max(1, (m - 1) // _STAT_SAMPLE))
    perm = np.argsort(-changes, kind="stable")
    return None if np.array_equal(perm, [0, 1, 2]) else perm


def _permute_py(lo, hi, perm, lo2, hi2):
    for i in prange(lo.shape[0]):
        for a in range(3):
            lo2[i, a] = lo[i, perm[a]]
            hi2[i, a] = hi[i, perm[a]]


_permute = parallel_kernel(_permute_py, "_bp_permute")


def _permuted(lo, hi, perm):
    """The boxes with their axes in the order `perm`."""
    lo2, hi2 = np.empty_like(lo), np.empty_like(hi)
    _permute(lo.shape[0], lo, hi, perm, lo2, hi2)
    return lo2, hi2


class _Cells(NamedTuple):
    """A plan's grid cells (`_Plan._sized`): sizes, the cell ranges and small-box masks
    of both sets, the reach, the table's dims, and its hash bits (-1: dense) and buckets."""

    h: np.ndarray
    cloA: np.ndarray
    chiA: np.ndarray
    smallA: np.ndarray
    cloB: np.ndarray
    chiB: np.ndarray
    smallB: np.ndarray
    reach: np.ndarray
    dims: np.ndarray
    bits: int
    nb: int


class _Plan:
    """Boxes of both sets on one grid; see the module docstring. `listing`: the plan
    lists pairs rather than folds minima. A listed self query takes a covering grid (a
    fold's lower-corner grid scans half the region); a fold's cells are cut along x
    (`_RUN_SPLIT`). Every layout answers every query, only the speed differs.

    `corners`: the two sets' bounding corners when the caller has them (`_box_arrays`).
    `axes`: None, and the plan orders the boxes' axes for its grid key (`_axis_order`,
    `axes` the order taken); else the boxes come with their axes in that order already
    (`_box_arrays(axes=)`, the order of an earlier plan of the same scene), and no order
    is chosen: the layout only, never a pair, depends on it."""

    def __init__(self, loA, hiA, TA, loB, hiB, TB, self_query, inflation=0.0, listing=True, cells="cube",
                 corners=(None, None), axes=None):
        if cells not in CELL_SHAPES:
            raise ValueError(f"cells must be one of {CELL_SHAPES}; got {cells!r}")
        self.self_query = bool(self_query)
        self.loA, self.hiA, self.TA = loA, hiA, TA
        self.loB, self.hiB, self.TB = loB, hiB, TB
        self.axes = _NATURAL_AXES if axes is None else np.ascontiguousarray(axes, dtype=np.int64)
        nA, nB = loA.shape[0], loB.shape[0]
        if nA == 0 or nB == 0:
            self.empty = True
            return
        self.empty = False
        cornA, extA = _box_stats(loA, hiA, corners[0])
        cornB, extB = (cornA, extA) if self_query else _box_stats(loB, hiB, corners[1])
        origin = np.minimum(cornA[0], cornB[0])
        # The min folds' box bound (`_gap_sq`): boxes are the primitives' inflated by
        # `inflation` per side; the slack covers every rounding (module docstring).
        self.scaleB = float(np.abs(cornB).max())
        self.slack = _PRUNE_SLACK * max(float(np.abs(cornA).max()), self.scaleB)
        self.gap_off = 2.0 * float(inflation) - self.slack
        spans = np.maximum(cornA[1], cornB[1]) - origin
        span = float(spans.max())
        # Per-axis cell sizes: yarn segments are long along the yarn and thin
        # across it, a sheet is thin along its normal.
        h = _CELL_FACTOR * _median_extents(extB)
        if not np.all(h > 0.0):
            h = np.where(h > 0.0, h, _CELL_FACTOR * _median_extents(extA))
        if not np.all(h > 0.0):
            fill = h.max() if h.max() > 0.0 else (span / np.cbrt(nA + nB) if span > 0.0 else 1.0)
            h = np.where(h > 0.0, h, fill)
        # Cubic cells at the largest axis's size (the default): the per-axis sizes
        # (tiny across a yarn or a sheet) made sparse grids whose boxes covered many
        # cells; cubes measured 1.2-2x faster on the 64K rods, cloth and draped-cloth
        # scenes. Per-axis cells ("axis") pay where the boxes fill space across the
        # thin axes, as in a bundle of yarns (`choose_cells` decides from counts).
        if cells == "cube":
            h = np.full(3, h.max())
        elif cells == "slab":
            cube = h.max()
            h = np.full(3, _SLAB_ALONG * cube)
            h[int(np.argmin(spans))] = _SLAB_ACROSS * cube
        covering = self.self_query and listing
        if axes is not None:  # the boxes' axes are in this key order already (`self.axes`)
            self.perm = perm = None if np.array_equal(self.axes, _NATURAL_AXES) else self.axes
        else:
            self.perm = perm = _axis_order(loB, origin, h) if _AXIS_ORDER else None
            self.axes = _NATURAL_AXES if perm is None else perm
            if perm is not None:  # from here on the plan sees the boxes' axes in key order
                loA, hiA = _permuted(loA, hiA, perm)
                loB, hiB = (loA, hiA) if self_query else _permuted(loB, hiB, perm)
                origin, h, spans = origin[perm], h[perm], spans[perm]
                self.loB, self.hiB = loB, hiB
        g = None
        if not listing and _RUN_SPLIT > 1:  # the min folds: finer cells along the runs
            g = self._sized(loA, hiA, loB, hiB, origin, h / np.array([_RUN_SPLIT, 1.0, 1.0]), spans, covering,
                            _SPLIT_MAX_REACH, _SPLIT_BIG_SHARE)
            if g.bits >= 0:  # hashed: cells visited one by one, the split would not pay
                g = None
        if g is None:
            g = self._sized(loA, hiA, loB, hiB, origin, h, spans, covering, _MAX_REACH, 1.0)
        self.boff, self.cmax, self.ent_key, self.ent_id, self.ent_box, self.ent_clo = _build_grid(
            g.cloB, g.chiB, g.smallB, covering, g.dims, g.bits, g.nb, loB, hiB)
        self.origin, self.h, self.dims, self.bits, self.reach = origin, g.h, g.dims, g.bits, g.reach
        self._set_rows(loA, hiA, TA, g.cloA, g.chiA, g.smallA)
        self.bigB = np.ascontiguousarray(np.flatnonzero(~g.smallB).astype(np.int64))

    def _sized(self, loA, hiA, loB, hiB, origin, h, spans, covering, max_reach, big_share):
        """The grid's cells (`_Cells`) from the sizes `h` (at least the span over
        `_MAX_DIM` cells), doubled while the boxes kept out of the grid would cost more
        than the brute-force budget. Rows scan up to `max_reach` cell layers below their
        own; the fewest that leave big boxes within `big_share` of the budget are taken."""
        h = np.maximum(h, spans / (_MAX_DIM - 2))
        nA, nB = loA.shape[0], loB.shape[0]
        budget = _BIG_WORK_PER_BOX * (nA + nB)
        while True:
            cloB, chiB, topB, reachB, overB = self._ranges(loB, hiB, origin, h, max_reach)
            if covering:  # each box in the cells it covers: no reach
                reach = np.zeros(3, dtype=np.int64)
                smallB, n_bigB, entries = _small_rows(cloB, chiB, reach, _MAX_DIM, _BIG_CELLS)
            else:
                # The fewest reach layers (>= 1) whose big grid boxes fit the brute-force budget.
                r = next((r for r in range(1, max_reach + 1) if overB[r] * nA <= big_share * budget), max_reach)
                reach = np.ascontiguousarray(reachB[r])
                smallB, n_bigB, _ = _small_rows(cloB, chiB, np.zeros(3, dtype=np.int64), r, (r + 1) ** 3)
                entries = nB - n_bigB
            if self.self_query:  # the rows are the grid's boxes: small rows are the small boxes
                cloA, chiA, topA, n_bigA = cloB, chiB, topB, n_bigB
            else:
                cloA, chiA, topA = self._ranges(loA, hiA, origin, h)[:3]
                smallA, n_bigA, _ = _small_rows(cloA, chiA, reach, _MAX_DIM, _BIG_ROW_CELLS)
            work = n_bigA * nB + n_bigB * nA
            if work <= budget or np.all(h >= spans):
                break
            h = 2.0 * h
        if self.self_query:
            smallA = smallB
        dims = np.maximum(topA, topB) + 1
        n_dense = int(dims[0]) * int(dims[1]) * int(dims[2])
        if n_dense <= _DENSE_FACTOR * entries + 4096:
            bits, nb = -1, n_dense
        else:
            bits = max(1, int(np.ceil(np.log2(max(2 * entries, 2)))))
            nb = 1 << bits
        return _Cells(h, cloA, chiA, smallA, cloB, chiB, smallB, reach, dims, bits, nb)

    def _set_rows(self, loA, hiA, TA, cloA, chiA, smallA):
        self.loA, self.hiA, self.TA = loA, hiA, TA
        self.cloA, self.chiA, self.smallA = cloA, chiA, smallA
        self.compact = False
        nA = loA.shape[0]
        if nA >= _COMPACT_MIN_ROWS:
            # The scan compacts its box hits first where few of many entries hit (a
            # sample of the rows' buckets; the choice changes the time, never the pairs).
            rows = np.arange(0, nA, max(1, nA // _SAMPLE_ROWS), dtype=np.int64)
            scanned, hits = _hit_rate(rows, self.self_query, loA, hiA, cloA, chiA, smallA, self.dims,
                                      self.bits, self.reach, self.boff, self.ent_id, self.ent_box)
            misses = scanned - hits
            self.compact = bool(hits < _COMPACT_HIT_RATE * scanned and misses >= _COMPACT_MISSES * rows.shape[0])

    def with_rows(self, loA, hiA, TA, inflation):
        """This plan's grid of the B boxes queried by other rows A (boxes inflated by
        `inflation`, as B's must be for the min folds' bound); None for an empty plan or
        a self query, or when a box of A leaves the grid's cells (their keys would
        alias others'). The pairs are those of a fresh `_Plan` over the same boxes: the
        cell size changes how rows scan, never which pairs they find."""
        if self.empty or self.self_query or loA.shape[0] == 0:
            return None
        if self.perm is not None:
            loA, hiA = _permuted(loA, hiA, self.perm)
        cornA = _box_corners(loA, hiA)
        if np.any(cornA[0] < self.origin):
            return None
        cloA, chiA, topA, _, _ = self._ranges(loA, hiA, self.origin, self.h)
        if np.any(topA >= self.dims):
            return None
        plan = copy.copy(self)
        plan.slack = _PRUNE_SLACK * max(float(np.abs(cornA).max()), self.scaleB)
        plan.gap_off = 2.0 * float(inflation) - plan.slack
        plan._set_rows(loA, hiA, TA, cloA, chiA, _small_rows(cloA, chiA, self.reach, _MAX_DIM, _BIG_ROW_CELLS)[0])
        return plan

    @staticmethod
    def _ranges(lo, hi, origin, h, max_reach=_MAX_REACH):
        """(clo, chi, top, reach, n_over) of the boxes (`_cell_ranges`)."""
        clo = np.empty(lo.shape, dtype=np.int64)
        chi = np.empty(lo.shape, dtype=np.int64)
        return (clo, chi, *_cell_ranges(lo, hi, origin, h, clo, chi, max_reach))

    @property
    def dense_lower_corner(self) -> bool:
        """A dense cell table whose boxes are entered in their lower corner's cell only (not
        hashed, not covering): `_visit_row` scans its cells by runs along x, and the
        deferred min folds take `_defer_dense` on it."""
        return self.bits < 0 and self.ent_clo.shape[0] == 0

    def _args(self):
        return (self.self_query, self.loA, self.hiA, self.TA, self.cloA, self.chiA, self.smallA,
                self.loB, self.hiB, self.TB, self.dims, self.bits, self.reach,
                self.boff, self.cmax, self.ent_key, self.ent_id, self.ent_box, self.ent_clo, self.compact, self.bigB,
                self.gap_off)

    def pairs(self):
        """(K, 2) int64 rows (i, j), sorted lexicographically.

        One pass over the rows in chunks, each filling its own slots of a buffer
        sized from a sample of the rows (`_pairs_pass`); chunks that overflow are
        refilled at exact offsets. Pairs come out in row order, whatever the chunks.
        """
        if self.empty:
            return np.zeros((0, 2), dtype=np.int64)
        return _pairs_pass(self._args(), self.loA.shape[0])

    def edge_face_pairs(self, V):
        """Like `pairs` for A = edges, B = faces, keeping only the pairs that the float
        filter `orient.segment_may_meet_triangle` cannot clear at positions `V`."""
        if self.empty:
            return np.zeros((0, 2), dtype=np.int64)
        return _pairs_pass(self._args(), self.loA.shape[0], MODE_FILL_EF, V)

    def start_pairs(self, V, owners, loE, hiE, loF, hiF, inflation, cap_sq=np.inf):
        """`edge_face_pairs` of rows A = edges E, B = faces F (this plan's), and the
        smaller of `cap_sq` and the edge-edge and vertex-face minima of `start_pass`, in
        one pass.

        `owners`: `_start_owners` of (E, F, vertices), ok; loE.. hiF: the boxes of E and
        F at V, inflated by `inflation`, in V's axes (this plan's are permuted).
        Every pair of the two folds is reached through a box hit (edge, face): an edge
        pair (a, b), a < b, from row a and the owner face f of b (f's box holds b's,
        so it meets a's), a vertex-face pair (v, f) from the owner edge of v (its box
        holds v's). The vertex-face pairs are the same floats as `min_pair_sq`'s; an
        edge pair is evaluated as (smaller id, larger), where the self fold takes the
        row whose cell comes first, so the minimum may differ from that fold's in its
        last bits (the distance kernels' rounding, `distance` module). Pairs whose
        projection gap proves them above the chunk's minimum so far (which starts at
        `cap_sq`) are not evaluated (`_fold_owned`).
        """
        face_edges, owner_face, owner_edge = owners[:3]
        n = self.loA.shape[0]
        partial = np.full((_pair_chunks(n), 1), float(cap_sq))
        cand = _pairs_pass(self._args(), n, MODE_FILL_EF, V,
                           (face_edges, owner_face, owner_edge, loE, hiE, loF, hiF, float(inflation), self.slack,
                            partial))
        return cand, float(partial.min())

    def min_sq_into(self, V, partial, mode=MODE_MIN):
        """Fold squared pair distances into `partial` (W, N): per-vertex minima.

        Each row of `partial` is one worker's, folding the chunks of the rows it claims
        (`_min_rows_py`); reduce with min afterwards. With ``MODE_GLOBAL_MIN`` `partial`
        is (W, 1) and gets each worker's smallest.
        """
        if not self.empty:
            m = self.loA.shape[0]
            chunks = chunk_count(m, _MIN_CHUNKS, _MIN_CHUNK_ROWS)
            if mode == MODE_MIN and (self.TA.shape[1], self.TB.shape[1]) in _DEFERRED_WIDTHS:
                (_defer_dense if self.dense_lower_corner else _defer_rows)(
                    m, *self._args(), V, partial, chunks, work_counter(), _DEFER_CAP, _DEFER_FLUSH)
            else:
                _min_rows(m, *self._args(), V, partial, mode, chunks, work_counter())


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
    idx = idx.astype(np.int64)
    if idx.size > 1 and not np.all(idx[1:] > idx[:-1]):
        idx = np.unique(idx)  # (already strictly ascending, e.g. all vertices: no sort)
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



def _pair_rows_py(TA, TB, P, out):
    for k in prange(P.shape[0]):
        for a in range(TA.shape[1]):
            out[k, a] = TA[P[k, 0], a]
        for b in range(TB.shape[1]):
            out[k, TA.shape[1] + b] = TB[P[k, 1], b]


_pair_rows = parallel_kernel(_pair_rows_py, "_bp_pair_rows")


def pair_rows(TA, TB, P):
    """(K, wA + wB) int64: the vertex rows ``TA[P[:, 0]] | TB[P[:, 1]]`` of pairs `P`, in
    one parallel pass (the fancy-indexed gathers were ~5% of a 64K cloth step)."""
    TA = np.ascontiguousarray(TA, dtype=np.int64)
    TB = np.ascontiguousarray(TB, dtype=np.int64)
    out = np.empty((P.shape[0], TA.shape[1] + TB.shape[1]), dtype=np.int64)
    if P.shape[0]:
        _pair_rows(P.shape[0], TA, TB, np.ascontiguousarray(P, dtype=np.int64), out)
    return out


def _pairs_overlapping_py(P, loA, hiA, loB, hiB, keep):
    for k in prange(P.shape[0]):  # each pair writes its own slot: both builds, one mask
        keep[k] = _overlap(loA, hiA, P[k, 0], loB, hiB, P[k, 1])


_pairs_overlapping = parallel_kernel(_pairs_overlapping_py, "_bp_pairs_overlapping")


def pairs_overlapping(V, TA, TB, P, inflation, keep=None) -> np.ndarray:
    """(K,) bool: which pairs (i, j) of `P` (rows of `TA`, `TB`) have overlapping boxes
    at the static positions `V`, inflated by `inflation`.

    The boxes and the test of `edge_edge_candidates` / `vertex_face_candidates` (the
    same `_boxes` and `_overlap`), so a superset of a static query's pairs keeps exactly
    that query's pairs (`penfree.core.trust.stencil_list`). Inputs are assumed validated
    (V float64 C-contiguous, P int64 pairs in range); `keep`: a (K,) bool array to
    write into, else a new one.
    """
    keep = np.empty(P.shape[0], dtype=np.bool_) if keep is None else keep
    if P.shape[0]:
        loA, hiA = _box_arrays(V, V, TA, inflation)
        loB, hiB = (loA, hiA) if TB is TA else _box_arrays(V, V, TB, inflation)
        _pairs_overlapping(P.shape[0], P, loA, hiA, loB, hiB, keep)
    return keep


def scan_cost(plan) -> float:
    """Estimated row-scan work of a plan per row: entries scanned plus
    `_CELL_VISIT_ENTRIES` per cell visited, over a strided sample of <= `_SAMPLE_ROWS`
    rows (`_hit_rate`'s scan regions); on a dense lower-corner table a row's cells along x
    are one run of entries (`_visit_row`), so each run counts as one visit. 0 for an
    empty plan."""
    if plan.empty:
        return 0.0
    nA = plan.loA.shape[0]
    rows = np.arange(0, nA, max(1, nA // _SAMPLE_ROWS), dtype=np.int64)
    scanned, _ = _hit_rate(rows, plan.self_query, plan.loA, plan.hiA, plan.cloA, plan.chiA, plan.smallA,
                           plan.dims, plan.bits, plan.reach, plan.boff, plan.ent_id, plan.ent_box)
    small = rows[plan.smallA[rows]]
    lo = np.maximum(plan.cloA[small] - plan.reach, 0)
    hi = np.minimum(plan.chiA[small], plan.dims - 1)
    first = 1 if plan.dense_lower_corner else 0  # runs along x, as `_visit_row` scans
    cells = float(np.prod(hi[:, first:] - lo[:, first:] + 1, axis=1).sum())
    return (scanned + _CELL_VISIT_ENTRIES * cells) / rows.size


def choose_cells(x, TA, TB, inflation, self_query) -> str:
    """The cell shape (`CELL_SHAPES`) under which the min fold of these primitives at
    `inflation` is estimated to scan least (`scan_cost` of a plan per shape, built once
    each): another shape than cubes only when it costs under `_SHAPE_GAIN` of the cubes'.

    The shape changes which cells the rows scan, never the pairs they find, so a
    fold's result is the same bits under any; callers that run the same scene's
    query again and again (`proximity.SeparationQuery`) choose once and pass it on.
    Measured (issue 13, 64K yarn bundle at its separations' reach): cubes scan ~400
    entries per row for 9 overlaps, per-axis cells ~130, and the separation query
    runs 1.25-1.5x faster. On the 64K cloth per-axis cells cost what cubes do, slabs
    0.70 of it: its two folds run 1.24x faster (the same bits), `deform --model auto`
    1.15x (thirty-eighth session).
    """
    loA, hiA = _box_arrays(x, x, TA, inflation)
    loB, hiB = (loA, hiA) if self_query else _box_arrays(x, x, TB, inflation)
    cost = {c: scan_cost(_Plan(loA, hiA, TA, loB, hiB, TB, self_query, inflation, listing=False, cells=c))
            for c in CELL_SHAPES}
    best = min(CELL_SHAPES, key=lambda c: (cost[c], CELL_SHAPES.index(c)))
    return best if cost[best] < _SHAPE_GAIN * cost["cube"] else "cube"


def fold_min_sq(x, TA, TB, inflation, partial, self_query, cells="cube", axes=None):
    """Fold the squared distances of near pairs into per-vertex minima (static scene);
    returns the grid key's axis order it used (`_Plan.axes`).

    Parameters
    ----------
    x : (N, 3) float64, C-contiguous
    TA, TB : (M, k) int64
        Primitives (rows of vertex indices); with `self_query` `TB` must be `TA`.
    inflation : float >= 0
        Box inflation: pairs farther apart than ``2 * inflation`` may be skipped.
    partial : (W, N) float64
        Row w receives worker w's minima (`_Plan.min_sq_into`); reduce with ``min``
        afterwards.
    self_query : bool
    cells : str
        Cell shape of the grid (`CELL_SHAPES`, `choose_cells`): the time, never the result.
    axes : (3,) int64, optional
        The grid key's axis order, as an earlier call returned it for the same scene:
        the boxes are made in it and no order is chosen (the time, never the result;
        choosing and permuting cost ~1 ms a query on the 64K cloth).

    Returns
    -------
    (3,) int64
        The axis order used.

    Notes
    -----
    Inputs are assumed validated (the trust-region stage does it once per sequence).
    """
    loA, hiA, cA = _box_arrays(x, x, TA, inflation, corners=True, axes=axes)
    loB, hiB, cB = (loA, hiA, cA) if self_query else _box_arrays(x, x, TB, inflation, corners=True, axes=axes)
    plan = _Plan(loA, hiA, TA, loB, hiB, TB, self_query, inflation, listing=False, cells=cells, corners=(cA, cB),
                 axes=axes)
    plan.min_sq_into(x, partial)
    return plan.axes


def min_pair_sq(x, TA, TB, inflation, self_query) -> float:
    """Smallest squared distance over the pairs whose static boxes, inflated, overlap.

    Parameters
    ----------
    x : (N, 3) float64, C-contiguous
    TA, TB : (M, k) int64
        Primitives as in `fold_min_sq` (with `self_query` `TB` must be `TA`).
    inflation : float >= 0
        Box inflation: every pair within ``2 * inflation`` is visited.

    Returns
    -------
    float
        The smallest computed squared distance of a visited pair (distance kernels of
        `penfree.core.contact.distance`), inf when no boxes overlap. One pass, no pair
        stored: the "is anything within g" question of the certificate path.
    """
    loA, hiA = _box_arrays(x, x, TA, inflation)
    loB, hiB = (loA, hiA) if self_query else _box_arrays(x, x, TB, inflation)
    return _global_min(_Plan(loA, hiA, TA, loB, hiB, TB, self_query, inflation, listing=False), x)


def start_pass(x, E, F, vertices, inflation, cap_sq=np.inf):
    """The certificate path's questions about a static state, on two grids.

    Parameters
    ----------
    x : (N, 3) float64, C-contiguous
    E : (M, 2) int64
    F : (K, 3) int64
    vertices : (P,) int64
        Validated index arrays into x.
    inflation : float >= 0
        Box inflation of every primitive, as in `min_pair_sq`.
    cap_sq : float, optional
        The folds start their minimum here (as `per_vertex_separation` starts at its
        radius), so pairs provably farther apart are never evaluated. A caller asking
        whether every pair is more than some distance apart passes a cap above its
        square: the answer is the same, and almost no pair is evaluated.

    Returns
    -------
    cand : (Q, 2) int64
        A superset of ``edge_face_candidates(x, E, F)`` (the boxes are inflated), rows
        (e, f) sorted lexicographically, for the exact test to decide.
    d2 : float
        The smallest of `cap_sq`, ``min_pair_sq(x, E, E, inflation, True)`` and
        ``min_pair_sq(x, vertices[:, None], F, inflation, False)``, the same floats up
        to the distance kernels' rounding (inf for none and no cap).

    Notes
    -----
    The edge-face candidates and the vertex-face fold share one grid of the faces
    (`_Plan.with_rows`; its own grid where the vertices' boxes leave that one's cells),
    and the edge boxes serve both the edge-face rows and the edge-edge grid: two grids
    and three box arrays instead of three and five (~10 ms of a 64K cloth's ~0.1 s).
    Where every edge is a face's and every vertex an edge's (a triangle mesh,
    `_start_owners`), one pass over the edge-face box hits also folds both minima
    (`_Plan.start_pairs`): one grid, no fold of its own for either. The faces' grid is
    a fold's (``listing=False``: cells cut along x, `_RUN_SPLIT`): its rows list few
    pairs and fold many (64K cloth, alternating in one process: 1.07-1.08x).
    """
    cand, d2 = np.zeros((0, 2), dtype=np.int64), np.inf
    vertices = np.asarray(vertices, dtype=np.int64)
    loE, hiE = _box_arrays(x, x, E, inflation)
    if len(F):
        loF, hiF = _box_arrays(x, x, F, inflation)
        plan = _Plan(loE, hiE, E, loF, hiF, F, False, inflation, listing=False) if len(E) else None
        if plan is not None:
            owners = _start_owners(E, F, vertices, x.shape[0])
            if owners[3]:
                return plan.start_pairs(x, owners, loE, hiE, loF, hiF, inflation, cap_sq)
            cand = plan.edge_face_pairs(x)
        if len(vertices):
            TV = np.ascontiguousarray(vertices[:, None])
            loV, hiV = _box_arrays(x, x, TV, inflation)
            vf = plan.with_rows(loV, hiV, TV, inflation) if plan is not None else None
            if vf is None:
                vf = _Plan(loV, hiV, TV, loF, hiF, F, False, inflation)
            d2 = _global_min(vf, x, cap_sq)
    if len(E) > 1:
        d2 = min(d2, _global_min(_Plan(loE, hiE, E, loE, hiE, E, True, inflation, listing=False), x, cap_sq))
    return cand, min(d2, float(cap_sq))


def _global_min(plan, x, cap_sq=np.inf):
    partial = np.full((_GLOBAL_MIN_CHUNKS, 1), float(cap_sq))
    plan.min_sq_into(x, partial, MODE_GLOBAL_MIN)
    return float(partial.min())


def edge_face_candidates(V, E, F) -> np.ndarray:
    """Pairs (edge e, face f) of a static state that may meet: boxes overlap, no shared
    vertex, and not cleared by the certified float filter of `orient`.

    Parameters
    ----------
    V : (N, 3) float64, C-contiguous
    E : (M, 2) int64
    F : (K, 3) int64
        Validated index arrays into V.

    Returns
    -------
    (P, 2) int64
        Rows (e, f), sorted lexicographically; a superset of the intersecting pairs
        (every pair left out provably misses), for the exact test to decide.
    """
    if not len(E) or not len(F):
        return np.zeros((0, 2), dtype=np.int64)
    loE, hiE = _box_arrays(V, V, E, 0.0)
    loF, hiF = _box_arrays(V, V, F, 0.0)
    return _Plan(loE, hiE, E, loF, hiF, F, False).edge_face_pairs(V)
