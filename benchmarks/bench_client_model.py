"""Benchmark: the cost of `auto` under a client model: shared queries against per-replay
ones, and the planar passes' stencils from lists against fresh queries.

`deform --model auto --client-model T` and `penfree.predeform` replay every shortlisted
candidate through penfree's own OGC client, and every replayed pass is a neighbourhood
query. Three ways of running those queries, in one process, alternating rounds:

- ``shared`` (penfree's default): one `ClientQuery` per scene for every replay (one
  `SeparationQuery`, whose cell shapes and reach carry over, a memo of the replays'
  start states, and the planar passes' stencils from one `StencilList` per replay),
  and `one_thread` through Numba's ctypes thread-count calls;
- ``fresh stencils``: the same without the stencil lists (a `candidate_stencils` query
  at every planar pass, as before the thirty-seventh session);
- ``per replay`` (before the shared query): a fresh query per replay (its cells chosen
  again, no reach, no memo, no lists) and `one_thread` through `numba.get_num_threads`
  / `set_num_threads`.

All must write the same bits: the script compares every output array and says so.

    .venv/bin/python benchmarks/bench_client_model.py [--rounds 3] [--steps 8] [--vertices 65536]

Rows: `deform_sequence` on ``--steps`` steps of bundled samples (from frame 1, and the
falling stack also from frame 18, where its layers rest on each other and on the
ground; seconds per step), then one `predeform` call on a 4K and a ``--vertices`` cloth
sheet.
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
from penfree.core.trust import client
from penfree.core.trust.client_stats import resolve_dhat

HERE = os.path.dirname(os.path.abspath(__file__))
SAMPLES = os.path.join(HERE, "..", "samples")
#: (sample, truncation, first frame): a rod coil, a cloth in contact, a planar stack in
#: free fall and at rest on the ground.
ROWS = (("swinging_coil.h5", "isotropic", 0), ("twisting_cloth_contact.h5", "isotropic", 0),
        ("falling_stack.h5", "planar", 0), ("falling_stack.h5", "planar", 17))
VARIANTS = ("shared", "fresh stencils", "per replay")


@contextlib.contextmanager
def variant(name):
    """``shared`` as it is; ``fresh stencils`` without `StencilList`s; ``per replay``: a
    fresh query per replay (no lists either), public thread-count calls."""
    query, calls = client_select.ClientModel.query, (parallel._get_threads, parallel._set_threads)
    after = client.STENCIL_LIST_AFTER
    if name != "shared":
        client.STENCIL_LIST_AFTER = 1 << 62
    if name == "per replay":
        client_select.ClientModel.query = lambda self, x: None
        parallel._get_threads, parallel._set_threads = numba.get_num_threads, numba.set_num_threads
    try:
        yield
    finally:
        client_select.ClientModel.query = query
        parallel._get_threads, parallel._set_threads = calls
        client.STENCIL_LIST_AFTER = after


def alternate(run, rounds, variants=VARIANTS):
    """Medians of `run()` under each variant over rounds in rotating order, and the last
    outputs of each: ``{name: (median seconds, output)}``."""
    times, outs = {v: [] for v in variants}, {}
    run()  # JIT and caches
    for k in range(rounds):
        for j in range(len(variants)):
            name = variants[(j + k) % len(variants)]
            with variant(name):
                t0 = time.perf_counter()
                outs[name] = run()
                times[name].append(time.perf_counter() - t0)
    return {v: (float(np.median(times[v])), outs[v]) for v in variants}


def deform_row(name, truncation, first, steps, rounds):
    seq = penfree.read_sequence(os.path.join(SAMPLES, name))
    dhat = resolve_dhat(None, seq.contact_radius, seq.thickness)
    info = {}

    def run():
        model = ClientModel(truncation=truncation, dhat=dhat, edges=seq.edges, faces=seq.faces,
                            obstacles=tuple(seq.obstacles))
        out = deform_sequence(seq, model="auto", frames=(first, first + steps + 1), client_model=model).steps
        if model._query is not None and client.STENCIL_LIST_AFTER < 1 << 62:
            info.update(model._query.info)
        return out

    res = alternate(run, rounds)
    ref = res["shared"][1]
    same = all(np.array_equal(np.asarray(ref[k]), np.asarray(out[k]))
               for _, out in res.values() for k in ("deformed", "A", "b", "model", "certificate_margin"))
    n = len(ref["frame"])
    t = {v: res[v][0] / n for v in VARIANTS}
    print(f"{name + ' from ' + str(first):<32} {truncation:<9} {seq.n_vertices:>6} {n:>5} {t['per replay']:>10.3f} "
          f"{t['fresh stencils']:>8.3f} {t['shared']:>8.3f} {t['per replay'] / t['shared']:>7.2f}x "
          f"{t['fresh stencils'] / t['shared']:>7.2f}x  {'yes' if same else 'NO':<4} queries {info.get('queries')}, "
          f"memo hits {info.get('memo_hits')}, stencil lists {info.get('lists')} answering {info.get('listed')}")


def predeform_row(n, rounds):
    sys.path.insert(0, HERE)
    from bench_verify import cloth

    x0, x1, _, F = cloth(n, "gentle")
    x_prev = x0 - (x1 - x0)  # the sheet keeps its motion
    res = alternate(lambda: penfree.predeform(x_prev, x0, faces=F, contact_radius=1e-3), rounds,
                    ("shared", "per replay"))
    (t_new, new), (t_old, old) = res["shared"], res["per replay"]
    same = np.array_equal(new.x_def, old.x_def) and new.model == old.model
    print(f"{'predeform, cloth sheet':<32} {'isotropic':<9} {x0.shape[0]:>6} {1:>5} {t_old:>10.3f} {'':>8} "
          f"{t_new:>8.3f} {t_old / t_new:>7.2f}x {'':>8}  {'yes' if same else 'NO':<4} applied {new.model}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=8, help="steps of each row (from its first frame + 1)")
    ap.add_argument("--vertices", type=int, default=65536, help="the larger predeform sheet")
    args = ap.parse_args(argv)
    retain_freed_memory()
    print(f"penfree {penfree.__version__}, numba {numba.__version__}, threads {numba.get_num_threads()}; "
          f"median of {args.rounds} alternating rounds; seconds per step (predeform: per call)")
    print(f"{'run':<32} {'trunc.':<9} {'N':>6} {'steps':>5} {'per replay':>10} {'fresh st.':>8} {'shared':>8} "
          f"{'ratio':>8} {'lists':>8}  same")
    for name, truncation, first in ROWS:
        deform_row(name, truncation, first, args.steps, args.rounds)
    for n in (4096, args.vertices):
        predeform_row(n, args.rounds)


if __name__ == "__main__":
    main()
