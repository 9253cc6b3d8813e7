"""Benchmark: the analytic-solid check at 64K vertices (issue 13; the solids of issue 14's
USD colliders).

A sheet of 256 x 256 vertices draped 2 mm over a ball of radius 0.3 (the exact solid of a
USD ``Sphere``), turning about the ball's axis: every step, `deform` runs the gate's
verdict (`solid_verdict`, the deform-result reading) and `auto` the solid's side of the
per-vertex separations (`solid_separation`). Both run in `penfree.core.contact.solid_kernels`
(Numba, one primitive at a time). Medians of repeats in one process, at 1 thread and at
the machine's thread count; the bits are the same at both (checked).

    .venv/bin/python benchmarks/bench_solids.py [--repeats 20] [--side 256]
"""

from __future__ import annotations

import argparse
import time

import numba
import numpy as np

from penfree.core.contact.solids import SolidFrames, solid_separation, solid_verdict
from penfree.core.trust.bounds import scene_arrays
from penfree.sequence import AnalyticShape

R, GAP = 0.3, 2e-3


def draped_sheet(side):
    """Two frames of a sheet resting GAP above the ball (a cap, then a tangent cone
    skirt), turned by 0.01 rad about the ball's axis; faces (K, 3)."""
    u, v = np.meshgrid(np.linspace(-0.45, 0.45, side), np.linspace(-0.45, 0.45, side))
    r = np.hypot(u, v).ravel()
    rg, a0 = R + GAP, np.deg2rad(60.0)
    rc = rg * np.sin(a0)
    z = np.where(r <= rc, np.sqrt(np.maximum(rg ** 2 - r ** 2, 0.0)), rg * np.cos(a0) - (r - rc) * np.tan(a0))
    x0 = np.c_[u.ravel(), v.ravel(), z]
    th = 0.01
    rot = np.array([[np.cos(th), -np.sin(th), 0.0], [np.sin(th), np.cos(th), 0.0], [0.0, 0.0, 1.0]])
    idx = np.arange(side * side).reshape(side, side)
    F = np.vstack([np.c_[idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[:-1, 1:].ravel()],
                   np.c_[idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()]])
    return x0, x0 @ rot.T, F


def median_ms(fn, repeats):
    fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.median(times))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--side", type=int, default=256)
    args = ap.parse_args()
    x0, x1, F = draped_sheet(args.side)
    _, E, F = scene_arrays(x0, None, F)
    profile = np.array([0.0, 0.0, R, 0.0, R])
    transform = np.vstack([np.eye(3), np.zeros(3)])
    shape = AnalyticShape("Sphere", 2, profile, transform)
    solid = SolidFrames(2, (profile, np.eye(3), np.zeros(3)), (profile, np.eye(3), np.zeros(3)))
    simplices = [F]
    threads = numba.get_num_threads()
    print(f"penfree solids: {len(x0)} vertices, {len(F)} faces {GAP * 1e3:.0f} mm over a ball of radius {R}; "
          f"medians of {args.repeats}")
    results = {}
    for n in sorted({1, threads}):
        numba.set_num_threads(n)
        verdict = solid_verdict(x0, x1, simplices, solid, 0.0, pre_existing=True)
        sep = solid_separation(x0, E, F, shape, radius=0.01)
        results[n] = (verdict, sep)
        t_v = median_ms(lambda: solid_verdict(x0, x1, simplices, solid, 0.0, pre_existing=True), args.repeats)
        t_s = median_ms(lambda: solid_separation(x0, E, F, shape, radius=0.01), args.repeats)
        (start, path, pre), = verdict[0]
        print(f"threads {n}: solid_verdict {t_v:7.1f} ms (path violations {len(path)}, pre-existing {len(pre)}), "
              f"solid_separation {t_s:7.1f} ms (vertices within 0.01: {(sep < 0.01).sum()})")
    numba.set_num_threads(threads)
    a, b = results[1], results[threads]
    same = all(np.array_equal(p, q) for p, q in zip(a[0][0][0], b[0][0][0])) and np.array_equal(a[1], b[1])
    print("same bits at 1 and", threads, "threads:", same)


if __name__ == "__main__":
    main()
