"""Spatial relabelling of a scene whose vertex labels carry no locality.

The broad phase's folds (`broad_phase`) visit their rows in label order and read the
vertices of each row's partners. On a mesh numbered row by row (a sheet, the strands of
a yarn) consecutive rows lie side by side, and their partners' boxes and vertices stay
in the caches. A scene whose labels carry no locality (vertices numbered by a remesher
or a hash, a tet mesh's surface, faces listed in any order) sends each row to cold
memory: the 64K cloth with its vertex labels and faces shuffled took 3.5x as long per
`deform --model auto` step, its separation query 3x (issue 13, BENCHMARKS.md).

`relabelling` renumbers such a scene once, from one state, along a Morton (Z-order)
curve: vertices close in space get close labels, and the edges and faces are listed by
their smallest new label. A query then runs on the relabelled scene and its per-vertex
values are taken back to the caller's labels.

Why the values are the same bits. Each edge keeps its endpoints' order and each face
its vertices' order, so every pair distance is evaluated on the same coordinates in the
same argument order; which of two edges is a fold's row may change, and the edge-edge
distance is symmetric bit for bit in its two segments (`distance._ee`); the pairs
visited are the same set (the broad phase finds every pair once, whatever the labels),
and ``min`` is exact. So the relabelled query equals the plain one bit for bit, which
the tests check.

A scene whose labels already carry locality is left as it is (`needs_relabelling`): on
the 64K cloth, listed row by row, a Morton order measured 1.15x slower than the mesh's
own (its scan lines fill the cache lines of neighbouring rows in order).
"""

from __future__ import annotations

import numpy as np

from ...errors import InputError

#: `needs_relabelling`: a scene is relabelled when the median label difference of its
#: edges' endpoints exceeds both of these (random labels give about n / 3; a sheet
#: numbered row by row gives its row length, about sqrt(n); strands numbered along
#: themselves give 1).
GAP_MIN = 1024
GAP_SHARE = 1.0 / 64.0
#: Bits per axis of the Morton code (3 x 21 = 63 bits of a uint64).
_MORTON_BITS = 21
#: Masks that spread 21 bits to every third bit of 63 (the classic "magic numbers").
_SPREAD = ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
           (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249))


def _spread(q):
    v = q.astype(np.uint64)
    for shift, mask in _SPREAD:
        v = (v | (v << np.uint64(shift))) & np.uint64(mask)
    return v


def morton_order(x) -> np.ndarray:
    """(N,) int64: the vertices of `x` ((N, 3) float) in Morton (Z-order) of their
    positions, quantized to ``2**21`` steps of the largest extent (the same step on
    every axis). Ties and non-finite coordinates (quantized to 0) keep label order."""
    x = np.asarray(x, dtype=np.float64)
    if x.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    finite = np.isfinite(x).all(axis=1)
    xf = x[finite]
    lo = xf.min(axis=0) if xf.size else np.zeros(3)
    span = float((xf.max(axis=0) - lo).max()) if xf.size else 0.0
    top = float((1 << _MORTON_BITS) - 1)
    with np.errstate(invalid="ignore"):
        q = (x - lo) * (top / span if span > 0.0 else 0.0)
    q = np.where(finite[:, None], np.clip(q, 0.0, top), 0.0).astype(np.int64)
    code = _spread(q[:, 0]) | (_spread(q[:, 1]) << np.uint64(1)) | (_spread(q[:, 2]) << np.uint64(2))
    return np.argsort(code, kind="stable").astype(np.int64)


def label_gap(E) -> float:
    """Median of ``|E[:, 0] - E[:, 1]|`` over the edges (0 for none)."""
    if E.shape[0] == 0:
        return 0.0
    gap = np.abs(E[:, 0] - E[:, 1])
    k = gap.size // 2
    return float(np.partition(gap, k)[k])


def needs_relabelling(n, E) -> bool:
    """Whether a scene of `n` vertices with edges `E` ((M, 2) int64) lists its vertices
    without locality: the median label difference of the edges' endpoints is above
    `GAP_MIN` and `GAP_SHARE` of `n`."""
    return label_gap(E) > max(GAP_MIN, GAP_SHARE * n)


class Relabelling:
    """A scene renumbered along a Morton curve of one state (module docstring).

    Parameters
    ----------
    x : (N, 3) float64
        The state the order is taken from (any state of the scene: the order changes the
        time of a query, never its values).
    E : (M, 2) int64
    F : (K, 3) int64
        The scene's edges and faces (`trust.bounds.scene_arrays`).

    Attributes
    ----------
    perm : (N,) int64
        New label k is the caller's vertex ``perm[k]``.
    inv : (N,) int64
        The caller's vertex v is new label ``inv[v]``.
    E, F : int64 arrays
        The edges and faces in new labels, each with its vertices in their order, listed
        by their smallest new label (then their largest, for edges).
    edge_order, face_order : int64 arrays
        New edge k is the caller's edge ``edge_order[k]``; likewise the faces.

    Examples
    --------
    >>> x = np.array([[2.0, 0, 0], [0, 0, 0], [1, 0, 0]])
    >>> r = Relabelling(x, np.array([[1, 2], [2, 0]]), np.zeros((0, 3), np.int64))
    >>> r.perm.tolist(), r.E.tolist()
    ([1, 2, 0], [[0, 1], [1, 2]])
    >>> r.to_caller(np.array([10.0, 11.0, 12.0])).tolist()
    [12.0, 10.0, 11.0]
    """

    def __init__(self, x, E, F):
        self.perm = morton_order(x)
        n = self.perm.size
        self.inv = np.empty(n, dtype=np.int64)
        self.inv[self.perm] = np.arange(n, dtype=np.int64)
        E2 = self.inv[E]
        self.edge_order = np.lexsort((E2.max(axis=1), E2.min(axis=1))) if E2.size else np.zeros(0, np.int64)
        self.E = np.ascontiguousarray(E2[self.edge_order])
        F2 = self.inv[F]
        self.face_order = np.argsort(F2.min(axis=1), kind="stable") if F2.size else np.zeros(0, np.int64)
        self.F = np.ascontiguousarray(F2[self.face_order])

    def fits(self, x) -> bool:
        """Whether `x` has this scene's number of vertices."""
        return np.shape(x)[0] == self.perm.size

    def positions(self, x) -> np.ndarray:
        """(N, 3) float64 C-contiguous: `x` in the new labels."""
        if not self.fits(x):
            raise InputError(f"x must be ({self.perm.size}, 3) like the relabelled scene; got {np.shape(x)}")
        return np.take(np.asarray(x, dtype=np.float64), self.perm, axis=0)  # a new C-contiguous array

    def to_caller(self, d) -> np.ndarray:
        """(N,) per-vertex values `d` of the new labels, in the caller's labels."""
        return d[self.inv]

    def edge_face_to_caller(self, ef) -> np.ndarray:
        """(K, 2) int64 (edge, face) pairs of the new lists as the caller's, sorted
        lexicographically."""
        e, f = self.edge_order[ef[:, 0]], self.face_order[ef[:, 1]]
        k = np.lexsort((f, e))
        return np.ascontiguousarray(np.stack([e[k], f[k]], axis=1).astype(np.int64))


def relabelling(x, E, F) -> Relabelling | None:
    """A `Relabelling` of the scene from state `x` when its labels carry no locality
    (`needs_relabelling`), else None."""
    if not needs_relabelling(np.asarray(x).shape[0], E):
        return None
    return Relabelling(x, E, F)


class SceneLabels:
    """Whether the queries of one scene run on its `Relabelling`: decided once, from the
    first state asked about (`relabelling`), for the classes that query a scene state
    after state (`proximity.SeparationQuery`, `neighbours.NeighbourList`).

    Examples
    --------
    >>> labels = SceneLabels(np.array([[0, 1]]), np.zeros((0, 3), np.int64))
    >>> labels.for_state(np.zeros((2, 3))) is None, labels.relabelled
    (True, False)
    """

    def __init__(self, E, F):
        self.E, self.F = E, F
        self._relabel = None  # a `Relabelling`, False (the labels carry locality), None (not decided)

    def for_state(self, x) -> Relabelling | None:
        """The scene's `Relabelling` for a query at `x`, or None: the labels carry
        locality, or `x` has another number of vertices (queried as given)."""
        if self._relabel is None:
            self._relabel = relabelling(x, self.E, self.F) or False
        return self._relabel if self._relabel and self._relabel.fits(x) else None

    @property
    def relabelled(self) -> bool:
        """Whether the scene was found to need its relabelling (False until decided)."""
        return bool(self._relabel)
