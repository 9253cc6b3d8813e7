"""What a sequence (or a deform result) holds, as a plain dict for ``penfree info``.

>>> from penfree.core.describe import describe
>>> d = describe(seq)                          # doctest: +SKIP
>>> d["frames"], d["kind"], d["motion"]["max"]["median"]  # doctest: +SKIP
(40, 'segments', 0.0021)
"""

from __future__ import annotations

import numpy as np

from ..sequence import Sequence
from .topology import edges_from_faces


def _unique_edges(seq: Sequence) -> np.ndarray | None:
    """Edges of the scene: the faces' edges for triangles (each once), else the edges."""
    if seq.kind == "triangles":
        return edges_from_faces(seq.faces)
    if seq.kind == "segments":
        return seq.edges
    return None


def _summary(values: np.ndarray) -> dict:
    if values.size == 0:
        return {"min": None, "median": None, "max": None}
    return {"min": float(values.min()), "median": float(np.median(values)), "max": float(values.max())}


def frame_motion(positions: np.ndarray):
    """Per step s = 1..T-1: max and RMS of ``|x[s] - x[s-1]|`` over vertices.

    Parameters
    ----------
    positions : (T, N, 3) float32 or float64

    Returns
    -------
    max, rms : (T-1,) float64
        Computed in float64, one step at a time (no (T, N, 3) float64 copy).
    """
    T = positions.shape[0]
    mx, rms = np.empty(T - 1), np.empty(T - 1)
    for s in range(1, T):
        d = np.linalg.norm(positions[s].astype(np.float64) - positions[s - 1].astype(np.float64), axis=1)
        mx[s - 1] = d.max()
        rms[s - 1] = np.sqrt(np.mean(d * d))
    return mx, rms


def _bbox(positions: np.ndarray) -> dict:
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for x in positions:  # frame by frame: min/max of a float32 frame is exact
        lo = np.minimum(lo, x.min(axis=0))
        hi = np.maximum(hi, x.max(axis=0))
    return {"min": lo.tolist(), "max": hi.tolist(), "extent": (hi - lo).tolist()}


def describe(seq: Sequence) -> dict:
    """Summary of a validated sequence.

    Returns
    -------
    dict
        ``frames``, ``vertices``, ``kind``, ``n_edges``, ``n_faces``, ``dtype``,
        ``bbox`` (over all frames: ``min``, ``max``, ``extent``, each 3 floats),
        ``edge_length_median`` (frame 0; faces' edges for triangles; None for points),
        ``motion`` (``max`` and ``rms`` per step, each summarised as
        ``min``/``median``/``max`` over steps, plus ``per_step_max``/``per_step_rms`` lists),
        ``thickness``, ``contact_radius``, ``dt``, ``source``, ``weights``, ``components``, ``obstacles``
        (list of dicts: ``name``, ``half_space``, ``vertices``, ``faces``, ``edges``, ``static``;
        half-spaces add ``normal``, ``offset``), ``origin``.

    Notes
    -----
    Motion step s is frame s-1 -> s; in float64 whatever the input dtype.
    """
    E = _unique_edges(seq)
    edge_len = None
    if E is not None and len(E):
        x0 = seq.positions[0].astype(np.float64)
        edge_len = float(np.median(np.linalg.norm(x0[E[:, 1]] - x0[E[:, 0]], axis=1)))
    mx, rms = frame_motion(seq.positions)
    return {
        "origin": seq.origin,
        "frames": seq.n_frames,
        "vertices": seq.n_vertices,
        "kind": seq.kind,
        "n_edges": 0 if seq.edges is None else int(len(seq.edges)),
        "n_faces": 0 if seq.faces is None else int(len(seq.faces)),
        "dtype": str(seq.dtype),
        "bbox": _bbox(seq.positions),
        "edge_length_median": edge_len,
        "motion": {
            "max": _summary(mx),
            "rms": _summary(rms),
            "per_step_max": mx.tolist(),
            "per_step_rms": rms.tolist(),
        },
        "thickness": float(seq.thickness),
        "contact_radius": float(seq.contact_radius),
        "dt": seq.dt,
        "source": seq.source,
        "weights": seq.weights is not None,
        "components": None if seq.components is None else int(len(np.unique(seq.components))),
        "obstacles": [_obstacle(ob) for ob in seq.obstacles],
    }


def _obstacle(ob) -> dict:
    if ob.is_half_space:
        return {"name": ob.name, "half_space": True, "normal": [float(v) for v in ob.normal],
                "offset": float(ob.offset), "vertices": 0, "faces": 0, "edges": 0, "static": True}
    return {
        "name": ob.name,
        "half_space": False,
        "vertices": int(ob.positions.shape[-2]),
        "faces": 0 if ob.faces is None else int(len(ob.faces)),
        "edges": 0 if ob.edges is None else int(len(ob.edges)),
        "static": ob.positions.ndim == 2,
        # an analytic collider: the mesh contains it; deform and verify check the solid
        "solid": None if ob.shape is None else ob.shape.source,
    }


def describe_result(result) -> dict:
    """:func:`describe` of the input sequence plus the deform steps.

    Parameters
    ----------
    result : penfree.formats.result.DeformResult

    Returns
    -------
    dict
        ``describe(result.sequence)`` with a ``result`` entry: ``steps``,
        ``frames`` (first, last), ``models`` and ``projections`` (name -> count),
        ``min_certificate_margin`` (None if absent; NaN margins count as uncertified
        and make it NaN), ``attrs``.
    """
    d = describe(result.sequence)
    steps = result.steps

    def counts(key):
        if key not in steps:
            return {}
        names, n = np.unique(np.asarray(steps[key]).astype(str), return_counts=True)
        return {str(a): int(b) for a, b in zip(names, n)}

    margin = None
    if "certificate_margin" in steps and len(steps["certificate_margin"]):
        cm = np.asarray(steps["certificate_margin"], dtype=np.float64)
        margin = float(np.nan if np.isnan(cm).any() else cm.min())
    frames = steps["frame"]
    d["result"] = {
        "steps": int(len(frames)),
        "frames": [int(frames.min()), int(frames.max())] if len(frames) else None,
        "models": counts("model"),
        "projections": counts("projection"),
        "min_certificate_margin": margin,
        "groups": sorted(result.groups),
        "attrs": result.attrs,
    }
    return d
