"""A small extended position-based dynamics (XPBD) solver for the sample scenes.

Distance constraints only (stretch, shear and "skip" bending springs), explicit
gravity and linear air drag, pinned vertices that follow prescribed targets,
and an optional frictional sphere obstacle handled by projection.

Self-contact is optional (`Solver.self_contact`). It follows the offset
geometric contact (OGC) recipe: non-adjacent vertex-face and edge-edge pairs
closer than a contact radius are pushed apart along their closest points
(inequality constraints, position-based friction), and every substep ends by
truncating each vertex's displacement to its OGC trust-region bound at the start
of the substep (``gamma * (d_v - thickness)``, penfree's `trust_region_bounds`),
which keeps every non-adjacent primitive pair farther apart than the thickness
along the whole straight path of the substep. Scenes without it are chosen so
that none is needed; ``check.py`` verifies every recorded file.

The kernels are serial Gauss-Seidel loops, so the result is bit-for-bit
deterministic for a given input on a given machine.
"""

from __future__ import annotations

import numpy as np
from numba import njit

GRAVITY = np.array([0.0, 0.0, -9.81])
_NO_PRIMS = np.zeros((0, 4), np.int64)
_NO_KINDS = np.zeros(0, np.int64)
_NO_BOUND = np.zeros(0)
#: Pairs within this multiple of the contact radius feel friction.
FRICTION_REACH = 1.05
#: Pairs within this multiple of the contact radius at the start of a substep
#: are the substep's contact candidates.
CONTACT_REACH = 1.5


@njit(cache=True)
def _substep(x, v, w, ij, rest, alpha, h, g, drag, iters, pin_idx, pin_pos,
             sphere_c, sphere_r, friction, prims, kinds, radius, mu, bound):
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
    for it in range(iters):
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
        _contacts(x, x_old, w, prims, kinds, radius, mu if it == iters - 1 else 0.0)
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
    if bound.shape[0] == n:
        _truncate(x, x_old, bound)
    for i in range(n):
        for k in range(3):
            v[i, k] = (x[i, k] - x_old[i, k]) / h


@njit(cache=True, inline="always")
def _closest_triangle(p, a, b, c):
    """Barycentric weights of the point of triangle abc closest to p (Ericson 5.1.5)."""
    ab = b - a
    ac = c - a
    ap = p - a
    d1 = ab @ ap
    d2 = ac @ ap
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0
    bp = p - b
    d3 = ab @ bp
    d4 = ac @ bp
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return 1.0 - v, v, 0.0
    cp = p - c
    d5 = ab @ cp
    d6 = ac @ cp
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return 1.0 - w, 0.0, w
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return 0.0, 1.0 - w, w
    den = 1.0 / (va + vb + vc)
    v = vb * den
    w = vc * den
    return 1.0 - v - w, v, w


@njit(cache=True, inline="always")
def _closest_segments(p1, q1, p2, q2):
    """Parameters (s, t) of the closest points of segments p1q1 and p2q2 (Ericson 5.1.9)."""
    d1 = q1 - p1
    d2 = q2 - p2
    r = p1 - p2
    a = d1 @ d1
    e = d2 @ d2
    f = d2 @ r
    c = d1 @ r
    b = d1 @ d2
    den = a * e - b * b
    s = 0.0
    if den > 1e-12 * a * e:
        s = min(max((b * f - c * e) / den, 0.0), 1.0)
    t = (b * s + f) / e
    if t < 0.0:
        t = 0.0
        s = min(max(-c / a, 0.0), 1.0)
    elif t > 1.0:
        t = 1.0
        s = min(max((b - c) / a, 0.0), 1.0)
    return s, t


@njit(cache=True, inline="always")
def _weights(x, i0, i1, i2, i3, kind, g):
    """Fill `g` with the signed closest-point weights of a pair; return the gap vector."""
    if kind == 0:
        u, v, t = _closest_triangle(x[i0], x[i1], x[i2], x[i3])
        g[0], g[1], g[2], g[3] = 1.0, -u, -v, -t
    else:
        s, t = _closest_segments(x[i0], x[i1], x[i2], x[i3])
        g[0], g[1], g[2], g[3] = 1.0 - s, s, t - 1.0, -t
    return g[0] * x[i0] + g[1] * x[i1] + g[2] * x[i2] + g[3] * x[i3]


@njit(cache=True)
def _within(x, prims, kinds, reach):
    """Mask of the pairs whose closest points are nearer than `reach`."""
    out = np.zeros(prims.shape[0], np.bool_)
    g = np.zeros(4)
    for k in range(prims.shape[0]):
        n = _weights(x, prims[k, 0], prims[k, 1], prims[k, 2], prims[k, 3], kinds[k], g)
        out[k] = n @ n < reach * reach
    return out


@njit(cache=True)
def _contacts(x, x_old, w, prims, kinds, radius, mu):
    """One Gauss-Seidel sweep of the contact constraints ``dist >= radius``.

    Row k of `prims` holds four vertex indices: a vertex and a face
    (``kinds[k] == 0``: p, a, b, c) or two edges (``kinds[k] == 1``: p1, q1,
    p2, q2). The closest points are recomputed, the pair is pushed apart
    along their difference with the barycentric weights (PBD), and, when `mu`
    is positive, the fraction `mu` of the closest points' relative tangential
    motion over the substep is undone (position-based friction) for pairs
    closer than ``FRICTION_REACH * radius``.
    """
    g = np.zeros(4)
    for k in range(prims.shape[0]):
        i0, i1, i2, i3 = prims[k, 0], prims[k, 1], prims[k, 2], prims[k, 3]
        n = _weights(x, i0, i1, i2, i3, kinds[k], g)
        dist = np.sqrt(n @ n)
        if dist >= FRICTION_REACH * radius or dist == 0.0:
            continue
        n = n / dist
        wsum = (w[i0] * g[0] * g[0] + w[i1] * g[1] * g[1] + w[i2] * g[2] * g[2]
                + w[i3] * g[3] * g[3])
        if wsum == 0.0:
            continue
        idx = (i0, i1, i2, i3)
        if dist < radius:
            lam = (radius - dist) / wsum
            for m in range(4):
                j = idx[m]
                x[j] += (lam * w[j] * g[m]) * n
        if mu > 0.0:
            rel = np.zeros(3)
            for m in range(4):
                j = idx[m]
                rel += g[m] * (x[j] - x_old[j])
            tan = rel - (rel @ n) * n
            for m in range(4):
                j = idx[m]
                x[j] -= (mu * w[j] * g[m] / wsum) * tan


@njit(cache=True)
def _truncate(x, x_old, bound):
    """OGC truncation: each vertex moves at most `bound[i]` from `x_old[i]`."""
    for i in range(x.shape[0]):
        m0 = x[i, 0] - x_old[i, 0]
        m1 = x[i, 1] - x_old[i, 1]
        m2 = x[i, 2] - x_old[i, 2]
        m = np.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
        if m > bound[i]:
            s = bound[i] / m
            x[i, 0] = x_old[i, 0] + s * m0
            x[i, 1] = x_old[i, 1] + s * m1
            x[i, 2] = x_old[i, 2] + s * m2


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
        self.contact = None

    def pin(self, idx, fn):
        """Pin vertices `idx`; `fn(t) -> (len(idx), 3)` gives their targets at time t."""
        self.pin_idx = np.asarray(idx, dtype=np.int64)
        self.pin_fn = fn
        self.w[self.pin_idx] = 0.0

    def sphere(self, center, radius, friction=0.5):
        self.sphere_c = np.asarray(center, dtype=np.float64)
        self.sphere_r = float(radius)
        self.friction = float(friction)

    def self_contact(self, radius, thickness, *, edges=None, faces=None, friction=0.3):
        """Enable self-contact (see the module docstring).

        Non-adjacent primitive pairs (vertex-face and edge-edge pairs sharing no
        vertex; edge-edge only for segment scenes) closer than `radius` are
        pushed apart, with friction `friction`. `radius` must stay below the
        mesh's own non-adjacent distances at rest (about 0.7 edge lengths on a
        grid), or the contacts fight the cloth. `thickness` defines the OGC
        bounds every substep is truncated to (penfree's default gamma, query
        radius ``2 * radius``).
        """
        from penfree.core.topology import edges_from_faces

        E = np.asarray(edges if faces is None else edges_from_faces(faces), dtype=np.int64)
        self.contact = dict(radius=float(radius), thickness=float(thickness), edges=E,
                            faces=None if faces is None else np.asarray(faces, np.int64),
                            mu=float(friction))

    def _contact_state(self):
        """Candidate contact pairs and the OGC bounds at the current positions."""
        from penfree.core.contact.broad_phase import edge_edge_candidates, vertex_face_candidates
        from penfree.core.trust.bounds import trust_region_bounds

        c = self.contact
        reach = 2 * c["radius"]
        E, F = c["edges"], c["faces"]
        ee = edge_edge_candidates(self.x, self.x, E, inflation=0.5 * reach)
        rows = [np.concatenate([E[ee[:, 0]], E[ee[:, 1]]], axis=1)]
        kinds = [np.ones(len(ee), np.int64)]
        if F is not None:
            vf = vertex_face_candidates(self.x, self.x, F, inflation=0.5 * reach)
            rows.insert(0, np.concatenate([vf[:, :1], F[vf[:, 1]]], axis=1))
            kinds.insert(0, np.zeros(len(vf), np.int64))
        bound = trust_region_bounds(self.x, edges=None if F is not None else E, faces=F,
                                    thickness=c["thickness"], query_radius=reach)
        prims = np.ascontiguousarray(np.concatenate(rows), dtype=np.int64)
        kinds = np.concatenate(kinds)
        # Pairs more than CONTACT_REACH radii apart at the start of the substep
        # cannot touch within it at the speeds of the scenes (the truncation
        # would stop them anyway).
        near = _within(self.x, prims, kinds, CONTACT_REACH * c["radius"])
        return np.ascontiguousarray(prims[near]), kinds[near], bound

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
                if self.contact is not None:
                    prims, kinds, bound = self._contact_state()
                    radius, mu = self.contact["radius"], self.contact["mu"]
                else:
                    prims, kinds, bound, radius, mu = _NO_PRIMS, _NO_KINDS, _NO_BOUND, 0.0, 0.0
                _substep(self.x, self.v, self.w, self.ij, self.rest, self.alpha, h,
                         self.g, self.drag, iters, self.pin_idx, pin_pos,
                         self.sphere_c, self.sphere_r, self.friction, prims, kinds, radius,
                         mu, bound)
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
