"""The shared safety gate of a step: one margin rule, the certificate, near pairs, obstacles.

Every map `deform` writes passes `StepGate.passes` (SPEC section 5, "Real start
states" and "Obstacles"):

- the exact certificate `certificate.certify_map(A, margin_rule(thickness))` of every
  applied map. With thickness 0 the margin is 0: a nonsingular path maps every
  primitive by one bijection, so no disjoint pair ever meets, whatever the start
  state holds;
- with thickness h > 0 the margin is ``m = 1 / MARGIN_GAP_RADIUS_FACTOR``: pairs that
  start more than ``R = h / m`` apart (times 1 + `NEAR_SLACK_REL`) stay at least h apart.
  The pairs closer than R are found once per step (`verify.near_pairs`, one proximity
  query) and each candidate's path goes through the conservative CCD for them
  (`verify.check_pairs`): a pair at least h apart must stay so, a pair resting inside h
  must stay disjoint, a pair touching at the start is left as it was. No global margin
  is derived from the smallest gap, so resting contact does not freeze a step;
- obstacles held at the step's frame: half-spaces exactly, meshes by conservative CCD
  (`verify.verify_step` with ``self_pairs=False``).

Doing nothing (``x_def = x`` bit for bit) always passes and is not checked.
"""

from __future__ import annotations

import numpy as np

from ..constants import MARGIN_GAP_RADIUS_FACTOR, NEAR_SLACK_REL
from .certificate import certify_map

_U = 2.0**-53


def margin_rule(thickness) -> float:
    """The certificate margin every path uses: 0 for thickness 0, else ``1 / MARGIN_GAP_RADIUS_FACTOR``."""
    return 0.0 if float(thickness) <= 0.0 else 1.0 / MARGIN_GAP_RADIUS_FACTOR


def near_radius(thickness) -> float:
    """Radius of the near-pair query: pairs farther apart are covered by the certificate."""
    return MARGIN_GAP_RADIUS_FACTOR * float(thickness) * (1.0 + NEAR_SLACK_REL)


def deviation_bound(x, x_def, A, b) -> float:
    """Rigorous upper bound of max_v |x_def_v - (A x_v + b)| (exact real A x + b).

    fl(A x + b) has per-component error <= gamma_4 (sum_j |A_ij x_j| + |b_i|)
    and the subtraction adds u |x_def - y|; 8 u covers both with room.
    """
    y = x @ A.T + b
    r = np.abs(x_def - y)
    s = np.abs(x) @ np.abs(A).T + np.abs(b) + np.abs(x_def)
    e = r + 8.0 * _U * s
    return float(np.sqrt((e * e).sum(axis=1)).max() * (1.0 + 8.0 * _U)) if len(x) else 0.0


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
    """

    def __init__(self, x, *, edges=None, faces=None, thickness=0.0, obstacles=(), frame=0):
        self.x = np.ascontiguousarray(x, dtype=np.float64)
        self.edges, self.faces = edges, faces
        self.thickness = float(thickness)
        self.margin = margin_rule(self.thickness)
        self.obstacles = list(obstacles or ())
        self.frame = int(frame)
        self._near = None
        self.has_topology = (edges is not None and len(edges) > 0) or (faces is not None and len(faces) > 0)

    @property
    def near(self):
        """Pairs within `near_radius` at the start (computed once, on first use)."""
        if self._near is None:
            from .verify import near_pairs

            self._near = near_pairs(self.x, self.edges, self.faces, near_radius(self.thickness))
        return self._near

    def passes(self, x_def, maps) -> bool:
        """True when the path x -> x_def is safe (see the module docstring).

        Parameters
        ----------
        x_def : (N, 3) float
        maps : list of (A (3, 3), b (3,), rows or None)
            Every applied map and the vertices it moved (None: all).
        """
        x_def64 = np.asarray(x_def, dtype=np.float64)
        if np.array_equal(x_def64, self.x):
            return True  # doing nothing
        if not all(np.isfinite(A).all() and certify_map(A, self.margin) for A, _, _ in maps):
            return False
        if self.thickness > 0.0 and self.has_topology and not self._near_ok(x_def64, maps):
            return False
        return self._obstacles_ok(x_def64)

    def _near_ok(self, x_def64, maps) -> bool:
        from .verify import check_pairs

        limit = 0.5 * NEAR_SLACK_REL * self.thickness
        for A, b, rows in maps:
            sl = slice(None) if rows is None else rows
            if not deviation_bound(self.x[sl], x_def64[sl], np.asarray(A, np.float64), np.asarray(b, np.float64)) <= limit:
                return False
        return check_pairs(self.near, self.x, x_def64, self.thickness)

    def _obstacles_ok(self, x_def64) -> bool:
        if not self.obstacles:
            return True
        from .obstacles import as_verify_obstacles
        from .verify import verify_step

        obs, names = as_verify_obstacles(self.obstacles, self.frame, self.frame)
        r = verify_step(self.x, x_def64, edges=self.edges, faces=self.faces, thickness=self.thickness,
                        obstacles=obs, obstacle_names=names, max_pairs=0, start_intersections=False,
                        pre_existing=True, self_pairs=False)
        return r.n_violations == 0
