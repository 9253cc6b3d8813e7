"""Issue 10 acceptance on the contact-rich samples: certified maps, verify, obstacle oracle.

For every sample and model: run `deform_sequence`, count the steps that carry a
certified non-translation map (model neither ``none`` nor ``translation``), verify
every written step with `verify_result` (the deform-result reading, obstacles held at
frame s), and check every step independently against the obstacles with the sample
checker's brute force (``samples/check.py``: the straight path sampled at 17 times,
all scene-obstacle pairs of static mesh obstacles, and the exact end-point test for
half-spaces). That minimum is the whole answer for a clean recording; for a dirty one
(`dirty_recording.py`: vertices inside a collider, resting contact inside the
thickness) `pair_oracle` reads each pair as the guarantee does: pairs that start at
least the thickness apart stay so, pairs that start closer never touch, and no vertex
on or behind a half-space goes deeper.

    python benchmarks/eval_contact.py [--models auto affine] [SAMPLE.h5 ...]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "samples"))

import check  # noqa: E402

from penfree.core.pipeline.deform import deform_sequence, summarize_steps  # noqa: E402
from penfree.core.pipeline.verification import verify_result  # noqa: E402
from penfree.formats import read_sequence  # noqa: E402
from penfree.formats.result import DeformResult  # noqa: E402

DEFAULT = ["samples/twisting_cloth_contact.h5", "samples/twisted_cables.h5", "samples/cloth_drape_box.h5"]


def pair_oracle(obs, seq, steps, samples=33):
    """The guarantee's reading of a recording that may start dirty, per scene-obstacle pair.

    Every vertex-face and edge-edge pair of the scene's triangles with a static mesh
    obstacle whose swept bounding spheres come within the thickness plus the median
    scene edge, and every vertex against each half-space, over every written path
    (sampled at `samples` times; half-spaces exactly, at the ends). Returns ``(beyond,
    inside, deeper)``: the smallest distance over the pairs that start at least the
    thickness apart (the guarantee: never below the thickness), over the pairs that start
    closer (resting contact or a crossing: never 0), and the number of vertices that
    start on or behind a half-space and end deeper (the guarantee: none). `obs`: the file's
    obstacles as `check.load` reads them.
    """
    beyond, inside, deeper = np.inf, np.inf, 0
    if not seq.obstacles or seq.faces is None:
        return beyond, inside, deeper
    h = float(seq.thickness)
    F = np.asarray(seq.faces, dtype=np.int64)
    E = check.unique_edges(F)
    ts = np.linspace(0.0, 1.0, samples)
    for k, s in enumerate(steps["frame"]):
        x0 = np.asarray(seq.positions[s], dtype=np.float64)
        x1 = np.asarray(steps["deformed"][k], dtype=np.float64)
        if np.array_equal(x0, x1):
            continue
        query = h + float(np.median(np.linalg.norm(x0[E[:, 0]] - x0[E[:, 1]], axis=1)))
        for ob in obs.values():
            if "normal" in ob:
                nv = np.asarray(ob["normal"], dtype=np.float64)
                d0, d1 = ((x @ nv - float(ob["offset"])) / np.linalg.norm(nv) for x in (x0, x1))
                out = d0 >= h
                beyond = min(beyond, float(d1[out].min(initial=np.inf)))
                mid = (d0 > 0) & ~out
                inside = min(inside, float(d1[mid].min(initial=np.inf)))
                deeper += int(np.count_nonzero((d0 <= 0) & (d1 < d0)))
                continue
            if "faces" not in ob:
                continue
            V = np.asarray(ob.get("vertices", ob.get("positions")), dtype=np.float64)
            V = V[s] if V.ndim == 3 else V  # deform holds obstacles at the step's frame
            BF = np.asarray(ob["faces"], dtype=np.int64)
            BE = check.unique_edges(BF)
            for A, B, dist in ((np.arange(len(x0))[:, None], BF, "vf"), (E, BE, "ee")):
                ca, ra = check._spheres(x0, x1, A)
                cb, rb = check._spheres(V, V, B)
                i, j = check._candidates(ca, ra, cb, rb, query, same=False)
                if not len(i):
                    continue

                def d(x):
                    if dist == "vf":
                        return check.point_triangle(x[A[i, 0]], V[B[j, 0]], V[B[j, 1]], V[B[j, 2]])
                    return check.segment_segment(x[A[i, 0]], x[A[i, 1]], V[B[j, 0]], V[B[j, 1]])

                d0 = d(x0)
                low = np.minimum.reduce([d((1 - t) * x0 + t * x1) for t in ts])
                beyond = min(beyond, float(low[d0 >= h].min(initial=np.inf)))
                inside = min(inside, float(low[d0 < h].min(initial=np.inf)))
    return beyond, inside, deeper


def obstacle_oracle(obs, seq, steps):
    """Smallest scene-obstacle distance over every written path (inf without obstacles);
    `obs` as `pair_oracle` takes it."""
    if not seq.obstacles:
        return np.inf
    best = np.inf
    for k, s in enumerate(steps["frame"]):
        x0 = np.asarray(seq.positions[s], dtype=np.float64)
        x1 = np.asarray(steps["deformed"][k], dtype=np.float64)
        best = min(best, check.half_space_min(np.stack([x0, x1]), obs))
        if seq.faces is not None and any("faces" in ob for ob in obs.values()):
            X, F = check.with_obstacles(np.stack([x0, x1]), np.zeros((0, 3), np.int64), obs)
            # the scene's faces plus the obstacle's: scene-obstacle pairs (and the scene's
            # own pairs, which verify checks too) within the query
            F = np.concatenate([seq.faces, F])
            best = min(best, check.step_min_distance(X[0], X[1], None, F, query=0.05, substeps=16))
    return best


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("samples", nargs="*", default=DEFAULT)
    ap.add_argument("--models", nargs="+", default=["auto", "affine"])
    a = ap.parse_args(argv)
    print("| sample | model | steps | certified non-translation | all certified | verify | obstacle oracle min "
          "| pairs starting beyond h: min | pairs starting within h: min, deeper |")
    print("|---|---|---|---|---|---|---|---|---|")
    for path in a.samples:
        seq = read_sequence(path)
        obs = check.load(path)[3]["obstacles"]
        for model in a.models:
            t0 = time.perf_counter()
            out = deform_sequence(seq, model=model)
            summary = summarize_steps(out.steps)
            moving = sum(str(m) not in ("none", "translation") for m in out.steps["model"])
            rep = verify_result(DeformResult(sequence=seq, steps=out.steps, origin=path))
            oracle = obstacle_oracle(obs, seq, out.steps)
            ok = oracle > max(seq.thickness, 1e-12)
            beyond, inside, deeper = pair_oracle(obs, seq, out.steps)
            ok_beyond, ok_inside = beyond >= seq.thickness, inside > 0 and deeper == 0
            S = len(out.steps["frame"])
            print(f"| {os.path.basename(path)} | {model} | {S} | {moving} ({100 * moving / S:.0f}%) | "
                  f"{'yes' if summary['all_certified'] else 'NO'} | {'ok' if rep.ok else 'FAIL'} | "
                  f"{'-' if oracle == np.inf else f'{oracle:.4g} ' + ('ok' if ok else 'FAIL')} | "
                  f"{'-' if beyond == np.inf else f'{beyond:.5g} ' + ('ok' if ok_beyond else 'FAIL')} | "
                  f"{'-' if inside == np.inf and not deeper else f'{inside:.3g}, {deeper} ' + ('ok' if ok_inside else 'FAIL')} |"
                  f" <!-- {time.perf_counter() - t0:.0f} s -->")
    return 0


if __name__ == "__main__":
    sys.exit(main())
