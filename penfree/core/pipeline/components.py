"""Per-component affine maps (``--model per-component``) with inter-object safety.

A scene of several objects (cables in a pile, garments on a body) moves poorly under
one global map. Here every object gets its own map, fitted and certified exactly like a
global one (`fit_step` on its vertices), which makes the paths of each object's own
primitives penetration-free. Pairs *between* objects are not covered by any single
certificate: their straight paths are checked with the conservative CCD of
`verify_step` (no false negatives), the check the step gate runs on every step moved by
several maps (`gate.StepGate.between_maps`, which deform passes in). When a pair of
different groups may touch, the two groups are merged and refitted with one shared
map; this repeats until the check is clean. It terminates: every round merges at least two groups, and a single group
is one global certified map, safe for every pair of an intersection-free start state.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ..verify.gate import StepGate, deform_margin
from ..fit.step import fit_step


@dataclass
class ComponentStep:
    """The maps of one step.

    Attributes
    ----------
    x_def : (N, 3) array of x's dtype
    A : (C, 3, 3) float64
        Map applied to each component (components of one group share it).
    b : (C, 3) float64
    group : (C,) int64
        Group (smallest component label of the group) each component ended in.
    certificate_margin : float
        Smallest certified margin over the groups' maps.
    rank : int
        Largest rank used by a group's map.
    rounds : int
        CCD rounds run (1 when no merge was needed).
    models : dict
        Model used -> number of groups.
    time_fit_s : float
    """

    x_def: np.ndarray
    A: np.ndarray
    b: np.ndarray
    group: np.ndarray
    certificate_margin: float
    rank: int
    rounds: int
    models: dict
    time_fit_s: float


def component_labels(n, edges=None, faces=None, components=None) -> np.ndarray:
    """Labels ``0 .. C-1`` per vertex: the `components` dataset, else connected components.

    Parameters
    ----------
    n : int
        Number of vertices.
    edges : (E, 2) int or None
    faces : (F, 3) int or None
    components : (N,) int or None
        Given labels (any integers); relabelled to ``0 .. C-1`` in sorted order.

    Returns
    -------
    (N,) int64
    """
    if components is not None:
        labels = np.unique(np.asarray(components), return_inverse=True)[1]
        return labels.astype(np.int64).reshape(n)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    pairs = [np.zeros((0, 2), np.int64)]
    if edges is not None and len(edges):
        pairs.append(np.asarray(edges, dtype=np.int64))
    if faces is not None and len(faces):
        F = np.asarray(faces, dtype=np.int64)
        pairs += [F[:, [0, 1]], F[:, [1, 2]]]
    P = np.concatenate(pairs)
    graph = coo_matrix((np.ones(len(P)), (P[:, 0], P[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    return labels.astype(np.int64)


def _primitive_vertices(kind, i, j, res, faces):
    """Vertex index arrays of the two primitives of a violating pair."""
    base = kind.split(":")[0]
    if base == "ee":
        return res.edges[i], res.edges[j]
    if base == "vf":
        return np.array([i]), faces[j]
    if base == "ef":
        return res.edges[i], faces[j]
    raise InputError(f"unexpected pair kind {kind!r} from verify_step")


def per_component_step(x_prev, x, labels, *, edges=None, faces=None, thickness=0.0, weights=None,
                       margin=None, model="affine", projection="auto", out=None, check=None) -> ComponentStep:
    """One certified map per component; components whose paths may meet share a map.

    Parameters
    ----------
    x_prev, x : (N, 3) float
        Frames s - 1 and s (target ``2 x - x_prev``).
    labels : (N,) int64
        Component of each vertex, ``0 .. C-1`` (`component_labels`).
    edges, faces : topology for the CCD between components.
    thickness : float
        Contact distance kept between components along the path.
    weights, model, projection
        As in `fit_step`, per group. `model` is a model of the ladder.
    margin : float or None
        Certificate margin of every group's map. None: deform's
        (`gate.deform_margin`); with a thickness the pairs closer than the rule covers
        are checked by the caller's gate (`gate.StepGate`).
    out : (N, 3) array or None
    check : callable or None
        ``check(x_def) -> VerifyResult`` of the path x -> x_def in the deform-result
        reading, every violating pair listed: deform passes its step gate's
        (`gate.StepGate.between_maps`), which checks the written step the same way.
        None: that of a gate of its own at `x`.

    Returns
    -------
    ComponentStep

    Notes
    -----
    Within a group the exact certificate of its map makes every path safe (SPEC
    section 5); between groups the conservative CCD does, in the deform-result reading
    (pairs resting inside the thickness must stay disjoint); a pair touching at the
    start that moves is a violation, whose groups merge (the step gate then refuses
    to move it at all: rounding alone can make it cross). A violation the
    CCD cannot attribute to two different groups (a near-miss flagged inside one
    certified group) merges everything into one global map, which is certified.
    """
    t0 = time.perf_counter()
    x = np.asarray(x)
    x_prev = np.asarray(x_prev)
    n = x.shape[0]
    labels = np.asarray(labels, dtype=np.int64)
    if labels.shape != (n,):
        raise InputError(f"component labels must be ({n},); got {labels.shape}")
    C = int(labels.max()) + 1 if n else 0
    if margin is None:
        margin = deform_margin(thickness)
    if check is None:
        check = StepGate(x, edges=edges, faces=faces, thickness=thickness).between_maps
    w = None if weights is None else np.asarray(weights, dtype=np.float64)
    faces_arr = None if faces is None else np.asarray(faces, dtype=np.int64)
    group = np.arange(C)  # group of each component: its smallest member
    x_def = np.empty_like(x) if out is None else out
    A = np.empty((C, 3, 3))
    b = np.empty((C, 3))
    fitted = {}  # members (tuple of components) -> StepResult
    rounds = 0
    while True:
        rounds += 1
        members = {g: tuple(np.flatnonzero(group == g)) for g in np.unique(group)}
        fitted = {key: fitted[key] for key in members.values() if key in fitted}
        for key in members.values():
            if key in fitted:
                continue
            idx = np.flatnonzero(np.isin(labels, key))
            wg = None if w is None or not w[idx].sum() > 0 else w[idx]
            r = fit_step(x_prev[idx], x[idx], weights=wg, model=model, projection=projection, margin=margin)
            fitted[key] = r
            x_def[idx] = r.x_def
            A[list(key)], b[list(key)] = r.A, r.b
        if len(fitted) == 1:
            break
        # a pair touching at the start that moves is a violation (`path._excuse`): its groups merge
        res = check(x_def)
        if res.ok:
            break
        before = group.copy()
        if res.start_ok:
            for kind, i, j in [p[:3] for p in res.pairs]:
                va, vb = _primitive_vertices(kind, i, j, res, faces_arr)
                touched = np.unique(group[labels[np.concatenate([va, vb])]])
                group[np.isin(group, touched)] = touched[0]
        if np.array_equal(group, before):  # start violation or an intra-group flag
            group[:] = 0
    models = {}
    for r in fitted.values():
        models[r.model] = models.get(r.model, 0) + 1
    return ComponentStep(
        x_def=x_def, A=A, b=b, group=group.astype(np.int64),
        certificate_margin=float(min(r.certificate_margin for r in fitted.values())),
        rank=int(max(r.rank for r in fitted.values())), rounds=rounds, models=models,
        time_fit_s=time.perf_counter() - t0,
    )
