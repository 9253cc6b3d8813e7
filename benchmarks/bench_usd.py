"""Benchmark: USD reading and writing against HDF5, and the cost of the conservative colliders.

For each committed HDF5 sample: write it as ``.usdc`` (binary crate) and ``.usda``
(text) and as HDF5 again, read each back (``read_sequence``, validated), check that
positions and topology come back bit for bit, and report median wall times and file
sizes. Then the inflation of the conservative tessellations of ``_usd_shapes``:
the largest vertex distance over the true radius (sphere; capsule, from its
segment), i.e. how much farther out the collider mesh reaches than the shape.

    .venv/bin/python benchmarks/bench_usd.py [--repeats 3] [--samples cloth rods]

Needs the ``usd`` extra (usd-core).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np

from penfree.formats import _usd_shapes as shapes
from penfree.formats import read_sequence, write_sequence

HERE = os.path.dirname(os.path.abspath(__file__))


def _median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def bench_io(names, repeats):
    print("| sample | frames x vertices | format | write s | read s | size KB | exact |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            seq = read_sequence(os.path.join(HERE, "..", "samples", f"{name}.h5"))
            for ext in (".h5", ".usdc", ".usda"):
                path = os.path.join(tmp, name + ext)
                tw = _median_time(lambda: write_sequence(path, seq, overwrite=True), repeats)
                tr = _median_time(lambda: read_sequence(path), repeats)
                back = read_sequence(path)
                topo = "faces" if seq.faces is not None else "edges"
                exact = np.array_equal(back.positions, seq.positions) and np.array_equal(
                    np.sort(getattr(back, topo), axis=1), np.sort(getattr(seq, topo), axis=1))
                print(f"| {name} | {seq.n_frames} x {seq.n_vertices} | {ext} | {tw:.3f} | {tr:.3f} | "
                      f"{os.path.getsize(path) / 1024:.0f} | {'yes' if exact else 'NO'} |")


def bench_shapes():
    V, F = shapes.sphere(1.0)
    r_max = np.linalg.norm(V, axis=1).max()
    print(f"\nsphere: {len(V)} vertices, {len(F)} faces; min face-plane distance "
          f"{shapes.face_plane_distances(V, F).min():.9f} r; vertices reach {r_max:.5f} r "
          f"(+{100 * (r_max - 1):.2f}%)")
    V, F = shapes.capsule(1.0, 2.0, "Z")
    d = np.linalg.norm(V - np.clip(V[:, 2], -1, 1)[:, None] * [0, 0, 1], axis=1).max()
    print(f"capsule (r=1, height 2): {len(V)} vertices, {len(F)} faces; vertices reach {d:.5f} r from the "
          f"segment (+{100 * (d - 1):.2f}%)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--samples", nargs="+", default=["cloth", "rods"])
    args = ap.parse_args(argv)
    bench_io(args.samples, args.repeats)
    bench_shapes()


if __name__ == "__main__":
    main()
