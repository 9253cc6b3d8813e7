"""Per-step strategies of `deform`: each proposes a step's maps, preferred first.

A strategy turns one step (`StepInput`) into a sequence of `Outcome` s, from the map
it prefers to safer ones; the driver (`pipeline.deform_sequence`) applies the first
outcome that passes the shared safety gate (`gate.StepGate`). Every chain ends with
doing nothing (`nothing`), which always passes: the last resort.

- `SingleMap`: one fitted model, then the simpler models of the ladder
  (affine -> similarity -> rigid -> translation), then nothing;
- `Auto`: the certified candidates of `selection` in the order of their predicted
  CD passes (`selection.rank`), the trust-region predictor seeing the obstacles;
- `PerComponent`: one map per object (`components.per_component_step`), then the
  `SingleMap` chain of the affine model.

`with_shortened` puts, just before doing nothing, the strategy's first (preferred)
map with its step shortened (`shortened`): ``x + alpha (x_def - x)``, whose straight
path is the first `alpha` of the preferred map's path. A vertex resting on the floor
that every full step would push through may allow a part of one.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ...constants import MODELS, SHORTEN_LEVELS
from ...errors import InputError
from ..contact.proximity import SeparationQuery
from ..fit.certificate import certified_margin
from ..verify.gate import StepGate
from ..trust.stats import contact_distance, query_radius
from ..fit.step import fit_step

_I3 = np.eye(3)


@dataclass
class StepInput:
    """What a strategy sees of step `s`: frames, target, query radius, gate."""

    s: int
    x_prev: np.ndarray
    x: np.ndarray
    x64: np.ndarray
    x_pred: np.ndarray
    r_q: float
    margin: float
    gate: StepGate
    weights: np.ndarray = None


@dataclass
class Outcome:
    """One proposed map of a step (or several, per component) and how it was made."""

    A: np.ndarray  # (3, 3); NaN when components moved with different maps
    b: np.ndarray
    x_def: np.ndarray
    model: str
    projection: str
    certificate_margin: float
    rank: int
    time_fit_s: float
    maps: list  # (A, b, rows or None): every distinct map applied, for the gate
    extra: dict = field(default_factory=dict)


def from_step_result(r) -> Outcome:
    return Outcome(r.A, r.b, r.x_def, r.model, r.projection, r.certificate_margin, r.rank, r.time_fit_s,
                   [(r.A, r.b, None)])


def nothing(step: StepInput) -> Outcome:
    """Doing nothing: ``x_def = x`` bit for bit (always safe)."""
    return Outcome(_I3.copy(), np.zeros(3), np.array(step.x, copy=True), "none", "none",
                   certified_margin(_I3, step.margin), 0, 0.0, [(_I3, np.zeros(3), None)])


def shortened(o: Outcome, step: StepInput, alpha: float) -> Outcome:
    """`o` with its step shortened to ``alpha``: map ``I + alpha (A - I)``, ``alpha b``.

    Only for a single finite map. ``M_alpha(t) = M(alpha t)``, so the shortened path
    is a prefix of `o`'s: it passes every certificate `o`'s map passes.
    """
    A = np.eye(3) + alpha * (np.asarray(o.A, np.float64) - np.eye(3))
    b = alpha * np.asarray(o.b, np.float64)
    x_def = (step.x64 + alpha * (np.asarray(o.x_def, np.float64) - step.x64)).astype(step.x.dtype, copy=False)
    return Outcome(A, b, x_def, f"{o.model}-short{alpha:g}", o.projection, certified_margin(A, step.margin),
                   o.rank, o.time_fit_s, [(A, b, None)], dict(o.extra))


def with_shortened(outcomes, step: StepInput):
    """`outcomes`, with the first one's shortened steps (`SHORTEN_LEVELS`) just before
    doing nothing (the last resort; nothing after it is ever needed)."""
    first = None
    for o in outcomes:
        if o.model == "none":
            break
        first = o if first is None else first
        yield o
    else:
        o = None
    if first is not None and np.isfinite(first.A).all():
        for alpha in SHORTEN_LEVELS:
            yield shortened(first, step, alpha)
    yield nothing(step) if o is None else o


class SingleMap:
    """One model of the ladder, then the simpler ones, then nothing."""

    def __init__(self, model, projection="auto"):
        self.model, self.projection = model, projection

    def chain(self):
        if self.model not in MODELS:  # fit_step's residual-based "auto" (no topology)
            return [self.model, "translation"]
        k = MODELS.index(self.model)
        return list(MODELS[k::-1])

    def outcomes(self, step: StepInput):
        for model in self.chain():
            yield from_step_result(fit_step(step.x_prev, step.x, weights=step.weights, model=model,
                                            projection=self.projection, margin=step.margin))
        yield nothing(step)

    def record(self, k, outcome):
        pass

    def groups(self):
        return {}


class Auto:
    """The candidates of `penfree.core.fit.auto`, in order of predicted CD passes (or, with a
    `client_select.ClientModel`, the one with the fewest replayed client passes first)."""

    def __init__(self, seq, projection="auto", thickness=0.0, n_steps=0, client_model=None, d_start=None,
                 contact_radius=None):
        from ..trust.bounds import scene_arrays

        _, self.E, self.F = scene_arrays(seq.positions[0], seq.edges, seq.faces)
        self.obstacles = seq.obstacles
        # where a solver holds what lands on a half-space (`landing_prediction`)
        self.rest = contact_distance(seq.contact_radius if contact_radius is None else contact_radius, thickness)
        self.projection, self.thickness = projection, thickness
        self.client_model = client_model
        self.d_start = d_start  # per-vertex scene separations the caller already has (predeform's bounds)
        self.query = SeparationQuery(self.E, self.F)  # each step at the reach of the last
        self.tables = [None] * n_steps

    def outcomes(self, step: StepInput):
        from ..fit.auto import candidate_result, candidate_table, rank, ranked_candidates

        d_start = start_separations(step.x64, self.E, self.F, step.r_q, obstacles=self.obstacles, s=step.s,
                                    known=self.d_start, query=self.query)
        if self.d_start is None:  # our own query (obstacles only lower it): the gate may trust it
            step.gate.use_separations(d_start)
        t0 = time.perf_counter()
        x_prev_target = landing_prediction(step.x_prev, step.x64, self.obstacles, self.rest)
        landing = None if x_prev_target is step.x_prev else x_prev_target
        x, x_prev, m, cands = ranked_candidates(step.x_prev, step.x, d_start, r_q=step.r_q, predict_from=landing,
                                                thickness=self.thickness, weights=step.weights,
                                                margin=step.margin, projection=self.projection,
                                                repeat=self.client_model is not None and self.client_model.repeat)
        order = rank(cands)
        if self.client_model is not None:  # the client's replayed passes pick the first; the rest as ranked
            from .client_select import choose_by_client

            best = choose_by_client(cands, x_prev, x, m.c, d_start, self.client_model, self.thickness, step.r_q,
                                    frame=step.s, landing=landing)
            order = [best] + [k for k in order if k != best]
        for k in order:
            o = from_step_result(candidate_result(x_prev, x, m, cands[k], t0))
            o.extra["table"] = candidate_table(cands, k)
            yield o

    def record(self, k, outcome):
        self.tables[k] = outcome.extra.get("table")

    def groups(self):
        return {"selection": selection_arrays(self.tables)}


class PerComponent:
    """One map per object (merged where paths may meet), then the affine chain."""

    def __init__(self, seq, projection="auto", thickness=0.0, n_steps=0):
        from .components import component_labels

        self.seq, self.projection, self.thickness = seq, projection, thickness
        self.labels = component_labels(seq.n_vertices, seq.edges, seq.faces, seq.components)
        C = int(self.labels.max()) + 1
        # NaN / -1 for steps that fell back to a single map
        self.comp = {"labels": self.labels, "A": np.full((n_steps, C, 3, 3), np.nan),
                     "b": np.full((n_steps, C, 3), np.nan), "group": np.full((n_steps, C), -1, dtype=np.int64),
                     "rounds": np.zeros(n_steps, dtype=np.int64)}
        self.fallback = SingleMap("affine", projection)

    def outcomes(self, step: StepInput):
        from .components import per_component_step

        cs = per_component_step(step.x_prev, step.x, self.labels, edges=self.seq.edges, faces=self.seq.faces,
                                thickness=self.thickness, weights=step.weights, margin=step.margin,
                                projection=self.projection, check=step.gate.between_maps)
        yield _component_outcome(cs, self.labels)
        yield from self.fallback.outcomes(step)

    def record(self, k, outcome):
        cs = outcome.extra.get("components")
        if cs is not None:
            self.comp["A"][k], self.comp["b"][k], self.comp["group"][k] = cs.A, cs.b, cs.group
            self.comp["rounds"][k] = cs.rounds

    def groups(self):
        return {"component_maps": self.comp}


def _component_outcome(cs, labels) -> Outcome:
    maps = []
    for g in np.unique(cs.group):
        c = int(np.flatnonzero(cs.group == g)[0])
        maps.append((cs.A[c], cs.b[c], np.flatnonzero(cs.group[labels] == g)))
    extra = {"components": cs}
    if len(maps) == 1:  # everything merged: one global map
        return Outcome(cs.A[0], cs.b[0], cs.x_def, next(iter(cs.models)), "auto", cs.certificate_margin,
                       cs.rank, cs.time_fit_s, maps, extra)
    # SPEC: steps/A is *the* map applied; with several there is none (NaN), and
    # component_maps/A holds each component's map.
    return Outcome(np.full((3, 3), np.nan), np.full(3, np.nan), cs.x_def, "per-component", "per-component",
                   cs.certificate_margin, cs.rank, cs.time_fit_s, maps, extra)


def make_strategy(model, seq, projection, thickness, n_steps, client_model=None, contact_radius=None):
    """The strategy of a ``--model`` value (`client_model` only with ``auto``;
    `contact_radius`: the run's, else the sequence's)."""
    if client_model is not None and model != "auto":
        raise InputError(f"a client model needs model auto; got {model!r}")
    if model == "per-component":
        return PerComponent(seq, projection, thickness, n_steps)
    if model == "auto" and seq.kind != "points":
        return Auto(seq, projection, thickness, n_steps, client_model,
                    contact_radius=seq.contact_radius if contact_radius is None else contact_radius)
    return SingleMap(model, projection)


def landing_prediction(x_prev, x64, obstacles, rest):
    """The previous frame `auto` predicts passes from (its candidates are still fit toward
    ``2 x - x_prev``): `x_prev`, except where that prediction lands on a half-space.

    A vertex whose prediction would come closer to a half-space than `rest` (the contact
    radius: where the solver holds what lands on it) and than it is now is predicted to
    stop at that distance: its target is moved back along the normal, and its row of
    the returned previous frame is ``2 x - target``. Other rows are `x_prev`'s own, and
    without a clip `x_prev` itself is returned (a recording that lands on nothing is
    chosen for exactly as before). Without the clip, `auto` at a landing chose maps that
    take the stack on toward the ground (down to the thickness, which the gate allows),
    where the solver stops it at the contact radius: ipctk needed 18-20% more isotropic
    passes than doing nothing on the falling stack; with it, 4% fewer (BENCHMARKS.md,
    issue 12). Mesh obstacles are not clipped.
    """
    half = [ob for ob in obstacles if ob.is_half_space]
    if not half or not rest > 0.0:
        return x_prev
    y = 2.0 * x64 - np.asarray(x_prev, dtype=np.float64)
    moved = np.zeros(x64.shape[0], dtype=bool)
    for ob in half:
        n = np.asarray(ob.normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        gap_y = y @ n - float(ob.offset)
        push = np.minimum(rest, x64 @ n - float(ob.offset)) - gap_y
        hit = push > 0.0
        if hit.any():
            y[hit] += push[hit, None] * n
            moved |= hit
    if not moved.any():
        return x_prev
    out = np.array(x_prev, copy=True)
    out[moved] = (2.0 * x64[moved] - y[moved]).astype(out.dtype, copy=False)
    return out


def step_input(seq, s, margin, gate, weights, contact_radius) -> StepInput:
    """Step `s` of `seq`; the query radius from the contact radius (at least the gate's thickness)."""
    x_prev, x = seq.positions[s - 1], seq.positions[s]
    x64, x_pred, r_q = step_target(x_prev, x, contact_radius, gate.thickness)
    return StepInput(int(s), x_prev, x, x64, x_pred, r_q, margin, gate, weights)


def step_target(x_prev, x, contact_radius, thickness) -> tuple:
    """``(x64, x_pred, r_q)`` of a step: `x` as float64, the prediction ``2 x - x_prev``
    and the query radius from the contact radius (at least `thickness`)."""
    x64 = np.ascontiguousarray(x, dtype=np.float64)
    x_pred = 2.0 * x64 - np.asarray(x_prev, dtype=np.float64)
    return x64, x_pred, query_radius(x64, x_pred, contact_distance(contact_radius, thickness))


def start_separations(x64, E, F, r_q, *, obstacles=(), s=None, known=None, query=None) -> np.ndarray:
    """(N,) float64: per-vertex separations at `x64` capped at `r_q`, the ``d_start`` of `auto`.

    `known` replaces the scene term when the caller already has it; else `query` (a
    `SeparationQuery` of the scene, the same values) or a fresh `per_vertex_separation`
    answers it. Obstacles (at frame `s`) lower it. Computed before an `auto` fit is timed:
    the simulator's last detection.
    """
    from ..trust.bounds import obstacle_separation, per_vertex_separation

    if known is not None:
        d_start = np.minimum(known, r_q)
    else:
        d_start = per_vertex_separation(x64, E, F, r_q) if query is None else query(x64, r_q)
    if obstacles:
        d_start = np.minimum(d_start, obstacle_separation(x64, E, F, obstacles, r_q, s))
    return d_start


def selection_arrays(table_rows) -> dict:
    """Per-step candidate tables of `select_step` as ``selection/...`` arrays.

    ``candidates`` (C,) names in a fixed order; ``predicted_<figure>`` (S, C) with NaN
    where a candidate was not certified (or the step was not selected); ``chosen`` (S,)
    the index of the applied candidate (-1 when the step was not selected).
    """
    names = []
    for table in table_rows:
        for row in table or ():
            if row["name"] not in names:
                names.append(row["name"])
    S, C = len(table_rows), len(names)
    figures = ("k_1pct", "k_any", "hit_rate", "r_q99", "sigma_lb", "certificate_margin")
    arrays = {f"predicted_{f}": np.full((S, C), np.nan) for f in figures}
    chosen = np.full(S, -1, dtype=np.int64)
    for k, table in enumerate(table_rows):
        for row in table or ():
            j = names.index(row["name"])
            for f in figures:
                arrays[f"predicted_{f}"][k, j] = row[f]
            if row["chosen"]:
                chosen[k] = j
    arrays["candidates"] = np.array(names, dtype=str)
    arrays["chosen"] = chosen
    return arrays
