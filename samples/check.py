"""Self-contained separation checker for recorded sequences (numpy + scipy only).

For every step it samples the straight path between consecutive frames at
``substeps + 1`` times and measures, over all *non-adjacent* primitive pairs,
the smallest distance:

- segment scenes: edge-edge pairs that share no vertex;
- triangle scenes: vertex-face pairs with the vertex not in the face, and
  edge-edge pairs (edges of the faces) that share no vertex.

Pairs are pruned per step with bounding spheres of the swept primitives (a
point of a linearly moving primitive stays in the convex hull of its vertices
at both frames, so the prune is conservative), keeping every pair that can
come within ``query`` of each other. Distances at or above ``query`` are
reported as ``>= query``.

Obstacles (``obstacles/<name>``) are checked too: a static mesh obstacle is
appended to every frame as extra, motionless primitives (so scene-obstacle pairs
enter the same measure), and a half-space by the smallest signed distance of any
vertex over all frames (exact for straight paths: the distance to a plane is
linear along them).

Usage::

    python samples/check.py samples/cloth.h5 [--substeps 16] [--query Q]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from scipy.spatial import cKDTree


def point_segment(p, a, b):
    """Distance from points `p` to segments `ab`; all (..., 3)."""
    ab = b - a
    t = np.einsum("...k,...k->...", p - a, ab) / np.maximum(
        np.einsum("...k,...k->...", ab, ab), 1e-300)
    t = np.clip(t, 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


def segment_segment(p1, q1, p2, q2):
    """Distance between segments `p1q1` and `p2q2`; all (..., 3).

    The closed-form closest points (Ericson, Real-Time Collision Detection
    5.1.9) are exact away from parallel configurations; near them the minimum
    sits at an endpoint, so the endpoint-to-segment distances cover it.
    """
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    dot = lambda u, v: np.einsum("...k,...k->...", u, v)  # noqa: E731
    a, e, f, c, b = dot(d1, d1), dot(d2, d2), dot(d2, r), dot(d1, r), dot(d1, d2)
    denom = a * e - b * b
    ok = denom > 1e-12 * a * e
    s = np.where(ok, np.clip((b * f - c * e) / np.where(ok, denom, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e
    lo, hi = t < 0.0, t > 1.0
    s = np.where(lo, np.clip(-c / a, 0.0, 1.0), np.where(hi, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    dist = np.linalg.norm(p1 + s[..., None] * d1 - p2 - t[..., None] * d2, axis=-1)
    return np.minimum.reduce([dist, point_segment(p1, p2, q2), point_segment(q1, p2, q2),
                              point_segment(p2, p1, q1), point_segment(q2, p1, q1)])


def point_triangle(p, a, b, c):
    """Distance from points `p` to triangles `abc`; all (..., 3)."""
    n = np.cross(b - a, c - a)
    nn = np.einsum("...k,...k->...", n, n)
    # Barycentric coordinates of the projection of p onto the plane.
    u = np.einsum("...k,...k->...", np.cross(c - b, p - b), n) / nn
    v = np.einsum("...k,...k->...", np.cross(a - c, p - c), n) / nn
    inside = (u >= 0) & (v >= 0) & (u + v <= 1)
    plane = np.abs(np.einsum("...k,...k->...", p - a, n)) / np.sqrt(nn)
    edge = np.minimum.reduce([point_segment(p, a, b), point_segment(p, b, c),
                              point_segment(p, c, a)])
    return np.where(inside, np.minimum(plane, edge), edge)


def unique_edges(faces):
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


def _spheres(x0, x1, prim):
    """Bounding spheres (center, radius) of primitives `prim` swept from x0 to x1."""
    pts = np.concatenate([x0[prim], x1[prim]], axis=1)
    ctr = pts.mean(axis=1)
    rad = np.linalg.norm(pts - ctr[:, None], axis=2).max(axis=1)
    return ctr, rad


def _candidates(ca, ra, cb, rb, query, same):
    if same:
        pairs = cKDTree(ca).query_pairs(2 * ra.max() + query, output_type="ndarray")
        i, j = pairs[:, 0], pairs[:, 1]
    else:
        m = cKDTree(ca).sparse_distance_matrix(
            cKDTree(cb), ra.max() + rb.max() + query, output_type="ndarray")
        i, j = m["i"].astype(np.int64), m["j"].astype(np.int64)
    keep = np.linalg.norm(ca[i] - cb[j], axis=1) <= ra[i] + rb[j] + query
    return i[keep], j[keep]


def _interval_min_distance(xa, xb, ts, edges, faces, query, chunk):
    """Smallest sampled distance for the motion xa -> xb at fractions `ts` (or `query`)."""
    ts = ts[:, None, None]
    best = float(query)
    groups = []
    if faces is not None and len(faces):
        verts = np.arange(len(xa))[:, None]
        cv, rv = _spheres(xa, xb, verts)
        cf, rf = _spheres(xa, xb, faces)
        i, j = _candidates(cv, rv, cf, rf, query, same=False)
        keep = ~(faces[j] == i[:, None]).any(axis=1)
        groups.append(("vf", i[keep], faces[j[keep]]))
    ce, re = _spheres(xa, xb, edges)
    i, j = _candidates(ce, re, ce, re, query, same=True)
    ea, eb = edges[i], edges[j]
    keep = ~((ea[:, :, None] == eb[:, None, :]).any(axis=(1, 2)))
    groups.append(("ee", ea[keep], eb[keep]))
    for kind, a, b in groups:
        for s in range(0, len(a), chunk):
            aa, bb = a[s:s + chunk], b[s:s + chunk]
            P = lambda idx: (1 - ts) * xa[idx] + ts * xb[idx]  # noqa: E731
            if kind == "vf":
                d = point_triangle(P(aa), P(bb[:, 0]), P(bb[:, 1]), P(bb[:, 2]))
            else:
                d = segment_segment(P(aa[:, 0]), P(aa[:, 1]), P(bb[:, 0]), P(bb[:, 1]))
            if d.size:
                best = min(best, float(d.min()))
    return best


def step_min_distance(x0, x1, edges, faces, query, substeps=16, chunk=50_000):
    """Smallest non-adjacent distance along the straight path x0 -> x1 (or `query`).

    The step is cut into intervals moving at most about ``query / 2`` each, so
    that the swept bounding spheres stay tight; each interval is sampled at
    its share of the ``substeps + 1`` times.

    Returns
    -------
    float
        The minimum over sampled times and candidate pairs, capped at `query`.
    """
    if faces is not None and len(faces):
        edges = unique_edges(faces)
    move = float(np.linalg.norm(x1 - x0, axis=1).max())
    n_int = int(min(substeps, max(1, np.ceil(2 * move / query))))
    cuts = np.linspace(0, substeps, n_int + 1).round().astype(int)
    best = float(query)
    for k in range(n_int):
        ta, tb = cuts[k] / substeps, cuts[k + 1] / substeps
        xa, xb = (1 - ta) * x0 + ta * x1, (1 - tb) * x0 + tb * x1
        ts = (np.arange(cuts[k], cuts[k + 1] + 1) / substeps - ta) / (tb - ta)
        best = min(best, _interval_min_distance(xa, xb, ts, edges, faces, query, chunk))
    return best


def check_sequence(positions, edges=None, faces=None, query=None, substeps=16, steps=None):
    """Minimum non-adjacent separation at every frame and along every straight step.

    Parameters
    ----------
    positions : (T, N, 3) float
    edges : (E, 2) int or None
    faces : (F, 3) int or None
    query : float or None
        Distances at or above it are not resolved; default: the median edge length.
    steps : iterable of int or None
        Steps (s -> s+1) to check; default all.

    Returns
    -------
    dict
        ``min`` (float), ``per_step`` ((T-1,) float, NaN where not checked),
        ``query``, ``min_edge`` (smallest edge length over all frames),
        ``max_disp_ratio`` (largest per-frame vertex displacement over the
        smallest rest edge length).
    """
    X = np.asarray(positions, dtype=np.float64)
    ed = unique_edges(faces) if faces is not None and len(faces) else np.asarray(edges)
    lens = np.linalg.norm(X[:, ed[:, 0]] - X[:, ed[:, 1]], axis=2)
    if query is None:
        query = float(np.median(lens[0]))
    per = np.full(len(X) - 1, np.nan)
    for s in (range(len(X) - 1) if steps is None else steps):
        per[s] = step_min_distance(X[s], X[s + 1], edges, faces, query, substeps)
    disp = np.linalg.norm(np.diff(X, axis=0), axis=2).max()
    return {"min": float(np.nanmin(per)), "per_step": per, "query": query,
            "min_edge": float(lens.min()), "max_disp_ratio": float(disp / lens[0].min())}


def load(path):
    import h5py
    with h5py.File(path, "r") as f:
        X = f["positions"][()]
        edges = f["edges"][()].astype(np.int64) if "edges" in f else None
        faces = f["faces"][()].astype(np.int64) if "faces" in f else None
        attrs = dict(f.attrs)
        obstacles = {}
        for name, g in (f["obstacles"].items() if "obstacles" in f else ()):
            obstacles[name] = {k: g[k][()] for k in g}
            obstacles[name].update({k: g.attrs[k] for k in g.attrs})
    attrs["obstacles"] = obstacles
    return X, edges, faces, attrs


def with_obstacles(X, faces, obstacles):
    """Append static mesh obstacles (faces) to every frame: ``(X, faces)`` of the union."""
    X = np.asarray(X, dtype=np.float64)
    for ob in obstacles.values():
        if "faces" not in ob:
            continue
        V = np.asarray(ob.get("vertices", ob.get("positions")), dtype=np.float64)
        n = X.shape[1]
        X = np.concatenate([X, np.broadcast_to(V, (X.shape[0],) + V.shape)], axis=1)
        faces = np.concatenate([faces, np.asarray(ob["faces"], dtype=np.int64) + n])
    return X, faces


def half_space_min(X, obstacles):
    """Smallest signed distance of any vertex to any half-space over all frames (inf if none)."""
    best = np.inf
    for ob in obstacles.values():
        if "normal" in ob:
            nv = np.asarray(ob["normal"], dtype=np.float64)
            best = min(best, float(((X @ nv - float(ob["offset"])) / np.linalg.norm(nv)).min()))
    return best


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("path")
    ap.add_argument("--substeps", type=int, default=16)
    ap.add_argument("--query", type=float, default=None)
    ap.add_argument("--every", type=int, default=1, help="check every k-th step only")
    a = ap.parse_args(argv)
    X, edges, faces, attrs = load(a.path)
    thickness = float(attrs.get("thickness", 0.0))
    obstacles = attrs["obstacles"]
    plane = half_space_min(np.asarray(X, dtype=np.float64), obstacles)
    if faces is not None and any("faces" in ob for ob in obstacles.values()):
        X, faces = with_obstacles(X, faces, obstacles)
    r = check_sequence(X, edges, faces, a.query, a.substeps, range(0, len(X) - 1, a.every))
    ok = r["min"] > max(thickness, 1e-9) and plane > max(thickness, 1e-9)
    print(f"{a.path}: T={X.shape[0]} N={X.shape[1]} thickness={thickness:.4g} "
          f"min_edge={r['min_edge']:.4g} max_disp/min_edge={r['max_disp_ratio']:.3f} "
          f"min_separation={'>=' if r['min'] >= r['query'] else ''}{r['min']:.4g} "
          f"(query {r['query']:.4g}, {a.substeps} substeps)"
          f"{'' if plane == np.inf else f' half-space min distance={plane:.4g}'} -> {'OK' if ok else 'FAIL'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
