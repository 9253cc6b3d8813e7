"""A dirty copy of a recording: vertices inside a collider, sunk into the thickness, through the scene, or a ground added.

Real OGC-family recordings are not as clean as the bundled samples: a few vertices end
up inside a collider or through another part of the scene (pre-existing crossings), and
cloth resting on a collider may sit a little inside the thickness the file declares. This writes such a copy of a clean recording, to
judge `deform` and `auto` on (`eval_client.py`, `eval_contact.py`):

* ``--dent K``: K vertices (seeded choice among those within ``--near`` (default 1.25
  contact radii: resting contact sits at the radius) of an obstacle face
  at the last frame) are moved, from the first frame they come that near on, to
  ``--depth`` beneath their nearest obstacle face, along its normal (faces are taken as
  outward, as the samples store them). Only vertices whose projection falls inside that
  face are chosen.
* ``--sink F``: at every frame, every vertex within ``--near`` of an obstacle face (its
  projection inside the face) is moved toward the face so that its distance becomes F
  times what it was.

* ``--push K --offset X,Y,Z``: K vertices (seeded choice, of component ``--component``
  when given) are displaced by the offset in every frame: through another part of the
  scene, pre-existing self-intersections (a stack of cloth layers with a few vertices
  of one layer pushed through the next).

* ``--ground Z``: records a ground the simulation had but the file lacks, the half-space
  ``z > Z`` as ``obstacles/ground`` (the falling stack lands on a 50 m sphere whose top
  is at z = 0; the copy with ``--ground 0`` holds its resting layer 0-1 mm inside that
  plane, as a recording of a solver without a collision offset would).

Nearest faces are found by brute force over the obstacle's faces (for small colliders:
the samples' box has 12). The input is never modified; the output is created exclusively
unless ``--overwrite``.

    python benchmarks/dirty_recording.py samples/cloth_drape_box.h5 -o dirty.h5 --dent 16
    python benchmarks/dirty_recording.py samples/cloth_drape_box.h5 -o sunk.h5 --sink 0.45
    python benchmarks/dirty_recording.py samples/falling_stack.h5 -o crossed.h5 --push 12 --offset 0,0,0.06 --component 0
    python benchmarks/dirty_recording.py samples/falling_stack.h5 -o grounded.h5 --ground 0
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys

import h5py
import numpy as np


def nearest_faces(P, V, F):
    """Per point of `P` (N, 3): signed distance to the plane of its nearest face of the mesh
    (V, F) among the faces its projection falls inside (inf where none), and that face's
    unit normal (N, 3)."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    rel = P[:, None, :] - a[None]  # (N, M, 3)
    h = np.einsum("nmk,mk->nm", rel, n)
    q = P[:, None, :] - h[..., None] * n[None]  # projections
    inside = np.ones(h.shape, bool)
    for s, t in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("nmk,mk->nm", np.cross(t - s, q - s[None]), n) >= 0.0
    dist = np.where(inside, np.abs(h), np.inf)
    j = dist.argmin(axis=1)
    rows = np.arange(len(P))
    found = np.isfinite(dist[rows, j])
    return np.where(found, h[rows, j], np.inf), n[j]


def _meshes(f):
    """``[(vertices (M, 3) or (T, M, 3), faces)]`` of the file's mesh obstacles."""
    return [(np.asarray(g["vertices"][...], dtype=np.float64), np.asarray(g["faces"][...], dtype=np.int64))
            for g in f.get("obstacles", {}).values() if "vertices" in g and "faces" in g]


def _nearest(x, meshes, s):
    """Signed plane distance and normal of each vertex of frame `x` to its nearest mesh face."""
    best_h, best_n = np.full(len(x), np.inf), np.zeros((len(x), 3))
    for V, F in meshes:
        h, n = nearest_faces(x, V[s] if V.ndim == 3 else V, F)
        closer = np.abs(h) < np.abs(best_h)
        best_h[closer], best_n[closer] = h[closer], n[closer]
    return best_h, best_n


def dirty(X, meshes, near, dent=0, depth=None, sink=None, seed=0):
    """The dirty frames (float64 copy of `X` (T, N, 3)) and the dented vertices."""
    X = np.array(X, dtype=np.float64)
    hs, ns = zip(*(_nearest(X[s], meshes, s) for s in range(X.shape[0])))
    H, Nrm = np.stack(hs), np.stack(ns)  # (T, N), (T, N, 3)
    is_near = (H >= 0.0) & (H <= near)
    picked = np.zeros(0, np.int64)
    if dent:
        picked = _choose(np.flatnonzero(is_near[-1]), dent, seed,
                         f"vertices within {near:g} of an obstacle face at the last frame")
        for v in picked:
            first = int(np.flatnonzero(is_near[:, v])[0])
            X[first:, v] -= (H[first:, v] + depth)[:, None] * Nrm[first:, v]
    if sink is not None:
        keep = np.ones(X.shape[1], bool)
        keep[picked] = False
        move = is_near & keep[None]
        X -= np.where(move, (1.0 - sink) * H, 0.0)[..., None] * Nrm
    return X, picked


def push(X, k, offset, pool, seed=0):
    """`X` (float64 copy) with `k` vertices of `pool` (seeded choice) moved by `offset` in
    every frame, and the chosen vertices."""
    X = np.array(X, dtype=np.float64)
    picked = _choose(pool, k, seed, "vertices to push")
    X[:, picked] += offset
    return X, picked


def _choose(pool, k, seed, what):
    """`k` of the vertices `pool`, a seeded choice, sorted."""
    if len(pool) < k:
        raise SystemExit(f"dirty_recording: only {len(pool)} {what}; asked for {k}")
    return np.sort(np.random.default_rng(seed).choice(pool, k, replace=False))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("input")
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--dent", type=int, default=0, help="vertices moved inside an obstacle")
    ap.add_argument("--depth", type=float, default=None, help="how far inside (default: a third of the thickness)")
    ap.add_argument("--sink", type=float, default=None,
                    help="scale the distance of vertices near an obstacle face by this factor (0 < F <= 1)")
    ap.add_argument("--near", type=float, default=None,
                    help="how near a face counts (default: 1.25 contact radii, where resting contact sits)")
    ap.add_argument("--push", type=int, default=0, help="vertices displaced by --offset in every frame")
    ap.add_argument("--offset", default="0,0,0", help="X,Y,Z displacement of the pushed vertices")
    ap.add_argument("--component", type=int, default=None, help="push vertices of this component only")
    ap.add_argument("--ground", type=float, default=None, help="add the half-space z > GROUND as obstacles/ground")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--overwrite", action="store_true")
    a = ap.parse_args(argv)
    if os.path.abspath(a.input) == os.path.abspath(a.output):
        raise SystemExit("dirty_recording: the output must not be the input")
    if os.path.exists(a.output) and not a.overwrite:
        raise SystemExit(f"dirty_recording: {a.output} exists (--overwrite to replace it)")
    if a.sink is not None and not 0.0 < a.sink <= 1.0:
        raise SystemExit(f"dirty_recording: --sink must be in (0, 1]; got {a.sink}")
    with h5py.File(a.input, "r") as f:
        X = f["positions"][...]
        meshes = _meshes(f)
        h = float(f.attrs.get("thickness", 0.0))
        r = float(f.attrs.get("contact_radius", h))
        comp = f["components"][...] if "components" in f else None
        has_ground = "obstacles/ground" in f
    Xd, msg = X, []
    if a.push:
        offset = np.array([float(v) for v in a.offset.split(",")])
        if offset.shape != (3,):
            raise SystemExit(f"dirty_recording: --offset must be X,Y,Z; got {a.offset!r}")
        pool = np.arange(X.shape[1])
        if a.component is not None:
            if comp is None:
                raise SystemExit(f"dirty_recording: {a.input} has no components dataset for --component")
            pool = np.flatnonzero(comp == a.component)
        Xd, pushed = push(Xd, a.push, offset, pool, a.seed)
        msg.append(f"pushed {len(pushed)} vertices {pushed.tolist()} by {offset.tolist()}")
    if a.dent or a.sink is not None:
        if not meshes:
            raise SystemExit(f"dirty_recording: {a.input} has no mesh obstacle (obstacles/<name>/vertices + faces)")
        near = a.near if a.near is not None else 1.25 * r
        depth = a.depth if a.depth is not None else (h / 3.0 if h > 0 else 1e-3 * near)
        Xd, picked = dirty(Xd, meshes, near, a.dent, depth, a.sink, a.seed)
        msg.append(f"dented {len(picked)} vertices {picked.tolist()} to {depth:g} inside")
        if a.sink is not None:
            msg.append(f"near vertices sunk to {a.sink:g} of their distance")
    if a.ground is not None:
        if has_ground:
            raise SystemExit(f"dirty_recording: {a.input} already has obstacles/ground")
        if not np.isfinite(a.ground):
            raise SystemExit(f"dirty_recording: --ground must be finite; got {a.ground}")
        below = int(np.count_nonzero((Xd[..., 2] < a.ground).any(axis=0)))
        msg.append(f"ground z > {a.ground:g} added ({below} vertices below it in some frame)")
    if not msg:
        raise SystemExit("dirty_recording: nothing to do (give --dent, --sink, --push or --ground)")
    tmp = a.output + ".tmp"
    shutil.copyfile(a.input, tmp)
    with h5py.File(tmp, "r+") as f:
        f["positions"][...] = Xd.astype(X.dtype)
        if a.ground is not None:
            g = f.create_group("obstacles/ground")
            g["normal"] = np.array([0.0, 0.0, 1.0])
            g["offset"] = float(a.ground)
        cmd = "python benchmarks/dirty_recording.py " + " ".join(sys.argv[1:] if argv is None else argv)
        f.attrs["source"] = f"{f.attrs.get('source', '')}\ndirty copy: {cmd}".strip()
    os.replace(tmp, a.output)
    print(f"{a.output}: " + "; ".join(msg))


if __name__ == "__main__":
    main()
