"""How close float64 arithmetic can bring a float32 fit to the memory floor, on this machine.

    .venv/bin/python benchmarks/fit_bound.py [--vertices 65536] [--rounds 8]

Issue 13 asks for the float32 `fit_step` within 3x of the memory floor (one
``np.add(x_prev, x, out=buf)`` pass, as `bench_fit.py` times it). SPEC section 4 computes
the fit in float64 whatever the input dtype. This script times, in one process and in
turns, the least a float64 fit can do per vertex, compiled as penfree's own passes are
(``prange`` over 64 chunks, the same fast-math flags, flat float32 inputs):

- ``moments``: the 21 sums of the affine fit (x, d = x - x_prev, x x^T, d x^T), without
  penfree's shift by the first vertex (which keeps scenes far from the origin exact) and
  without the squared displacement its rank test needs;
- ``apply``: ``x_def = A x + b`` in float64, stored as float32, without the residual
  summaries `fit_step` returns by default;

and prints their sum against the floor and against penfree's `fit_step` (default call,
and ``evaluate=False``). What the stripped passes leave of 3x the floor is all the rest of
a call may take: the shift, the 3x3 eigen-decomposition, rank and certificate, the input
checks and the result. None of it is optional in SPEC sections 4-5 and 10.
"""

from __future__ import annotations

import argparse

import numpy as np
from numba import njit, prange

import penfree

from bench_fit import aligned_empty_like, timings

_FM = {"reassoc", "contract"}  # the flags of penfree's fit passes (`kernels._FIT_FASTMATH`)


@njit(parallel=True, fastmath=_FM)
def _stripped_moments(x_prev, x, n_chunks):
    n = x.shape[0] // 3
    part = np.zeros((n_chunks, 21))
    for k in prange(n_chunks):
        lo = k * n // n_chunks
        hi = (k + 1) * n // n_chunks
        sp0 = sp1 = sp2 = sd0 = sd1 = sd2 = 0.0
        c00 = c11 = c22 = c01 = c02 = c12 = 0.0
        g00 = g01 = g02 = g10 = g11 = g12 = g20 = g21 = g22 = 0.0
        for j in range(hi - lo):
            i3 = np.uint64(3) * np.uint64(lo + j)
            a0 = np.float64(x[i3])
            a1 = np.float64(x[i3 + np.uint64(1)])
            a2 = np.float64(x[i3 + np.uint64(2)])
            q0 = a0 - np.float64(x_prev[i3])
            q1 = a1 - np.float64(x_prev[i3 + np.uint64(1)])
            q2 = a2 - np.float64(x_prev[i3 + np.uint64(2)])
            sp0 += a0
            sp1 += a1
            sp2 += a2
            sd0 += q0
            sd1 += q1
            sd2 += q2
            c00 += a0 * a0
            c11 += a1 * a1
            c22 += a2 * a2
            c01 += a0 * a1
            c02 += a0 * a2
            c12 += a1 * a2
            g00 += q0 * a0
            g01 += q0 * a1
            g02 += q0 * a2
            g10 += q1 * a0
            g11 += q1 * a1
            g12 += q1 * a2
            g20 += q2 * a0
            g21 += q2 * a1
            g22 += q2 * a2
        r = part[k]
        r[0], r[1], r[2], r[3], r[4], r[5] = sp0, sp1, sp2, sd0, sd1, sd2
        r[6], r[7], r[8], r[9], r[10], r[11] = c00, c11, c22, c01, c02, c12
        r[12], r[13], r[14], r[15], r[16] = g00, g01, g02, g10, g11
        r[17], r[18], r[19], r[20] = g12, g20, g21, g22
    tot = np.zeros(21)
    for k in range(n_chunks):
        for j in range(21):
            tot[j] += part[k, j]
    return tot


@njit(parallel=True, fastmath=_FM)
def _stripped_apply(x, A, b, out, n_chunks):
    n = x.shape[0] // 3
    for k in prange(n_chunks):
        lo = k * n // n_chunks
        hi = (k + 1) * n // n_chunks
        for j in range(hi - lo):
            i3 = np.uint64(3) * np.uint64(lo + j)
            a0 = np.float64(x[i3])
            a1 = np.float64(x[i3 + np.uint64(1)])
            a2 = np.float64(x[i3 + np.uint64(2)])
            out[i3] = np.float32(A[0, 0] * a0 + A[0, 1] * a1 + A[0, 2] * a2 + b[0])
            out[i3 + np.uint64(1)] = np.float32(A[1, 0] * a0 + A[1, 1] * a1 + A[1, 2] * a2 + b[1])
            out[i3 + np.uint64(2)] = np.float32(A[2, 0] * a0 + A[2, 1] * a1 + A[2, 2] * a2 + b[2])


def _median_us(fn, repeats):
    return 1e6 * float(np.median(timings(fn, repeats)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vertices", type=int, default=65536)
    ap.add_argument("--rounds", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=300)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    x = rng.standard_normal((args.vertices, 3)).astype(np.float32)
    x_prev = (x + 0.01 * rng.standard_normal(x.shape)).astype(np.float32)
    flat, flat_prev = x.reshape(-1), x_prev.reshape(-1)
    out = np.empty_like(x)
    buf = aligned_empty_like(flat)  # as bench_fit.py's floor
    A, b = np.eye(3), np.zeros(3)
    jobs = {
        "floor": lambda: np.add(flat_prev, flat, out=buf),
        "moments": lambda: _stripped_moments(flat_prev, flat, 64),
        "apply": lambda: _stripped_apply(flat, A, b, out.reshape(-1), 64),
        "fit_step": lambda: penfree.fit_step(x_prev, x, out=out),
        "no-eval": lambda: penfree.fit_step(x_prev, x, out=out, evaluate=False),
    }
    for fn in jobs.values():  # compile, and the fit's first calls of each build
        for _ in range(20):
            fn()
    print(f"penfree {penfree.__version__}, N = {args.vertices}, float32, median of {args.repeats}, "
          f"{args.rounds} rounds (us; ratios to the round's floor)")
    print(f"{'floor':>8} {'moments':>8} {'apply':>8} {'both':>8} {'fit_step':>9} {'no-eval':>8} "
          f"{'both/floor':>11} {'fit/floor':>10} {'no-eval/floor':>14}")
    rows = []
    for _ in range(args.rounds):
        t = {name: _median_us(fn, args.repeats) for name, fn in jobs.items()}
        both = t["moments"] + t["apply"]
        rows.append((both / t["floor"], t["fit_step"] / t["floor"], t["no-eval"] / t["floor"]))
        print(f"{t['floor']:8.1f} {t['moments']:8.1f} {t['apply']:8.1f} {both:8.1f} {t['fit_step']:9.1f} "
              f"{t['no-eval']:8.1f} {rows[-1][0]:10.2f}x {rows[-1][1]:9.2f}x {rows[-1][2]:13.2f}x")
    med = np.median(np.array(rows), axis=0)
    print(f"medians: stripped passes {med[0]:.2f}x the floor, fit_step {med[1]:.2f}x, no-eval {med[2]:.2f}x; "
          f"the rest of a call may take {max(3.0 - med[0], 0.0):.2f}x the floor to stay within 3x")


if __name__ == "__main__":
    main()
