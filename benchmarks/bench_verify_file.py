"""Benchmark: whole-file `verify` of a deform result with reused neighbour lists against
fresh proximity passes per step (issue 13), in one process.

Generates the 64K reference scene (``samples/generate.py``), deforms it in memory
(``--model affine``, margin thickness / d0), writes the result to a temporary file and
runs `verify_file` twice: as shipped (one `NeighbourList` for the start states of all
steps: the margin's smallest start gap and the certificate path's proximity pass) and
with the lists switched off (every step queries from scratch). Reports must be equal.

    .venv/bin/python benchmarks/bench_verify_file.py [--frames 30] [--scene cloth-ref]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

from penfree.core.pipeline import verification as vf
from penfree.core.pipeline.deform import deform_sequence
from penfree.formats import read_sequence
from penfree.formats.result import write_result

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "samples"))
import generate  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--vertices", type=int, default=65536)
    ap.add_argument("--scenes", nargs="*", default=["yarn-bundle", "cloth-ref"])
    args = ap.parse_args(argv)
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; {args.frames} frames")
    for scene in args.scenes:
        with tempfile.TemporaryDirectory() as tmp:
            src, out = os.path.join(tmp, "in.h5"), os.path.join(tmp, "out.h5")
            pos, topo, attrs = generate.generate(scene, vertices=args.vertices, frames=args.frames)
            generate.write_h5(src, pos, topo, attrs)
            seq = read_sequence(src)
            res = deform_sequence(seq, model="affine")
            write_result(out, seq, res.steps, {"options": res.options})
            vf.verify_file(out, frames=(1, 3))  # JIT outside the timings
            t0 = time.perf_counter()
            with_lists = vf.verify_file(out)
            t1 = time.perf_counter()
            keep, vf._result_lists = vf._result_lists, lambda seq, mode: None
            try:
                fresh = vf.verify_file(out)
            finally:
                vf._result_lists = keep
            t2 = time.perf_counter()
            same = with_lists.to_dict() == fresh.to_dict()
            print(f"{scene:<12} lists {t1 - t0:7.1f} s, fresh {t2 - t1:7.1f} s, ratio {(t2 - t1) / (t1 - t0):.2f}x; "
                  f"ok {with_lists.ok}, reports equal {same}; methods "
                  f"{sorted({s.result.method for s in with_lists.steps})}")


if __name__ == "__main__":
    main()
