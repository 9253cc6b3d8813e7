"""Real-client CD passes (ipctk.ogc.TrustRegion) of `auto` against the baseline, per sample.

For every sample, `penfree deform --model auto --client-model T` is run for each
truncation T (predicting for radius rule ``step``; with ``--radius own``, as
``--client-radius own``, for rule ``own``), and every step is replayed through
``ipctk.ogc.TrustRegion`` from the recorded ``x`` and from ``x_def``, under both
radius rules (``step``: the simulator keeps the radius of ``x``; ``own``: ipctk's warm
start recomputes it from ``x_def`` and moves isotropically within the radii). The
sample's obstacles are in the client's collision mesh, for the prediction and the
replay alike (`penfree.core.trust.client_scene`). Printed: passes summed over the
sequence, each rule against its own baseline from ``x``.

    python benchmarks/eval_client.py [--every K] [--client ipctk|own] [--truncation T] [--radius step|own]
                                     [SAMPLE.h5 ...]

Needs ipctk (pip install 'penfree[ogc]') for ``--client ipctk``.
"""

from __future__ import annotations

import argparse
import glob
import os
import sys
import time

import numpy as np

from penfree import read_sequence
from penfree.core.pipeline.client_select import ClientModel
from penfree.core.trust.client_stats import client_counts, resolve_dhat, summarize_counts
from penfree.core.pipeline.deform import deform_sequence

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")


def evaluate(path, every=1, client="ipctk", truncations=("isotropic", "planar"), predictor="own", repeat=True,
             radius="step"):
    seq = read_sequence(path)
    dhat = resolve_dhat(None, seq.contact_radius, seq.thickness)
    rows = {}
    for tr in truncations:
        cm = ClientModel(truncation=tr, dhat=dhat, edges=seq.edges, faces=seq.faces, predictor=predictor,
                         repeat=repeat, radius=radius, obstacles=tuple(seq.obstacles))
        t0 = time.perf_counter()
        out = deform_sequence(seq, model="auto", client_model=cm)
        t_fit = time.perf_counter() - t0
        counts = client_counts(seq.positions, out.steps["deformed"], out.steps["frame"], edges=seq.edges,
                               faces=seq.faces, dhat=dhat, thickness=seq.thickness, truncations=(tr,),
                               every=every, client=client, models=out.steps["model"], obstacles=seq.obstacles)
        sm = summarize_counts(counts)[tr]
        moved = int(np.count_nonzero(counts["model"] != "none"))
        rows[tr] = dict(sm, moved=moved, n=len(counts["frame"]), t_fit=t_fit, dhat=dhat)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*")
    ap.add_argument("--every", type=int, default=1)
    ap.add_argument("--client", default="ipctk", choices=("ipctk", "own"))
    ap.add_argument("--truncation", default="both", choices=("isotropic", "planar", "both"))
    ap.add_argument("--predictor", default="own", choices=("own", "ipctk"),
                    help="the client auto replays its candidates through (ClientModel.predictor)")
    ap.add_argument("--no-repeat", action="store_true",
                    help="without the rigid-repeat candidate and the co-rotated target (ClientModel.repeat)")
    ap.add_argument("--radius", default="step", choices=("step", "own"),
                    help="the radius rule auto predicts for (ClientModel.radius, deform --client-radius)")
    a = ap.parse_args(argv)
    files = a.files or sorted(glob.glob(os.path.join(ROOT, "samples", "*.h5")))
    print(f"real-client CD passes summed over each sequence ({a.client}, every {a.every} step(s)); "
          f"auto chosen with --client-model = the truncation of the column, radius rule {a.radius}, predictor {a.predictor}")
    print()
    print("| sample | truncation | steps (moved) | baseline, rule step | auto, rule step | change "
          "| baseline, rule own | auto, rule own | change |")
    print("|---|---|---|---|---|---|---|---|---|")
    for path in files:
        trs = ("isotropic", "planar") if a.truncation == "both" else (a.truncation,)
        rows = evaluate(path, a.every, a.client, trs, a.predictor, not a.no_repeat, a.radius)
        for tr, r in rows.items():
            print(f"| {os.path.basename(path)} | {tr} | {r['n']} ({r['moved']}) | {r['baseline']} | {r['step']} | "
                  f"{100 * r['step_change']:+.0f}% | {r['baseline_own']} | {r['own']} | {100 * r['own_change']:+.0f}% |")
        sys.stdout.flush()


if __name__ == "__main__":
    main()
