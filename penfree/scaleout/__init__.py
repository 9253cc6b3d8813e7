"""Scale-out on Dask: many recordings, or one long recording, without a job script.

`penfree deform`, `verify` and `report` accept several inputs (files, directories,
globs); with several inputs, ``--workers N`` or ``--scheduler ADDRESS`` the work runs on
`dask.distributed` (an optional extra: ``pip install 'penfree[dask]'``).

Partitioning. ``deform``, ``verify`` and ``report`` split each file into ranges of steps;
a step `s` reads frames ``s - 1``, ``s`` and ``s + 1`` only, so ranges of steps need
overlapping frames and nothing else: a ``deform`` range reads just the frames
``lo - 1 .. hi`` of its file (HDF5 ``frame_window``) and runs the library on them, its
frame numbers shifted back to the file's; a ``verify`` range of a result reads the frames
of its steps (``read_result(window=)``), a ``report`` range those and their neighbours
(``report.build.read_range``). A file whose frames exceed `plan.MAX_TASK_BYTES` always
goes in ranges of bounded size, on a serial run too (`cluster.InProcess`).

Outputs. ``deform`` of one input file writes the ``-o`` file, as a serial run; several
inputs (several files, a directory of recordings, a pattern) write ``<dir>/<stem>.h5``.
Every input's layout, topology and attributes are validated on the driver first (of an
HDF5 file only its first two frames are read; the tasks validate the frames they read),
so a bad input fails before a cluster starts and nothing is written. A ``deform`` run then
works in a folder of its own, a new ``.pfXXXXXXXX.tmp`` in the output directory: a file
that is one task is deformed and written there by that task on its worker; each range of
a split file writes a partial result into ``<stem>.parts/`` there, and one more task,
which Dask runs once all ranges of the file are done, merges them in frame order into
the layout of a serial run. When every task succeeded the results are moved to their
names together (`penfree.formats.atomic`); on any failure or interrupt none appears,
and the run removes its folder and the directories it created, nothing else. Only file
names and the small per-step tables travel back to the driver; results are compressed
and written by the workers in parallel. ``report`` of a split file reads only its
per-step tables on the driver, decides there what needs every step (a stored ``stats/``
group, verify's path-check error, the client's replayed steps), and joins the ranges'
per-step figures in step order into the entry of a whole read (`penfree.report.entry`).

Results are those of a serial run, bit for bit: every step is computed by the same
code from the same frames, and the per-step tables are merged in frame order (the
selection table's candidate columns in order of first appearance, as a serial run
orders them). One progress callback counts finished tasks; a failed task names its
file and frame range in one line (the workers' own error logs are silenced).
"""

from .cluster import DASK_MISSING, client, gather, n_workers_of, require_dask, run_tasks
from .deform import deform_file_task, deform_many, deform_task, merge_task
from .plan import (DIRECTORY_PATTERNS, FILE_EXTENSIONS, MIN_STEPS_PER_TASK, TASKS_PER_WORKER, Task,
                   deform_outputs, expand_inputs, is_long, is_scaleout, one_input, output_paths, plan)
from .verify_report import report_many, report_task, verify_many, verify_task

__all__ = ["DASK_MISSING", "DIRECTORY_PATTERNS", "FILE_EXTENSIONS", "MIN_STEPS_PER_TASK", "TASKS_PER_WORKER", "Task",
           "client", "deform_file_task", "deform_many", "deform_outputs", "deform_task", "expand_inputs", "gather",
           "is_long", "is_scaleout", "merge_task", "n_workers_of", "one_input", "output_paths", "plan", "report_many",
           "report_task", "require_dask", "run_tasks", "verify_many", "verify_task"]
