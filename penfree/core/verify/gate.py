"""The shared safety gate of a step: deform's margin, the certificate, near pairs, obstacles.

Every map `deform` writes passes `StepGate.passes` (SPEC section 5, "Real start
states" and "Obstacles"):

- the exact certificate `certificate.certify_map(A, deform_margin(thickness))` of every
  applied map. With thickness 0 a margin of 0 would do (`margin_rule`, what verify
  holds a result to): a nonsingular path of the exact map ``A x + b`` maps every
  primitive by one bijection, so no disjoint pair ever meets, whatever the start state
  holds. deform asks 0.1 there too (`DEFORM_MIN_MARGIN`): a map that is nonsingular only
  barely squashes the scene (a half-turn projected at margin 0 put it on a line). The
  stored x_def is that map rounded (delta, below);
  a pair starting within ``2 delta / m_c`` (``m_c >= 0.1`` a certified margin of the map)
  could cross by the rounding alone, so those pairs go through the exact CCD as below
  (a vertex 1e-17 above a face crossed it under a certified rotation);
- with thickness h > 0 the margin is ``m = 1 / MARGIN_GAP_RADIUS_FACTOR``. A map whose
  path keeps ``sigma_min >= m_c`` (``m_c >= m``: its rigorous fast bound, else m)
  keeps every pair that starts more than ``(h + 2 delta) / m_c`` apart at least h
  apart (delta: the rounding of the stored x_def, at most `NEAR_SLACK_REL` h / 2 or the
  rounding of its dtype at its magnitude, `StepGate.rounding_limit`).
  The pairs closer than that and their start distances come from one proximity
  query per step (`verify.near_pairs`, radius `NEAR_FIRST_FACTOR` h, redone larger,
  up to ``1.01 h / m``, only for a candidate that needs it); each candidate's path
  goes through the conservative CCD (`verify.check_pairs`) for them: a pair at least h apart must stay so, a pair
  resting inside h must stay disjoint, a pair touching at the start must not move
  (the rounded map can make it cross). No global margin is derived from the smallest
  gap, so resting contact does not freeze a step;
- several maps (`per-component`: each group of objects moved by its own map): no
  certificate covers a pair whose two primitives different maps move, however far apart
  they start, so the whole path goes through the conservative CCD (`StepGate.between_maps`:
  `verify.verify_step` in the deform-result reading, as `verify` judges the written
  step). The strategy that merges groups until their paths are apart asks the gate the
  same question (the last answer is kept, so a step pays for one CCD per distinct
  x_def); the gate never takes a strategy's word for it;
- obstacles held at the step's frame: half-spaces exactly, meshes by conservative CCD
  (`verify.verify_step` with ``self_pairs=False``).

Doing nothing (``x_def = x`` bit for bit) always passes and is not checked.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ...constants import (
    DEFORM_MIN_MARGIN, DISTANCE_ROUNDING_REL, MARGIN_GAP_RADIUS_FACTOR, NEAR_FIRST_FACTOR, NEAR_SLACK_REL,
    UNIT_ROUNDOFF, VERIFY_MARGIN_LADDER,
)
from ..fit.certificate import certify, certify_map, fast_margin_bound


#: `StepGate.between_maps` lists violating pairs up to this many (all of them in practice:
#: `per-component` merges their groups).
ALL_PAIRS = 1 << 30


def margin_rule(thickness) -> float:
    """The certificate margin that proves the guarantee (SPEC section 5): 0 for thickness 0,
    else ``1 / MARGIN_GAP_RADIUS_FACTOR``. verify and the report's re-check hold a
    result's maps to it (files written before `deform_margin` included)."""
    return 0.0 if float(thickness) <= 0.0 else 1.0 / MARGIN_GAP_RADIUS_FACTOR


def deform_margin(thickness) -> float:
    """The margin every map deform writes is certified with: `margin_rule`'s, and at least
    `DEFORM_MIN_MARGIN` (0.1) at thickness 0, where margin 0 admits maps that squash the
    scene onto a line."""
    return max(margin_rule(thickness), DEFORM_MIN_MARGIN)


def positive_margin(A):
    """A margin ``m > 0`` with ``certify(A, m)`` True (the exact test), or None: the
    fast bound when it is clear of 0, else the first of `VERIFY_MARGIN_LADDER` that
    certifies."""
    fb = fast_margin_bound(A)  # fb > m implies certify(A, m); the exact test still decides
    for m in [min(fb * (1 - 1e-6), 1 - 1e-9)] if fb > 0.01 else list(VERIFY_MARGIN_LADDER):
        if certify(A, m):
            return m
    return None


def deviation_bound(x, x_def, A, b) -> float:
    """Rigorous upper bound of max_v |x_def_v - (A x_v + b)| (exact real A x + b).

    fl(A x + b) has per-component error <= gamma_4 (sum_j |A_ij x_j| + |b_i|)
    and the subtraction adds u |x_def - y|; 8 u covers both with room.
    """
    if not len(x):
        return 0.0
    x = np.ascontiguousarray(x, dtype=np.float64)
    x_def = np.ascontiguousarray(x_def, dtype=np.float64)
    A = np.ascontiguousarray(A, dtype=np.float64)
    b = np.ascontiguousarray(b, dtype=np.float64)
    # One pass, no temporaries (the numpy form took ~10 ms at 64K vertices, most of the
    # certificate path's non-proximity time); the bound holds for any evaluation order.
    return float(np.sqrt(_max_dev_sq(x, x_def, A, b, 8.0 * UNIT_ROUNDOFF)) * (1.0 + 8.0 * UNIT_ROUNDOFF))


@njit(cache=True)
def _max_dev_sq(x, x_def, A, b, k):
    m = 0.0
    for v in range(x.shape[0]):
        q = 0.0
        for i in range(3):
            y = A[i, 0] * x[v, 0] + A[i, 1] * x[v, 1] + A[i, 2] * x[v, 2] + b[i]
            s = (abs(A[i, 0]) * abs(x[v, 0]) + abs(A[i, 1]) * abs(x[v, 1]) + abs(A[i, 2]) * abs(x[v, 2])
                 + abs(b[i]) + abs(x_def[v, i]))
            e = abs(x_def[v, i] - y) + k * s
            q += e * e
        if q > m or q != q:
            m = q
    return m


def _start_distance(x, kind, idx):
    """Distances at `x` of the pairs `idx` (rows p, f0, f1, f2 or ea0, ea1, eb0, eb1)."""
    from ..contact.distance import indexed_distance

    return indexed_distance(x, idx, kind)


class StepGate:
    """The safety gate of one step: start state `x`, topology, thickness, obstacles at `frame`.

    Parameters
    ----------
    x : (N, 3) float
    edges, faces : topology or None
    thickness : float >= 0
    obstacles : list of `penfree.sequence.Obstacle`
    frame : int
        The step's frame s (kinematic obstacles are held there).
    topology : `verify.path.SceneTopology`, optional
        `edges` and `faces` validated once, for the gates of many steps.
    """

    def __init__(self, x, *, edges=None, faces=None, thickness=0.0, obstacles=(), frame=0, topology=None):
        self.x = np.ascontiguousarray(x, dtype=np.float64)
        self.magnitude = float(np.abs(self.x).max()) if len(self.x) else 0.0  # largest start coordinate
        self.edges, self.faces = edges, faces
        self.topology = topology  # `verify.SceneTopology` of edges and faces, made once for many gates
        self.thickness = float(thickness)
        self.margin = deform_margin(self.thickness)
        self.obstacles = list(obstacles or ())
        self.frame = int(frame)
        self._near, self._near_radius = None, 0.0
        self._separations = None
        self._between = None  # (x_def, VerifyResult) of the last `between_maps`
        self.has_topology = (edges is not None and len(edges) > 0) or (faces is not None and len(faces) > 0)

    def use_separations(self, d):
        """Let the near-pair query skip the primitives that are in no near pair.

        `d` : (N,) float64, the scene's per-vertex separations at the gate's `x`
        (`per_vertex_separation` at any radius, e.g. `auto`'s start separations, or
        lower values). A pair's distance is one of its vertices' terms, so a pair within
        the query radius R has only vertices with ``d < R``: the query searches just the
        primitives made of those (`near_pairs` with `keep`) and finds the same pairs
        within R, so every verdict is the same (`near_pairs` ignores it when a vertex is
        in no primitive: such a vertex has pairs with faces that no separation records).
        """
        d = np.asarray(d, dtype=np.float64)
        if d.shape == (self.x.shape[0],):
            self._separations = d

    def near(self, reach):
        """``[(kind, ij, idx, d0)]``: the pairs within at least `reach` at the start, with
        their start distances. One proximity query, redone with a larger radius only when
        a candidate needs one (a strongly shrinking map): pairs it leaves out start
        farther apart than `reach`."""
        if self._near is None or reach > self._near_radius:
            from .pairs import near_pairs

            self._near_radius = max(reach, NEAR_FIRST_FACTOR * self.thickness)
            keep = None if self._separations is None else self._separations < self._near_radius
            self._near = [(kind, ij, idx, _start_distance(self.x, kind, idx))
                          for kind, ij, idx in near_pairs(self.x, self.edges, self.faces, self._near_radius, keep,
                                                            self.topology)]
        return self._near

    def passes(self, x_def, maps) -> bool:
        """True when the path x -> x_def is safe (see the module docstring).

        Parameters
        ----------
        x_def : (N, 3) float
        maps : list of (A (3, 3), b (3,), rows or None)
            Every applied map and the vertices it moved (None: all).
        """
        stored = np.asarray(x_def).dtype
        x_def64 = np.asarray(x_def, dtype=np.float64)
        if np.array_equal(x_def64, self.x):
            return True  # doing nothing
        if not all(np.isfinite(A).all() and certify_map(A, self.margin) for A, _, _ in maps):
            return False
        if self.has_topology and not self._near_ok(x_def64, maps, stored):
            return False
        if self.has_topology and len(maps) > 1 and not self.between_maps(x_def64).ok:
            return False
        return self._obstacles_ok(x_def64)

    def rounding_limit(self, x_def64, stored) -> float:
        """The largest deviation of the stored x_def from its exact map that a candidate
        may have: `NEAR_SLACK_REL` h / 2, or the rounding of storing x_def in its dtype
        when that is larger (at most h); inf at thickness 0 (any rounding: the pairs it
        could make cross are checked instead).

        The limit only bounds the near-pair radius ``(h + 2 delta) / m_c`` (every pair it
        leaves out starts farther apart than the rounding could close), never a verdict.
        Without the dtype term, float32 coordinates beyond ~8e4 h from the origin (84 m at
        h = 1 mm, 8 m at 0.1 mm) made every map fail: their rounding alone exceeded h / 200.
        """
        if not self.thickness > 0.0:
            return np.inf
        limit = 0.5 * NEAR_SLACK_REL * self.thickness
        if np.issubdtype(stored, np.floating) and len(x_def64):
            # 4 half-ulps of the largest stored coordinate, with the start's magnitude
            scale = max(float(np.abs(x_def64).max()), self.magnitude)
            limit = max(limit, min(self.thickness, 2.0 * float(np.finfo(stored).eps) * scale))
        return limit

    def _near_ok(self, x_def64, maps, stored) -> bool:
        from .pairs import check_pairs

        limit = self.rounding_limit(x_def64, stored)
        reach = 0.0  # pairs starting closer than this are not covered by the certificates
        for A, b, rows in maps:
            sl = slice(None) if rows is None else rows
            A = np.asarray(A, np.float64)
            delta = deviation_bound(self.x[sl], x_def64[sl], A, np.asarray(b, np.float64))
            if not delta <= limit:
                return False
            if self.thickness == 0.0 and delta == 0.0:
                continue  # x_def is the exact map: its certificate covers every pair
            m_c = max(self.margin, fast_margin_bound(A))  # certify_map(A, margin) passed; margin >= 0.1
            reach = max(reach, (self.thickness + 2.0 * delta) / m_c)
        if not np.isfinite(reach):
            return False
        if reach == 0.0:
            return True
        # computed distances can lie above the true ones (`DISTANCE_ROUNDING_REL`)
        reach = reach * (1.0 + 1e-6) + DISTANCE_ROUNDING_REL * self.magnitude
        close = [(kind, ij[d0 < reach], idx[d0 < reach]) for kind, ij, idx, d0 in self.near(reach)]
        return check_pairs(close, self.x, x_def64, self.thickness)

    def between_maps(self, x_def):
        """`verify.verify_step` of the path x -> `x_def` in the deform-result reading
        (pre-existing contact excused as `verify` excuses it), every violating pair listed:
        the check of a step whose maps move different objects. The last answer is kept
        for an equal `x_def` (`per-component` merges its groups by it, then the gate
        passes the same x_def)."""
        x_def64 = np.asarray(x_def, dtype=np.float64)
        if self._between is not None and np.array_equal(self._between[0], x_def64):
            return self._between[1]
        from .path import verify_step

        r = verify_step(self.x, x_def64, edges=self.edges, faces=self.faces, thickness=self.thickness,
                        max_pairs=ALL_PAIRS, start_intersections=False, pre_existing=True)
        self._between = (x_def64.copy(), r)
        return r

    def _obstacles_ok(self, x_def64) -> bool:
        if not self.obstacles:
            return True
        from ..contact.obstacles import as_verify_obstacles
        from .path import verify_step

        obs, names = as_verify_obstacles(self.obstacles, self.frame, self.frame)
        r = verify_step(self.x, x_def64, edges=self.edges, faces=self.faces, thickness=self.thickness,
                        obstacles=obs, obstacle_names=names, max_pairs=0, start_intersections=False,
                        pre_existing=True, self_pairs=False)
        return r.n_violations == 0
