"""Numba kernels of the collision-aware model choice (`penfree.core.fit.auto`).

`predict_kernel` evaluates one candidate map in a single pass over the vertices:
the deformed position, its distance to the prediction and the predicted bound are
formed on the fly (``x_def`` is never written), leaving only ``r_v`` in a reusable
buffer, from which the caller takes the percentile.

No fastmath anywhere: the ratios feed the choice of a certified map and are compared
against `predict_passes`, so the arithmetic is IEEE as written. ``error_model="numpy"``
is not a fast-math flag: it only drops Python's ZeroDivisionError check (division by
zero gives inf/NaN as in IEEE and numpy), which would otherwise keep the loop scalar.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ... import constants as K
from ..parallel import Pace, named
from .kernels import fit_build


def _predict_py(x_prev, x, D, u, c, d_start, s, r_q, thickness, gamma, out32, r, n_chunks):
    # Per vertex, with the same operations (and order) as
    #   predict_passes(apply_map(x, D, u, c), 2 x - x_prev, predicted_bounds(d_start, ...)):
    #   x_def = x + (D (x - c) + u), rounded to the stored dtype;
    #   dist  = |x_pred - x_def| with x_pred = 2 x - x_prev in float64;
    #   b     = gamma * max(0, min(r_q, s * d_start) - thickness), s = sigma (1 - slack).
    # A blocked vertex (moving, with a zero start bound b0 = gamma * max(0, min(r_q,
    # d_start) - thickness)) gets r = -inf, so that the non-blocked ratios are exactly
    # the top N - n_blocked entries of r in sorted order. A vertex whose start bound is
    # positive but whose predicted bound b is 0 (the map's sigma may shrink its gap
    # into the thickness) is not left out but gets r = +inf: a predicted bound of 0 is
    # then only a lower bound, the recomputed one may be tiny and positive. For doing
    # nothing (s = 1) b is b0, so both readings agree.
    # x, x_prev are flat (3N,) views and the index is unsigned: with a constant
    # stride 3 and no negative-index wraparound LLVM vectorises the loop (~4x).
    n = d_start.shape[0]
    d00, d01, d02 = D[0, 0], D[0, 1], D[0, 2]
    d10, d11, d12 = D[1, 0], D[1, 1], D[1, 2]
    d20, d21, d22 = D[2, 0], D[2, 1], D[2, 2]
    u0, u1, u2 = u[0], u[1], u[2]
    c0, c1, c2 = c[0], c[1], c[2]
    part = np.zeros((n_chunks, 2), dtype=np.int64)
    for k in prange(n_chunks):
        lo = k * n // n_chunks
        hi = (k + 1) * n // n_chunks
        hits = 0
        blocked = 0
        for j in range(hi - lo):
            i = np.uint64(lo + j)
            i3 = np.uint64(3) * i
            a0 = np.float64(x[i3])
            a1 = np.float64(x[i3 + np.uint64(1)])
            a2 = np.float64(x[i3 + np.uint64(2)])
            p0, p1, p2 = a0 - c0, a1 - c1, a2 - c2
            v0 = a0 + (d00 * p0 + d01 * p1 + d02 * p2 + u0)
            v1 = a1 + (d10 * p0 + d11 * p1 + d12 * p2 + u1)
            v2 = a2 + (d20 * p0 + d21 * p1 + d22 * p2 + u2)
            if out32:
                v0 = np.float64(np.float32(v0))
                v1 = np.float64(np.float32(v1))
                v2 = np.float64(np.float32(v2))
            e0 = (2.0 * a0 - np.float64(x_prev[i3])) - v0
            e1 = (2.0 * a1 - np.float64(x_prev[i3 + np.uint64(1)])) - v1
            e2 = (2.0 * a2 - np.float64(x_prev[i3 + np.uint64(2)])) - v2
            dist = np.sqrt((e0 * e0 + e1 * e1) + e2 * e2)
            # np.minimum / np.maximum semantics (NaN propagates), without branches.
            d = d_start[i]
            t = s * d
            t = r_q if r_q < t else t
            t = t - thickness
            b = gamma * (0.0 if t < 0.0 else t)
            t0 = r_q if r_q < d else d
            t0 = t0 - thickness
            b0 = gamma * (0.0 if t0 < 0.0 else t0)
            moving = dist > 0.0
            zero_b = moving & ~(b > 0.0)
            is_blocked = zero_b & ~(b0 > 0.0)
            rv = dist / b  # IEEE division (error_model="numpy"); masked where b is not > 0
            rv = rv if moving & ~zero_b else (np.inf if zero_b else 0.0)
            r[i] = -np.inf if is_blocked else rv
            blocked += np.int64(is_blocked)
            hits += np.int64(~is_blocked & (rv <= 1.0))
        part[k, 0] = hits
        part[k, 1] = blocked
    res = np.zeros(2, dtype=np.int64)
    for k in range(n_chunks):
        res[0] += part[k, 0]
        res[1] += part[k, 1]
    return res


_predict_serial = njit(cache=True, error_model="numpy")(named(_predict_py, "_predict_serial"))
_predict_parallel = njit(cache=True, parallel=True, error_model="numpy")(named(_predict_py, "_predict_parallel"))
_PREDICT_PACE = Pace()


def predict_kernel(x_prev, x, D, u, c, d_start, s, r_q, thickness, gamma, r):
    """Fill `r` (N,) float64 with the candidate's ratios; return ``(hits, n_blocked)``.

    Inputs as validated by `penfree.core.fit.auto.select_step`; ``s = sigma * (1 - PREDICT_SLACK_REL)``
    (1 for doing nothing, whose bounds are the start bounds exactly). A moving vertex
    whose start bound is 0 is blocked (left out, r = -inf) for every candidate; one
    whose start bound is positive but whose predicted bound is 0 gets r = +inf.
    The chunks are fixed (`REDUCTION_CHUNKS`) and the sums are integers, so the result
    does not depend on the thread count.
    """
    out32 = x.dtype == np.float32
    res = fit_build(x.shape[0], _PREDICT_PACE, _predict_serial, _predict_parallel,
                    x_prev.reshape(-1), x.reshape(-1), D, u, c, d_start, s, r_q, thickness, gamma, out32,
                    r, K.REDUCTION_CHUNKS)
    return int(res[0]), int(res[1])


#: `upper_quantile` picks its threshold from a strided sample of at most this many ratios.
_SELECT_SAMPLE = 4096
#: ... at the sample entry with this many times the expected share of entries above it
#: (plus `_SELECT_PAD`), so that the entries at or above it hold the answer (else numpy).
_SELECT_SLACK = 2
_SELECT_PAD = 16


@njit(cache=True)
def _upper_select(r, rank):
    # The value at sorted position `rank` is the k-th largest (k = n - rank), and the
    # largest of the entries from `rank` on is the overall maximum. Only the entries at
    # or above a threshold t taken from a sample are partitioned: when at least k of
    # them are, the k-th largest is among them. NaN (numpy sorts it last) or a
    # threshold that leaves fewer than k entries: ok = False, the caller partitions.
    n = r.shape[0]
    k = n - rank
    step = max(1, n // _SELECT_SAMPLE)
    m = (n + step - 1) // step
    sample = np.empty(m)
    for j in range(m):
        sample[j] = r[j * step]
    ks = min(m, _SELECT_SLACK * (k * m) // n + _SELECT_PAD)
    t = np.partition(sample, m - ks)[m - ks]
    if t != t:
        return 0.0, 0.0, False
    cap = min(n, _SELECT_SLACK * ks * step + _SELECT_PAD)
    buf = np.empty(cap)
    count = 0
    top = -np.inf
    for i in range(n):
        v = r[i]
        if v != v:
            return 0.0, 0.0, False
        top = v if v > top else top
        if v >= t:
            if count < cap:
                buf[count] = v
            count += 1
    if count < k or count > cap:
        return 0.0, 0.0, False
    return np.partition(buf[:count], count - k)[count - k], top, True


def upper_quantile(r, rank):
    """``(sorted(r)[rank], max(r[rank:]))`` for a high `rank`, as ``r.partition(rank)``
    gives them (the same floats), without partitioning all of `r`.

    Parameters
    ----------
    r : (N,) float64, C-contiguous
        Left unchanged, except where the fallback partitions it in place (scratch).
    rank : int, 0 <= rank < N

    Notes
    -----
    The 99th percentile of `predict_kernel`'s ratios, ~10 per step: ``numpy.partition``
    of 64K ratios took 0.45-0.9 ms each, the thresholded selection ~0.1 ms. Exact: the
    k-th largest entry is the k-th largest of the entries at or above any threshold
    that at least k of them reach; otherwise (or with NaN) numpy decides.
    """
    q, top, ok = _upper_select(r, rank)
    if not ok:
        r.partition(rank)
        return float(r[rank]), float(r[rank:].max())
    return float(q), float(top)
