"""Numba kernels of the fit stage (SPEC section 4): moments, centring, rank, applying the map.

Pure functions over C-contiguous arrays; `penfree.core.fit.models` validates and converts
before calling them. The moment and apply kernels exist in a serial and a parallel
build of the same source (same fixed chunks, same summation order, so the same bits).
They take flat ``(3N,)`` views of the ``(N, 3)`` positions and loop over an unsigned
index: with 2-D indexing and a signed index, Numba's runtime strides and
negative-index wraparound keep LLVM from vectorising (measured 2-4x slower).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ... import constants as K
from ..parallel import Pace, named
from ..vector_width import wide
from .certificate import _fast_bound_kernel

#: Layout of the moment vector the kernel returns (offsets into it).
_W, _SP, _SD, _SPP, _SDP, _SDD, _SW2, _NMOM = 0, 1, 4, 7, 13, 22, 23, 24
_SYM = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def _moments_py(x_prev, x, w, n_chunks):
    # Shift every vertex by the first vertex (and its displacement) before
    # accumulating: second moments of coordinates 1e6 from the origin would
    # otherwise cancel catastrophically when centred afterwards.
    # x, x_prev are flat (3N,) views and the loop index is unsigned: a constant
    # stride 3 and no negative-index wraparound let LLVM vectorise the loop.
    n = x.shape[0] // 3
    x00, x01, x02 = np.float64(x[0]), np.float64(x[1]), np.float64(x[2])
    d00 = x00 - np.float64(x_prev[0])
    d01 = x01 - np.float64(x_prev[1])
    d02 = x02 - np.float64(x_prev[2])
    part = np.zeros((n_chunks, _NMOM))
    for k in prange(n_chunks):
        lo = k * n // n_chunks
        hi = (k + 1) * n // n_chunks
        sw = sw2 = 0.0
        sp0 = sp1 = sp2 = sd0 = sd1 = sd2 = 0.0
        c00 = c11 = c22 = c01 = c02 = c12 = 0.0
        g00 = g01 = g02 = g10 = g11 = g12 = g20 = g21 = g22 = 0.0
        sdd = 0.0
        for j in range(hi - lo):
            i = np.uint64(lo + j)
            i3 = np.uint64(3) * i
            a0 = np.float64(x[i3])
            a1 = np.float64(x[i3 + np.uint64(1)])
            a2 = np.float64(x[i3 + np.uint64(2)])
            p0, p1, p2 = a0 - x00, a1 - x01, a2 - x02
            q0 = (a0 - np.float64(x_prev[i3])) - d00
            q1 = (a1 - np.float64(x_prev[i3 + np.uint64(1)])) - d01
            q2 = (a2 - np.float64(x_prev[i3 + np.uint64(2)])) - d02
            if w is None:
                wp0, wp1, wp2 = p0, p1, p2
                sd0 += q0
                sd1 += q1
                sd2 += q2
                sdd += q0 * q0 + q1 * q1 + q2 * q2
            else:
                wi = w[i]
                wp0, wp1, wp2 = wi * p0, wi * p1, wi * p2
                sw += wi
                sw2 += wi * wi
                sd0 += wi * q0
                sd1 += wi * q1
                sd2 += wi * q2
                sdd += wi * (q0 * q0 + q1 * q1 + q2 * q2)
            sp0 += wp0
            sp1 += wp1
            sp2 += wp2
            c00 += wp0 * p0
            c11 += wp1 * p1
            c22 += wp2 * p2
            c01 += wp0 * p1
            c02 += wp0 * p2
            c12 += wp1 * p2
            g00 += q0 * wp0
            g01 += q0 * wp1
            g02 += q0 * wp2
            g10 += q1 * wp0
            g11 += q1 * wp1
            g12 += q1 * wp2
            g20 += q2 * wp0
            g21 += q2 * wp1
            g22 += q2 * wp2
        if w is None:
            sw = sw2 = float(hi - lo)
        row = part[k]
        row[0] = sw
        row[1], row[2], row[3] = sp0, sp1, sp2
        row[4], row[5], row[6] = sd0, sd1, sd2
        row[7], row[8], row[9], row[10], row[11], row[12] = c00, c11, c22, c01, c02, c12
        row[13], row[14], row[15] = g00, g01, g02
        row[16], row[17], row[18] = g10, g11, g12
        row[19], row[20], row[21] = g20, g21, g22
        row[22] = sdd
        row[23] = sw2
    # Partials are summed in chunk order, so the result is independent of
    # how many threads ran the chunks.
    tot = np.zeros(_NMOM + 6)
    for k in range(n_chunks):
        for j in range(_NMOM):
            tot[j] += part[k, j]
    tot[_NMOM + 0], tot[_NMOM + 1], tot[_NMOM + 2] = x00, x01, x02
    tot[_NMOM + 3], tot[_NMOM + 4], tot[_NMOM + 5] = d00, d01, d02
    return tot


# The same source compiled twice, each build under its own name (`parallel.named`): a
# parallel region costs tens of microseconds (far more on a loaded machine), so small
# inputs run the chunks serially. The choice depends on N only, never on the thread count.
#: Reassociation lets LLVM vectorise the per-chunk sums (about 2x); it is fixed
#: at compile time, so results still do not depend on the thread count. No
#: flag that assumes finite values: NaN/Inf inputs must still poison the sums.
_FIT_FASTMATH = {"reassoc", "contract"}

# Both with 512-bit vectors where the CPU has them (`vector_width`): 1.2-1.3x faster at
# 64K vertices on 2 threads of an AVX-512 host, float32 and float64.
_moments_serial = wide(njit(cache=True, fastmath=_FIT_FASTMATH)(named(_moments_py, "_moments_serial")))
_moments_parallel = wide(njit(cache=True, parallel=True, fastmath=_FIT_FASTMATH)(
    named(_moments_py, "_moments_parallel")))


def fit_build(n, pace, serial, parallel, *args):
    """Run one of a fit kernel's two builds on `n` vertices: the serial one below
    ``K.PARALLEL_MIN_VERTICES``, else as ``K.FIT_BUILD`` and `pace` choose."""
    build = K.FIT_BUILD
    if build == "adaptive" and n < K.PARALLEL_MIN_VERTICES:
        build = "serial"
    return pace.run(n, build, serial, parallel, *args)


_MOMENTS_PACE = Pace()


def _moments_kernel(x_prev, x, w, n_chunks):
    return fit_build(x.shape[0], _MOMENTS_PACE, _moments_serial, _moments_parallel,
                     x_prev.reshape(-1), x.reshape(-1), w, n_chunks)


@njit(cache=True)
def _finish_kernel(tot, use_w, n):
    # Centre the shifted sums: C = Spp - Sp mp^T, G = Sdp - Sd mp^T (the shift
    # by the first vertex keeps these differences free of large cancellation).
    f = np.empty(28)
    W = tot[_W]
    mp = tot[_SP:_SP + 3] / W
    mq = tot[_SD:_SD + 3] / W
    f[0] = W
    tr = 0.0
    for a in range(3):
        f[1 + a] = tot[_NMOM + a] + mp[a]
        f[4 + a] = tot[_NMOM + 3 + a] + mq[a]
    for j in range(6):
        a, b = _SYM[j]
        cab = tot[_SPP + j] - 0.5 * (tot[_SP + a] * mp[b] + tot[_SP + b] * mp[a])
        f[7 + 3 * a + b] = cab
        f[7 + 3 * b + a] = cab
        if a == b:
            tr += cab
    for a in range(3):
        for b in range(3):
            f[16 + 3 * a + b] = tot[_SDP + 3 * a + b] - tot[_SD + a] * mp[b]
    f[25] = max(tot[_SDD] - (tot[_SD] * mq[0] + tot[_SD + 1] * mq[1] + tot[_SD + 2] * mq[2]), 0.0)
    f[26] = W * W / tot[_SW2] if use_w else float(n)
    f[27] = max(abs(f[1]), abs(f[2]), abs(f[3])) + np.sqrt(max(tr, 0.0) / W)
    return f


@njit(cache=True)
def _offset_kernel(D, u, c):
    # b = u - D c, so that x + D (x - c) + u = (I + D) x + b (summed in a fixed order).
    b = np.empty(3)
    for a in range(3):
        b[a] = u[a] - (D[a, 0] * c[0] + D[a, 1] * c[1] + D[a, 2] * c[2])
    return b


#: Relative size of the rounding in the fit's residual sum of squares (1e3 float64 ulps).
_RESID_RTOL = 1e3 * 2.0**-52


@njit(cache=True)
def _subspace_kernel(C, G, qq, n_eff, floor, rtol, tol):
    lam, E = np.linalg.eigh(C)
    keep = np.zeros(3, dtype=np.bool_)
    if not lam[2] > 0:
        return lam, E, keep
    r = 0
    for k in range(3):
        keep[k] = lam[k] > rtol * lam[2] and lam[k] > floor
        r += keep[k]
    if r == 0 or not np.isfinite(tol):
        return lam, E, keep
    # Residual of the affine fit on the kept directions: the directions are
    # C-orthogonal, so each explains |G e|^2 / lam of the squared residual.
    explained = 0.0
    for k in range(3):
        if keep[k]:
            g0 = G[0, 0] * E[0, k] + G[0, 1] * E[1, k] + G[0, 2] * E[2, k]
            g1 = G[1, 0] * E[0, k] + G[1, 1] * E[1, k] + G[1, 2] * E[2, k]
            g2 = G[2, 0] * E[0, k] + G[2, 1] * E[1, k] + G[2, 2] * E[2, k]
            explained += (g0 * g0 + g1 * g1 + g2 * g2) / lam[k]
    dof = 3.0 * (n_eff - 1.0 - r)
    # qq - explained cancels: on exact affine data the difference is rounding of the
    # order of eps * qq, which at a large slope (x_pred = 1e6 x) alone exceeds the
    # tolerance. A residual below _RESID_RTOL * qq is taken as none: the slope error it
    # could hide is ~1e-6 of the slope itself.
    resid = qq - explained
    if resid <= _RESID_RTOL * max(qq, explained):
        resid = 0.0
    sigma2 = resid / dof if dof > 0 else 0.0
    for k in range(3):
        keep[k] = keep[k] and sigma2 <= tol * tol * lam[k]
    return lam, E, keep


@njit(cache=True)
def _gain_kernel(D, C, G):
    # trace(D C D^T) - 2 trace(D G^T), summed in a fixed order.
    s = 0.0
    for a in range(3):
        for b in range(3):
            dcb = D[a, 0] * C[0, b] + D[a, 1] * C[1, b] + D[a, 2] * C[2, b]
            s += dcb * D[a, b] - 2.0 * D[a, b] * G[a, b]
    return s


@njit(cache=True)
def _slopes_kernel(G, E, lam, keep):
    # D = sum over kept k of (G e_k / lam_k) e_k^T: the affine slope on the kept
    # eigen-directions of C, 0 on the others.
    D = np.zeros((3, 3))
    for k in range(3):
        if keep[k]:
            for a in range(3):
                s = (G[a, 0] * E[0, k] + G[a, 1] * E[1, k] + G[a, 2] * E[2, k]) / lam[k]
                for b in range(3):
                    D[a, b] += s * E[b, k]
    return D


def _apply_py(x_prev, x, D, u, c, out, evaluate, n_chunks):
    # x_def = x + D (x - c) + u in float64, then cast on store. With `evaluate`, also
    # residual sums of the *stored* x_def (cast to out's dtype and back: a float32 x_def's
    # summaries see its rounding; for float64 the casts are no-ops) and of x against
    # x_pred = 2x - x_prev, formed as d - (x_def - x) to keep far-from-origin digits.
    # Never reads `out` back, so the loop carries no memory dependence through it.
    # Flat (3N,) views and an unsigned index, as in _moments_py.
    n = x.shape[0] // 3
    store = out.dtype.type
    d00, d01, d02 = D[0, 0], D[0, 1], D[0, 2]
    d10, d11, d12 = D[1, 0], D[1, 1], D[1, 2]
    d20, d21, d22 = D[2, 0], D[2, 1], D[2, 2]
    u0, u1, u2 = u[0], u[1], u[2]
    c0, c1, c2 = c[0], c[1], c[2]
    part = np.zeros((n_chunks, 4))
    for k in prange(n_chunks):
        lo = k * n // n_chunks
        hi = (k + 1) * n // n_chunks
        s_def = s_base = 0.0
        m_def = m_base = np.uint64(0)
        for j in range(hi - lo):
            i = np.uint64(lo + j)
            i3 = np.uint64(3) * i
            a0 = np.float64(x[i3])
            a1 = np.float64(x[i3 + np.uint64(1)])
            a2 = np.float64(x[i3 + np.uint64(2)])
            p0, p1, p2 = a0 - c0, a1 - c1, a2 - c2
            w0 = store(a0 + (d00 * p0 + d01 * p1 + d02 * p2 + u0))
            w1 = store(a1 + (d10 * p0 + d11 * p1 + d12 * p2 + u1))
            w2 = store(a2 + (d20 * p0 + d21 * p1 + d22 * p2 + u2))
            out[i3] = w0
            out[i3 + np.uint64(1)] = w1
            out[i3 + np.uint64(2)] = w2
            if evaluate:
                q0 = a0 - np.float64(x_prev[i3])
                q1 = a1 - np.float64(x_prev[i3 + np.uint64(1)])
                q2 = a2 - np.float64(x_prev[i3 + np.uint64(2)])
                e0 = q0 - (np.float64(w0) - a0)
                e1 = q1 - (np.float64(w1) - a1)
                e2 = q2 - (np.float64(w2) - a2)
                ed = e0 * e0 + e1 * e1 + e2 * e2
                eb = q0 * q0 + q1 * q1 + q2 * q2
                s_def += ed
                s_base += eb
                # Maxima of the bit patterns: for non-negative floats the unsigned
                # order is the float order, and NaN (either sign) compares above
                # every number, so it still poisons the result. Unlike a float
                # max, an integer max reduction vectorises without fast-math flags
                # that assume finite values (about 4x for this loop).
                m_def = max(m_def, np.float64(ed).view(np.uint64))
                m_base = max(m_base, np.float64(eb).view(np.uint64))
        part[k, 0], part[k, 2] = s_def, s_base
        part[k, 1], part[k, 3] = np.uint64(m_def).view(np.float64), np.uint64(m_base).view(np.float64)
    res = np.zeros(4)
    m_def = m_base = np.uint64(0)
    for k in range(n_chunks):
        res[0] += part[k, 0]
        res[2] += part[k, 2]
        m_def = max(m_def, np.float64(part[k, 1]).view(np.uint64))
        m_base = max(m_base, np.float64(part[k, 3]).view(np.uint64))
    res[1], res[3] = np.uint64(m_def).view(np.float64), np.uint64(m_base).view(np.float64)
    return res


_apply_serial = njit(cache=True, fastmath=_FIT_FASTMATH)(named(_apply_py, "_apply_serial"))
_apply_parallel = njit(cache=True, parallel=True, fastmath=_FIT_FASTMATH)(named(_apply_py, "_apply_parallel"))
# float32 positions: 512-bit vectors where the CPU has them (`vector_width`): with the
# summaries 1.5x faster at 64K vertices on 2 threads of an AVX-512 host; float64 ran
# 1.1-1.2x slower wide, and keeps the builds above.
_apply_wide_serial = wide(njit(cache=True, fastmath=_FIT_FASTMATH)(named(_apply_py, "_apply_wide_serial")))
_apply_wide_parallel = wide(njit(cache=True, parallel=True, fastmath=_FIT_FASTMATH)(
    named(_apply_py, "_apply_wide_parallel")))

# Per width and with or without the summaries: different costs.
_APPLY_PACE = {(w, e): Pace() for w in (False, True) for e in (False, True)}


def _apply_kernel(x_prev, x, D, u, c, out, evaluate, n_chunks):
    w = out.dtype == np.float32
    return fit_build(x.shape[0], _APPLY_PACE[w, bool(evaluate)],
                     _apply_wide_serial if w else _apply_serial, _apply_wide_parallel if w else _apply_parallel,
                     x_prev.reshape(-1), x.reshape(-1), D, u, c, out.reshape(-1), evaluate, n_chunks)


@njit(cache=True)
def _affine_step_kernel(tot, use_w, n, input_eps, precision, rtol_floor, tol, allowance):
    """`fit_step`'s default call (affine model, projection ``auto`` or ``none``) after the
    moment pass, in one call: the same kernels, in the same order, as `fit_moments`,
    `fit_affine`, the fast certificate of ``A = I + D`` and `residual_gain`.

    Returns ``(f, D, A, fast_bound, rank, gain, b, finite)``: `f` the finished moments
    (`_finish_kernel`), ``D = A - I`` as rounded through `A`, and whether the moment
    sums were finite (else the rest is meaningless: `fit_moments` names the input).
    """
    f = _finish_kernel(tot, use_w, n)
    finite = True
    for k in range(tot.shape[0]):
        finite = finite and np.isfinite(tot[k])
    C = f[7:16].reshape((3, 3))
    G = f[16:25].reshape((3, 3))
    s = precision * input_eps * f[27]
    lam, E, keep = _subspace_kernel(C, G, f[25], f[26], s * s * f[0], rtol_floor, tol)
    D0 = _slopes_kernel(G, E, lam, keep)
    A = np.empty((3, 3))
    D = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            A[a, b] = (1.0 if a == b else 0.0) + D0[a, b]
            D[a, b] = A[a, b] - (1.0 if a == b else 0.0)
    rank = 0
    for k in range(3):
        rank += keep[k]
    return f, D, A, _fast_bound_kernel(A, allowance), rank, _gain_kernel(D, C, G), _offset_kernel(D, f[4:7], f[1:4]), finite
