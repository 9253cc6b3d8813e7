"""Fixtures shared by the whole suite.

This file also puts ``tests/`` on ``sys.path`` (pytest's default ``prepend`` import
mode inserts a rootless conftest's folder), so test modules import the shared
helpers by name: ``from _geom import rot``, ``from oracles import exact_dist_sq``.
"""

import numpy as np
import pytest


@pytest.fixture
def rng(request):
    """A seeded generator; a test module picks its seed with a module-level ``RNG_SEED``."""
    return np.random.default_rng(getattr(request.module, "RNG_SEED", 20261121))
