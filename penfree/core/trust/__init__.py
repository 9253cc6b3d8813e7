"""Stage 4, trust regions and statistics: per-vertex bounds, hit rates, CD-pass replay.

Imports the contact stage (broad phase) and the base modules.
"""
