"""Small contact scenes of issue 10 (floors, boxes, resting contact, fold-through)."""

import numpy as np

from penfree.sequence import Obstacle, Sequence

from _geom import rot


def grid_faces(n, m=None):
    m = n if m is None else m
    F = []
    for i in range(n - 1):
        for j in range(m - 1):
            p, q, r, s = i * m + j, (i + 1) * m + j, i * m + j + 1, (i + 1) * m + j + 1
            F += [[p, q, r], [q, s, r]]
    return np.array(F, dtype=np.int64)


def sheet(n, size=1.0):
    g = np.linspace(0.0, size, n)
    X, Y = np.meshgrid(g, g, indexing="ij")
    return X.ravel(), Y.ravel()


def floor_mesh(z=0.0, half=5.0):
    P = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]])
    return Obstacle("floor", positions=P, faces=np.array([[0, 1, 2], [0, 2, 3]]))


def floor_half_space(z=0.0):
    return Obstacle("ground", normal=np.array([0.0, 0.0, 1.0]), offset=z)


def landing_sheet(n=10, T=8, rest=1e-3, speed=0.03, tilt=0.3, h0=0.12):
    """A tilted sheet falling onto z = 0: its low side lands (rests `rest` above), the rest falls.

    ``z(u, t) = max(rest, h0 + tilt u - speed t)``: the first steps are all in the air,
    the later ones half landed, half falling.
    """
    u, v = sheet(n)
    frames = []
    for t in range(T):
        z = np.maximum(rest, h0 + tilt * u - speed * t)
        frames.append(np.stack([u, v, z], axis=1))
    return np.array(frames), grid_faces(n)


def rods_on_ground(kind, T=7, K=6, m=12, seed=0):
    """``(P (T, K m, 3), E)``: K rods of m vertices (0.4 long) in contact-rich motion over z = 0.

    - "stack": rods along x resting 1.2e-3 above the ground; rods along y come down across
      them and rest 1.1e-3 or more above them (their bend wobbles);
    - "spin": rods falling 0.05 a step while turning 1.3 rad a step, landing at t = 4 at
      1.1e-3 + 7e-4 k; in the air they sweep through each other's paths at one height.
    """
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 0.4, m)
    ang, x0, y0 = rng.uniform(0, np.pi, K), rng.uniform(-0.3, 0.3, K), rng.uniform(-0.3, 0.3, K)
    P = np.zeros((T, K * m, 3))
    for t in range(T):
        for k in range(K):
            if kind == "stack":
                lower = k % 2 == 0
                d = np.array([1.0, 0, 0]) if lower else np.array([0, 1.0, 0])
                base = np.array([-0.2, -0.2 + 0.11 * (k // 2), 0]) if lower else np.array([-0.2 + 0.11 * (k // 2), -0.2, 0])
                z = 1.2e-3 + 0 * s if lower else max(0.03 - 0.012 * t, 2.6e-3 + 1e-4 * t) + 3e-4 * np.sin(9 * s + t)
            elif kind == "spin":
                a = ang[k] + 1.3 * t
                d = np.array([np.cos(a), np.sin(a), 0.0])
                base = np.array([x0[k], y0[k], 0.0]) - 0.2 * d
                z = max(0.2 - 0.05 * t, 1.1e-3 + 7e-4 * k) + 0.05 * np.sin(a) * s * (t < 4)
            else:
                raise ValueError(kind)
            pts = base + s[:, None] * d
            pts[:, 2] = z
            P[t, k * m:(k + 1) * m] = pts
    E = np.array([[k * m + i, k * m + i + 1] for k in range(K) for i in range(m - 1)])
    return P, E


def chain_links(T=10, K=7, m=16, R=0.05, gap=4e-3, slide=2.5, seed=0):
    """``(P (T, K m, 3), E)``: a hanging chain of K interlocked links, closed loops of m
    segments (radius R), in alternating planes, `gap` apart where they cross.

    The chain swings about y (0.25 rad); each link twists about the chain's axis (0.15
    rad) and slides along it by up to ``slide gap / 2``: neighbouring links close in on
    each other, to 5e-5 apart at the default `slide`, so the constant-velocity prediction
    drives links through each other on most steps.
    """
    rng = np.random.default_rng(seed)
    th = np.linspace(0.0, 2.0 * np.pi, m, endpoint=False)
    ph = rng.uniform(0.0, 2.0 * np.pi, K)
    d = 2.0 * R - gap  # centre spacing: the links cross `gap` apart
    P = np.zeros((T, K * m, 3))
    for t in range(T):
        swing = rot([0, 1, 0], np.degrees(0.25 * np.sin(0.5 * t)))
        for k in range(K):
            ring = np.stack([R * np.cos(th), np.zeros(m), R * np.sin(th)], 1)  # in the xz plane
            if k % 2:
                ring = ring @ rot([0, 0, 1], 90.0).T  # in the yz plane
            ring = ring @ rot([0, 0, 1], np.degrees(0.15 * np.sin(0.7 * t + ph[k]))).T
            c = np.array([0.0, 0.0, -k * d - slide * gap * 0.5 * np.sin(0.9 * t + ph[k])])
            P[t, k * m:(k + 1) * m] = (ring + c) @ swing.T
    E = np.array([[k * m + i, k * m + (i + 1) % m] for k in range(K) for i in range(m)])
    return P, E


def box_mesh(lo, hi):
    """A closed box (12 triangles) between corners lo and hi."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    P = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    F = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
         [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    return Obstacle("box", positions=P, faces=np.array(F))


def scene(positions, faces=None, edges=None, obstacles=(), thickness=0.0, contact_radius=0.0):
    return Sequence(positions=np.asarray(positions), faces=faces, edges=edges, obstacles=list(obstacles),
                    thickness=thickness, contact_radius=contact_radius).validate()
