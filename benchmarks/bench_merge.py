"""Memory of merging a split file (scale-out `deform`): the streamed `merge_task` against
a whole-read merge (the former one: every partial and the whole input in memory), on
the same partial results, in one process.

The frame ranges of FILE are deformed in-process (`--model affine`, thickness 0), their
partial results copied twice, and each merge writes a result; peaks are Python-heap
peaks (`tracemalloc`, numpy's buffers included); the two results are compared.

    .venv/bin/python benchmarks/bench_merge.py FILE.h5 [--parts 8] [--per-vertex]

``--per-vertex`` deforms with the per-vertex residuals (two ``(S, N)`` float32 datasets),
which the streamed merge writes one range at a time (`partials.PartialRows`) and the
whole-read merge concatenates.

e.g. FILE from ``samples/generate.py cloth-ref -o /tmp/big/cloth.h5 --vertices 65536 --frames 100``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
import tracemalloc

import h5py
import numpy as np

from penfree import scaleout
from penfree.formats import read_sequence
from penfree.formats.partials import merge_partials
from penfree.scaleout import plan
from penfree.scaleout.deform import _write_output


def whole_read_merge(path, out, parts, options):
    """The merge as it was: every partial's states and the whole input in memory."""
    steps, groups = merge_partials(sorted(parts))
    seq = read_sequence(path)
    _write_output(path, out, seq, steps, groups, options)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("file")
    ap.add_argument("--parts", type=int, default=8, help="frame ranges (plan's target: 2 per worker)")
    ap.add_argument("--per-vertex", action="store_true", help="with the per-vertex residuals")
    args = ap.parse_args()
    opts = {"model": "affine", "projection": "auto", "margin": None, "thickness": 0.0, "per_vertex": args.per_vertex,
            "frames": None}
    with h5py.File(args.file, "r") as f:
        shape, dtype = f["positions"].shape, f["positions"].dtype
    print(f"{args.file}: positions {shape} {dtype} ({np.prod(shape) * dtype.itemsize / 2**20:.0f} MiB)")
    with tempfile.TemporaryDirectory() as work:
        tasks = plan([args.file], max(1, args.parts // 2))
        t0 = time.perf_counter()
        parts = [scaleout.deform_task(t, work, opts, False, 1) for t in tasks]
        print(f"{len(tasks)} frame ranges deformed in {time.perf_counter() - t0:.1f} s")
        outs = {}
        for name, merge in (("whole-read", whole_read_merge), ("streamed", scaleout.merge_task)):
            d = os.path.join(work, name)
            os.makedirs(d)
            copies = [shutil.copy(p, d) for p in parts]
            outs[name] = os.path.join(work, name + ".h5")
            tracemalloc.start()
            t0 = time.perf_counter()
            merge(args.file, outs[name], copies, opts)
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
            print(f"{name:>10} merge: peak {peak / 2**20:7.1f} MiB, {time.perf_counter() - t0:5.1f} s")
        with h5py.File(outs["whole-read"], "r") as a, h5py.File(outs["streamed"], "r") as b:
            keys = ["positions", "steps/deformed", "steps/A"] + [k for k in ("steps/residual_pred_per_vertex",
                                                                             "steps/residual_next_per_vertex") if k in a]
            same = set(a["steps"]) == set(b["steps"]) and all(
                np.array_equal(a[k][()], b[k][()], equal_nan=True) for k in keys)
        print("results equal" if same else "RESULTS DIFFER")


if __name__ == "__main__":
    main()
