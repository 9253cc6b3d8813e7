"""Benchmark: the added cost of ``--model auto`` (select_step) over the plain affine fit.

Per step at 65,536 vertices on the reference scenes of samples/generate.py
(``yarn-bundle``: segments, ``cloth-ref``: triangles; generated in memory):

- ``affine``: ``fit_step(x_prev, x, model="affine", out=out)``;
- ``auto``: ``select_step(x_prev, x, d_start, r_q=..., thickness=..., out=out)``,
  excluding the one ``per_vertex_separation`` call (the simulator's own detection);
- ``unfused``: the same candidates predicted the way select_step did before the fused
  kernel (``apply_map`` into a buffer, then ``predict_passes`` with numpy), for reference;
- ``sep``: the ``per_vertex_separation`` call itself, timed separately.

Medians of repeats, one process, float32 and float64; the issue's figure is the
ratio auto / affine. On a machine shared with other CPU-bound work, ``--threads 1``
gives the steadier figures (a parallel region waits for its slowest thread).

    .venv/bin/python benchmarks/bench_select.py [--repeats 30] [--sep-repeats 3] [--threads T]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

import penfree
from penfree.core.fit import models as _fit
from penfree.core.fit.auto import candidate_maps, predict_passes, predicted_bounds, select_step
from penfree.core.trust.bounds import scene_arrays, per_vertex_separation

SCENES = ("yarn-bundle", "cloth-ref")


def reference_step(scene, n, step=10):
    """Frames step-1, step of a reference scene, its topology and thickness."""
    here = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "samples")
    sys.path.insert(0, here)
    try:
        import generate  # type: ignore
    finally:
        sys.path.remove(here)
    pos, topo, attrs = generate.generate(scene, vertices=n, frames=step + 2)
    return (np.asarray(pos[step - 1], np.float64), np.asarray(pos[step], np.float64),
            topo.get("edges"), topo.get("faces"), float(attrs["thickness"]))


def median_time(fn, repeats):
    fn()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def unfused_select(x_prev, x, d_start, r_q, thickness):
    """The candidate loop as it was: apply_map into a buffer, then numpy's prediction."""
    m = _fit.fit_moments(x_prev, x)
    x_pred = 2.0 * np.asarray(x, dtype=np.float64) - np.asarray(x_prev, dtype=np.float64)
    cands = candidate_maps(m)
    buf = np.empty_like(x)
    for cand in cands:
        x_def = x if cand.name == "none" else _fit.apply_map(x, cand.D, cand.u, m.c, out=buf)[0]
        cand.predicted = predict_passes(x_def, x_pred, predicted_bounds(d_start, cand.sigma_lb, r_q, thickness))
    return cands


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vertices", type=int, default=65536)
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--sep-repeats", type=int, default=3, help="repeats of the (slow) separation query")
    ap.add_argument("--threads", type=int, default=None, help="Numba threads (default: all)")
    args = ap.parse_args(argv)
    import numba

    if args.threads:
        numba.set_num_threads(args.threads)
    print(f"penfree {penfree.__version__}, numpy {np.__version__}, numba {numba.__version__}, "
          f"threads {numba.get_num_threads()}, N = {args.vertices}, median of {args.repeats}")
    hdr = (f"{'scene':<12} {'dtype':<8} {'affine':>9} {'auto':>9} {'unfused':>9} {'sep':>9} "
           f"{'auto/affine':>12} {'unfused/affine':>15} {'cands':>6}  chosen (K_1pct: none -> chosen)")
    print(hdr)
    print("-" * len(hdr))
    for scene in SCENES:
        x_prev64, x64, edges, faces, thickness = reference_step(scene, args.vertices)
        _, E, F = scene_arrays(x64, edges, faces)
        r_q = thickness + float(np.linalg.norm(x64 - x_prev64, axis=1).max())
        t_sep = median_time(lambda: per_vertex_separation(x64, E, F, r_q), args.sep_repeats)
        d_start = per_vertex_separation(x64, E, F, r_q)
        for dtype in (np.float32, np.float64):
            x_prev, x = x_prev64.astype(dtype), x64.astype(dtype)
            out = np.empty_like(x)
            t_aff = median_time(lambda: penfree.fit_step(x_prev, x, model="affine", out=out), args.repeats)
            t_auto = median_time(lambda: select_step(x_prev, x, d_start, r_q=r_q, thickness=thickness, out=out),
                                 args.repeats)
            t_old = median_time(lambda: unfused_select(x_prev, x, d_start, r_q, thickness), max(5, args.repeats // 3))
            r, table = select_step(x_prev, x, d_start, r_q=r_q, thickness=thickness, out=out)
            k_none = table[0]["k_1pct"]
            k_best = next(t["k_1pct"] for t in table if t["chosen"])
            print(f"{scene:<12} {np.dtype(dtype).name:<8} {t_aff*1e3:7.3f}ms {t_auto*1e3:7.3f}ms {t_old*1e3:7.3f}ms "
                  f"{t_sep*1e3:7.0f}ms {t_auto/t_aff:11.1f}x {t_old/t_aff:14.1f}x {len(table):>6}  "
                  f"{r.model} ({k_none} -> {k_best})")


if __name__ == "__main__":
    main()
