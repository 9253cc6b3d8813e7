"""`predeform`: the one call a simulator loop makes before its collision detection.

The integration contract (README, "Using penfree inside a simulator"):

1. call ``r = penfree.predeform(x_prev, x, edges=..., faces=..., contact_radius=dhat,
   thickness=...)`` at the start of the step, before the first CD pass;
2. start the step from ``r.x_def`` instead of ``x``: the straight path from ``x`` to
   ``r.x_def`` is certified penetration-free (the map passed
   `certificate.certify_map`);
3. **keep the query radius** ``r.query_radius`` (``max(2 dhat, max_v |x_pred - x|)``,
   computed at the recorded ``x``, *before* the move) as the client's inflation
   radius for the whole step: with ipctk, set ``trust_region_inflation_radius`` to it
   and call ``update`` instead of ``warm_start_time_step`` (which would recompute the
   radius from ``|x_pred - x_def|``). A client that recomputes it (the ``own`` rule)
   shrinks every free vertex's cap when ``x_def`` is close to ``x_pred`` and can need
   *more* CD passes than without penfree (BENCHMARKS.md, "Real-client CD passes").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np

from .. import constants as K
from ..errors import InputError
from . import fit as _fit
from .client import inflation_radius
from .client_select import ClientModel
from .pipeline import step_margin
from .selection import select_step
from .stats import query_radius as _stats_query_radius
from .trust_region import per_vertex_separation, scene_arrays


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
        The inflation radius the client must keep for this step (rule ``step``).
    model : str
        The chosen candidate (``"none"``: x_def is x).
    certificate_margin : float
    obstacles_note : str
        Why obstacles forced doing nothing, else ``""``.
    table : list of dict
        The candidates and their predictions (`select_step`).
    """

    x_def: np.ndarray
    A: np.ndarray
    b: np.ndarray
    query_radius: float
    model: str
    certificate_margin: float
    obstacles_note: str = ""
    table: list = field(default_factory=list)


def _half_space_ok(obstacle, x, x_def, thickness):
    """Both ends of every vertex path on the free side, no closer than before or the thickness."""
    n = np.asarray(obstacle.normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    off = float(obstacle.offset)
    g0 = x @ n - off
    g1 = np.asarray(x_def, dtype=np.float64) @ n - off
    need = np.minimum(g0, thickness)
    return bool(np.all(g1 >= need) and np.all(g1 > 0))


def predeform(x_prev, x, *, edges=None, faces=None, contact_radius=0.0, thickness=0.0, obstacles=None,
              bounds=None, truncation="isotropic", weights=None) -> Predeformed:
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
        Half-spaces are checked exactly (both ends of every vertex path on the free
        side, at least `thickness` away unless the start was closer); with any mesh
        obstacle the call does nothing (``x_def = x``), which is always safe against
        static obstacles, until the obstacle-aware selection lands.
    bounds : (N,) float, optional
        The per-vertex OGC bounds ``0.45 (d_v - thickness)`` the simulator already
        has at `x` (its last CD pass, with query radius >= the step's); saves
        penfree's own neighbourhood query.
    truncation : {"isotropic", "planar"}
        The client's filter (`client_select.ClientModel`).
    weights : (N,) float, optional
        Fit weights (e.g. masses).

    Returns
    -------
    Predeformed

    Notes
    -----
    The choice is `selection.select_step` with a `client_select.ClientModel` under
    the radius rule ``step``: doing nothing stays a candidate and wins ties. Keep
    ``query_radius`` (module doc): with the ``own`` rule the savings can turn into
    losses.

    Examples
    --------
    >>> import numpy as np
    >>> x = np.zeros((4, 3)); x[:, 0] = np.arange(4.0)
    >>> r = predeform(x - [0, 0, 0.01], x, edges=[[0, 1], [2, 3]], contact_radius=0.1)
    >>> r.model, round(r.query_radius, 3)
    ('none', 0.2)
    """
    x_arr = _fit.as_positions(x, "x")
    x_prev = _fit.as_positions(x_prev, "x_prev", x_arr.shape[0])
    x64 = np.asarray(x_arr, dtype=np.float64)
    _, E, F = scene_arrays(x64, edges, faces)
    if not (E.shape[0] or F.shape[0]):
        raise InputError("predeform needs edges or faces (the client's collision mesh)")
    thickness = float(thickness)
    dhat = float(contact_radius) if contact_radius else thickness
    if not (math.isfinite(dhat) and dhat > 0):
        raise InputError(f"predeform needs contact_radius > 0 (or a thickness); got {contact_radius}, {thickness}")
    x_pred = 2.0 * x64 - np.asarray(x_prev, dtype=np.float64)
    R = inflation_radius(x64, x_pred, dhat)
    r_q = _stats_query_radius(x64, x_pred, thickness)
    if bounds is not None:
        b = np.asarray(bounds, dtype=np.float64)
        if b.shape != (x64.shape[0],):
            raise InputError(f"bounds must be ({x64.shape[0]},); got {b.shape}")
        d_start = np.minimum(r_q, b / K.DEFAULT_GAMMA + thickness)
    else:
        d_start = per_vertex_separation(x64, E, F, r_q)
    kind = "triangles" if F.shape[0] else "segments"
    scene = SimpleNamespace(kind=kind, edges=edges, faces=faces)
    m, _ = step_margin(x64, scene, thickness, None, d0=float(d_start.min()) if d_start.size else r_q)
    identity = Predeformed(np.array(x_arr), np.eye(3), np.zeros(3), R, "none", 1.0)
    obstacles = list(obstacles or [])
    if m is None:
        identity.obstacles_note = "start state within the thickness: doing nothing"
        return identity
    if any(not ob.is_half_space for ob in obstacles):
        identity.obstacles_note = "mesh obstacles: doing nothing (always safe against static obstacles)"
        return identity
    cm = ClientModel(truncation=truncation, dhat=dhat, edges=edges, faces=faces)
    res, table = select_step(x_prev, x_arr, d_start, r_q=r_q, thickness=thickness, weights=weights, margin=m,
                             client_model=cm)
    for ob in obstacles:
        if not _half_space_ok(ob, x64, res.x_def, thickness):
            identity.obstacles_note = "a half-space obstacle would be approached: doing nothing"
            identity.table = table
            return identity
    return Predeformed(res.x_def, res.A, res.b, R, res.model, res.certificate_margin, "", table)
