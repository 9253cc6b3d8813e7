"""Stage 2, contact primitives: broad phase, distances, CCD (float and exact), intersection.

Knows nothing about maps or sequences; imports only `penfree.core` base modules.
"""
