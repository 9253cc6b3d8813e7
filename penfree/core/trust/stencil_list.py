"""The own client's candidate stencils of a replay's passes, from one superset.

Every CD pass of the planar client lists its candidate stencils afresh
(`planar.candidate_stencils`: the non-adjacent edge-edge and vertex-face pairs whose
boxes at the pass's positions, inflated by the radius, overlap). On dense contact (a
pile of layers: ~400K stencils for 768 vertices) that query was half of a replay's
time, and a replay runs up to `DEFAULT_CLIENT_MAX_ITER` passes.

A replay moves every vertex between states it knows in advance: its start, the
warm-start target and the iteration target (`client.replay_step`; each pass moves a
vertex by a fraction in [0, 1] of the way to its target). A `StencilList` is built
once over the *region* of those states, each vertex's coordinate-wise box ``lo..hi``
(padded by `REGION_PAD` for the rounding of ``x + beta dx``), and answers every pass
whose positions lie in the region by testing its pairs:

**Superset.** The list holds the pairs that `planar.candidate_stencils` finds for the
motion from ``lo`` to ``hi`` (`broad_phase._boxes`: a primitive's box spans the
smallest and largest coordinate of its vertices over both states). For positions
``x`` with ``lo <= x <= hi`` (exact comparisons, `covers`), each vertex's coordinate
lies between its ``lo`` and ``hi``, so a primitive's smallest coordinate at ``x`` is
at least its smallest at ``lo`` and its largest at most its largest at ``hi``; rounding
is monotone, so its box at ``x`` (the same subtraction and addition of the inflation)
lies inside its box over the region. Two boxes that overlap at ``x`` therefore
overlap over the region, and the broad phase reports every overlapping pair: the
pass's pairs are among the list's.

**Same arrays.** A pass keeps the list's pairs whose boxes at ``x`` overlap, with the
boxes the fresh query computes (`broad_phase._box_arrays`) and its test (`_overlap`:
``lo_a <= hi_b`` and ``lo_b <= hi_a`` on every axis), in the list's order; both are
sorted lexicographically, edge-edge before vertex-face, and the scene filter (obstacle
pairs left out, `client_scene.ClientScene.scene_pairs`) depends on the topology only.
The stencils and kinds are those of a fresh query, bit for bit. A pass outside the
region (a ball ratio outside [0, 1] can move a vertex backwards) runs the fresh query.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from ..contact.broad_phase import pairs_overlapping
from ..parallel import parallel_kernel
from .planar import candidate_pairs, pair_stencils

#: Relative padding of a region (of each coordinate's magnitude plus the region's
#: extent): ``x + beta (y - x)`` with ``beta = 1`` can land an ulp beyond ``y``.
REGION_PAD = 1e-12


def region(states) -> tuple:
    """``(lo, hi)``: the padded coordinate-wise box of each vertex over `states`
    (``(N, 3)`` float64 arrays)."""
    lo = np.minimum.reduce([np.asarray(s, dtype=np.float64) for s in states])
    hi = np.maximum.reduce([np.asarray(s, dtype=np.float64) for s in states])
    pad = REGION_PAD * (np.maximum(np.abs(lo), np.abs(hi)) + (hi - lo))
    return lo - pad, hi + pad


def contains(outer, inner) -> bool:
    """Whether region `outer` holds region `inner` (both ``(lo, hi)``)."""
    return bool((outer[0] <= inner[0]).all() and (inner[1] <= outer[1]).all())


#: Chunks of a list's kept pairs (each copies its own, in order: the rows come out in
#: the list's order whatever the threads).
_CHUNKS = 64


def _gather_py(keep, rows, kinds, offsets, out, out_kinds):
    # Chunk c copies its kept rows from out[offsets[c]] on, in order.
    n_chunks = offsets.shape[0] - 1
    m = keep.shape[0]
    for c in prange(n_chunks):
        o = offsets[c]
        for k in range(c * m // n_chunks, (c + 1) * m // n_chunks):
            if keep[k]:
                for a in range(rows.shape[1]):
                    out[o, a] = rows[k, a]
                out_kinds[o] = kinds[k]
                o += 1


_gather = parallel_kernel(_gather_py, "_stencil_gather")


class StencilList:
    """The candidate stencils within `radius` of every state in a region (module doc).

    Parameters
    ----------
    lo, hi : (N, 3) float64
        The region (`region`).
    E : (M, 2) int64
    F : (K, 3) int64
        The client's edges and faces (`planar.candidate_stencils`).
    radius : float
        The query radius (`candidate_stencils`'s: boxes inflated by it).
    keep : callable or None
        Stencil rows -> (C,) bool, the scene filter applied to every answer
        (`ClientScene.scene_pairs`), or None.
    """

    def __init__(self, lo, hi, E, F, radius, keep=None):
        self.lo, self.hi = lo, hi
        self.E, self.F = E, F
        self.radius = float(radius)
        self.Q = np.arange(lo.shape[0], dtype=np.int64)[:, None]
        ee, vf = candidate_pairs(lo, hi, E, F, self.radius)  # the motion lo -> hi: each vertex's box
        st, kinds = pair_stencils(lo.shape[0], E, F, ee, vf)
        sel = np.ones(st.shape[0], dtype=bool) if keep is None else np.asarray(keep(st), dtype=bool)
        self.n_ee = int(np.count_nonzero(sel[:ee.shape[0]]))
        self.ee = np.ascontiguousarray(ee[sel[:ee.shape[0]]])
        self.vf = np.ascontiguousarray(vf[sel[ee.shape[0]:]])
        self.stencils = np.ascontiguousarray(st[sel])
        self.kinds = np.ascontiguousarray(kinds[sel])

    def __len__(self):
        return self.stencils.shape[0]

    def covers(self, x) -> bool:
        """Whether every coordinate of `x` lies in the region (then `stencils_at` answers)."""
        return contains((self.lo, self.hi), (x, x))

    def stencils_at(self, x) -> tuple:
        """``(stencils, kinds)`` at `x` (inside the region): `candidate_stencils`'s
        arrays, with the scene filter, bit for bit (the list's own arrays, not a copy,
        when every pair is kept: read them only)."""
        m = len(self)
        keep = np.empty(m, dtype=np.bool_)
        pairs_overlapping(x, self.E, self.E, self.ee, self.radius, keep[:self.n_ee])
        pairs_overlapping(x, self.Q, self.F, self.vf, self.radius, keep[self.n_ee:])
        if np.count_nonzero(keep) == m:  # every pair kept (dense contact within the radius): the list's own arrays
            return self.stencils, self.kinds
        kept = np.zeros(m + 1, dtype=np.int64)
        np.cumsum(keep, out=kept[1:])
        offsets = kept[np.arange(_CHUNKS + 1) * m // _CHUNKS]  # where chunk c of `_gather_py` writes
        out = np.empty((int(offsets[-1]), 4), dtype=np.int64)
        out_kinds = np.empty(out.shape[0], dtype=np.int64)
        if m:
            _gather(m, keep, self.stencils, self.kinds, offsets, out, out_kinds)
        return out, out_kinds


__all__ = ["StencilList", "region", "contains", "REGION_PAD"]
