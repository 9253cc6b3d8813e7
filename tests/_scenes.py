"""Small contact scenes of issue 10 (floors, boxes, resting contact, fold-through)."""

import numpy as np

from penfree.sequence import Obstacle, Sequence


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
