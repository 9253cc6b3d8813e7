"""Issue 10 acceptance on the contact-rich samples: certified maps, verify, obstacle oracle.

For every sample and model: run `deform_sequence`, count the steps that carry a
certified non-translation map (model neither ``none`` nor ``translation``), verify
every written step with `verify_result` (the deform-result reading, obstacles held at
frame s), and check every step independently against the obstacles with the sample
checker's brute force (``samples/check.py``: the straight path sampled at 17 times,
all scene-obstacle pairs of static mesh obstacles, and the exact end-point test for
half-spaces).

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


def obstacle_oracle(path, seq, steps):
    """Smallest scene-obstacle distance over every written path (inf without obstacles)."""
    if not seq.obstacles:
        return np.inf
    _, _, _, attrs = check.load(path)
    obs = attrs["obstacles"]
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
    print("| sample | model | steps | certified non-translation | all certified | verify | obstacle oracle min |")
    print("|---|---|---|---|---|---|---|")
    for path in a.samples:
        seq = read_sequence(path)
        for model in a.models:
            t0 = time.perf_counter()
            out = deform_sequence(seq, model=model)
            summary = summarize_steps(out.steps)
            moving = sum(str(m) not in ("none", "translation") for m in out.steps["model"])
            rep = verify_result(DeformResult(sequence=seq, steps=out.steps, origin=path))
            oracle = obstacle_oracle(path, seq, out.steps)
            ok = oracle > max(seq.thickness, 1e-12)
            S = len(out.steps["frame"])
            print(f"| {os.path.basename(path)} | {model} | {S} | {moving} ({100 * moving / S:.0f}%) | "
                  f"{'yes' if summary['all_certified'] else 'NO'} | {'ok' if rep.ok else 'FAIL'} | "
                  f"{'-' if oracle == np.inf else f'{oracle:.4g} ' + ('ok' if ok else 'FAIL')} |"
                  f" <!-- {time.perf_counter() - t0:.0f} s -->")
    return 0


if __name__ == "__main__":
    sys.exit(main())
