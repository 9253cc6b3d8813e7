"""Verification of whole sequences and deform results, and the certificate fast path.

`verify_file` dispatches on the file: a deform result (``steps/`` present) is
checked step by step from ``positions[frame]`` to ``steps/deformed`` together
with the exact certificate of ``steps/A``; a raw sequence from frame s to s + 1.
The CLI (`penfree verify`) only parses, calls `verify_file` and prints.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ...constants import DEFAULT_MAX_PAIRS
from ...errors import InputError
from ..contact.obstacles import as_verify_obstacles
from ..fit.certificate import certify
from ..topology import as_topology, referenced_vertices, scene_edges
from ..verify.affine import verify_affine_step
from ..verify.gate import margin_rule
from ..verify.path import check_thickness, verify_step
from ..verify.result import VerifyResult
from ..verify.reuse import result_lists

MODES = ("auto", "ccd", "certificate")


@dataclass
class StepReport:
    """One verified step: start frame, verdict, and (deform results) the certificate."""

    frame: int
    target: str
    result: VerifyResult
    certificate: bool | None = None
    margin: float | None = None
    certificate_claimed: bool = False
    strict: bool = False

    @property
    def ok(self) -> bool:
        # a certificate the file claims must hold; an unclaimed one (projection "none") is informational
        if self.strict and self.result.n_pre_existing:
            return False
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

    @property
    def n_started_dirty(self) -> int:
        """Steps whose start state already held intersections (pre-existing, deform results)."""
        return sum(s.result.n_pre_existing > 0 for s in self.steps)

    def to_dict(self) -> dict:
        return {"file": self.origin, "kind": self.kind, "thickness": self.thickness, "mode": self.mode,
                "ok": self.ok, "n_steps": len(self.steps), "n_failed": self.n_failed,
                "n_started_dirty": self.n_started_dirty,
                "steps": [s.to_dict() for s in self.steps]}


def _selected(n_frames, frames):
    if frames is None:
        return set(range(n_frames))
    start, stop = frames
    return set(range(n_frames)[slice(start, stop)])


def _obstacles(seq, s0, s1):
    return as_verify_obstacles(seq.obstacles, s0, s1)


def _check_something_to_verify(seq) -> None:
    """InputError for a scene of bare points without obstacles: no pair of it can come
    close, so "all steps safe" would be said of nothing (SPEC section 2: verify needs
    edges or faces). Points against obstacles are checked."""
    if seq.kind == "points" and not seq.obstacles:
        raise InputError(f"verify needs edges (E, 2) or faces (F, 3), or obstacles, to check; got none "
                         f"(only {seq.n_vertices} points) in {seq.origin}:/faces")


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
    _check_something_to_verify(seq)
    h = check_thickness(seq.thickness if thickness is None else thickness)
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
        rep.steps.append(StepReport(s, f"frame {s + 1}", _shared_edges(r, rep)))
        if progress is not None:
            progress()
    return rep


def verify_result(res, *, thickness=None, frames=None, mode="auto", max_pairs=DEFAULT_MAX_PAIRS, progress=None,
                  strict=False):
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
        `verify_affine_step` where it applies (no obstacles, clean start), else full
        CCD. ``certificate``: the certificate proof only; a step it cannot prove is
        reported as not ok (never as safe). All three are sound.
    progress : callable or None
    strict : bool
        Pre-existing intersections of a start state fail the step.

    Returns
    -------
    VerifyReport

    Notes
    -----
    The guarantee checked is deform's (SPEC section 6): the start state is not
    judged, the path must add no new intersecting or thickness-violating pair; pairs
    that already touch or intersect at the start are reported as pre-existing. The
    certificate reported per step is the exact ``certify(A, margin_rule(thickness))``
    of every applied map. A step fails when its path check fails, or when the file
    claims a certificate (finite ``certificate_margin`` >= 0) that does not hold.
    Obstacles are held at the step's start frame (deform moves only the scene).
    """
    if mode not in MODES:
        raise InputError(f"mode must be one of {', '.join(MODES)}; got {mode!r}")
    seq = res.sequence
    _check_something_to_verify(seq)
    h = check_thickness(seq.thickness if thickness is None else thickness)
    m = margin_rule(h)
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
        per_component = not np.isfinite(A).all()
        maps = _component_maps(res, k) if per_component else [A]
        cert = all(certify(A_c, m) for A_c in maps)
        r = None
        if mode != "ccd" and not seq.obstacles and not per_component:
            r = verify_affine_step(x, x_def, A, b, edges=seq.edges, faces=seq.faces, thickness=h, max_pairs=max_pairs,
                                   neighbours=nl)
        if r is None and mode == "certificate":
            r = VerifyResult(ok=False, start_ok=True, min_separation=0.0, method="certificate")
        if r is None:
            r = verify_deformed_path(seq, s, x_def, h, max_pairs)
        is_claimed = claimed is not None and bool(np.isfinite(claimed[k]) and claimed[k] >= 0)
        rep.steps.append(StepReport(s, "deformed", _shared_edges(r, rep), cert, float(m), is_claimed, strict))
        if progress is not None:
            progress()
    return rep


def verify_deformed_path(seq, s, x_def, thickness, max_pairs=DEFAULT_MAX_PAIRS):
    """The full check of a result's step: the path ``positions[s] -> x_def`` by CCD, obstacles
    held at frame s, pairs that start closer than `thickness` (or intersecting) keeping
    their state (SPEC section 6). A `VerifyResult`."""
    obs, names = _obstacles(seq, s, s)
    return verify_step(np.asarray(seq.positions[s], dtype=np.float64), np.asarray(x_def, dtype=np.float64),
                       edges=seq.edges, faces=seq.faces, thickness=thickness, obstacles=obs,
                       obstacle_names=names, max_pairs=max_pairs, pre_existing=True)


def _shared_edges(r, rep):
    """`r` holding the edges array of the report's last step when its edges equal them:
    each step's check makes the scene's edges anew, and a report of thousands of steps held
    thousands of copies (0.4 MB a step at 8K vertices)."""
    E = rep.steps[-1].result.edges if rep.steps else None
    if r.edges is not None and E is not None and r.edges.shape == E.shape and np.array_equal(r.edges, E):
        r.edges = E
    return r


def _result_lists(seq, mode):
    """One neighbour list for the start states of all steps (`verify.reuse`), or None.

    None for CCD-only runs, with obstacles (their steps take the full CCD), and for
    scenes with isolated vertices, whose pair sets differ between the proximity
    stages (the fresh passes handle those).
    """
    if mode == "ccd" or seq.obstacles or seq.kind == "points":
        return None
    n = seq.n_vertices
    F = as_topology(seq.faces, 3, n, "faces") if seq.faces is not None else np.zeros((0, 3), np.int64)
    E = scene_edges(as_topology(seq.edges, 2, n, "edges") if seq.edges is not None else np.zeros((0, 2), np.int64), F)
    if not referenced_vertices(n, F, E).all():
        return None
    return result_lists(E, F)


def check_component_maps(res) -> None:
    """Raise the InputError `verify_result` raises at its first per-component step (``steps/A``
    not finite) whose maps it cannot use, without verifying anything: the per-step tables
    and groups suffice (`formats.result.read_result_tables`)."""
    A = np.asarray(res.steps["A"], dtype=np.float64)
    for k in range(A.shape[0]):
        if not np.isfinite(A[k]).all():
            _component_maps(res, k)


def _component_maps(res, k):
    """The distinct maps of per-component step k (``component_maps/A``, validated): a step
    whose ``steps/A`` is NaN needs them."""
    where = f"{res.origin}:/component_maps/A"
    comp = res.groups.get("component_maps")
    A = comp.get("A") if isinstance(comp, dict) else None
    A = None if A is None or isinstance(A, dict) else np.asarray(A)
    S = len(res.steps["frame"])
    row = k if res.rows is None else int(res.rows[k])  # the file's row (a frame window's read)
    if A is None or A.dtype.kind not in "iuf" or A.ndim != 4 or A.shape[0] != S or A.shape[2:] != (3, 3):
        got = "nothing" if A is None else f"{A.shape} {A.dtype}"
        raise InputError(f"steps/A of step {row} is NaN (a per-component step): component_maps/A must be "
                         f"({S}, C, 3, 3) numeric; got {got} in {where}")
    if not np.isfinite(A[k]).all():
        raise InputError(f"steps/A of step {row} is not finite and no finite per-component maps were found in {where}")
    return list(np.unique(A[k].astype(np.float64), axis=0))


def verify_file(path, *, thickness=None, frames=None, mode="auto", max_pairs=DEFAULT_MAX_PAIRS, progress=None,
                strict=False, prims=None, obstacles=None, window=None):
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
    strict : bool
        Deform results: pre-existing intersections of a start state fail the step.
    prims, obstacles : sequence of str, optional
        Raw USD stages: the prims read as the scene and as obstacles (as for
        ``penfree deform --prim/--obstacle``); ignored for other formats.
    window : (start, stop), optional
        HDF5 files: read only the frames ``start .. stop - 1`` and verify the steps
        among them (a result's steps from those frames, a raw sequence's steps between
        two of them; `frames` then selects within the window, in its numbering). The
        report numbers frames as the file does. A frame range of a long recording
        (`penfree.scaleout`).

    Returns
    -------
    VerifyReport

    Examples
    --------
    >>> rep = verify_file("deformed.h5")                 # doctest: +SKIP
    >>> rep.ok, rep.n_failed                             # doctest: +SKIP
    (True, 0)
    """
    from ...formats import read_sequence
    from ...formats.result import is_result_file, read_result

    if mode not in MODES:
        raise InputError(f"mode must be one of {', '.join(MODES)}; got {mode!r}")
    if is_result_file(path):
        if prims or obstacles:
            raise InputError(f"--prim and --obstacle choose prims of a USD stage; {path} is a deform result "
                             f"(its scene and obstacles are stored in it)")
        rep = verify_result(read_result(path, window=window), thickness=thickness, frames=frames, mode=mode,
                            max_pairs=max_pairs, progress=progress, strict=strict)
    else:
        if window is None:
            seq = read_sequence(path, prims=prims, obstacles=obstacles)
        else:
            seq = read_sequence(path, format="hdf5", frame_window=window)
        rep = verify_sequence(seq, thickness=thickness, frames=frames, max_pairs=max_pairs, progress=progress)
    return rep if window is None else _renumbered(rep, int(window[0]))


def _renumbered(rep, first):
    """`rep` of a frame window whose frame 0 is the file's frame `first`, in the file's numbers."""
    for k, st in enumerate(rep.steps):
        target = f"frame {st.frame + first + 1}" if rep.kind == "sequence" else st.target
        rep.steps[k] = replace(st, frame=st.frame + first, target=target)
    return rep


def n_steps(path, frames=None) -> int:
    """Number of steps `verify_file` will check (for a progress bar); 0 if unknown."""
    try:
        import h5py

        with h5py.File(path, "r") as f:
            if "steps/frame" in f:
                fr = f["steps/frame"][()]
                if not isinstance(fr, np.ndarray) or fr.dtype.kind not in "iu":
                    return 0  # unusable: the reader reports it
                sel = _selected(f["positions"].shape[0], frames)
                return int(sum(int(s) in sel for s in fr))
            T = f["positions"].shape[0]
            sel = _selected(T, frames)
            return sum(s in sel and s + 1 in sel for s in range(T - 1))
    except Exception:  # not HDF5 or unreadable here: the real reader reports it
        return 0

