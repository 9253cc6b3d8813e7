"""The numeric pipeline, one subpackage per stage (see ARCHITECTURE.md).

Base modules (`topology`, `polynomial`, `describe`, `parallel`, `memory`, `jit_cache`)
serve every stage. The stages: `fit` and `contact` import only the base; `verify` also
imports `fit` and `contact`; `trust` also imports `contact`. `pipeline` wires them, and
no stage imports it (tests/test_architecture.py checks all of this).
"""

from pathlib import Path

from penfree.core import jit_cache

# Before any kernel is decorated: a cached kernel is stale when any penfree module
# it can reach changes, not only its own file.
jit_cache.install(Path(__file__).resolve().parents[1])
