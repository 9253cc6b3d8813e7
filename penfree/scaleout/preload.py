"""Imported once by the process a local cluster's workers are forked from
(`cluster.start_worker_server`), and only there: it exists for what importing it does.

A worker forked from that process starts with all of this done, instead of doing it
itself before its first task, on every run and in each worker (0.5-0.8 s):

- Dask's worker and penfree's task modules (``deform``, ``verify``, ``report``) and what
  they import, at once or inside a task (Numba, h5py, SciPy);
- Numba's CPU target: its registry of typing and lowering rules, which Numba otherwise
  fills at the first kernel a process loads (0.25 s, ``scipy.linalg`` included);
- the objects all this made are moved out of the collector's sight (`gc.freeze`), as
  Python's documentation advises before forking: a worker's collections then skip them,
  and do not copy the pages they lie on.

It starts no thread, and loads no kernel: loading a parallel kernel starts Numba's
threading layer, and GNU OpenMP's is not safe to fork once started (a forked worker's
first parallel region would end it). Each worker loads its own kernels at its first task.
"""

import gc

import distributed  # noqa: F401  (the worker's own machinery)

# The task modules and the ones they import only inside a task (`auto`, a range's partial
# result, a scene's solids, the real-client replay; ipctk itself is left to the task: 0.2 s
# to import, for `report --client` only). A test runs the tasks after this module and
# checks that they import no penfree module left out here.
from ..core.contact import solids  # noqa: F401
from ..core.fit import auto  # noqa: F401
from ..core.pipeline import deform, verification  # noqa: F401
from ..core.trust import bounds  # noqa: F401
from ..core.verify import pairs  # noqa: F401
from ..formats import partials, result  # noqa: F401
from ..report import build, client as report_client  # noqa: F401
from . import deform as scaleout_deform, verify_report  # noqa: F401


def prepare_numba() -> bool:
    """Fill Numba's CPU target registry now; False (left to the worker) if that fails."""
    try:
        from numba.core.registry import cpu_target

        cpu_target.target_context.refresh()
    except Exception:  # an import or API change: the worker fills it itself, as without this
        return False
    return True


prepare_numba()
gc.freeze()
