"""Numeric pipeline stages: fit, projection and certificate, broad phase, distances,
CCD, verification, trust region, statistics. `step` and `pipeline` wire them."""
