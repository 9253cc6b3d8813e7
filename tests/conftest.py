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


@pytest.fixture(scope="session")
def scheduler():
    """One local Dask cluster (2 processes) for the session, used through ``--scheduler``;
    skipped without the ``dask`` extra."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                                  silence_logs=50) as cluster:
        yield cluster.scheduler_address
