"""Benchmark: `penfree deform` on Dask, 2 local workers against 1 (issue 13), same process.

Writes ``--files`` recordings of the 64K reference scene (``samples/generate.py``,
``--frames`` frames each, float32) into a temporary directory, then runs the several-inputs
path (`penfree.scaleout.deform_many`) with ``--workers 1`` and ``--workers 2`` (cluster
start-up included: it is what a user waits for) and checks that both outputs are equal,
dataset by dataset (wall times excepted). It also prints the driver's own CPU time: the
serial part (planning, collecting, anything the driver computes or writes itself), which
bounds the speedup whatever the load of the machine.

Dask is imported before anything is timed (the first run would pay it alone), and with
``--repeats`` the two worker counts take turns, 1-2 then 2-1, and so on: the ratio is of the
medians. On Linux the workers are forked from a prepared server
(`penfree.scaleout.cluster.start_worker_server`) that the first run starts and the later
runs of this process reuse, as in any process that runs several of them (a notebook): its
start-up (about 1 s) is in the first run only. ``--cli`` times the command instead, one
process per run (``penfree deform DIR -o OUT --workers N --threads 1``, wall time): each run
starts its own server, while the command reads and checks its inputs.

    .venv/bin/python benchmarks/bench_scaleout.py [--files 4] [--frames 50] [--repeats 2] [--scene yarn-bundle] [--cli]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

import h5py
import numpy as np

from penfree.scaleout import deform_many

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "samples"))
import generate  # noqa: E402


#: The command of this environment (``--cli``).
PENFREE = os.path.join(os.path.dirname(sys.executable), "penfree")


def datasets(path):
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda n, o: out.__setitem__(n, o[()]) if isinstance(o, h5py.Dataset) else None)
    return out


def same(a, b):
    return np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--files", type=int, default=4)
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--vertices", type=int, default=65536)
    ap.add_argument("--scene", default="yarn-bundle")
    ap.add_argument("--model", default="auto")
    ap.add_argument("--repeats", type=int, default=2, help="runs of each worker count, in turns")
    ap.add_argument("--cli", action="store_true", help="time `penfree deform`, one process per run")
    args = ap.parse_args(argv)
    import distributed  # noqa: F401  (imported once, outside every timed run)

    with tempfile.TemporaryDirectory() as tmp:
        src = os.path.join(tmp, "in")
        os.makedirs(src)
        for k in range(args.files):
            pos, topo, attrs = generate.generate(args.scene, vertices=args.vertices, frames=args.frames, seed=k)
            generate.write_h5(os.path.join(src, f"rec{k}.h5"), pos, topo, attrs)
        options = dict(model=args.model, projection="auto", margin=None, thickness=None, per_vertex=False,
                       frames=None, format=None)
        times, cpu = {1: [], 2: []}, {1: [], 2: []}
        for r in range(args.repeats):
            for w in ((1, 2) if r % 2 == 0 else (2, 1)):
                out = os.path.join(tmp, f"out{w}")
                t0, c0 = time.perf_counter(), time.process_time()
                if args.cli:
                    subprocess.run([PENFREE, "deform", src, "-o", out, "--overwrite", "--model", args.model,
                                    "--workers", str(w), "--threads", "1"], check=True, capture_output=True)
                else:
                    deform_many([src], out, options=options, overwrite=True, workers=w, threads=1)
                times[w].append(time.perf_counter() - t0)
                cpu[w].append(time.process_time() - c0)
        equal = all(
            all(same(a[k], b[k]) for k in a if k != "steps/time_fit_s")
            for a, b in ((datasets(os.path.join(tmp, "out1", f"rec{k}.h5")),
                          datasets(os.path.join(tmp, "out2", f"rec{k}.h5"))) for k in range(args.files)))
    steps = args.files * (args.frames - 1)
    print(f"{args.files} x {args.scene} ({args.vertices} vertices x {args.frames} frames), --model {args.model}, "
          f"{'penfree deform (one process per run)' if args.cli else 'deform_many (in this process)'}, "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    for w, ts in times.items():
        t = statistics.median(ts)
        print(f"  --workers {w}: median {t:5.1f} s ({steps / t:5.1f} steps/s) of {', '.join(f'{x:.1f}' for x in ts)}"
              + ("" if args.cli else f"; driver CPU {statistics.median(cpu[w]):.2f} s"))
    ratio = statistics.median(times[1]) / statistics.median(times[2])
    print(f"  speedup 2 vs 1 workers: {ratio:.2f}x (medians); outputs equal: {equal}")


if __name__ == "__main__":
    main()
