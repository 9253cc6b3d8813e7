"""Kinematic 64K-vertex reference scenes for benchmarks (not committed; regenerate).

A 64K-vertex dynamic simulation is too slow to regenerate on demand, so these
scenes prescribe smooth, non-affine motion in closed form (sums of
sinusoids and damped oscillations, so positions are smooth in time) plus a
small smooth per-vertex perturbation. They are built so that non-adjacent
primitives stay apart:

- ``yarn_bundle``: every cross-section of the bundle is a rigid copy of a
  fixed point pattern (yarn spacing >= d_min) placed on a swinging, twisting
  centerline whose bend radius stays far above the bundle radius;
- ``cloth_ref``: the sheet is a height field over an in-plane map whose
  Jacobian stays close to the identity, so it cannot fold onto itself.

``check.py --every K`` confirms the separation on a subset of the steps.
"""

from __future__ import annotations

import numpy as np

#: Golden angle, for the sunflower (Vogel) pattern of yarns in the cross-section.
GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


def _smooth_noise(rng, K, s, t, amp, waves=3):
    """Sum of `waves` travelling sinusoids per item: (T, K, S, 3), smooth in s and t."""
    out = np.zeros((len(t), K, len(s), 3))
    for _ in range(waves):
        kappa = rng.uniform(2.0, 8.0, (K, 1, 3))
        omega = rng.uniform(3.0, 9.0, (K, 1, 3))
        phase = rng.uniform(0, 2 * np.pi, (K, 1, 3))
        out += np.sin(kappa[None] * s[None, None, :, None] + omega[None] * t[:, None, None, None]
                      + phase[None])
    return out * (amp / np.sqrt(waves))


def yarn_bundle(vertices=65536, frames=100, seed=0):
    """A hanging bundle of twisted yarns, swinging and twisting (kinematic).

    256 yarns (sunflower pattern, bundle radius 2 cm, spacing about 2 mm) of
    ``vertices // 256`` vertices each along a 1 m centerline pinned at the
    top. The centerline swings in two directions with different periods
    plus a second bending mode; the twist rate oscillates about 1 turn per
    metre, with a wave travelling down the bundle; each yarn carries a small
    smooth wobble (0.1 mm). 60 Hz.
    """
    rng = np.random.default_rng(seed)
    n_yarns = 256
    per = max(4, vertices // n_yarns)
    L, R, dt = 1.0, 0.02, 1.0 / 60.0
    k = np.arange(n_yarns)
    rad = R * np.sqrt((k + 0.5) / n_yarns)
    ang = k * GOLDEN_ANGLE
    pattern = np.column_stack([rad * np.cos(ang), rad * np.sin(ang)])  # (K, 2)
    s = np.linspace(0.0, L, per)
    t = np.arange(frames) * dt
    q = s / L
    # Centerline: first mode q^1.5 (tip moves most), second mode sin(pi q) in
    # the other direction, with different periods, so no single affine fits.
    p1, p2, p3 = rng.uniform(0, 2 * np.pi, 3)
    cx = 0.05 * np.sin(2 * np.pi * 0.55 * t + p1)[:, None] * q ** 1.5 \
        + 0.015 * np.sin(2 * np.pi * 1.4 * t + p3)[:, None] * np.sin(np.pi * q)
    cy = 0.04 * np.sin(2 * np.pi * 0.8 * t + p2)[:, None] * q ** 1.5
    c = np.stack([cx, cy, np.broadcast_to(-s, cx.shape)], -1)  # (T, S, 3)
    tangent = np.gradient(c, s, axis=1)
    tangent /= np.linalg.norm(tangent, axis=2, keepdims=True)
    # Cross-section frame: x projected off the tangent (the tangent stays near -z).
    e1 = np.array([1.0, 0.0, 0.0]) - tangent[..., :1] * tangent
    e1 /= np.linalg.norm(e1, axis=2, keepdims=True)
    e2 = np.cross(tangent, e1)
    twist = 2 * np.pi * (1.0 + 0.3 * np.sin(2 * np.pi * 0.5 * t))[:, None] * s[None] \
        + 0.25 * np.sin(2 * np.pi * (1.2 * t[:, None] - 1.5 * q[None])) * q[None]
    ct, st = np.cos(twist), np.sin(twist)  # (T, S)
    u = ct[:, None] * pattern[None, :, 0, None] - st[:, None] * pattern[None, :, 1, None]
    v = st[:, None] * pattern[None, :, 0, None] + ct[:, None] * pattern[None, :, 1, None]
    X = c[:, None] + u[..., None] * e1[:, None] + v[..., None] * e2[:, None]  # (T, K, S, 3)
    # Pinned top: the wobble fades in along the yarn.
    X += _smooth_noise(rng, n_yarns, s, t, 1e-4) * np.sqrt(q)[None, None, :, None]
    X = X.reshape(frames, n_yarns * per, 3)
    starts = np.arange(n_yarns) * per
    i = (starts[:, None] + np.arange(per - 1)[None]).ravel()
    edges = np.stack([i, i + 1], 1).astype(np.int64)
    comp = np.repeat(np.arange(n_yarns), per)
    return X, {"edges": edges, "components": comp}, {
        "dt": dt, "thickness": 5e-4,
        "description": f"yarn-bundle: {n_yarns} twisted yarns x {per} vertices, "
                       f"kinematic swing + twist + wobble, {1/dt:.0f} Hz"}


def cloth_ref(vertices=65536, frames=100, seed=0):
    """A square sheet draping onto a central support (kinematic height field).

    ``n x n`` vertices (256 x 256 by default) over 1 m x 1 m. The sheet sags
    around its held centre with a damped bounce, is drawn inwards as it
    drapes (a radial in-plane contraction), and carries outward-travelling
    ripples and six-fold wrinkles that grow as it settles; the profile widens
    and the skirt rocks from side to side. 60 Hz.
    """
    rng = np.random.default_rng(seed)
    n = max(8, int(round(np.sqrt(vertices))))
    size, dt = 1.0, 1.0 / 60.0
    g = np.linspace(-size / 2, size / 2, n)
    x0, y0 = [a.ravel() for a in np.meshgrid(g, g, indexing="ij")]
    r = np.hypot(x0, y0)
    th = np.arctan2(y0, x0)
    t = np.arange(frames) * dt
    p = rng.uniform(0, 2 * np.pi, 4)
    # Damped settling of the drape depth (inertia: overshoot, then rest).
    # Step response of a damped oscillator, starting at rest.
    om, tau = 2 * np.pi * 0.9, 0.45
    sag = 0.1 * (1 - np.exp(-t / tau) * (np.cos(om * t) + np.sin(om * t) / (om * tau)))
    # Profile 0 at the held centre -> 1 at the rim; its knee widens as the
    # sheet settles, so the displacement is not a function of the current shape.
    knee = 0.15 + 0.12 * (1 - np.exp(-t / 0.5))
    shape = r[None] ** 2 / (r[None] ** 2 + knee[:, None] ** 2)  # (T, N)
    z = 0.5 - sag[:, None] * shape
    # The skirt rocks from side to side about the centre.
    rock = 0.06 * sag / 0.1 * np.sin(2 * np.pi * 0.7 * t + p[3])
    z += rock[:, None] * shape * (np.cos(p[3]) * x0 + np.sin(p[3]) * y0)[None]
    grow = (1 - np.exp(-t / 0.6))[:, None]
    z += 0.008 * grow * np.sin(2 * np.pi * (r[None] / 0.18 - 0.7 * t[:, None]) + p[0]) * shape
    z += 0.01 * grow * np.cos(6 * th + p[1] + 0.4 * np.sin(2 * np.pi * 0.3 * t)[:, None]) \
        * shape ** 2
    # In-plane: radial pull-in proportional to the sag, plus a gentle swirl.
    pull = 1 - 0.25 * sag[:, None] * shape
    swirl = 0.03 * np.sin(2 * np.pi * 0.4 * t + p[2])[:, None] * shape ** 2
    xs = pull * (np.cos(swirl) * x0 - np.sin(swirl) * y0)
    ys = pull * (np.sin(swirl) * x0 + np.cos(swirl) * y0)
    X = np.stack([xs, ys, z], -1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c_, d = (idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(),
                   idx[:-1, 1:].ravel())
    faces = np.concatenate([np.stack([a, b, c_], 1), np.stack([a, c_, d], 1)]).astype(np.int64)
    h = size / (n - 1)
    return X, {"faces": faces}, {
        "dt": dt, "thickness": 0.2 * h,
        "description": f"cloth-ref: {n}x{n} sheet draping around a held centre, "
                       f"kinematic height field + ripples + in-plane pull, {1/dt:.0f} Hz"}
