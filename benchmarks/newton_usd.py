"""Optional (not in CI): record one of Newton's own cloth examples to USD on the CPU, run penfree on it.

Newton's example runner has a USD viewer (``--viewer usd``) that writes the run as
a USD stage: the cloth as a Mesh with time-sampled points, the ground as a rigid
instance, debugging glyphs as PointInstancer prototypes. This script records
``cloth_hanging`` (VBD solver) on the CPU, then runs ``penfree info``, ``deform``
(with the ground named as an obstacle), ``verify`` and ``report`` on the stage,
exactly as a user would, and prints their output.

Needs ``newton`` and ``warp-lang`` (PyPI) besides penfree's ``usd`` extra, e.g. in
a separate environment (warp compiles its CPU kernels on first use: minutes):

    python -m venv /tmp/newton && /tmp/newton/bin/pip install newton warp-lang usd-core
    .venv/bin/python benchmarks/newton_usd.py --newton-python /tmp/newton/bin/python [--frames 40]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile

GROUND = "/root/model/shapes/shape_0/instance_0"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--newton-python", default=sys.executable,
                    help="A Python with newton and warp-lang installed (default: this one).")
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--width", type=int, default=32)
    ap.add_argument("--height", type=int, default=8)
    ap.add_argument("--out", default=None, help="Directory for the stage and results (default: a temporary one).")
    args = ap.parse_args(argv)
    out = args.out or tempfile.mkdtemp(prefix="penfree-newton-")
    stage = os.path.join(out, "cloth_hanging.usd")
    record = [args.newton_python, "-m", "newton.examples", "cloth_hanging", "--viewer", "usd",
              "--output-path", stage, "--num-frames", str(args.frames), "--device", "cpu",
              "--width", str(args.width), "--height", str(args.height), "--solver", "vbd", "--quiet"]
    print("$", " ".join(record), flush=True)
    subprocess.run(record, check=True)
    penfree = [sys.executable, "-m", "penfree"]
    result = os.path.join(out, "deformed.h5")
    for cmd in (["info", stage],
                ["deform", stage, "-o", result, "--stats", "--obstacle", GROUND, "--overwrite"],
                ["verify", result],
                ["report", result, "-o", os.path.join(out, "report"), "--overwrite", "--no-plots"],
                ["convert", result, os.path.join(out, "deformed.usd"), "--deformed", "--overwrite"]):
        print("$ penfree", " ".join(cmd), flush=True)
        subprocess.run(penfree + cmd, check=True)


if __name__ == "__main__":
    main()
