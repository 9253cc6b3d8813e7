"""Small geometry helpers and scenes shared by the tests (importable: tests/ is on sys.path
through tests/conftest.py)."""

import numpy as np


def rot(axis, deg):
    """Rotation matrix about `axis` by `deg` degrees (Rodrigues)."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    th = np.deg2rad(deg)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def prev_for(x, A, b):
    """x_prev such that x_pred = 2 x - x_prev = A x + b."""
    return 2 * x - (x @ A.T + b)


def grid(n, z=0.0, shift=(0.0, 0.0)):
    """(n*n, 3) vertices and (2 (n-1)^2, 3) faces of a unit-spaced flat sheet."""
    ij = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1).reshape(-1, 2).astype(float)
    V = np.c_[ij + shift, np.full(len(ij), z)]
    F = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            F += [[a, a + n, a + 1], [a + 1, a + n, a + n + 1]]
    return V, np.array(F)


def two_sheets(n=4, gap=1.0):
    V0, F0 = grid(n, 0.0, (0.3, 0.3))
    V1, F1 = grid(n, gap)
    return np.r_[V0, V1], np.r_[F0, F1 + len(V0)]


def rods(k=3, n=4, spacing=1.0):
    """k parallel polylines of n vertices along x, stacked in z."""
    V = np.array([[i, 0.0, spacing * r] for r in range(k) for i in range(n)])
    E = np.array([[r * n + i, r * n + i + 1] for r in range(k) for i in range(n - 1)])
    return V, E
