"""Trust-region statistics of a deformed sequence (SPEC section 7).

For every step and for both start states (``baseline``: the recorded positions `x`;
``deformed``: `x_def`) the OGC bounds `b` are computed once at the start state, with
the step's query radius `r_q = contact_radius + max_v |x_pred[v] - x[v]|` (the contact
radius taken at least as large as the thickness, `contact_distance`; the same for both
start states, so they are comparable). Against each target (``next``: the simulator's
next frame; ``pred``: the constant-velocity prediction) the per-vertex ratio
`r_v = |y_v - x_s[v]| / b_v` gives the hit rate and the CD-pass estimates.

Per-step keys of `compute_stats` (every array `(S,)` float64 unless noted; ``<t>`` is
``next`` or ``pred``, ``<s>`` is ``baseline`` or ``deformed``; NaN for the ``next``
figures of a step without a next frame):

=================================  ==================================================
``frame``                          (S,) int64, the step's frame index (as steps/frame)
``query_radius``                   r_q of the step
``hit_rate_<t>_<s>``               fraction of all N vertices with r_v <= 1
``k_any_<t>_<s>``                  max(1, ceil(max r_v)), blocked vertices left out
``k_1pct_<t>_<s>``                 max(1, ceil(r_q99)), blocked vertices left out
``n_blocked_<t>_<s>``              vertices with b_v = 0 that must move
``r_q50_<t>_<s>``, ``r_q90_..``,   quantiles of r_v over the non-blocked vertices
``r_q99_<t>_<s>``, ``r_max_<t>_<s>``  (method `PERCENTILE_METHOD`)
``residual_<t>_rms_<s>``,          RMS / max of |x_s - y| (x_s = x or x_def)
``residual_<t>_max_<s>``
``r_hist_<t>_<s>``                 (S, len(R_HIST_EDGES) - 1) counts of r_v per bin
                                   of `R_HIST_EDGES` (blocked vertices in the last bin)
``replay_k_any_<t>_<s>``,          replay pass counts (only with ``replay=True``)
``replay_k_1pct_<t>_<s>``,
``replay_capped_<t>_<s>``          1.0 where the replay hit its cap, else 0.0
=================================  ==================================================

Their sequence-level summary and the projected frame time are in `penfree.core.trust.summary`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ...constants import (
    DEFAULT_GAMMA, DEFAULT_REPLAY_CAP, K_PERCENTILE, REDUCTION_CHUNKS,
    R_HIST_BINS_PER_DECADE, R_HIST_DECADES,
)
from ...errors import InputError

STARTS = ("baseline", "deformed")
TARGETS = ("next", "pred")

#: Percentiles of r_v reported per step (the last is the one behind K_1pct); all with
#: numpy's `PERCENTILE_METHOD` ("higher"), computed with exact integer indices.
QUANTILES = (50, 90, K_PERCENTILE)
#: Bin edges of the r_v histograms: 0, the log bins of R_HIST_DECADES, inf.
_LO, _HI = R_HIST_DECADES
R_HIST_EDGES = np.concatenate(([0.0], np.logspace(_LO, _HI, (_HI - _LO) * R_HIST_BINS_PER_DECADE + 1), [np.inf]))


def contact_distance(contact_radius, thickness) -> float:
    """The contact distance that sizes the query radius: the contact radius, never below
    the thickness (a simulator's contact radius is at least its hard separation; a file
    that gives only a thickness keeps the query radius it had before the two were
    separated)."""
    return max(float(contact_radius or 0.0), float(thickness or 0.0))


def query_radius(x, x_pred, contact_radius=0.0) -> float:
    """`r_q = contact_radius + max_v |x_pred[v] - x[v]|`, the step's OGC query radius.

    Callers pass `contact_distance(contact_radius, thickness)`.
    """
    n, a, b = _flat_pair(x_pred, x, "query_radius")
    # the largest |x_pred - x| as numpy's norm gives it: sqrt is monotone, so
    # sqrt(max |.|^2) is max sqrt(|.|^2), bit for bit (`_residual_sq`)
    top = math.sqrt(_residual_sq(a, b, REDUCTION_CHUNKS)[1]) if n else 0.0
    return float(contact_radius) + top


def _higher_quantile(r_sorted, q):
    # PERCENTILE_METHOD "higher": numpy's index ceil(q (n-1) / 100), computed in
    # integers so that no float rounding of q / 100 can move it by one vertex.
    n = r_sorted.size
    return float(r_sorted[-((-q * (n - 1)) // 100)])


def ratio_stats(x_s, y, b) -> dict:
    """Hit rate, static CD-pass estimates and quantiles of `r_v` for one start/target.

    Parameters
    ----------
    x_s : (N, 3) float
        Start state (where CD ran).
    y : (N, 3) float
        Target positions.
    b : (N,) float
        Trust-region bounds at `x_s` (>= 0).

    Returns
    -------
    dict
        ``hit_rate``, ``k_any``, ``k_1pct``, ``n_blocked``, ``r_q50``, ``r_q90``,
        ``r_q99``, ``r_max`` (floats) and ``r_hist`` (counts per `R_HIST_EDGES` bin).

    Notes
    -----
    `r_v = |y_v - x_s[v]| / b_v`, 0 where the vertex does not move. A vertex with
    `b_v = 0` that must move is *blocked*: it is not a hit and is left out of the K
    estimates and the quantiles. With `n` non-blocked vertices, `r_q99` is the sorted
    value at index `ceil(0.99 (n - 1))` (numpy ``method="higher"``), which equals index
    `floor(0.99 n)`; so `K_1pct = max(1, ceil(r_q99))` is the smallest pass count after
    which fewer than 1% of the non-blocked vertices are still truncated.

    >>> import numpy as np
    >>> x = np.zeros((2, 3)); y = np.array([[0.5, 0, 0], [3.0, 0, 0]])
    >>> s = ratio_stats(x, y, np.array([0.5, 1.0]))
    >>> s["hit_rate"], s["k_any"]
    (0.5, 3)
    """
    x_s = np.asarray(x_s, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    n_all = x_s.shape[0]
    if y.shape != x_s.shape or b.shape != (n_all,):
        raise InputError(f"ratio_stats needs x_s, y (N, 3) and b (N,); got {x_s.shape}, {y.shape}, {b.shape}")
    d = np.linalg.norm(y - x_s, axis=1)
    moving = d > 0
    blocked = moving & ~(b > 0)
    ok = moving & ~blocked
    r = np.zeros(n_all)
    r[ok] = d[ok] / b[ok]
    out = {
        "hit_rate": float(np.count_nonzero(~blocked & (r <= 1.0)) / n_all) if n_all else math.nan,
        "n_blocked": int(np.count_nonzero(blocked)),
    }
    hist_r = np.where(blocked, np.inf, r)
    idx = np.searchsorted(R_HIST_EDGES, hist_r, side="right") - 1
    out["r_hist"] = np.bincount(np.minimum(idx, R_HIST_EDGES.size - 2), minlength=R_HIST_EDGES.size - 1)
    keep = np.sort(r[~blocked])
    if keep.size == 0:
        out.update(k_any=1, k_1pct=1, r_max=math.nan, **{f"r_q{q}": math.nan for q in QUANTILES})
        return out
    for q in QUANTILES:
        out[f"r_q{q}"] = _higher_quantile(keep, q)
    out["r_max"] = float(keep[-1])
    out["k_any"] = max(1, math.ceil(out["r_max"]))
    out["k_1pct"] = max(1, math.ceil(out[f"r_q{K_PERCENTILE}"]))
    return out


def replay_passes(x_s, y, bounds_fn, *, cap=DEFAULT_REPLAY_CAP, b0=None) -> dict:
    """Replay estimate of the CD passes: move by at most the bound, re-detect, repeat.

    Parameters
    ----------
    x_s, y : (N, 3) float
        Start state and target.
    bounds_fn : callable
        ``bounds_fn(x (N, 3) float64) -> (N,) float64`` trust-region bounds at `x`
        (with the step's fixed query radius).
    cap : int
        Largest number of passes tried.
    b0 : (N,) float, optional
        Bounds at `x_s` if already computed (saves the first bound computation).

    Returns
    -------
    dict
        ``k_any`` (passes until no vertex is truncated), ``k_1pct`` (until fewer than
        1% of the non-blocked vertices are truncated), ``capped`` (bool: ``k_any`` hit
        the cap; the counts are then `cap`), ``n_blocked`` (blocked at the last pass).

    Notes
    -----
    Pass k computes the bounds at the current positions (one CD) and moves every
    vertex toward `y` by at most its bound. Vertices with `b_v = 0` that must move are
    blocked in that pass and, as in the static estimate, not counted as truncated.
    With bounds that do not change between passes this reproduces `ratio_stats`'
    ``k_any`` and ``k_1pct`` exactly.
    """
    x = np.array(x_s, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    cap = int(cap)
    if cap < 1:
        raise InputError(f"replay cap must be >= 1; got {cap}")
    k_1pct = None
    n_blocked = 0
    for k in range(1, cap + 1):
        b = np.asarray(b0 if k == 1 and b0 is not None else bounds_fn(x), dtype=np.float64)
        delta = y - x
        d = np.linalg.norm(delta, axis=1)
        moving = d > 0
        blocked = moving & ~(b > 0)
        trunc = moving & ~blocked & (d > b)
        n_blocked = int(np.count_nonzero(blocked))
        n_trunc = int(np.count_nonzero(trunc))
        if k_1pct is None and (n_trunc == 0 or 100 * n_trunc < x.shape[0] - n_blocked):
            k_1pct = k
        if n_trunc == 0:
            return {"k_any": k, "k_1pct": k_1pct, "capped": False, "n_blocked": n_blocked}
        reach = moving & ~blocked & ~trunc
        # Land exactly on y when within reach, so no rounding residue needs another pass.
        x[reach] = y[reach]
        x[trunc] += delta[trunc] * (b[trunc] / d[trunc])[:, None]
    return {"k_any": cap, "k_1pct": cap if k_1pct is None else k_1pct, "capped": True, "n_blocked": n_blocked}


def residual_summary(x_s, y) -> tuple:
    """``(rms, max)`` of the per-vertex distances |x_s - y| (float64 arithmetic).

    One pass without temporaries (`_residual_sq`): a 64K step of ``deform`` records four
    of these, 4.4 ms with numpy's copies and passes (issue 13). The squared distances are
    summed in `REDUCTION_CHUNKS` fixed chunks, so the bits do not depend on anything but
    the inputs; NaN propagates to both figures.
    """
    n, a, b = _flat_pair(x_s, y, "residual_summary")
    if n == 0:
        raise InputError("residual_summary needs at least one vertex")
    s, m = _residual_sq(a, b, REDUCTION_CHUNKS)
    return math.sqrt(s / n), math.sqrt(m)


def _flat_pair(a, b, who):
    """``(N, a, b)``: two (N, 3) arrays of one shape as flat contiguous (3N,) views
    (copies only where they were not contiguous), for `_residual_sq`."""
    a, b = np.ascontiguousarray(a), np.ascontiguousarray(b)
    if a.ndim != 2 or a.shape[1:] != (3,) or b.shape != a.shape:
        raise InputError(f"{who} needs two (N, 3) arrays of one shape; got {a.shape} and {b.shape}")
    return a.shape[0], a.reshape(-1), b.reshape(-1)


@numba.njit(cache=True)
def _residual_sq(a, b, n_chunks):
    # (sum, max) of |a_v - b_v|^2 over flat (3N,) arrays; the chunk sums are added in
    # chunk order. The maximum is taken over the bit patterns (non-negative floats order
    # as unsigned integers, and NaN above every number, so NaN still poisons it).
    n = a.shape[0] // 3
    total = 0.0
    top = np.uint64(0)
    for k in range(n_chunks):
        s = 0.0
        for i in range(k * n // n_chunks, (k + 1) * n // n_chunks):
            e0 = np.float64(a[3 * i]) - np.float64(b[3 * i])
            e1 = np.float64(a[3 * i + 1]) - np.float64(b[3 * i + 1])
            e2 = np.float64(a[3 * i + 2]) - np.float64(b[3 * i + 2])
            q = e0 * e0 + e1 * e1 + e2 * e2
            s += q
            top = max(top, np.float64(q).view(np.uint64))
        total += s
    return total, np.uint64(top).view(np.float64)


def stats_keys(replay=False) -> list:
    """Names of the per-step arrays `compute_stats` returns (stable; see module doc)."""
    keys = ["frame", "query_radius"]
    figs = ["hit_rate", "k_any", "k_1pct", "n_blocked", *(f"r_q{q}" for q in QUANTILES), "r_max", "r_hist"]
    if replay:
        figs += ["replay_k_any", "replay_k_1pct", "replay_capped"]
    for t in TARGETS:
        for s in STARTS:
            keys += [f"{f}_{t}_{s}" for f in figs]
            keys += [f"residual_{t}_rms_{s}", f"residual_{t}_max_{s}"]
    return keys


def _unpack(source, deformed, frames, edges, faces, thickness, contact_radius=None, obstacles=None):
    # A DeformResult (formats.result) or plain arrays; duck-typed so that the core does
    # not import the formats layer.
    if hasattr(source, "sequence") and hasattr(source, "steps"):
        seq, steps = source.sequence, source.steps
        positions = seq.positions
        deformed = steps["deformed"] if deformed is None else deformed
        frames = steps["frame"] if frames is None else frames
        edges = seq.edges if edges is None else edges
        faces = seq.faces if faces is None else faces
        thickness = seq.thickness if thickness is None else thickness
        contact_radius = seq.contact_radius if contact_radius is None else contact_radius
        obstacles = seq.obstacles if obstacles is None else obstacles
    else:
        positions = source
    positions = np.asarray(positions)
    if deformed is None or frames is None:
        raise InputError("compute_stats needs a deform result, or positions with deformed= and frames=")
    deformed, frames = np.asarray(deformed), np.asarray(frames, dtype=np.int64)
    T, N = positions.shape[0], positions.shape[1]
    S = frames.shape[0]
    if positions.ndim != 3 or deformed.shape != (S, N, 3):
        raise InputError(f"deformed must be (S, N, 3) = ({S}, {N}, 3) to match positions {positions.shape}; "
                         f"got {deformed.shape}")
    if S and (frames.min() < 1 or frames.max() >= T):
        raise InputError(f"step frames must be in [1, {T - 1}] for {T} frames; got {frames.min()}..{frames.max()}")
    return (positions, deformed, frames, edges, faces, float(thickness or 0.0), float(contact_radius or 0.0),
            list(obstacles or ()))


#: Skin of a step's neighbour list (`StepBounds`), relative to the step's query radius:
#: reaches every affine image of the start whose smallest singular value is >= 0.91.
STEP_SKIN_REL = 0.1


class StepBounds:
    """``bounds(x, r_q)``: `trust_region_bounds` of the scene's own pairs, bit for bit,
    from one neighbour list per step.

    `begin_step` builds the list at the step's start `x` with a skin of `STEP_SKIN_REL`
    times r_q. A later state of the step is answered from the list when the list
    provably holds every pair within r_q there (`NeighbourList.reach`: the affine images
    of `x`, i.e. the deformed states of the ladder's maps and of a result, need about
    r_q / sigma_min), any other state (the prediction, replay states) by a fresh
    query that leaves the list alone. Without `begin_step` every query is fresh.
    The model ladder uses it (7-8 states per step: 1.35-1.63x), and `compute_stats`
    without obstacles (two states per step: a list at r_q measured 0.82-1.09x there, at
    the reach 1.25-1.3x).

    Reach (`penfree.core.contact.proximity`): every answer remembers the largest
    separation below r_q; the next step's list is built at that reach (1.1 times it)
    when it is below r_q, and a state the list covers only up to ``cover < r_q``
    (`NeighbourList.coverage`) is answered from it at ``cover``, the vertices left at
    that cap completed at r_q (`complete_separations`): the same bits, with a list of
    the pairs within the separations instead of the query radius (ladder 2.0x / 3.0x
    faster on the 64K yarn / cloth results). A fresh query runs at the reach too.

    Labels (`penfree.core.contact.locality`): given a state `x` of the scene, a scene
    whose vertex labels carry no locality is renumbered along a Morton curve of it, and
    the lists and queries run on that (the same bits, taken back to the caller's labels).

    Attributes
    ----------
    info : dict
        ``listed`` and ``fresh`` queries answered, ``builds``, ``completed`` (vertices
        of listed answers completed at r_q), ``relabelled``.
    """

    def __init__(self, E, F, thickness, gamma, x=None):
        from ..contact.locality import relabelling
        from ..contact.proximity import SeparationQuery
        from .bounds import _radius

        self.E, self.F = E, F
        self.h = _radius(thickness, "thickness")
        self.gamma = _radius(gamma, "gamma")
        self.nl = None
        self._relabel = None if x is None else relabelling(x, E, F)
        # the scene the lists and queries run on: the relabelled one, or the caller's
        self._E, self._F = (self._relabel.E, self._relabel.F) if self._relabel else (E, F)
        # fresh queries, and the reach of the last answer (`proximity.next_reach`)
        self.query = SeparationQuery(self._E, self._F)
        self.info = {"listed": 0, "fresh": 0, "builds": 0, "completed": 0, "relabelled": self._relabel is not None}

    @classmethod
    def for_scene(cls, x, edges, faces, thickness, gamma):
        from .bounds import scene_arrays

        x, E, F = scene_arrays(np.asarray(x), edges, faces)
        return cls(E, F, thickness, gamma, x=x)

    def _local(self, x):
        x = np.ascontiguousarray(x, dtype=np.float64)
        return self._relabel.positions(x) if self._relabel else x

    def begin_step(self, x, r_q):
        """Build the step's list at its start `x` (a no-op for r_q <= 0: no query then),
        at the reach of the last answer when that is below r_q."""
        from ..contact.neighbours import NeighbourList

        self.nl = None
        if r_q > 0 and (self.E.shape[0] > 1 or self.F.shape[0]):
            reach = self.query.reach
            r = float(r_q) if reach is None else min(float(r_q), reach)
            self.nl = NeighbourList(self._E, self._F, skin=STEP_SKIN_REL * r)
            self.nl.ensure(self._local(x), r, need_list=True)
            self.info["builds"] += 1

    def separations(self, x, r_q):
        """Per-vertex separations at `x` capped at `r_q`, as `per_vertex_separation`."""
        d = self._separations(self._local(x), r_q)
        return self._relabel.to_caller(d) if self._relabel else d

    def _separations(self, x, r_q):
        from ..contact.proximity import REACH_HEADROOM, complete_separations

        r_q = float(r_q)
        nl = self.nl
        cover = -np.inf if nl is None else nl.coverage(x)
        reach = self.query.reach
        expect = None if reach is None else reach / REACH_HEADROOM  # the last largest separation
        if cover >= r_q:
            d = nl.listed_separations(x, r_q)
        elif expect is not None and expect <= cover:
            # the list holds every pair within `cover` < r_q: the vertices it leaves at the
            # cap are completed at r_q, as a query at a reach (`complete_separations`)
            d = complete_separations(x, self._E, self._F, r_q, cover, nl.listed_separations(x, cover))
            self.info["completed"] += int(np.count_nonzero(d >= cover))
        else:
            self.info["fresh"] += 1
            return self.query(x, r_q)
        self.info["listed"] += 1
        self.query.observe(d, r_q)
        return d

    def __call__(self, x, r_q):
        return self.gamma * np.maximum(0.0, self.separations(x, r_q) - self.h)


def compute_stats(source=None, *, positions=None, deformed=None, frames=None, edges=None, faces=None,
                  thickness=None, gamma=DEFAULT_GAMMA, replay=False, replay_cap=DEFAULT_REPLAY_CAP,
                  bounds_fn=None, progress=None, contact_radius=None, obstacles=None) -> dict:
    """Per-step trust-region statistics of a deformed sequence.

    Parameters
    ----------
    source : DeformResult or (T, N, 3) float
        A result read by `penfree.formats.result.read_result` (positions, topology,
        thickness, ``steps/frame`` and ``steps/deformed`` are taken from it), or the
        recorded positions, then with `deformed` and `frames`.
    positions : (T, N, 3) float, optional
        The recorded positions, when `source` is not given.
    deformed : (S, N, 3) float, optional
        `x_def` of each step.
    frames : (S,) int, optional
        Frame index `s` of each step (1 <= s < T).
    edges : (E, 2) int, faces : (F, 3) int, thickness : float, optional
        Override the result's topology / thickness.
    contact_radius : float, optional
        The simulator's contact distance (sizes the query radius); default the
        result's, else 0.
    obstacles : list of Obstacle, optional
        Colliders counted in the bounds (held at the step's frame); default the
        result's.
    gamma : float
        OGC gamma_p.
    replay : bool
        Also run the replay estimate (one bound computation per pass).
    replay_cap : int
        Cap on replay passes.
    bounds_fn : callable, optional
        ``bounds_fn(x (N, 3) float64, query_radius float) -> (N,) float64``, with an
        optional ``begin_step(x, query_radius)`` called at each step's start; default
        `StepBounds` of this topology (`trust_region_bounds` bit for bit), or
        `trust_region_bounds` itself with obstacles.
    progress : callable, optional
        Called once per finished step.

    Returns
    -------
    dict of str -> ndarray
        The arrays named in the module docstring (`stats_keys(replay)`).

    Notes
    -----
    Two bound computations per step (at `x` and `x_def`), plus one per replay pass.
    """
    if source is None:
        source = positions
    if source is None:
        raise InputError("compute_stats needs a deform result, or positions with deformed= and frames=")
    positions, deformed, frames, edges, faces, thickness, contact_radius, obstacles = _unpack(
        source, deformed, frames, edges, faces, thickness, contact_radius, obstacles)
    frame_now = [0]  # kinematic obstacles are held at the step's frame
    if bounds_fn is None and not obstacles:
        # One list per step at its start, at the reach of the last answers (`StepBounds`):
        # x_def is an affine image of x. 1.25-1.3x over fresh queries at the reach on the
        # 64K yarn and cloth results (12 frames; at r_q it measured 0.82-1.09x).
        bounds_fn = StepBounds.for_scene(positions[0], edges, faces, thickness, gamma)
    elif bounds_fn is None:
        # Obstacles: fresh queries, each at the reach of the last state's separations.
        from ..contact.proximity import SeparationQuery
        from .bounds import scene_arrays, trust_region_bounds

        query = SeparationQuery(*scene_arrays(positions[0], edges, faces)[1:])

        def bounds_fn(x, r_q):
            return trust_region_bounds(x, edges=edges, faces=faces, thickness=thickness, gamma=gamma,
                                       query_radius=r_q, obstacles=obstacles, frame=frame_now[0], query=query)

    T, N = positions.shape[0], positions.shape[1]
    S = frames.shape[0]
    out = {k: np.full(S, np.nan) for k in stats_keys(replay)}
    out["frame"] = frames.copy()
    nbins = R_HIST_EDGES.size - 1
    for t in TARGETS:
        for s in STARTS:
            out[f"r_hist_{t}_{s}"] = np.full((S, nbins), np.nan)
    for i, f in enumerate(frames):
        x = np.asarray(positions[f], dtype=np.float64)
        x_pred = 2.0 * x - np.asarray(positions[f - 1], dtype=np.float64)
        starts = {"baseline": x, "deformed": np.asarray(deformed[i], dtype=np.float64)}
        targets = {"pred": x_pred}
        if f + 1 < T:
            targets["next"] = np.asarray(positions[f + 1], dtype=np.float64)
        r_q = query_radius(x, x_pred, contact_distance(contact_radius, thickness))
        out["query_radius"][i] = r_q
        frame_now[0] = int(f)
        if hasattr(bounds_fn, "begin_step"):
            bounds_fn.begin_step(x, r_q)

        def bounds_at(z, r_q=r_q):
            # r_q = 0 (no motion, no thickness): every d_v = 0, no CD query needed.
            return np.zeros(z.shape[0]) if r_q <= 0 else bounds_fn(z, r_q)

        for s, x_s in starts.items():
            b = bounds_at(x_s)
            for t, y in targets.items():
                rs = ratio_stats(x_s, y, b)
                for key, val in rs.items():
                    out[f"{key}_{t}_{s}"][i] = val
                out[f"residual_{t}_rms_{s}"][i], out[f"residual_{t}_max_{s}"][i] = residual_summary(x_s, y)
                if replay:
                    rp = replay_passes(x_s, y, bounds_at, cap=replay_cap, b0=b)
                    out[f"replay_k_any_{t}_{s}"][i] = rp["k_any"]
                    out[f"replay_k_1pct_{t}_{s}"][i] = rp["k_1pct"]
                    out[f"replay_capped_{t}_{s}"][i] = float(rp["capped"])
        if progress is not None:
            progress()
    return out
