"""`VerifyResult`: the verdict of one verified step (`penfree.core.verify.path.verify_step`,
`penfree.core.verify.affine.verify_affine_step`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np


@dataclass
class VerifyResult:
    """Verdict of one step.

    Attributes
    ----------
    ok : bool
        True iff the start state is clean and no pair comes within `thickness`
        along the path.
    start_ok : bool
    start_violations : list of (kind, i, j)
        First start-state violations (at most `max_pairs`), see the module docstring.
    n_start_violations : int
    pairs : list of (kind, i, j, toi)
        First path violations sorted by toi (a lower bound of the time of
        contact in [0, 1]), at most `max_pairs`.
    n_violations : int
        Number of violating pairs along the path (all of them; with thickness
        0, flagged pairs beyond `CCD_MAX_EXACT` per block of candidates are
        counted without the exact decision, i.e. conservatively).
    min_separation : float
        Certified lower bound of the distance between any two checked
        primitives over the whole path: the smallest of the per-pair lower
        bounds proven by the CCD (0 for violating pairs, and for pairs that
        only the exact decision could separate) and of the thickness, which
        bounds every pair the broad phase did not pass on (so never +inf,
        and never above the true minimum distance of any pair).
    n_candidates : int
        Pairs that went through the narrow phase along the path.
    edges : (E, 2) int64 or None
        The edges the ``"ee"``/``"ef"`` indices refer to (given edges, or the
        edges of the faces when faces are given).
    method : str
        ``"ccd"`` or ``"certificate"`` (see `verify_affine_step`).
    pre_existing : list of (kind, i, j)
        With ``pre_existing=True`` (deform results): first pairs that already touch
        or intersect at the start and that the path leaves as they were.
    n_pre_existing : int
    """

    ok: bool
    start_ok: bool
    start_violations: list = field(default_factory=list)
    n_start_violations: int = 0
    pairs: list = field(default_factory=list)
    n_violations: int = 0
    min_separation: float = np.inf
    n_candidates: int = 0
    edges: Optional[np.ndarray] = field(default=None, repr=False)
    method: str = "ccd"
    pre_existing: list = field(default_factory=list)
    n_pre_existing: int = 0

    def to_dict(self) -> dict:
        """JSON-ready summary (no arrays)."""
        return {
            "ok": bool(self.ok),
            "start_ok": bool(self.start_ok),
            "n_start_violations": int(self.n_start_violations),
            "start_violations": [[k, int(i), int(j)] for k, i, j in self.start_violations],
            "n_violations": int(self.n_violations),
            "pairs": [[k, int(i), int(j), float(t)] for k, i, j, t in self.pairs],
            "min_separation": float(self.min_separation),
            "n_candidates": int(self.n_candidates),
            "method": self.method,
            "n_pre_existing": int(self.n_pre_existing),
            "pre_existing": [[k, int(i), int(j)] for k, i, j in self.pre_existing],
        }
