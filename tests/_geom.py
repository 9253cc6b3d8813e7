"""Small geometry helpers shared by the fit, step, projection and certificate tests."""

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
