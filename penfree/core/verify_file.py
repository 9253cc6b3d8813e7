"""Verification of whole sequences and deform results, and the certificate fast path.

`verify_file` dispatches on the file: a deform result (``steps/`` present) is
checked step by step from ``positions[frame]`` to ``steps/deformed`` together
with the exact certificate of ``steps/A``; a raw sequence from frame s to s + 1.
The CLI (`penfree verify`) only parses, calls `verify_file` and prints.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..constants import DEFAULT_MAX_PAIRS, MARGIN_GAP_RADIUS_FACTOR
from ..errors import InputError
from .certificate import certify, fast_margin_bound
from .verify import (
    VerifyResult,
    _bodies,
    _Collector,
    _edge_face,
    _pairs_self,
    _thickness,
    verify_step,
)
from .topology import referenced_vertices
from .verify_reuse import listed_start_pass, result_lists

MODES = ("auto", "ccd", "certificate")
#: Margins tried (largest first) when the field-of-values bound gives none:
#: rotations beyond arccos(m) per step need a smaller m.
_MARGIN_LADDER = (0.5, 0.25, 0.1, 0.03, 0.01)
_U = 2.0**-53


def _deviation_bound(x, x_def, A, b):
    """Rigorous upper bound of max_v |x_def_v - (A x_v + b)| (exact real A x + b).

    fl(A x + b) has per-component error <= gamma_4 (sum_j |A_ij x_j| + |b_i|)
    and the subtraction adds u |x_def - y|; 8 u covers both with room.
    """
    y = x @ A.T + b
    r = np.abs(x_def - y)
    s = np.abs(x) @ np.abs(A).T + np.abs(b) + np.abs(x_def)
    e = r + 8.0 * _U * s
    return float(np.sqrt((e * e).sum(axis=1)).max() * (1.0 + 8.0 * _U)) if len(x) else 0.0


def _margin(A, need_positive):
    """A margin m with certify(A, m) True (exact), or None."""
    if not need_positive:
        return 0.0 if certify(A, 0.0) else None
    fb = fast_margin_bound(A)  # fb > m implies certify(A, m); the exact test still decides
    tries = [min(fb * (1 - 1e-6), 1 - 1e-9)] if fb > 0.01 else list(_MARGIN_LADDER)
    for m in tries:
        if certify(A, m):
            return m
    return None


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
        Reused across the steps of a result (`verify_reuse.result_lists`, built over
        this scene's E and F): the static proximity pass is answered from it.

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
    g), no pair comes within thickness along the path. With thickness 0 and
    delta 0, m = 0 suffices (M(t) nonsingular, start gaps > 0). Edge-face
    intersections at the start are checked as in `verify_step`. Obstacles
    are not moved by A: steps with obstacles always use the full CCD.
    """
    thickness = _thickness(thickness)
    scene, _ = _bodies(x_t0, x_def, edges, faces, None)
    A = np.asarray(A, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if A.shape != (3, 3) or b.shape != (3,) or not (np.isfinite(A).all() and np.isfinite(b).all()):
        raise InputError(f"A must be finite (3, 3) and b finite (3,); got {A.shape} and {b.shape}")
    delta = _deviation_bound(scene.x_t0, scene.x_t1, A, b)
    m = _margin(A, need_positive=thickness > 0 or delta > 0)
    if m is None:
        return None
    g = 0.0 if m == 0.0 else (thickness + 2.0 * delta) / m * (1.0 + 1e-9)
    if not np.isfinite(g):
        return None
    col = _Collector()
    if neighbours is None or not listed_start_pass(col, neighbours, scene.x_t0, g):
        if len(scene.F):
            _edge_face(col, "ef", scene.x_t0, scene.E, scene.F)
        _pairs_self(col, scene, g, static=True)
    if col.kinds:
        return None  # a start pair within g (maybe a real violation): full CCD decides
    sep = thickness if m == 0.0 else max(thickness, m * g / (1.0 + 1e-9) - 2.0 * delta)
    return VerifyResult(ok=True, start_ok=True, min_separation=sep, n_candidates=0,
                        edges=scene.E if len(scene.E) else None, method="certificate")


@dataclass
class StepReport:
    """One verified step: start frame, verdict, and (deform results) the certificate."""

    frame: int
    target: str
    result: VerifyResult
    certificate: bool | None = None
    margin: float | None = None
    certificate_claimed: bool = False

    @property
    def ok(self) -> bool:
        # a certificate the file claims must hold; an unclaimed one (projection "none") is informational
        return self.result.ok and not (self.certificate_claimed and self.certificate is False)

    def to_dict(self) -> dict:
        d = {"frame": self.frame, "target": self.target, "ok": self.ok, **self.result.to_dict()}
        d["ok"] = self.ok
        if self.certificate is not None or self.certificate_claimed:
            d.update(certificate=self.certificate, certificate_margin=self.margin,
                     certificate_claimed=self.certificate_claimed)
        return d


@dataclass
class VerifyReport:
    """All steps of a file."""

    origin: str
    kind: str
    thickness: float
    mode: str
    steps: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return all(s.ok for s in self.steps)

    @property
    def n_failed(self) -> int:
        return sum(not s.ok for s in self.steps)

    def to_dict(self) -> dict:
        return {"file": self.origin, "kind": self.kind, "thickness": self.thickness, "mode": self.mode,
                "ok": self.ok, "n_steps": len(self.steps), "n_failed": self.n_failed,
                "steps": [s.to_dict() for s in self.steps]}


def _selected(n_frames, frames):
    if frames is None:
        return set(range(n_frames))
    start, stop = frames
    return set(range(n_frames)[slice(start, stop)])


def _obstacles(seq, s0, s1):
    return [(ob.frame(s0), ob.frame(s1), ob.faces, ob.edges) for ob in seq.obstacles], [ob.name for ob in seq.obstacles]


def verify_sequence(seq, *, thickness=None, frames=None, max_pairs=DEFAULT_MAX_PAIRS, progress=None):
    """Verify every step s -> s + 1 of a raw sequence (both frames selected).

    Parameters
    ----------
    seq : Sequence
        Validated.
    thickness : float or None
        None: the sequence's thickness.
    frames : (start, stop) or None
        Python slice of frame indices.
    progress : callable or None
        Called once per step.

    Returns
    -------
    VerifyReport
    """
    h = _thickness(seq.thickness if thickness is None else thickness)
    sel = _selected(seq.n_frames, frames)
    rep = VerifyReport(seq.origin, "sequence", h, "ccd")
    clean_frame = None  # end frame of the last step that verified ok
    for s in range(seq.n_frames - 1):
        if s not in sel or s + 1 not in sel:
            continue
        obs, names = _obstacles(seq, s, s + 1)
        # frame s is the end state of step s - 1: if that verified ok, it is intersection-free
        r = verify_step(seq.positions[s], seq.positions[s + 1], edges=seq.edges, faces=seq.faces, thickness=h,
                        obstacles=obs, obstacle_names=names, max_pairs=max_pairs,
                        start_intersections=clean_frame != s)
        clean_frame = s + 1 if r.ok else None
        rep.steps.append(StepReport(s, f"frame {s + 1}", r))
        if progress is not None:
            progress()
    return rep


def verify_result(res, *, thickness=None, frames=None, mode="auto", max_pairs=DEFAULT_MAX_PAIRS, progress=None):
    """Verify every step of a deform result: positions[frame] -> steps/deformed, and steps/A.

    Parameters
    ----------
    res : DeformResult
    thickness : float or None
        None: the sequence's thickness.
    frames : (start, stop) or None
        Steps whose frame lies in this slice.
    mode : {"auto", "ccd", "certificate"}
        ``ccd``: full CCD for every step. ``auto``: the certificate proof of
        `verify_affine_step` where it applies (no obstacles), else full CCD.
        ``certificate``: the certificate proof only; a step it cannot prove
        is reported as not ok (never as safe). All three are sound.
    progress : callable or None

    Returns
    -------
    VerifyReport

    Notes
    -----
    The certificate reported per step is the exact ``certify(A, margin)`` with
    the margin deform uses (thickness / d0, d0 the smallest start gap; 0 when
    thickness is 0). A step fails when its path check fails, or when the file
    claims a certificate (finite ``certificate_margin`` >= 0) that does not
    hold. Obstacles are held at the step's start frame (deform moves only the
    scene).
    """
    from .pipeline import step_margin

    if mode not in MODES:
        raise InputError(f"mode must be one of {', '.join(MODES)}; got {mode!r}")
    seq = res.sequence
    h = _thickness(seq.thickness if thickness is None else thickness)
    sel = _selected(seq.n_frames, frames)
    st = res.steps
    if "deformed" not in st:
        raise InputError(f"{res.origin} holds no steps/deformed to verify in {res.origin}:/steps/deformed")
    claimed = st.get("certificate_margin")
    rep = VerifyReport(res.origin, "result", h, mode)
    nl = _result_lists(seq, mode)
    for k, s in enumerate(np.asarray(st["frame"]).tolist()):
        if s not in sel:
            continue
        x = np.asarray(seq.positions[s], dtype=np.float64)
        x_def = np.asarray(st["deformed"][k], dtype=np.float64)
        A, b = np.asarray(st["A"][k], np.float64), np.asarray(st["b"][k], np.float64)
        m, _ = step_margin(x, seq, h, None, d0=_start_gap(nl, x, seq, h))
        per_component = not np.isfinite(A).all()
        if per_component:
            # Several maps (deform --model per-component): each must be certified, and
            # only the full CCD can prove the paths between components.
            maps = _component_maps(res, k)
            cert = m is not None and all(certify(A_c, m) for A_c in maps)
        else:
            cert = certify(A, m) if m is not None else bool(np.array_equal(A, np.eye(3)))
        r = None
        if mode != "ccd" and not seq.obstacles and not per_component:
            r = verify_affine_step(x, x_def, A, b, edges=seq.edges, faces=seq.faces, thickness=h, max_pairs=max_pairs,
                                   neighbours=nl)
        if r is None and mode == "certificate":
            r = VerifyResult(ok=False, start_ok=True, min_separation=0.0, method="certificate")
        if r is None:
            obs, names = _obstacles(seq, s, s)
            r = verify_step(x, x_def, edges=seq.edges, faces=seq.faces, thickness=h, obstacles=obs,
                            obstacle_names=names, max_pairs=max_pairs)
        is_claimed = claimed is not None and bool(np.isfinite(claimed[k]) and claimed[k] >= 0)
        rep.steps.append(StepReport(s, "deformed", r, cert, None if m is None else float(m), is_claimed))
        if progress is not None:
            progress()
    return rep


def _result_lists(seq, mode):
    """One neighbour list for the start states of all steps (`verify_reuse`), or None.

    None for CCD-only runs, with obstacles (their steps take the full CCD), and for
    scenes with isolated vertices or degenerate segments, whose pair sets differ
    between the proximity stages (the fresh passes handle those).
    """
    if mode == "ccd" or seq.obstacles or seq.kind == "points":
        return None
    scene, _ = _bodies(seq.positions[0], seq.positions[0], seq.edges, seq.faces, None)
    E = scene.E
    if (E[:, 0] == E[:, 1]).any() or not referenced_vertices(scene.x_t0.shape[0], scene.F, E).all():
        return None
    return result_lists(E, scene.F)


def _start_gap(nl, x, seq, h):
    """d0 of `step_margin` from the list (equal to the fresh `min_separation`), or None."""
    if nl is None or h <= 0:
        return None
    return float(nl.separations(x, MARGIN_GAP_RADIUS_FACTOR * h).min())


def _component_maps(res, k):
    """Distinct per-component maps of step k (``component_maps/A``), for a step whose
    ``steps/A`` is NaN; a NaN A without them is unusable input."""
    comp = res.groups.get("component_maps", {})
    if "A" not in comp or not np.isfinite(comp["A"][k]).all():
        raise InputError(f"steps/A of step {k} is not finite and no finite per-component maps were found "
                         f"in {res.origin}:/component_maps/A")
    return list(np.unique(np.asarray(comp["A"][k], dtype=np.float64), axis=0))


def verify_file(path, *, thickness=None, frames=None, mode="auto", max_pairs=DEFAULT_MAX_PAIRS, progress=None):
    """Verify a deform result or a raw sequence file (any readable format).

    Parameters
    ----------
    path : str or Path
    thickness : float or None
        None: the file's thickness attribute, else 0.
    frames : (start, stop) or None
    mode : {"auto", "ccd", "certificate"}
        For deform results (see `verify_result`); raw sequences always use CCD.
    max_pairs : int
    progress : callable or None
        Called once per step.

    Returns
    -------
    VerifyReport

    Examples
    --------
    >>> rep = verify_file("deformed.h5")                 # doctest: +SKIP
    >>> rep.ok, rep.n_failed                             # doctest: +SKIP
    (True, 0)
    """
    from ..formats import read_sequence
    from ..formats.result import is_result_file, read_result

    if mode not in MODES:
        raise InputError(f"mode must be one of {', '.join(MODES)}; got {mode!r}")
    if is_result_file(path):
        return verify_result(read_result(path), thickness=thickness, frames=frames, mode=mode,
                             max_pairs=max_pairs, progress=progress)
    seq = read_sequence(path)
    return verify_sequence(seq, thickness=thickness, frames=frames, max_pairs=max_pairs, progress=progress)


def n_steps(path, frames=None) -> int:
    """Number of steps `verify_file` will check (for a progress bar); 0 if unknown."""
    try:
        import h5py

        with h5py.File(path, "r") as f:
            if "steps/frame" in f:
                fr = f["steps/frame"][()]
                sel = _selected(f["positions"].shape[0], frames)
                return int(sum(int(s) in sel for s in fr))
            T = f["positions"].shape[0]
            sel = _selected(T, frames)
            return sum(s in sel and s + 1 in sel for s in range(T - 1))
    except Exception:  # not HDF5 or unreadable here: the real reader reports it
        return 0

