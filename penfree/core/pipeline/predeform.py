"""`predeform`: the one call a simulator loop makes before its collision detection.

The integration contract (README, "Using penfree inside a simulator"):

1. call ``r = penfree.predeform(x_prev, x, edges=..., faces=..., contact_radius=dhat,
   thickness=...)`` at the start of the step, before the first CD pass;
2. start the step from ``r.x_def`` instead of ``x``: the straight path from ``x`` to
   ``r.x_def`` is certified penetration-free and clear of the obstacles (the map
   passed the step gate of `deform`, `penfree.core.verify.gate.StepGate`);
3. **keep the query radius** ``r.query_radius`` (``max(2 dhat, max_v |x_pred - x|)``,
   computed at the recorded ``x``, *before* the move) as the client's inflation
   radius for the whole step: with ipctk, set ``trust_region_inflation_radius`` to it
   and call ``update`` instead of ``warm_start_time_step`` (which would recompute the
   radius from ``|x_pred - x_def|``). A client that recomputes it (the ``own`` rule)
   shrinks every free vertex's cap when ``x_def`` is close to ``x_pred`` and can need
   *more* CD passes than without penfree (BENCHMARKS.md, "Real-client CD passes").
   A simulator that must call ``warm_start_time_step`` anyway passes
   ``radius_rule="own"``: the candidates are then replayed under that rule, and doing
   nothing wins wherever a map would cost passes there.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ... import constants as K
from ...errors import InputError
from ...sequence import Sequence
from ..trust.client import inflation_radius
from ..trust.client_stats import resolve_dhat
from .client_select import ClientModel
from .deform import required_margin, run_step
from .strategy import Auto


@dataclass
class Predeformed:
    """Result of `predeform`.

    Attributes
    ----------
    x_def : (N, 3) ndarray, dtype of `x`
        Where the simulator starts the step.
    A : (3, 3) float64
    b : (3,) float64
        The applied map ``x_def = A x + b`` (up to rounding); the identity when
        doing nothing was best.
    query_radius : float
        Rule ``step``: the inflation radius the client must keep for this step,
        computed at ``x``. Rule ``own``: the radius ipctk's warm start computes from
        ``x_def``, ``max(2 dhat, max_v |x_pred - x_def|)``.
    model : str
        The applied candidate (``"none"``: x_def is x; ``...-short0.5``: a shortened
        step, when the preferred map failed the gate).
    certificate_margin : float
    table : list of dict
        The candidates and their predictions (`penfree.core.fit.auto.candidate_table`).
    """

    x_def: np.ndarray
    A: np.ndarray
    b: np.ndarray
    query_radius: float
    model: str
    certificate_margin: float
    table: list = field(default_factory=list)


def predeform(x_prev, x, *, edges=None, faces=None, contact_radius=0.0, thickness=0.0, obstacles=None,
              bounds=None, truncation="isotropic", weights=None, radius_rule="step") -> Predeformed:
    """Certified pre-deformation of one step, chosen by the client's predicted CD passes.

    Parameters
    ----------
    x_prev, x : (N, 3) float
        Positions at the previous and the current step (the target is
        ``x_pred = 2 x - x_prev``).
    edges : (E, 2) int, optional
    faces : (F, 3) int, optional
        Topology (at least one of them).
    contact_radius : float
        The simulator's contact offset ``dhat`` (ipctk ``TrustRegion(dhat)``); 0 takes
        the thickness.
    thickness : float
        Hard minimum separation (ipctk ``min_distance``).
    obstacles : list of penfree.Obstacle, optional
        Half-spaces, and mesh obstacles at the current frame (static ``(M, 3)``
        positions). The applied map keeps every vertex path at least `thickness` from
        them, exactly as `penfree deform` does (half-spaces exactly, meshes by CCD),
        and they are in the predicted client's collision mesh (`client_scene`).
    bounds : (N,) float, optional
        The per-vertex OGC bounds ``0.45 (d_v - thickness)`` the simulator already
        has at `x` (its last CD pass, with a query radius at least the step's): they
        replace penfree's own neighbourhood query in the prediction (never in the
        safety checks).
    truncation : {"isotropic", "planar"}
        The client's filter (`client_select.ClientModel`).
    weights : (N,) float, optional
        Fit weights (e.g. masses).
    radius_rule : {"step", "own"}
        The client's radius rule (`client_select.ClientModel.radius`): ``step``, the
        simulator keeps `query_radius` (the contract above); ``own``, it calls
        ``warm_start_time_step`` from `x_def`, and the candidates are replayed that way.

    Returns
    -------
    Predeformed

    Notes
    -----
    One step of `penfree deform --model auto --client-model TRUNCATION`: the certified
    candidates (the model ladder, clamps and blends toward ``x_pred``, and
    ``rigid-repeat``, the step's own rigid motion applied again), ordered by the
    client's replayed CD passes under `radius_rule` toward the co-rotated
    target (`client_select.corotated_target`; doing nothing stays a candidate and wins
    ties), then shortened steps,
    then doing nothing; the first that passes the step gate (certificate, near-pair
    CCD with the thickness, obstacles) is applied. Under rule ``step`` keep
    ``query_radius`` (module doc): a client that recomputes it can turn the savings
    into losses unless it was predicted for (``radius_rule="own"``).

    Examples
    --------
    >>> import numpy as np
    >>> x = np.zeros((4, 3)); x[:, 0] = np.arange(4.0)
    >>> r = predeform(x - [0, 0, 0.01], x, edges=[[0, 1], [2, 3]], contact_radius=0.1)
    >>> r.model, round(r.query_radius, 3)
    ('none', 0.2)
    """
    xp_arr, x_arr = np.asarray(x_prev), np.asarray(x)
    for name, a in (("x_prev", xp_arr), ("x", x_arr)):
        if a.dtype.kind not in "iuf":
            raise InputError(f"{name} must be real numbers; got dtype {a.dtype}")
    if xp_arr.shape != x_arr.shape:
        raise InputError(f"x_prev and x must have the same (N, 3) shape; got {xp_arr.shape} and {x_arr.shape}")
    # float32 only when both are: an integer or mixed pair is computed (and returned) in float64.
    dtype = np.float32 if xp_arr.dtype == x_arr.dtype == np.float32 else np.float64
    seq = Sequence(positions=np.stack([xp_arr.astype(dtype), x_arr.astype(dtype)]), edges=edges, faces=faces,
                   weights=weights, thickness=thickness, contact_radius=contact_radius,
                   obstacles=list(obstacles or []), origin="predeform").validate()
    if seq.kind == "points":
        raise InputError("predeform needs edges or faces (the client's collision mesh)")
    if not (seq.contact_radius > 0 or seq.thickness > 0):
        raise InputError("predeform needs the simulator's contact offset: contact_radius > 0 (ipctk "
                         "TrustRegion's dhat) or thickness > 0; got both 0")
    dhat = resolve_dhat(None, seq.contact_radius, seq.thickness)
    x64 = np.asarray(seq.positions[1], dtype=np.float64)
    x_pred = 2.0 * x64 - np.asarray(seq.positions[0], dtype=np.float64)
    d_start = None
    if bounds is not None:
        b = np.asarray(bounds)
        if b.shape != (x64.shape[0],) or b.dtype.kind not in "iuf" or not np.isfinite(b).all() or (b < 0).any():
            raise InputError(f"bounds must be ({x64.shape[0]},) real, finite and >= 0; got {b.shape} {b.dtype}")
        b = b.astype(np.float64)
        d_start = b / K.DEFAULT_GAMMA + seq.thickness
    cm = ClientModel(truncation=truncation, dhat=dhat, edges=seq.edges, faces=seq.faces, radius=radius_rule,
                     obstacles=tuple(seq.obstacles))
    strategy = Auto(seq, "auto", seq.thickness, 1, client_model=cm, d_start=d_start)
    _, o = run_step(seq, 1, strategy, required_margin(seq.thickness), seq.thickness, seq.weights,
                    seq.contact_radius)
    at = x64 if radius_rule == "step" else np.asarray(o.x_def, dtype=np.float64)
    return Predeformed(o.x_def, np.asarray(o.A, dtype=np.float64), np.asarray(o.b, dtype=np.float64),
                       inflation_radius(at, x_pred, dhat), o.model, o.certificate_margin,
                       o.extra.get("table") or [])
