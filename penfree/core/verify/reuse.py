"""The certificate path of `verify` over reused neighbour lists.

`verify_file.verify_affine_step` proves an affine step from its exact certificate and
one static proximity pass at the start state: every vertex-face and edge-edge pair must
be at least ``g`` apart, and no edge may meet a face. Across the steps of a result that
pass is answered from a `NeighbourList` (superset of the pairs within ``g``, see
`penfree.core.contact.neighbours`): the listed pairs are filtered by their distance at the start
state, and only the survivors (those possibly within ``g``) go through the same static
conservative CCD as the fresh pass, so the verdict is the one the fresh pass gives.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ...constants import DISTANCE_ROUNDING_REL
from ..contact.neighbours import NeighbourList
from ..contact.orient import segment_may_meet_triangle_at
from .path import _narrow, _share_no_vertex, edge_face_exact

#: A listed pair is dropped before the CCD only when its computed distance exceeds
#: g (1 + _KEEP_REL) + _PAD_REL * |x|max: beyond how far a computed distance can lie
#: above the true one (`DISTANCE_ROUNDING_REL`), so a dropped pair is truly > g.
_KEEP_REL = 1e-9
_PAD_REL = DISTANCE_ROUNDING_REL


def apart_sq(g, x) -> float:
    """Squared distance above which a computed pair distance proves the pair more than
    `g` apart at `x` (``(g (1 + _KEEP_REL) + _PAD_REL |x|max)^2``)."""
    mag = float(np.abs(x).max()) if x.size else 0.0
    return (g * (1.0 + _KEEP_REL) + _PAD_REL * mag) ** 2


def result_lists(scene_E, scene_F):
    """A `NeighbourList` for the start states of a result's steps, with edge-face pairs."""
    return NeighbourList(scene_E, scene_F, edge_face=True)


@njit(cache=True)
def _boxes_touch(x, E, F, ef):
    # The fresh pass's broad phase: exact (uninflated) boxes of edge and face at x,
    # and its certified float filter (a pair it clears provably misses).
    out = np.empty(ef.shape[0], dtype=np.bool_)
    for k in range(ef.shape[0]):
        e, f = ef[k, 0], ef[k, 1]
        ok = True
        for a in range(3):
            elo = min(x[E[e, 0], a], x[E[e, 1], a])
            ehi = max(x[E[e, 0], a], x[E[e, 1], a])
            flo = min(x[F[f, 0], a], x[F[f, 1], a], x[F[f, 2], a])
            fhi = max(x[F[f, 0], a], x[F[f, 1], a], x[F[f, 2], a])
            if elo > fhi or flo > ehi:
                ok = False
                break
        if ok:
            ok = segment_may_meet_triangle_at(x, E[e, 0], E[e, 1], F[f, 0], F[f, 1], F[f, 2])
        out[k] = ok
    return out


def listed_edge_face(col, x, E, F, ef):
    """`verify._edge_face` (kind ``"ef"``) over the listed edge-face pairs `ef` (K, 2).

    The listed pairs whose exact boxes at `x` touch and which the float filter of
    `penfree.core.contact.orient` cannot clear are the fresh pass's candidates (an
    edge meeting a face has touching boxes), tested by the same exact test.
    """
    if not len(ef):
        return
    ef = ef[_boxes_touch(x, E, F, ef)]
    k = np.ascontiguousarray(ef[:, 0])
    f = np.ascontiguousarray(ef[:, 1])
    keep = _share_no_vertex(E, F, k, f)
    edge_face_exact(col, "ef", x, E, F, k[keep], f[keep])


def listed_start_pass(col, nl, x, g):
    """Fill `col` as ``_edge_face(col, "ef", ...)`` + ``_pairs_self(col, scene, g, static=True)``.

    Parameters
    ----------
    col : verify._Collector
    nl : NeighbourList
        Built over the scene's E, F (the `_Body` arrays) with ``edge_face=True``.
    x : (N, 3) float64
        Start state.
    g : float >= 0
        Required separation.

    Returns
    -------
    bool
        False when the list declined (its cost model prefers a fresh query at this
        state): `col` is untouched and the caller runs the fresh passes.
    """
    if nl.ensure(x, g) == "fresh":
        return False  # the cost model prefers a fresh pass here
    E, F = nl.E, nl.F
    pairs = nl.pairs(x, g)
    if len(F):
        listed_edge_face(col, x, E, F, pairs["ef"])
    d_ee, d_vf = nl.pair_sq(x)
    keep = apart_sq(g, x)
    ee = pairs["ee"][d_ee <= keep]
    if len(ee):
        _narrow(col, "ee", ee, E[ee].reshape(-1, 4), x, x, "ee", g)
    vf = pairs["vf"][d_vf <= keep]
    if len(vf):
        idx = np.concatenate([vf[:, :1], F[vf[:, 1]]], axis=1)
        _narrow(col, "vf", vf, idx, x, x, "vf", g)
    return True
