"""Benchmark: fit_step at 64K vertices with one core held by another process (issue 13).

One process measures, for float32 and float64: ``fit_step`` as dispatched (the
default: `constants.FIT_BUILD`, "adaptive", `penfree.core.parallel.Pace`), with the serial
kernels forced and with the parallel kernels forced, and the memory floor (one
``np.add(x_prev, x, out=buf)`` pass, `buf` 64-byte aligned as in `bench_fit.py`); first on
the machine as it is ("idle"), then with a background busy process spinning on one core
("loaded"). Ratios are formed within one condition (fit / floor) and across the two
(loaded / idle).

With ``--verify``, the same for two proofs on the 64K cloth of `bench_verify.py`: the
certificate path of an affine step (`verify_affine_step`, thickness 0: its fused start
pass) and `verify_step` of the gentle step at thickness 1e-4 (its listing passes and CCD
batches), on all threads idle and loaded and on one thread idle. Their parallel passes
claim chunks by ranges (`penfree.core.parallel.range_counter`), so a descheduled thread
should cost a loaded run its share of the work, not the whole region's wait.

    .venv/bin/python benchmarks/bench_contention.py [--repeats 200] [--vertices 65536] [--busy 1] [--verify]

The machine the figures in BENCHMARKS.md come from is shared: "idle" means "as loaded as
it was", which is why the medians of many short repeats and ratios are reported.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

import numba
import numpy as np

import penfree
from penfree import constants as K

from bench_fit import aligned_empty_like, reference_or_own, timings


def median_time(fn, repeats):
    ts = timings(fn, repeats)
    return float(np.median(ts)), float(np.mean(ts))


def variants(x_prev, x, out, repeats):
    """{name: (median, p90)} for the default dispatch, serial and parallel kernels, and the floor."""
    res = {}
    default = K.FIT_BUILD
    for build in ("serial", "parallel"):  # first calls (cache loads) before any timing
        K.FIT_BUILD = build
        try:
            penfree.fit_step(x_prev, x, out=out)
        finally:
            K.FIT_BUILD = default
    for name, build in (("default", default), ("serial", "serial"), ("parallel", "parallel")):
        K.FIT_BUILD = build
        try:
            res[name] = median_time(lambda: penfree.fit_step(x_prev, x, out=out), repeats)
        finally:
            K.FIT_BUILD = default
    buf = aligned_empty_like(x)
    res["floor"] = median_time(lambda: np.add(x_prev, x, out=buf), repeats)
    return res


def proofs(n):
    """{name: callable} of the two proofs of ``--verify`` on the n-vertex cloth of bench_verify."""
    from bench_verify import affine_cloth_step, cloth

    from penfree.core.verify.affine import verify_affine_step

    x0, x_def, A, b, F = affine_cloth_step(n)
    g0, g1, _, _ = cloth(n, "gentle")  # g0 is x0: the step that verify_step checks is frame 0 -> 1
    fns = {"certificate path": lambda: verify_affine_step(x0, x_def, A, b, faces=F, thickness=0.0),
           "verify_step": lambda: penfree.verify_step(g0, g1, faces=F, thickness=1e-4)}
    for fn in fns.values():
        assert fn().ok  # first calls (cache loads) before any timing; both proofs hold
    return fns


def proof_times(fns, repeats):
    return {name: median_time(fn, repeats) for name, fn in fns.items()}


def busy(n):
    code = "import time\nt = time.time()\nwhile time.time() - t < 600: pass\n"
    procs = [subprocess.Popen([sys.executable, "-c", code]) for _ in range(n)]
    time.sleep(0.5)
    return procs


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vertices", type=int, default=65536)
    ap.add_argument("--repeats", type=int, default=200)
    ap.add_argument("--busy", type=int, default=1, help="background busy processes in the loaded run")
    ap.add_argument("--verify", action="store_true", help="also the certificate path and verify_step (64K cloth)")
    args = ap.parse_args(argv)
    print(f"penfree {penfree.__version__}, numba {numba.__version__} (threads {numba.get_num_threads()}), N = {args.vertices}, median of {args.repeats}; "
          f"PARALLEL_MIN_VERTICES = {K.PARALLEL_MIN_VERTICES}, FIT_BUILD = {K.FIT_BUILD}")
    x_prev64, x64, source = reference_or_own("rods", args.vertices)
    inputs = []
    for dtype in (np.float32, np.float64):
        x_prev, x = x_prev64.astype(dtype), x64.astype(dtype)
        inputs.append((np.dtype(dtype).name, x_prev, x, np.empty_like(x)))
    # Both dtypes idle first, then both loaded: the default's choice of build carries
    # over from call to call (`penfree.core.parallel.Pace`), and an idle run right after
    # a loaded one would start from the loaded machine's choice.
    idle = [variants(x_prev, x, out, args.repeats) for _, x_prev, x, out in inputs]
    fns = proofs(args.vertices) if args.verify else {}
    proof_repeats = max(5, args.repeats // 10)  # a proof takes 40-200 ms
    if fns:
        proof_idle = proof_times(fns, proof_repeats)
        threads = numba.get_num_threads()
        numba.set_num_threads(1)
        try:
            proof_one = proof_times(fns, proof_repeats)
        finally:
            numba.set_num_threads(threads)
    procs = busy(args.busy)
    try:
        loaded = [variants(x_prev, x, out, args.repeats) for _, x_prev, x, out in inputs]
        proof_loaded = proof_times(fns, proof_repeats) if fns else {}
    finally:
        for p in procs:
            p.kill()
            p.wait()
    rows = [(name, i, ld) for (name, *_), i, ld in zip(inputs, idle, loaded)]
    hdr = (f"{'dtype':<8} {'kernel':<9} {'idle':>9} {'mean':>9} {'/floor':>7} {'loaded':>9} {'mean':>9} {'/floor':>7} "
           f"{'loaded/idle':>12} {'loaded/idle default':>19}")
    print(hdr)
    print("-" * len(hdr))
    for dtype, idle, loaded in rows:
        for name in ("default", "serial", "parallel"):
            (ti, pi), (tl, pl) = idle[name], loaded[name]
            print(f"{dtype:<8} {name:<9} {ti*1e3:7.3f}ms {pi*1e3:7.3f}ms {ti/idle['floor'][0]:6.2f}x "
                  f"{tl*1e3:7.3f}ms {pl*1e3:7.3f}ms {tl/loaded['floor'][0]:6.2f}x {tl/ti:11.2f}x "
                  f"{tl/idle['default'][0]:18.2f}x")
        print(f"{dtype:<8} {'floor':<9} {idle['floor'][0]*1e3:7.3f}ms {'':>9} {'':>7} {loaded['floor'][0]*1e3:7.3f}ms")
    print("median times; /floor and loaded/idle are ratios of medians; mean shows the stalls of late threads")
    print(f"(scene: {source}; loaded = {args.busy} busy process(es) on a {__import__('os').cpu_count()}-core machine)")
    if fns:
        print(f"\nproofs on the {args.vertices}-vertex cloth of bench_verify.py, median of {proof_repeats}")
        hdr = (f"{'proof':<17} {'idle':>9} {'mean':>9} {'loaded':>9} {'mean':>9} {'loaded/idle':>12} "
               f"{'1 thread idle':>14}")
        print(hdr)
        print("-" * len(hdr))
        for name in fns:
            (ti, mi), (tl, ml), (t1, _) = proof_idle[name], proof_loaded[name], proof_one[name]
            print(f"{name:<17} {ti*1e3:7.1f}ms {mi*1e3:7.1f}ms {tl*1e3:7.1f}ms {ml*1e3:7.1f}ms {tl/ti:11.2f}x "
                  f"{t1*1e3:12.1f}ms")


if __name__ == "__main__":
    main()
