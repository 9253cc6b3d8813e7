"""The affine certificate path of step verification: prove an affine step safe from the
exact certificate of its map plus a static start-gap check, without CCD along the path.

`verify_affine_step` never claims a step safe that `penfree.core.verify.path.verify_step`
would not; when its proof does not apply it returns None and the caller runs the full CCD.
"""

from __future__ import annotations

import numpy as np

from ...constants import DEFAULT_MAX_PAIRS, UNIT_ROUNDOFF
from ...errors import InputError
from ..contact.broad_phase import start_pass
from ..fit.certificate import certify
from .gate import deviation_bound, positive_margin
from .reuse import apart_sq, listed_start_pass
from .path import _bodies, _Collector, _inflation, _pairs_self, check_thickness, edge_face_exact
from .result import VerifyResult


def _margin(A, need_positive):
    """A margin m with certify(A, m) True (exact), or None."""
    if not need_positive:
        return 0.0 if certify(A, 0.0) else None
    return positive_margin(A)


def _start_pass(col, scene, g, relabel=None):
    """The start state's edge-face intersections into `col` (as `path._edge_face`), and
    True when every vertex-face and edge-edge pair is proven more than `g` apart: the
    computed distances of the pairs whose boxes come within g (folded, no pair stored,
    no CCD; `broad_phase.start_pass`) all above `reuse.apart_sq` (far above the distance
    kernels' rounding). False means "maybe within g": the static CCD then decides. The
    folds start at twice that distance (`start_pass`'s cap): pairs provably farther
    apart are not evaluated, and the answer is the uncapped one. `relabel`: the scene's
    `locality.Relabelling`, the pass run on it (the same pairs and minimum)."""
    x = scene.x_t0
    apart = apart_sq(g, x)
    run = (x, scene.E, scene.F, scene.V) if relabel is None else (
        relabel.positions(x), relabel.E, relabel.F, relabel.inv[scene.V])
    cand, d2 = start_pass(*run, _inflation(g, x), cap_sq=4.0 * apart)
    if relabel is not None:
        cand = relabel.edge_face_to_caller(cand)
    if len(cand):
        edge_face_exact(col, "ef", x, scene.E, scene.F, cand[:, 0], cand[:, 1])
    return d2 > apart


def verify_affine_step(x_t0, x_def, A, b, *, edges=None, faces=None, thickness=0.0,
                       max_pairs=DEFAULT_MAX_PAIRS, neighbours=None):
    """Prove an affine step safe from its certificate; None when the proof does not apply.

    Parameters
    ----------
    x_t0 : (N, 3) float
        Start positions.
    x_def : (N, 3) float
        End positions, ``A x_t0 + b`` up to rounding (as stored by deform).
    A : (3, 3) float64
    b : (3,) float64
    edges, faces, thickness, max_pairs
        As in `verify_step`.
    neighbours : NeighbourList, optional
        Reused across the steps of a result (`penfree.core.verify.reuse.result_lists`,
        built over this scene's E and F): the static proximity pass is answered from it,
        or, where its cost model declines, run fresh on its scene's relabelling when the
        scene's labels carry no locality (`NeighbourList.relabelling`).

    Returns
    -------
    VerifyResult or None
        ``ok=True, method="certificate"`` when proven; None otherwise (then
        run `verify_step`, which is always sound). Never claims a step safe
        that `verify_step` would not.

    Notes
    -----
    Soundness. Let M(t) = (1 - t) I + t A, delta >= max_v |x_def_v - (A x_v + b)|
    (bounded rigorously in floating point), and m a margin with the exact
    ``certify(A, m)``: sigma_min(M(t)) > m on [0, 1]. For points p, q of two
    non-adjacent primitives (convex combinations of their vertices), the path
    x + t (x_def - x) moves them to M(t) p + t b + t e_p and M(t) q + t b + t e_q
    with |e_p|, |e_q| <= delta, so their distance at t is at least
    m |p - q| - 2 delta. Hence, if every vertex-face and edge-edge pair is at
    least g = (thickness + 2 delta) / m apart at the start (proven by the static
    conservative CCD run with thickness g on all pairs whose boxes come within
    g, or, first, by their computed distances exceeding g by far more than the
    distance kernels' rounding), no pair comes within thickness along the path. With thickness 0 and
    delta 0, m = 0 suffices (M(t) nonsingular, start gaps > 0). Edge-face
    intersections at the start are checked as in `verify_step`. Obstacles
    are not moved by A: steps with obstacles always use the full CCD.
    """
    thickness = check_thickness(thickness)
    scene = _bodies(x_t0, x_def, edges, faces, None)[0]
    A = np.asarray(A, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if A.shape != (3, 3) or b.shape != (3,):
        raise InputError(f"the map must be A (3, 3) and b (3,); got A {A.shape} and b {b.shape}")
    if not (np.isfinite(A).all() and np.isfinite(b).all()):
        bad = " and ".join(n for n, v in (("A", A), ("b", b)) if not np.isfinite(v).all())
        raise InputError(f"the map must be finite; {bad} holds NaN or Inf")
    delta = deviation_bound(scene.x_t0, scene.x_t1, A, b)
    m = _margin(A, need_positive=thickness > 0 or delta > 0)
    if m is None:
        return None
    g = 0.0 if m == 0.0 else (thickness + 2.0 * delta) / m * (1.0 + 1e-9)
    if not np.isfinite(g):
        return None
    col = _Collector()
    if neighbours is None or not listed_start_pass(col, neighbours, scene.x_t0, g):
        relabel = None if neighbours is None else neighbours.relabelling(scene.x_t0)
        if not _start_pass(col, scene, g, relabel) and not col.kinds:
            _pairs_self(col, scene, g, static=True)
    if col.kinds:
        return None  # a start pair within g (maybe a real violation): full CCD decides
    sep = thickness if m == 0.0 else max(thickness, m * g / (1.0 + 1e-9) - 2.0 * delta)
    return VerifyResult(ok=True, start_ok=True, min_separation=sep, n_candidates=0,
                        edges=scene.E if len(scene.E) else None, method="certificate")
