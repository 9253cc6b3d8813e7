"""A small extended position-based dynamics (XPBD) solver for the sample scenes.

Distance constraints only (stretch, shear and "skip" bending springs), explicit
gravity and linear air drag, pinned vertices that follow prescribed targets,
and an optional frictional sphere obstacle handled by projection. There is no
self-collision handling: the scenes are chosen so that none is needed, and
``check.py`` verifies it.

The kernels are serial Gauss-Seidel loops, so the result is bit-for-bit
deterministic for a given input on a given machine.
"""

from __future__ import annotations

import numpy as np
from numba import njit

GRAVITY = np.array([0.0, 0.0, -9.81])


@njit(cache=True)
def _substep(x, v, w, ij, rest, alpha, h, g, drag, iters, pin_idx, pin_pos,
             sphere_c, sphere_r, friction):
    n = x.shape[0]
    x_old = x.copy()
    damp = np.exp(-drag * h)
    for i in range(n):
        if w[i] > 0.0:
            for k in range(3):
                v[i, k] = (v[i, k] + h * g[k]) * damp
                x[i, k] += h * v[i, k]
    for p in range(pin_idx.shape[0]):
        for k in range(3):
            x[pin_idx[p], k] = pin_pos[p, k]
    lam = np.zeros(ij.shape[0])
    inv_h2 = 1.0 / (h * h)
    for _ in range(iters):
        for c in range(ij.shape[0]):
            a = ij[c, 0]
            b = ij[c, 1]
            wsum = w[a] + w[b]
            if wsum == 0.0:
                continue
            d0 = x[a, 0] - x[b, 0]
            d1 = x[a, 1] - x[b, 1]
            d2 = x[a, 2] - x[b, 2]
            length = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            if length == 0.0:
                continue
            at = alpha[c] * inv_h2
            dlam = (rest[c] - length - at * lam[c]) / (wsum + at)
            lam[c] += dlam
            s = dlam / length
            x[a, 0] += w[a] * s * d0
            x[a, 1] += w[a] * s * d1
            x[a, 2] += w[a] * s * d2
            x[b, 0] -= w[b] * s * d0
            x[b, 1] -= w[b] * s * d1
            x[b, 2] -= w[b] * s * d2
    if sphere_r > 0.0:
        for i in range(n):
            if w[i] == 0.0:
                continue
            d0 = x[i, 0] - sphere_c[0]
            d1 = x[i, 1] - sphere_c[1]
            d2 = x[i, 2] - sphere_c[2]
            r = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            if r < sphere_r:
                s = sphere_r / r
                x[i, 0] = sphere_c[0] + s * d0
                x[i, 1] = sphere_c[1] + s * d1
                x[i, 2] = sphere_c[2] + s * d2
                # Coulomb-like friction: undo part of the tangential move.
                m0 = x[i, 0] - x_old[i, 0]
                m1 = x[i, 1] - x_old[i, 1]
                m2 = x[i, 2] - x_old[i, 2]
                nn = (m0 * d0 + m1 * d1 + m2 * d2) / (r * r)
                x[i, 0] -= friction * (m0 - nn * d0)
                x[i, 1] -= friction * (m1 - nn * d1)
                x[i, 2] -= friction * (m2 - nn * d2)
    for i in range(n):
        for k in range(3):
            v[i, k] = (x[i, k] - x_old[i, k]) / h


class Solver:
    """XPBD state plus constraints; `run` records frames.

    Parameters
    ----------
    x : (N, 3) float64
        Initial positions.
    mass : (N,) float64
        Vertex masses; pinned vertices are given by `pins`, not by zero mass.
    constraints : list of ((C, 2) int64, (C,) float64 compliance)
        Distance constraints; rest lengths are taken from `x`.
    """

    def __init__(self, x, mass, constraints, drag=0.0, gravity=GRAVITY):
        self.x = np.ascontiguousarray(x, dtype=np.float64).copy()
        self.v = np.zeros_like(self.x)
        self.w = 1.0 / np.asarray(mass, dtype=np.float64)
        ij = np.concatenate([c[0] for c in constraints]).astype(np.int64)
        self.ij = np.ascontiguousarray(ij)
        self.alpha = np.concatenate(
            [np.broadcast_to(np.asarray(c[1], float), (len(c[0]),)) for c in constraints])
        self.rest = np.linalg.norm(self.x[ij[:, 0]] - self.x[ij[:, 1]], axis=1)
        self.drag = float(drag)
        self.g = np.asarray(gravity, dtype=np.float64)
        self.pin_idx = np.zeros(0, np.int64)
        self.pin_fn = None
        self.sphere_c = np.zeros(3)
        self.sphere_r = 0.0
        self.friction = 0.0

    def pin(self, idx, fn):
        """Pin vertices `idx`; `fn(t) -> (len(idx), 3)` gives their targets at time t."""
        self.pin_idx = np.asarray(idx, dtype=np.int64)
        self.pin_fn = fn
        self.w[self.pin_idx] = 0.0

    def sphere(self, center, radius, friction=0.5):
        self.sphere_c = np.asarray(center, dtype=np.float64)
        self.sphere_r = float(radius)
        self.friction = float(friction)

    def run(self, frames, dt, substeps, iters, t0=0.0):
        """Advance and record `frames` frames `dt` apart (the first is the current state).

        Returns
        -------
        (frames, N, 3) float64
        """
        out = np.empty((frames,) + self.x.shape)
        out[0] = self.x
        h = dt / substeps
        t = t0
        for f in range(1, frames):
            for _ in range(substeps):
                t += h
                pin_pos = (np.ascontiguousarray(self.pin_fn(t), dtype=np.float64)
                           if self.pin_fn is not None else np.zeros((0, 3)))
                _substep(self.x, self.v, self.w, self.ij, self.rest, self.alpha, h,
                         self.g, self.drag, iters, self.pin_idx, pin_pos,
                         self.sphere_c, self.sphere_r, self.friction)
            out[f] = self.x
        return out

    def settle(self, duration, dt, substeps, iters):
        """Run without recording (to reach a rest state or a moving state)."""
        n = max(2, int(round(duration / dt)) + 1)
        self.run(n, dt, substeps, iters)


def chain_constraints(starts, lengths, stretch, bend):
    """Stretch (i, i+1) and bending (i, i+2) constraints of polylines.

    Parameters
    ----------
    starts, lengths : sequence of int
        First vertex and vertex count of each polyline.
    """
    s1, s2 = [], []
    for s, n in zip(starts, lengths):
        i = np.arange(s, s + n - 1)
        s1.append(np.stack([i, i + 1], 1))
        s2.append(np.stack([i[:-1], i[:-1] + 2], 1))
    return [(np.concatenate(s1), stretch), (np.concatenate(s2), bend)]


def chain_edges(starts, lengths):
    out = [np.stack([np.arange(s, s + n - 1), np.arange(s + 1, s + n)], 1)
           for s, n in zip(starts, lengths)]
    return np.concatenate(out).astype(np.int64)


def grid_faces(nu, nv):
    """Triangles of an `nu x nv` vertex grid (vertex `i * nv + j`), alternating diagonals."""
    i, j = np.meshgrid(np.arange(nu - 1), np.arange(nv - 1), indexing="ij")
    i, j = i.ravel(), j.ravel()
    a, b, c, d = i * nv + j, (i + 1) * nv + j, (i + 1) * nv + j + 1, i * nv + j + 1
    flip = (i + j) % 2 == 1
    t1 = np.where(flip[:, None], np.stack([a, b, d], 1), np.stack([a, b, c], 1))
    t2 = np.where(flip[:, None], np.stack([b, c, d], 1), np.stack([a, c, d], 1))
    return np.concatenate([t1, t2]).astype(np.int64)


def grid_constraints(nu, nv, stretch, shear, bend):
    """Structural, shear (both diagonals) and skip-one bending springs of a vertex grid."""
    idx = np.arange(nu * nv).reshape(nu, nv)
    st = np.concatenate([np.stack([idx[:-1].ravel(), idx[1:].ravel()], 1),
                         np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1)])
    sh = np.concatenate([np.stack([idx[:-1, :-1].ravel(), idx[1:, 1:].ravel()], 1),
                         np.stack([idx[1:, :-1].ravel(), idx[:-1, 1:].ravel()], 1)])
    bd = np.concatenate([np.stack([idx[:-2].ravel(), idx[2:].ravel()], 1),
                         np.stack([idx[:, :-2].ravel(), idx[:, 2:].ravel()], 1)])
    return [(st, stretch), (sh, shear), (bd, bend)]
