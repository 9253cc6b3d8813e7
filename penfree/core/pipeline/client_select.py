"""`auto` by the client: the candidate map with the fewest predicted client CD passes.

The static prediction of `selection` holds the bounds fixed and compares every
vertex with ``x_pred``. What a simulator's OGC client actually spends depends on
two things it misses:

* **the radius cap.** The client's inflation radius caps every vertex's region.
  Under the radius rule ``step`` (how a pre-deformation is integrated: the
  simulator keeps the radius it computed at ``x``) the cap is the same for every
  candidate; under ``own`` it shrinks when ``x_def`` is closer to ``x_pred``.
* **contact vertices that should not move.** Vertices in resting contact (start
  separation within `CONTACT_HOLD_FACTOR` contact radii, and a last step no longer
  than `CONTACT_REST_STEP` contact radii) barely move in reality: the solver holds
  them, whatever ``x_pred`` says. A map that moves them spends their small bounds and
  costs passes to bring them back. Contact vertices that moved farther in the last
  step move with what they touch (a swinging coil's turns) and are not held: a target
  that held them would be one the solver never reaches, and every moved candidate's
  replay toward it would deadlock.

The predictor therefore replays each shortlisted candidate through penfree's own
client (`client.replay_step` with ``client="own"``: the same warm start, filters and
1% update rule as ``ipctk.ogc.TrustRegion``; ``ClientModel.predictor="ipctk"``
replays through ipctk itself), warm-starting toward ``x_pred`` and iterating toward
the *held target* ``y_hat`` (`corotated_target` for free vertices: ``x_pred`` with
the step's rotation continued, ``x`` for the held vertices), and again toward
``(x + y_hat) / 2`` (the solver stopping half-way: contacts, damping, turning
motion). Besides the shortlist (the best static predictions), the ``rigid-repeat``
candidate (the step's own rigid motion applied again,
`penfree.core.fit.models.fit_rigid_repeat`) is always replayed. Doing nothing is
always replayed and is the first candidate; a later one replaces the best so far
only if it needs fewer passes toward ``y_hat``, or as many and fewer toward the
half-way point (`_better`; ties go to the earlier candidate). Where doing nothing
itself deadlocks toward ``y_hat`` (replays up to the iteration cap: resting layers
creeping toward their planes), the half-way point alone decides: a candidate must
reach it in fewer passes than doing nothing, which may deadlock there too.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ... import constants as K
from ...errors import InputError
from ..fit import models as _fit
from ..trust.client import CLIENTS, RADIUS_RULES, TRUNCATIONS, ClientQuery, replay_step


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
    obstacles : tuple of Obstacle
        The sequence's colliders, in the client's collision mesh (`client_scene`).
    """

    truncation: str
    dhat: float
    radius: str = "step"
    edges: object = None
    faces: object = None
    shortlist: int = K.CLIENT_SELECT_SHORTLIST
    predictor: str = "own"
    repeat: bool = True
    obstacles: tuple = ()
    _query: object = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        if self.predictor not in CLIENTS:
            raise InputError(f"client model predictor must be one of {CLIENTS}; got {self.predictor!r}")
        if self.truncation not in TRUNCATIONS:
            raise InputError(f"client model truncation must be one of {TRUNCATIONS}; got {self.truncation!r}")
        if self.radius not in RADIUS_RULES:
            raise InputError(f"client model radius rule must be one of {RADIUS_RULES}; got {self.radius!r}")
        if not (np.isfinite(self.dhat) and self.dhat > 0):
            raise InputError(f"client model dhat must be > 0; got {self.dhat}")

    def query(self, x):
        """The own predictor's `ClientQuery` of this scene, one for every step's replays
        (None for the ipctk predictor)."""
        if self.predictor != "own":
            return None
        if self._query is None or self._query.n != x.shape[0]:
            self._query = ClientQuery(x, self.edges, self.faces, self.obstacles)
        return self._query


def held_target(x, x_pred, d_start, dhat, r_q=np.inf, x_prev=None):
    """``y_hat``: `x_pred`, with the vertices in resting contact held at `x`.

    A vertex is in contact when its start separation (capped at `r_q`: a vertex at
    the cap has nothing within the query) is at most `CONTACT_HOLD_FACTOR` `dhat`. With
    `x_prev` given, it is held only if it is also at rest: its last step
    ``|x - x_prev|`` is at most `CONTACT_REST_STEP` `dhat`, the largest trust region a
    vertex in contact can have. A contact vertex that moved farther than that was not
    held by its contact: it moves with what it touches (a coil's turns swinging
    together, layers carried together), and holding it would make the target one the
    solver never reaches.
    """
    d_start = np.asarray(d_start)
    hold = (d_start <= K.CONTACT_HOLD_FACTOR * float(dhat)) & (d_start < r_q)
    x64 = np.asarray(x, dtype=np.float64)
    if x_prev is not None:
        step = np.linalg.norm(x64 - np.asarray(x_prev, dtype=np.float64), axis=1)
        hold &= step <= K.CONTACT_REST_STEP * float(dhat)
    y = np.array(x_pred, dtype=np.float64)
    y[hold] = x64[hold]
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


def choose_by_client(cands, x_prev, x, c, d_start, model, thickness=0.0, r_q=np.inf, frame=None,
                     landing=None) -> int:
    """Index of the candidate with the fewest predicted client passes (module doc).

    `frame`: the step's frame, where the model's obstacles are taken (needed with
    mesh obstacles). `landing`: `strategy.landing_prediction`'s previous frame; the
    vertices it clips are targeted where it stops them (the warm start still aims at
    ``2 x - x_prev``, as the simulator's does).

    Fills ``predicted["client_passes"]`` (toward ``y_hat``) and
    ``predicted["client_passes_half"]`` (toward the half-way point) of the replayed
    candidates, None where a replay was not needed. Candidate 0 must be doing nothing.
    """
    x64 = np.asarray(x, dtype=np.float64)
    x_pred = 2.0 * x64 - np.asarray(x_prev, dtype=np.float64)
    rot = next((cd for cd in cands if cd.name in ALWAYS_REPLAYED), None)
    y = x_pred if rot is None else corotated_target(x_prev, x64, rot.A, rot.u, c)
    if landing is not None and landing is not x_prev:
        clipped = np.any(np.asarray(landing) != np.asarray(x_prev), axis=1)
        y = np.array(y, dtype=np.float64)
        y[clipped] = 2.0 * x64[clipped] - np.asarray(landing, dtype=np.float64)[clipped]
    y_hat = held_target(x64, y, d_start, model.dhat, r_q, x_prev=x_prev)
    # The solver rarely lands on the prediction: the half-way point breaks ties, and
    # decides alone where the prediction deadlocks (see `_better`).
    y_half = 0.5 * (x64 + y_hat)
    cap = K.DEFAULT_CLIENT_MAX_ITER
    query = model.query(x64)

    def replay(x_def, y, max_iter):
        return replay_step(x_def, x64, x_pred, y, edges=model.edges, faces=model.faces, dhat=model.dhat,
                           thickness=thickness, truncation=model.truncation, radius=model.radius, client=model.predictor,
                           max_iter=max_iter, query=query, obstacles=model.obstacles, frame=frame)["passes"]

    def start(cand):
        if cand.D.any() or cand.u.any():
            return np.asarray(_fit.apply_map(x, cand.D, cand.u, c)[0], dtype=np.float64)
        return x64

    none = replay(x64, y_hat, cap), replay(x64, y_half, cap)
    cands[0].predicted["client_passes"], cands[0].predicted["client_passes_half"] = none
    deadlock = none[0] > cap
    best, best_p = 0, none
    seen = {}
    for i in _replay_order(cands, model.shortlist):
        key = (cands[i].A.tobytes(), cands[i].u.tobytes())
        if key in seen:
            cands[i].predicted.update({k: cands[seen[key]].predicted[k]
                                       for k in ("client_passes", "client_passes_half")})
            continue
        seen[key] = i
        p = _candidate_passes(replay, start(cands[i]), y_hat, y_half, best_p, deadlock, cap)
        cands[i].predicted["client_passes"], cands[i].predicted["client_passes_half"] = p
        if _better(p, best_p, deadlock, cap):
            best, best_p = i, p
    return best


def _better(p, q, deadlock, cap) -> bool:
    """Does a candidate with passes ``p = (toward y_hat, toward half-way)`` beat ``q``?

    Fewer passes toward ``y_hat`` (counts beyond the iteration cap are all alike: a
    deadlock), then fewer toward the half-way point; equal is not better (ties go to
    the earlier candidate, doing nothing first). Where doing nothing already deadlocks
    toward ``y_hat`` (a pile creeping toward its planes: one CD pass per iteration up
    to the cap), the predictions toward ``y_hat`` say nothing, and the half-way point
    decides alone: a candidate must need fewer passes there than doing nothing.
    """
    if deadlock:
        return p[1] is not None and p[1] < q[1]
    return (min(p[0], cap + 1), p[1]) < (min(q[0], cap + 1), q[1])


def _candidate_passes(replay, x_def, y_hat, y_half, best_p, deadlock, cap):
    """A candidate's ``(passes toward y_hat, passes toward half-way)``, each replay cut
    short where its count can no longer make the candidate `_better` than `best_p`.

    A replay stopped after k iterations that each asked for a CD pass has at least
    k + 1 passes, so one capped at k iterations is exact up to k passes and above k
    otherwise; a value that is not needed is None.
    """
    if deadlock:
        return None, replay(x_def, y_half, max(0, best_p[1] - 1))
    p0 = replay(x_def, y_hat, best_p[0])
    if p0 > best_p[0]:
        return p0, None  # loses on the first key whatever the second
    if p0 == best_p[0]:
        return p0, replay(x_def, y_half, max(0, best_p[1] - 1))
    return p0, replay(x_def, y_half, cap)  # the new best: its second key must be exact
