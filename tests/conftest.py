"""Suite-wide set-up.

This file puts ``tests/`` on ``sys.path`` (pytest's default ``prepend`` import mode
inserts a rootless conftest's folder), so test modules in any folder import the shared
helpers by name: ``from _geom import rot``, ``from oracles import exact_dist_sq``.
"""
