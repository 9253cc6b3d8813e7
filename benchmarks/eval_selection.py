"""Issue 5 evaluation: actual CD passes of every map choice on the bundled samples.

For every step of each sample the maps of the ladder, the collision-aware ``auto``, the
``per-component`` maps and the unsafe ideal ``x_pred`` are applied; the OGC bounds are
recomputed at each deformed state and the passes counted against the simulator's real
next frame (static K_1pct and K_any; replay with --replay). Prints, per sample, the
K_1pct summed over the steps for each choice and the two acceptance checks of the issue:

- auto never needs more passes than doing nothing (baseline);
- auto keeps at least 90% of the best fixed model's reduction.

    .venv/bin/python benchmarks/eval_selection.py [--replay] [--no-per-component] [FILES...]
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import penfree  # noqa: E402
from penfree.core.pipeline.ladder import FIXED_MODELS, model_ladder  # noqa: E402

SAMPLES = ["cloth.h5", "rods.h5", "twisting_cloth.h5", "twisting_cloth_contact.h5", "cables.h5",
           "twisted_cables.h5"]


def evaluate(path, replay, per_component):
    seq = penfree.read_sequence(path)
    frames = np.arange(1, seq.n_frames)
    models = (*FIXED_MODELS, "auto", *(("per-component",) if per_component else ()))
    t0 = time.perf_counter()
    lad = model_ladder(seq.positions, frames, edges=seq.edges, faces=seq.faces, thickness=seq.thickness,
                       weights=seq.weights, models=models, replay=replay, components=seq.components)
    rows = {r["model"]: r for r in lad["rows"]}
    base = rows["baseline"]["k_1pct_next_sum"]
    best_fixed = min(rows[m]["k_1pct_next_sum"] for m in FIXED_MODELS)
    auto = rows["auto"]["k_1pct_next_sum"]
    gain_best, gain_auto = base - best_fixed, base - auto
    ok_base = auto <= base
    ok_90 = gain_auto >= 0.9 * gain_best if gain_best > 0 else gain_auto >= 0
    print(f"\n{Path(path).name}: {seq.n_vertices} vertices, {lad['n_steps_next']} steps with a next frame "
          f"({time.perf_counter() - t0:.1f} s)")
    head = f"  {'map':14s} {'K_1pct sum':>10s} {'K_any mean':>10s} {'hit rate':>9s} {'RMS to next':>12s}"
    if replay:
        head += f" {'replay K_1pct':>13s}"
    print(head)
    for r in lad["rows"]:
        line = (f"  {r['model']:14s} {r['k_1pct_next_sum']:10.0f} {r['k_any_next']:10.2f} "
                f"{100 * r['hit_rate_next']:8.1f}% {r['residual_next_rms']:12.3e}")
        if replay:
            line += f" {r['replay_k_1pct_next']:13.2f}"
        print(line)
    print(f"  auto <= baseline: {'yes' if ok_base else 'NO'} ({auto:.0f} vs {base:.0f}); "
          f"auto keeps {100 * gain_auto / gain_best if gain_best > 0 else 100:.0f}% of the best fixed "
          f"model's reduction ({gain_auto:.0f} of {gain_best:.0f}): {'yes' if ok_90 else 'NO'}; "
          f"auto chose the actual best on {100 * lad['auto_best_rate']:.0f}% of steps")
    return ok_base and ok_90


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*", default=[str(ROOT / "samples" / s) for s in SAMPLES])
    ap.add_argument("--replay", action="store_true")
    ap.add_argument("--no-per-component", action="store_true")
    a = ap.parse_args()
    ok = [evaluate(f, a.replay, not a.no_per_component) for f in a.files]
    print(f"\nacceptance (issue 5) on {len(ok)} files: {'PASS' if all(ok) else 'FAIL'}")
    return 0 if all(ok) else 1


if __name__ == "__main__":
    sys.exit(main())
