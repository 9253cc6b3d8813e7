"""`auto` by the client: the candidate map with the fewest predicted client CD passes.

The static prediction of `selection` holds the bounds fixed and compares every
vertex with ``x_pred``. What a simulator's OGC client actually spends depends on
two things it misses:

* **the radius cap.** The client's inflation radius caps every vertex's region.
  Under the radius rule ``step`` (how a pre-deformation is integrated: the
  simulator keeps the radius it computed at ``x``) the cap is the same for every
  candidate; under ``own`` it shrinks when ``x_def`` is closer to ``x_pred``.
* **contact vertices that should not move.** Vertices in contact (start separation
  within `CONTACT_HOLD_FACTOR` contact radii) barely move in reality: the solver
  holds them, whatever ``x_pred`` says. A map that moves them spends their small
  bounds and costs passes to bring them back.

The predictor therefore replays each shortlisted candidate through penfree's own
client (`client.replay_step` with ``client="own"``: the same warm start, filters and
1% update rule as ``ipctk.ogc.TrustRegion``; ``ClientModel.predictor="ipctk"``
replays through ipctk itself), warm-starting toward ``x_pred`` and iterating toward
the *held target* ``y_hat`` (`corotated_target` for free vertices: ``x_pred`` with
the step's rotation continued, ``x`` for contact vertices), and again toward
``(x + y_hat) / 2`` (the solver stopping half-way: contacts, damping, turning
motion). The score is the sum of the two pass counts. Besides the shortlist (the
best static predictions), the ``rigid-repeat`` candidate (the step's own rigid
motion applied again, `penfree.core.fit.models.fit_rigid_repeat`) is always
replayed. Doing nothing is always replayed; a candidate replaces it only with a
strictly smaller score and no more passes toward ``y_hat`` than doing nothing (ties
go to the earlier candidate, doing nothing first).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ... import constants as K
from ...errors import InputError
from ..fit import models as _fit
from ..trust.client import CLIENTS, RADIUS_RULES, TRUNCATIONS, replay_step


@dataclass
class ClientModel:
    """The client `auto` predicts for (``--client-model``).

    Attributes
    ----------
    truncation : {"isotropic", "planar"}
    dhat : float > 0
        Contact offset (the sequence's contact radius, else its thickness).
    radius : {"step", "own"}
        Radius rule the simulator follows (default ``step``).
    edges, faces : int arrays
        Topology.
    shortlist : int
        Candidates (besides doing nothing) replayed per step, best static first.
    predictor : {"own", "ipctk"}
        The client the candidates are replayed through: penfree's own
        re-implementation (default; no ipctk needed) or ``ipctk.ogc.TrustRegion``
        itself (slower; exact where the own client's filters can only match it up to
        rounding, e.g. nearly parallel stacked layers, see `penfree.core.trust.planar`).
    repeat : bool
        Add the ``rigid-repeat`` candidate and predict toward the co-rotated target
        (default); False keeps the candidates and target of the static `auto`.
    """

    truncation: str
    dhat: float
    radius: str = "step"
    edges: object = None
    faces: object = None
    shortlist: int = K.CLIENT_SELECT_SHORTLIST
    predictor: str = "own"
    repeat: bool = True

    def __post_init__(self):
        if self.predictor not in CLIENTS:
            raise InputError(f"client model predictor must be one of {CLIENTS}; got {self.predictor!r}")
        if self.truncation not in TRUNCATIONS:
            raise InputError(f"client model truncation must be one of {TRUNCATIONS}; got {self.truncation!r}")
        if self.radius not in RADIUS_RULES:
            raise InputError(f"client model radius rule must be one of {RADIUS_RULES}; got {self.radius!r}")
        if not (np.isfinite(self.dhat) and self.dhat > 0):
            raise InputError(f"client model dhat must be > 0; got {self.dhat}")


def held_target(x, x_pred, d_start, dhat, r_q=np.inf):
    """``y_hat``: `x_pred`, with the contact vertices held at `x`.

    A vertex is in contact when its start separation (capped at `r_q`: a vertex at
    the cap has nothing within the query) is at most `CONTACT_HOLD_FACTOR` `dhat`.
    """
    d_start = np.asarray(d_start)
    hold = (d_start <= K.CONTACT_HOLD_FACTOR * float(dhat)) & (d_start < r_q)
    y = np.array(x_pred, dtype=np.float64)
    y[hold] = np.asarray(x, dtype=np.float64)[hold]
    return y


#: Candidates replayed whatever their static prediction (besides the shortlist): the
#: static predictor measures the distance to ``x_pred``, which a rotating body's
#: ``rigid-repeat`` map deliberately misses.
ALWAYS_REPLAYED = ("rigid-repeat",)


def corotated_target(x_prev, x, A, u, c):
    """Where the solver is expected to go: constant velocity in the co-rotating frame.

    With ``T(p) = c + u + A (p - c)`` the step's own rigid motion (the ``rigid-repeat``
    candidate, `models.fit_rigid_repeat`: ``T(x_prev) ~ x``), the target is
    ``T(x) + A (x - T(x_prev))``: the rigid motion continued, plus the non-rigid part
    of the last step carried along. It is ``2 x - x_prev`` exactly when ``A = I``, and
    the next frame (to rounding) for a body rotating at a constant angular velocity.
    """
    A = np.asarray(A, dtype=np.float64)
    base = np.asarray(c, dtype=np.float64) + np.asarray(u, dtype=np.float64)
    t_x = base + (x - c) @ A.T
    t_prev = base + (np.asarray(x_prev, dtype=np.float64) - c) @ A.T
    return t_x + (x - t_prev) @ A.T


def _replay_order(cands, shortlist):
    """Candidate indices to replay (doing nothing excluded): the `shortlist` distinct
    maps with the best static prediction, their duplicates, then `ALWAYS_REPLAYED`."""
    rest = [i for i in range(1, len(cands)) if cands[i].name not in ALWAYS_REPLAYED]
    rest.sort(key=lambda i: (cands[i].predicted["k_1pct"], cands[i].predicted["r_q99"], i))
    order, keys = [], set()
    for i in rest:
        key = (cands[i].A.tobytes(), cands[i].u.tobytes())
        if key not in keys and len(keys) >= shortlist:
            break
        keys.add(key)
        order.append(i)
    return order + [i for i in range(1, len(cands)) if cands[i].name in ALWAYS_REPLAYED]


def choose_by_client(cands, x_prev, x, c, d_start, model, thickness=0.0, r_q=np.inf) -> int:
    """Index of the candidate with the fewest predicted client passes (module doc).

    Fills ``predicted["client_passes"]`` of the replayed candidates (others keep
    none). Candidate 0 must be doing nothing.
    """
    x64 = np.asarray(x, dtype=np.float64)
    x_pred = 2.0 * x64 - np.asarray(x_prev, dtype=np.float64)
    rot = next((cd for cd in cands if cd.name in ALWAYS_REPLAYED), None)
    y = x_pred if rot is None else corotated_target(x_prev, x64, rot.A, rot.u, c)
    y_hat = held_target(x64, y, d_start, model.dhat, r_q)
    # The solver rarely lands on the prediction: a move must also pay off when it
    # gets only half-way there (contacts, damping, a turning motion).
    y_half = 0.5 * (x64 + y_hat)

    def replay(x_def, y, max_iter):
        return replay_step(x_def, x64, x_pred, y, edges=model.edges, faces=model.faces, dhat=model.dhat,
                           thickness=thickness, truncation=model.truncation, radius=model.radius, client=model.predictor,
                           max_iter=max_iter)["passes"]

    def passes(cand, none=None):
        if cand.D.any() or cand.u.any():
            x_def, _ = _fit.apply_map(x, cand.D, cand.u, c)
            x_def = np.asarray(x_def, dtype=np.float64)
        else:
            x_def = x64
        if none is None:
            return replay(x_def, y_hat, K.DEFAULT_CLIENT_MAX_ITER), replay(x_def, y_half, K.DEFAULT_CLIENT_MAX_ITER)
        # A replay stopped after k iterations that each asked for a CD pass has at
        # least k + 1 passes: with these caps a stopped candidate always loses, so
        # the comparison below is the same as with full replays (and far cheaper).
        p0 = replay(x_def, y_hat, none[0])
        if p0 > none[0]:
            return p0, none[1] + 1
        return p0, replay(x_def, y_half, max(0, sum(none) - p0))

    none = passes(cands[0])
    cands[0].predicted["client_passes"] = none[0]
    cands[0].predicted["client_passes_half"] = none[1]
    if none[0] > K.DEFAULT_CLIENT_MAX_ITER:
        # Doing nothing already deadlocks the predicted client (a pile creeping toward
        # its planes, one CD pass per iteration up to the cap): the predictions are
        # no better than the cap there, so nothing is moved.
        return 0
    best, best_p = 0, none
    seen = {}
    n = 0
    for i in _replay_order(cands, model.shortlist):
        key = (cands[i].A.tobytes(), cands[i].u.tobytes())
        if key in seen:
            cands[i].predicted.update({k: cands[seen[key]].predicted[k]
                                       for k in ("client_passes", "client_passes_half")})
            continue
        seen[key] = i
        p = passes(cands[i], none)
        cands[i].predicted["client_passes"], cands[i].predicted["client_passes_half"] = p
        # The score is the passes toward the target plus those toward the half-way
        # point; a candidate must lower it strictly, and must not need more passes
        # than doing nothing toward the target. Ties go to the earlier candidate
        # (doing nothing first, the always-replayed ones last).
        if sum(p) < sum(best_p) and p[0] <= none[0]:
            best, best_p = i, p
    return best
