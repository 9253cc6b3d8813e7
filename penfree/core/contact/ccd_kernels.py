"""Numba kernels of the conservative CCD (see `penfree.core.contact.ccd` for the method).

Every query is 4 points at t=0 and at t=1 moving linearly; the contact function

    edge-edge:    F(t, u, v) = ea0(t) + u (ea1 - ea0)(t) - eb0(t) - v (eb1 - eb0)(t)
    vertex-face:  F(t, u, v) = p(t) - f0(t) - u (f1 - f0)(t) - v (f2 - f0)(t)

is multilinear in (t, u, v), so over a box its exact image lies in the convex
hull of its 8 corner values. A box is discarded only when that hull, widened
by a proven bound on the floating-point error of the corners, is farther than
`thickness` from the origin along some direction. No fastmath anywhere.
"""

import numpy as np
from numba import njit, prange

from ...constants import (
    CCD_ERR_ABS,
    CCD_ERR_REL,
    CCD_MAX_BOXES,
    CCD_MAX_COORD,
    CCD_TOI_TOL,
    CCD_TOL_REL,
    UNIT_ROUNDOFF,
)
from ..parallel import claim_next, range_counter

_U = UNIT_ROUNDOFF  # the short name of the error bounds below
_MAX_COORD = CCD_MAX_COORD
#: Batches up to this size run on one thread (thread wake-up costs ~ms on a busy machine).
_SERIAL_MAX = 512

# status codes written per query
SEPARATED = 0  # certified: no contact on [0, t_max]
CLOSE = 1  # a box of image width <= tol could not be discarded
BUDGET = 2  # box budget exhausted: undecided, reported as a hit


@njit(cache=True)
def _corners(x0, x1, is_vf, t_lo, t_hi, u_lo, u_hi, v_lo, v_hi, P, Fc):
    """Corner values Fc (8, 3) of F on the box; index bit 2 = t, bit 1 = u, bit 0 = v."""
    for a in range(2):
        t = t_lo if a == 0 else t_hi
        for i in range(4):
            for k in range(3):
                P[a, i, k] = x0[i, k] + t * (x1[i, k] - x0[i, k])
    for a in range(2):
        for b in range(2):
            u = u_lo if b == 0 else u_hi
            for c in range(2):
                v = v_lo if c == 0 else v_hi
                idx = 4 * a + 2 * b + c
                for k in range(3):
                    if is_vf:
                        Fc[idx, k] = (
                            (P[a, 0, k] - P[a, 1, k])
                            - u * (P[a, 2, k] - P[a, 1, k])
                            - v * (P[a, 3, k] - P[a, 1, k])
                        )
                    else:
                        Fc[idx, k] = (
                            (P[a, 0, k] - P[a, 2, k])
                            + u * (P[a, 1, k] - P[a, 0, k])
                            - v * (P[a, 3, k] - P[a, 2, k])
                        )


@njit(cache=True)
def _dir_margin(Fc, n0, n1, n2, err_f, f_max, thickness):
    """Certified lower bound of |F| - thickness over the hull of Fc along n (<= 0: no proof).

    s_c = n . Fc_c is computed in floating point; its distance to the exact
    n . F_c is at most |n|_1 (err_f + 4u max|Fc|) (gamma_3 < 4u for the 3-term
    dot product). |n|_2 computed by sqrt is within (1 + 3u) of the exact norm.
    The final (1 + 16u) / (1 - 8u) factors absorb the rounding of this bound itself.
    """
    nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    if not nn > 0.0:
        return -1.0
    n1norm = abs(n0) + abs(n1) + abs(n2)
    err = n1norm * (err_f + 4.0 * _U * f_max) * (1.0 + 16.0 * _U) + CCD_ERR_ABS
    lo = np.inf
    hi = -np.inf
    for c in range(8):
        s = n0 * Fc[c, 0] + n1 * Fc[c, 1] + n2 * Fc[c, 2]
        lo = min(lo, s)
        hi = max(hi, s)
    gap = max(lo, -hi) - err  # hull on one side of the plane n.y = 0
    if not gap > 0.0:
        return -1.0
    dist = gap / (nn * (1.0 + 4.0 * _U)) * (1.0 - 8.0 * _U)
    return dist - thickness * (1.0 + 4.0 * _U)


@njit(cache=True)
def _push(boxes, n, t_lo, t_hi, u_lo, u_hi, v_lo, v_hi):
    boxes[n, 0] = t_lo
    boxes[n, 1] = t_hi
    boxes[n, 2] = u_lo
    boxes[n, 3] = u_hi
    boxes[n, 4] = v_lo
    boxes[n, 5] = v_hi
    return n + 1


@njit(cache=True)
def _query(x0, x1, is_vf, thickness, t_max, boxes, P, Fc):
    """One query: returns (status, toi, sep, witness) — see `ccd_batch`.

    Depth-first search, earlier time half first, until a first contact box is
    found (phase 1); then the boxes left that start earlier are split in time
    only, to lift the toi lower bound (phase 2; boxes starting at or after the
    current bound cannot hold an earlier contact and are dropped).
    """
    m = 0.0
    for i in range(4):
        for k in range(3):
            m = max(m, abs(x0[i, k]), abs(x1[i, k]))
    if not m <= _MAX_COORD:  # products could overflow: no proof attempted (a conservative hit)
        return BUDGET, 0.0, 0.0, np.nan
    err_f = CCD_ERR_REL * m + CCD_ERR_ABS
    extent = 0.0
    for k in range(3):
        lo = np.inf
        hi = -np.inf
        for i in range(4):
            lo = min(lo, x0[i, k], x1[i, k])
            hi = max(hi, x0[i, k], x1[i, k])
        extent = max(extent, hi - lo)
    tol = max(CCD_TOL_REL * extent, 4.0 * err_f)
    toi_tol = CCD_TOI_TOL * t_max
    cap = boxes.shape[0]
    n = _push(boxes, 0, 0.0, t_max, 0.0, 1.0, 0.0, 1.0)
    sep = np.inf
    best = np.inf  # toi bound once a contact box is found
    witness = np.nan
    for _ in range(CCD_MAX_BOXES):
        if n == 0:
            break
        n -= 1
        t_lo, t_hi, u_lo, u_hi, v_lo, v_hi = (
            boxes[n, 0], boxes[n, 1], boxes[n, 2], boxes[n, 3], boxes[n, 4], boxes[n, 5])
        if t_lo >= best:
            continue  # cannot lower the toi bound: any contact in it is at or after `best`
        if is_vf and u_lo + v_lo > 1.0:  # outside u + v <= 1 (rounding is monotone)
            continue
        _corners(x0, x1, is_vf, t_lo, t_hi, u_lo, u_hi, v_lo, v_hi, P, Fc)
        f_max = 0.0
        margin = -1.0
        width = 0.0
        for k in range(3):
            lo = np.inf
            hi = -np.inf
            for c in range(8):
                lo = min(lo, Fc[c, k])
                hi = max(hi, Fc[c, k])
                f_max = max(f_max, abs(Fc[c, k]))
            width = max(width, hi - lo)
            g = (max(lo, -hi) - err_f) * (1.0 - 4.0 * _U) - thickness * (1.0 + 4.0 * _U)
            margin = max(margin, g)
        if margin <= 0.0:
            # centroid of the hull: the right direction once the box is small
            c0 = 0.0
            c1 = 0.0
            c2 = 0.0
            for c in range(8):
                c0 += Fc[c, 0]
                c1 += Fc[c, 1]
                c2 += Fc[c, 2]
            margin = max(margin, _dir_margin(Fc, c0, c1, c2, err_f, f_max, thickness))
        if margin <= 0.0:
            # geometric normal at mid-time: the gap direction of interior contacts
            tm = 0.5 * (t_lo + t_hi)
            # any float vector is a valid direction: its own rounding needs no bound
            if is_vf:
                ia, ib, ic, id_ = 1, 2, 1, 3
            else:
                ia, ib, ic, id_ = 0, 1, 2, 3
            ex = (x0[ib, 0] + tm * (x1[ib, 0] - x0[ib, 0])) - (x0[ia, 0] + tm * (x1[ia, 0] - x0[ia, 0]))
            ey = (x0[ib, 1] + tm * (x1[ib, 1] - x0[ib, 1])) - (x0[ia, 1] + tm * (x1[ia, 1] - x0[ia, 1]))
            ez = (x0[ib, 2] + tm * (x1[ib, 2] - x0[ib, 2])) - (x0[ia, 2] + tm * (x1[ia, 2] - x0[ia, 2]))
            fx = (x0[id_, 0] + tm * (x1[id_, 0] - x0[id_, 0])) - (x0[ic, 0] + tm * (x1[ic, 0] - x0[ic, 0]))
            fy = (x0[id_, 1] + tm * (x1[id_, 1] - x0[id_, 1])) - (x0[ic, 1] + tm * (x1[ic, 1] - x0[ic, 1]))
            fz = (x0[id_, 2] + tm * (x1[id_, 2] - x0[id_, 2])) - (x0[ic, 2] + tm * (x1[ic, 2] - x0[ic, 2]))
            nx = ey * fz - ez * fy
            ny = ez * fx - ex * fz
            nz = ex * fy - ey * fx
            margin = max(margin, _dir_margin(Fc, nx, ny, nz, err_f, f_max, thickness))
        if margin > 0.0:
            sep = min(sep, margin + thickness)
            continue
        if best < np.inf:  # phase 2: only the start time matters now
            if t_hi - t_lo <= toi_tol:
                best = t_lo
                continue
            mid = 0.5 * (t_lo + t_hi)
            if not (t_lo < mid < t_hi) or n + 2 > cap:
                best = t_lo
                continue
            n = _push(boxes, n, mid, t_hi, u_lo, u_hi, v_lo, v_hi)
            n = _push(boxes, n, t_lo, mid, u_lo, u_hi, v_lo, v_hi)
            continue
        # not discarded: refine or stop
        wt = 0.0
        wu = 0.0
        wv = 0.0
        for c in range(8):
            for k in range(3):
                if c < 4:
                    wt = max(wt, abs(Fc[c + 4, k] - Fc[c, k]))
                if (c & 2) == 0:
                    wu = max(wu, abs(Fc[c + 2, k] - Fc[c, k]))
                if (c & 1) == 0:
                    wv = max(wv, abs(Fc[c + 1, k] - Fc[c, k]))
        if width <= tol:
            if t_hi - t_lo <= toi_tol:
                best = t_lo  # phase 1 ends: a contact within tolerance
                witness = t_lo
                continue
            dim = 0
        elif wt >= wu and wt >= wv:
            dim = 0
        elif wu >= wv:
            dim = 1
        else:
            dim = 2
        lo = boxes[n, 2 * dim]
        hi = boxes[n, 2 * dim + 1]
        mid = 0.5 * (lo + hi)
        if not (lo < mid < hi):
            best = min(best, t_lo)  # a float interval that cannot be split: undecided, a hit
            continue
        if n + 2 > cap:
            break
        # push the later / upper half first so that the earlier one is searched first
        if dim == 0:
            n = _push(boxes, n, mid, t_hi, u_lo, u_hi, v_lo, v_hi)
            n = _push(boxes, n, t_lo, mid, u_lo, u_hi, v_lo, v_hi)
        elif dim == 1:
            n = _push(boxes, n, t_lo, t_hi, mid, u_hi, v_lo, v_hi)
            n = _push(boxes, n, t_lo, t_hi, u_lo, mid, v_lo, v_hi)
        else:
            n = _push(boxes, n, t_lo, t_hi, u_lo, u_hi, mid, v_hi)
            n = _push(boxes, n, t_lo, t_hi, u_lo, u_hi, v_lo, mid)
    # every contact lies in a box still on the stack or starts at or after `best`
    toi = best
    for i in range(n):
        toi = min(toi, boxes[i, 0])
    if witness == witness:  # not NaN: a box within tolerance was found
        return CLOSE, toi, 0.0, witness
    if best < np.inf or n > 0:
        return BUDGET, toi, 0.0, np.nan
    return SEPARATED, np.inf, sep, np.nan


@njit(cache=True)
def _run_chunk(x_t0, x_t1, is_vf, thickness, t_max, lo, hi, status, toi, sep, witness):
    boxes = np.empty((CCD_MAX_BOXES + 2, 6))  # each of the CCD_MAX_BOXES pops pushes at most 2
    P = np.empty((2, 4, 3))
    Fc = np.empty((8, 3))
    for i in range(lo, hi):
        s, t, g, w = _query(x_t0[i], x_t1[i], is_vf, thickness, t_max, boxes, P, Fc)
        status[i] = s
        toi[i] = t
        sep[i] = g
        witness[i] = w


@njit(cache=True, parallel=True)
def _batch_parallel(x_t0, x_t1, is_vf, thickness, t_max, n_chunks, status, toi, sep, witness, counter):
    q = x_t0.shape[0]
    per = (q + n_chunks - 1) // n_chunks
    for w in prange(counter[-1]):  # the chunks claimed by ranges (`parallel.claim_next`)
        ch, k = claim_next(counter, w, 0)
        while ch >= 0:
            _run_chunk(x_t0, x_t1, is_vf, thickness, t_max, ch * per, min(q, (ch + 1) * per), status, toi, sep,
                       witness)
            ch, k = claim_next(counter, w, k)


@njit(cache=True)
def _run_chunk_idx(V_t0, V_t1, idx, is_vf, thickness, t_max, lo, hi, status, toi, sep, witness):
    boxes = np.empty((CCD_MAX_BOXES + 2, 6))
    P = np.empty((2, 4, 3))
    Fc = np.empty((8, 3))
    x0 = np.empty((4, 3))
    x1 = np.empty((4, 3))
    for i in range(lo, hi):
        for r in range(4):
            for k in range(3):
                x0[r, k] = V_t0[idx[i, r], k]
                x1[r, k] = V_t1[idx[i, r], k]
        s, t, g, w = _query(x0, x1, is_vf, thickness, t_max, boxes, P, Fc)
        status[i] = s
        toi[i] = t
        sep[i] = g
        witness[i] = w


@njit(cache=True, parallel=True)
def _batch_idx_parallel(V_t0, V_t1, idx, is_vf, thickness, t_max, n_chunks, status, toi, sep, witness, counter):
    q = idx.shape[0]
    per = (q + n_chunks - 1) // n_chunks
    for w in prange(counter[-1]):  # the chunks claimed by ranges (`parallel.claim_next`)
        ch, k = claim_next(counter, w, 0)
        while ch >= 0:
            _run_chunk_idx(V_t0, V_t1, idx, is_vf, thickness, t_max, ch * per, min(q, (ch + 1) * per),
                           status, toi, sep, witness)
            ch, k = claim_next(counter, w, k)


def ccd_batch_indexed(V_t0, V_t1, idx, is_vf, thickness, t_max, n_chunks):
    """`ccd_batch` on rows gathered inside the kernel: query i is V[idx[i]] (idx (Q, 4) int64)."""
    q = idx.shape[0]
    status = np.zeros(q, dtype=np.int8)
    toi = np.full(q, np.inf)
    sep = np.zeros(q)
    witness = np.full(q, np.nan)
    if q <= _SERIAL_MAX:
        _run_chunk_idx(V_t0, V_t1, idx, is_vf, thickness, t_max, 0, q, status, toi, sep, witness)
    else:
        _batch_idx_parallel(V_t0, V_t1, idx, is_vf, thickness, t_max, n_chunks, status, toi, sep, witness,
                            range_counter(n_chunks))
    return status, toi, sep, witness


def ccd_batch(x_t0, x_t1, is_vf, thickness, t_max, n_chunks):
    """Run `_query` over (Q, 4, 3) arrays; returns status (Q,) int8, toi, sep, witness (Q,).

    Queries are independent, so the chunking only bounds workspace allocations
    and the result of each query does not depend on the thread count. Small
    batches run serially: waking threads costs more than they save.
    sep is a certified lower bound of the distance over [0, t_max] when status
    is SEPARATED (inf if every box was discarded by the u + v > 1 test), 0 otherwise.
    witness is, where status is CLOSE, a time at which the primitives are
    within sqrt(3) (thickness + tol + 2 err) (NaN elsewhere).
    """
    q = x_t0.shape[0]
    status = np.zeros(q, dtype=np.int8)
    toi = np.full(q, np.inf)
    sep = np.zeros(q)
    witness = np.full(q, np.nan)
    if q <= _SERIAL_MAX:
        _run_chunk(x_t0, x_t1, is_vf, thickness, t_max, 0, q, status, toi, sep, witness)
    else:
        _batch_parallel(x_t0, x_t1, is_vf, thickness, t_max, n_chunks, status, toi, sep, witness,
                        range_counter(n_chunks))
    return status, toi, sep, witness
