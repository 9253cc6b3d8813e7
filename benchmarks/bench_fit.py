"""Benchmark: fit_step against numpy.linalg.lstsq and the memory floor (SPEC section 9).

Per step at 65,536 vertices: ``fit_step`` (moments + fit + projection +
certificate + writing x_def into a preallocated ``out`` + residual summaries;
``no-eval`` is ``evaluate=False``, without the summaries; ``serial`` forces
the serial kernels), the homogeneous
``N x 4`` ``numpy.linalg.lstsq`` of the same fit (plus forming x_def), and the
memory floor (one ``np.add(x_prev, x, out=buf)`` pass into a 64-byte aligned ``buf``:
numpy's add is 1.3-1.5x faster into a cache-line aligned array, and numpy's own
arrays land aligned or not from run to run, so the floor is timed at its best;
``fit_step`` takes the same time into either). Medians of repeats,
one process, float32 and float64. ``fit_step``, ``no-eval`` and the floor are
timed in turns, ``--rounds`` times, and each ratio to the floor is the median
of the rounds' ratios, with their range: a machine's state drifts (the floor of
one scene measured 0.041-0.086 ms in separate runs), and timing the floor minutes
after the fit compared two states. Then first-call JIT time against cached, in
fresh subprocesses sharing one new Numba cache directory.

    .venv/bin/python benchmarks/bench_fit.py [--repeats 30] [--rounds 5] [--vertices 65536] [--threads T]

On a machine shared with other CPU-bound work, ``--threads 1`` gives the steadier
figures: a parallel region waits for its slowest thread, and a descheduled thread
costs a whole scheduler time slice.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

import penfree
from penfree import constants as K
from penfree.core.fit.models import apply_map, fit_moments


def rod_bundle(n, seed=0):
    """Frames s-1, s of a bundle of twisted rods swinging and bending smoothly."""
    rng = np.random.default_rng(seed)
    per = 256
    k = n // per
    s = np.linspace(0.0, 1.0, per)
    ang0 = rng.uniform(0, 2 * np.pi, k)
    rad = 0.02 * np.sqrt(rng.uniform(0, 1, k))

    def frame(t):
        a = ang0[:, None] + 6.0 * s[None, :] + 0.05 * t  # twist, slowly turning
        x = np.stack([rad[:, None] * np.cos(a), rad[:, None] * np.sin(a), -np.broadcast_to(s, a.shape)], -1)
        sway = 0.1 * np.sin(0.07 * t) * s[None, :] ** 2  # bending swing
        x[..., 0] += sway
        return x.reshape(-1, 3)[:n] + np.array([0.3, -0.2, 1.5])

    return frame(9.0), frame(10.0)


def cloth_sheet(n, seed=0):
    """Frames s-1, s of a 256 x (n/256) sheet under a travelling wave and a drift."""
    side = 256
    u, v = np.meshgrid(np.linspace(0, 1, side), np.linspace(0, 1, n // side), indexing="ij")

    def frame(t):
        z = 0.02 * np.sin(4 * u + 0.1 * t) * np.cos(3 * v - 0.05 * t)
        x = np.stack([u + 0.001 * t, v * np.cos(0.01 * t), z + v * np.sin(0.01 * t)], -1)
        return x.reshape(-1, 3)

    return frame(9.0), frame(10.0)


def reference_or_own(name, n):
    """The samples' reference generator when it exists, else the scenes above."""
    here = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "samples")
    try:
        sys.path.insert(0, here)
        import generate  # type: ignore

        scene = {"rods": "yarn-bundle", "cloth": "cloth-ref"}[name]
        pos = generate.generate(scene, vertices=n, frames=12)[0]
        return np.asarray(pos[9], np.float64), np.asarray(pos[10], np.float64), "samples/generate.py " + scene
    except Exception:
        f = rod_bundle if name == "rods" else cloth_sheet
        return (*f(n), "bench_fit." + f.__name__)
    finally:
        if here in sys.path:
            sys.path.remove(here)


def timings(fn, repeats):
    """Wall times of `repeats` calls of `fn`, after one untimed warm-up call."""
    fn()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return ts


def median_time(fn, repeats):
    return float(np.median(timings(fn, repeats)))


def aligned_empty_like(a, align=64):
    """An uninitialised array like `a` whose data start on an `align`-byte boundary."""
    raw = np.empty(a.nbytes + align, np.uint8)
    start = -raw.ctypes.data % align
    return raw[start:start + a.nbytes].view(a.dtype).reshape(a.shape)


def rounds_against(floor, fns, repeats, rounds):
    """Median times of `fns` and of `floor`, timed in turns `rounds` times, and each fn's
    ratios to the floor round by round: ``(times, floor_time, ratios)``, where
    ``ratios[k]`` lists the rounds' ratios of ``fns[k]``."""
    runs = [[] for _ in fns]
    floors = []
    for _ in range(rounds):
        for k, fn in enumerate(fns):
            runs[k].append(median_time(fn, repeats))
        floors.append(median_time(floor, repeats))
    ratios = [[t / f for t, f in zip(run, floors)] for run in runs]
    return [float(np.median(run)) for run in runs], float(np.median(floors)), ratios


def ratio_text(ratios):
    """``median (min-max)`` of a list of ratios."""
    return f"{np.median(ratios):.2f}x ({min(ratios):.2f}-{max(ratios):.2f})"


def lstsq_step(x_prev, x):
    x64 = x.astype(np.float64)
    d = x64 - x_prev
    H = np.c_[x64, np.ones(len(x64))]
    coef = np.linalg.lstsq(H, d, rcond=None)[0]
    return (x64 + H @ coef).astype(x.dtype)


def jit_times():
    code = (
        "import time; t0 = time.perf_counter(); import numpy as np, penfree; "
        "x = np.random.default_rng(0).random((1000, 3)); "
        "[penfree.fit_step(x.astype(d) - d(0.01), x.astype(d)) for d in (np.float32, np.float64)]; "
        "print(time.perf_counter() - t0)"
    )
    out = []
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        for _ in range(2):
            r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
            out.append(float(r.stdout.strip().splitlines()[-1]))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vertices", type=int, default=65536)
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--rounds", type=int, default=5, help="turns of fit_step, no-eval and the floor")
    ap.add_argument("--no-jit", action="store_true", help="skip the subprocess JIT timing")
    ap.add_argument("--threads", type=int, default=None, help="Numba threads (default: all)")
    args = ap.parse_args(argv)
    import numba

    if args.threads:
        numba.set_num_threads(args.threads)

    print(f"penfree {penfree.__version__}, numpy {np.__version__}, numba {numba.__version__}, "
          f"threads {numba.get_num_threads()}, N = {args.vertices}, median of {args.repeats}, "
          f"{args.rounds} rounds")
    hdr = (f"{'scene':<7} {'dtype':<8} {'fit_step':>10} {'no-eval':>9} {'serial':>9} {'moments':>9} {'apply':>9} "
           f"{'lstsq':>10} {'floor':>9} {'lstsq/fit':>10} {'fit/floor (rounds)':>20} {'no-eval/floor (rounds)':>23}  "
           f"model/proj/rank/cert")
    print(hdr)
    print("-" * len(hdr))
    for name in ("rods", "cloth"):
        x_prev64, x64, source = reference_or_own(name, args.vertices)
        for dtype in (np.float32, np.float64):
            x_prev, x = x_prev64.astype(dtype), x64.astype(dtype)
            out = np.empty_like(x)
            r = penfree.fit_step(x_prev, x, out=out)
            m = fit_moments(x_prev, x)
            buf = aligned_empty_like(x)
            (t_fit, t_fast), t_floor, (r_fit, r_fast) = rounds_against(
                lambda: np.add(x_prev, x, out=buf),
                [lambda: penfree.fit_step(x_prev, x, out=out), lambda: penfree.fit_step(x_prev, x, out=out, evaluate=False)],
                args.repeats, args.rounds)
            build, K.FIT_BUILD = K.FIT_BUILD, "serial"  # serial kernels
            try:
                t_ser = median_time(lambda: penfree.fit_step(x_prev, x, out=out), args.repeats)
            finally:
                K.FIT_BUILD = build
            t_mom = median_time(lambda: fit_moments(x_prev, x, validate=False), args.repeats)
            t_app = median_time(lambda: apply_map(x, r.D, r.u, r.c, out=out, x_prev=x_prev), args.repeats)
            t_ls = median_time(lambda: lstsq_step(x_prev, x), max(5, args.repeats // 3))
            ref = lstsq_step(x_prev.astype(np.float64), x.astype(np.float64))
            dev = np.abs(r.x_def.astype(np.float64) - ref).max()
            print(f"{name:<7} {np.dtype(dtype).name:<8} {t_fit*1e3:8.3f}ms {t_fast*1e3:7.3f}ms {t_ser*1e3:7.3f}ms "
                  f"{t_mom*1e3:7.3f}ms "
                  f"{t_app*1e3:7.3f}ms {t_ls*1e3:8.3f}ms {t_floor*1e3:7.3f}ms {t_ls/t_fit:9.1f}x "
                  f"{ratio_text(r_fit):>20} {ratio_text(r_fast):>23}  "
                  f"{r.model}/{r.projection}/{r.rank}/{r.certified_by} |x_def-lstsq|max={dev:.1e}")
            del m
        print(f"        (scene: {source})")
    if not args.no_jit:
        first, cached = jit_times()
        print(f"fresh process, import + first fit_step (float32 and float64): "
              f"{first:.2f} s with an empty Numba cache, {cached:.2f} s cached")


if __name__ == "__main__":
    main()
