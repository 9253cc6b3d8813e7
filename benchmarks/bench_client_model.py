"""Benchmark: the cost of `auto` under a client model, shared queries against per-replay ones.

`deform --model auto --client-model T` and `penfree.predeform` replay every shortlisted
candidate through penfree's own OGC client, and every replayed pass is a neighbourhood
query. Two ways of running those queries, in one process, alternating rounds:

- ``shared`` (penfree's default): one `ClientQuery` per scene for every replay (one
  `SeparationQuery`, whose cell shapes and reach carry over, and a memo of the replays'
  start states), and `one_thread` through Numba's ctypes thread-count calls;
- ``per replay`` (before): a fresh query per replay (its cells chosen again, no reach,
  no memo) and `one_thread` through `numba.get_num_threads` / `set_num_threads`.

Both must write the same bits: the script compares every output array and says so.

    .venv/bin/python benchmarks/bench_client_model.py [--rounds 3] [--steps 8] [--vertices 65536]

Rows: `deform_sequence` on the first ``--steps`` steps of bundled samples (seconds per
step), then one `predeform` call on a 4K and a ``--vertices`` cloth sheet.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time

import numba
import numpy as np

import penfree
from penfree.core import parallel
from penfree.core.memory import retain_freed_memory
from penfree.core.pipeline import client_select
from penfree.core.pipeline.client_select import ClientModel
from penfree.core.pipeline.deform import deform_sequence
from penfree.core.trust.client_stats import resolve_dhat

HERE = os.path.dirname(os.path.abspath(__file__))
SAMPLES = os.path.join(HERE, "..", "samples")
#: (sample, truncation): a rod coil, a cloth in contact, a planar stack.
ROWS = (("swinging_coil.h5", "isotropic"), ("twisting_cloth_contact.h5", "isotropic"),
        ("falling_stack.h5", "planar"))


@contextlib.contextmanager
def per_replay():
    """The state before: a fresh query per replay, public thread-count calls."""
    query, calls = client_select.ClientModel.query, (parallel._get_threads, parallel._set_threads)
    client_select.ClientModel.query = lambda self, x: None
    parallel._get_threads, parallel._set_threads = numba.get_num_threads, numba.set_num_threads
    try:
        yield
    finally:
        client_select.ClientModel.query = query
        parallel._get_threads, parallel._set_threads = calls


def alternate(run, rounds):
    """Medians of `run(shared)` for shared True / False over alternating rounds, and the
    last outputs of each."""
    times, outs = {True: [], False: []}, {}
    run(True)  # JIT and caches
    for k in range(rounds):
        for shared in ((True, False) if k % 2 == 0 else (False, True)):
            with (contextlib.nullcontext() if shared else per_replay()):
                t0 = time.perf_counter()
                outs[shared] = run(shared)
                times[shared].append(time.perf_counter() - t0)
    return float(np.median(times[True])), float(np.median(times[False])), outs


def deform_row(name, truncation, steps, rounds):
    seq = penfree.read_sequence(os.path.join(SAMPLES, name))
    dhat = resolve_dhat(None, seq.contact_radius, seq.thickness)
    info = {}

    def run(shared):
        model = ClientModel(truncation=truncation, dhat=dhat, edges=seq.edges, faces=seq.faces,
                            obstacles=tuple(seq.obstacles))
        out = deform_sequence(seq, model="auto", frames=(0, steps + 1), client_model=model).steps
        if model._query is not None:
            info.update(model._query.info)
        return out

    t_new, t_old, outs = alternate(run, rounds)
    same = all(np.array_equal(np.asarray(outs[True][k]), np.asarray(outs[False][k]))
               for k in ("deformed", "A", "b", "model", "certificate_margin"))
    n = len(outs[True]["frame"])
    print(f"{name:<28} {truncation:<9} {seq.n_vertices:>7} {n:>5} {t_old / n:>11.3f} {t_new / n:>9.3f} "
          f"{t_old / t_new:>7.2f}x  {'yes' if same else 'NO':<4} queries {info.get('queries')}, "
          f"memo hits {info.get('memo_hits')}")


def predeform_row(n, rounds):
    sys.path.insert(0, HERE)
    from bench_verify import cloth

    x0, x1, _, F = cloth(n, "gentle")
    x_prev = x0 - (x1 - x0)  # the sheet keeps its motion
    t_new, t_old, outs = alternate(lambda shared: penfree.predeform(x_prev, x0, faces=F, contact_radius=1e-3),
                                   rounds)
    same = np.array_equal(outs[True].x_def, outs[False].x_def) and outs[True].model == outs[False].model
    print(f"{'predeform, cloth sheet':<28} {'isotropic':<9} {x0.shape[0]:>7} {1:>5} {t_old:>11.3f} {t_new:>9.3f} "
          f"{t_old / t_new:>7.2f}x  {'yes' if same else 'NO':<4} applied {outs[True].model}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=8, help="steps of each sample (from frame 1)")
    ap.add_argument("--vertices", type=int, default=65536, help="the larger predeform sheet")
    args = ap.parse_args(argv)
    retain_freed_memory()
    print(f"penfree {penfree.__version__}, numba {numba.__version__}, threads {numba.get_num_threads()}; "
          f"median of {args.rounds} alternating rounds; seconds per step (predeform: per call)")
    print(f"{'run':<28} {'trunc.':<9} {'N':>7} {'steps':>5} {'per replay':>11} {'shared':>9} {'ratio':>8}  same")
    for name, truncation in ROWS:
        deform_row(name, truncation, args.steps, args.rounds)
    for n in (4096, args.vertices):
        predeform_row(n, args.rounds)


if __name__ == "__main__":
    main()
