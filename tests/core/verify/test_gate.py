"""`gate.deviation_bound` against exact rational arithmetic."""

from fractions import Fraction

import numpy as np

from penfree.core.verify.gate import deviation_bound


def _exact_max_dev_sq(x, x_def, A, b):
    best = Fraction(0)
    for v in range(len(x)):
        q = Fraction(0)
        for i in range(3):
            y = sum(Fraction(float(A[i, j])) * Fraction(float(x[v, j])) for j in range(3)) + Fraction(float(b[i]))
            q += (Fraction(float(x_def[v, i])) - y) ** 2
        best = max(best, q)
    return best


def test_deviation_bound_is_rigorous_and_tight(rng):
    for scale, noise in ((1.0, 0.0), (1e3, 1e-12), (1e-2, 1e-6)):
        x = rng.normal(size=(60, 3)) * scale
        A = rng.normal(size=(3, 3))
        b = rng.normal(size=3) * scale
        x_def = x @ A.T + b + rng.normal(size=x.shape) * noise * scale
        d = deviation_bound(x, x_def, A, b)
        exact = _exact_max_dev_sq(x, x_def, A, b)
        assert Fraction(d) ** 2 >= exact
        assert d <= float(exact) ** 0.5 + 1e-13 * scale * 10
    assert deviation_bound(np.zeros((0, 3)), np.zeros((0, 3)), np.eye(3), np.zeros(3)) == 0.0
