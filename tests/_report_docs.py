"""Editing report.json documents (baselines) in tests."""

from __future__ import annotations


def set_in_entry(doc, dotted, value, entry=0):
    """Set ``doc["files"][entry]`` at the dotted key to `value`; `KeyError` as the value deletes the key."""
    d = doc["files"][entry]
    parts = dotted.split(".")
    for p in parts[:-1]:
        d = d[p]
    if value is KeyError:
        del d[parts[-1]]
    else:
        d[parts[-1]] = value
