"""Per-vertex proximity of a static state: the smallest distance from each vertex's
primitives to the non-adjacent primitives around them, within a radius.

The broad phase finds the pairs whose static boxes, inflated by half the radius,
overlap (every pair closer than the radius is among them: the Euclidean distance is
at least the per-axis box gap), and the pair distances are folded into per-vertex
minima inside the same parallel pass, so no candidate list is ever stored. The
trust-region bounds (`penfree.core.trust.bounds`) and the neighbour lists
(`penfree.core.contact.neighbours`) are built on it.
"""

from __future__ import annotations

import numba
import numpy as np

from ...constants import REDUCTION_CHUNKS
from ...errors import InputError
from ..topology import referenced_vertices
from .broad_phase import fold_min_sq

#: Cap on the per-chunk partial minima, in float64 entries (32 MiB).
_PARTIAL_ENTRIES_MAX = 1 << 22


def _cap_sq(radius):
    """The smallest float64 c >= radius**2 with sqrt(c) >= radius (sqrt correctly rounded)."""
    c = float(radius) * float(radius)
    while np.sqrt(c) < radius:
        c = float(np.nextafter(c, np.inf))
    return c


def partial_chunks(n) -> int:
    """Rows of per-chunk partial minima for `n` vertices: min is exact, so the chunk
    count may follow the thread count (a few chunks per thread for balance) without
    changing a single bit; capped at `_PARTIAL_ENTRIES_MAX` entries."""
    return max(1, min(REDUCTION_CHUNKS, 4 * numba.get_num_threads(), _PARTIAL_ENTRIES_MAX // max(n, 1)))


def start_minima(n, radius) -> np.ndarray:
    """(chunks, n) per-chunk partial minima of squared distances, each at the cap
    radius**2 (`_cap_sq`) instead of inf: the result is min(sqrt(.), radius), so it is
    unchanged, and a fold can skip every pair that provably lies beyond the radius."""
    return np.full((partial_chunks(n), n), _cap_sq(radius))


def capped_separations(partial, radius) -> np.ndarray:
    """(n,) ``min(radius, sqrt(min over the chunks))`` of `start_minima`'s rows."""
    return np.minimum(np.sqrt(partial.min(axis=0)), float(radius))


def per_vertex_separation(x, E, F, radius):
    """Per-vertex smallest distance to non-adjacent primitives, capped at `radius`.

    Parameters
    ----------
    x : (N, 3) float64, C-contiguous
    E : (M, 2) int64
        Edges (for a triangle scene: the edges of the faces).
    F : (K, 3) int64
        Faces; empty for a segment scene.
    radius : float >= 0
        Finite (an infinite radius would make every box cover the whole space):
        InputError otherwise.

    Returns
    -------
    d : (N,) float64
        ``d[v] = min(radius, terms)`` with the terms of SPEC section 7:
        vertex-face distances fold into the vertex and into the face's three
        vertices, edge-edge distances (edges sharing no vertex) into the four
        vertices. A vertex in no primitive, or with nothing within `radius`,
        gets `radius`.

    Notes
    -----
    Inputs are assumed validated (`trust_region_bounds` does it). Rows are
    split into chunks, each with its own row of partial minima, reduced with
    ``min`` (exact): the result does not depend on the number of threads.
    """
    r = float(radius)
    if not (np.isfinite(r) and r >= 0.0):
        raise InputError(f"radius must be finite and >= 0; got {radius}")
    n = x.shape[0]
    inflation = 0.5 * radius
    # from the cap: pairs beyond the radius are skipped from the first pair on
    partial = start_minima(n, radius)
    if E.shape[0]:
        fold_min_sq(x, E, E, inflation, partial, self_query=True)
    if F.shape[0]:
        used = referenced_vertices(n, F, E)
        Q = np.ascontiguousarray(np.flatnonzero(used).astype(np.int64)[:, None])
        fold_min_sq(x, Q, F, inflation, partial, self_query=False)
    return capped_separations(partial, radius)
