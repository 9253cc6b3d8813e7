"""Benchmark: the first run of `penfree deform`, `verify` and `report` after an install
(an empty Numba cache: every kernel compiled) against the second (kernels loaded).

    .venv/bin/python benchmarks/cold_start.py [samples/cloth.h5] [--top 8]

Each command runs in its own subprocess, as a user runs it, with ``NUMBA_CACHE_DIR`` set
to a new temporary directory shared by the first and the second round; the outputs go
to another temporary directory and are removed. With ``--top N`` the first round also
lists the N kernels that took longest to compile (Numba's compile events, a kernel's
time including the functions compiled for it).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))

#: Run inside each subprocess: the CLI, with Numba's compile events timed per kernel.
_PROBE = r"""
import sys, time, collections
import numba.core.event as ev
top = int(sys.argv[1]); times = collections.Counter(); stack = []
class Timer(ev.Listener):
    def on_start(self, e):
        f = e.data["dispatcher"].py_func
        stack.append((f.__module__ + "." + f.__qualname__, time.perf_counter()))
    def on_end(self, e):
        name, t0 = stack.pop()
        if not stack:  # outermost only: a kernel's time includes what it compiled
            times[name] += time.perf_counter() - t0
ev.register("numba:compile", Timer())
from penfree.cli import main
sys.argv = ["penfree"] + sys.argv[2:]
try:
    main()
except SystemExit as e:
    code = e.code
else:
    code = 0
for name, t in times.most_common(top):
    print(f"compile {t:.2f} {name}", file=sys.stderr)
sys.exit(code)
"""


def run(args, cache, top):
    """Wall time of one CLI command in a fresh interpreter, and its top compile times."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", _PROBE, str(top), *args], env=env, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"penfree {' '.join(args)} failed ({r.returncode}):\n{r.stderr}")
    kernels = [line.split(" ", 2)[1:] for line in r.stderr.splitlines() if line.startswith("compile ")]
    return dt, [(float(t), name) for t, name in kernels]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sample", nargs="?", default=os.path.join(HERE, "..", "samples", "cloth.h5"))
    ap.add_argument("--top", type=int, default=0, help="list the N slowest kernels to compile (first round)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out:
        deformed = os.path.join(out, "deformed.h5")
        commands = [("deform", ["deform", args.sample, "-o", deformed, "--overwrite"]),
                    ("verify", ["verify", deformed]),
                    ("report", ["report", deformed, "-o", os.path.join(out, "report"), "--overwrite"])]
        print(f"{os.path.basename(args.sample)}, fresh Numba cache, {os.cpu_count()} CPUs")
        print(f"{'command':<8} {'first run':>10} {'second run':>11}")
        first = {}
        for name, cmd in commands:
            first[name] = run(cmd, cache, args.top)
        for name, cmd in commands:
            second, _ = run(cmd, cache, 0)
            print(f"{name:<8} {first[name][0]:9.1f}s {second:10.1f}s")
        for name, _ in commands:
            for t, kernel in first[name][1]:
                print(f"  {name}: {t:7.2f} s  {kernel}")


if __name__ == "__main__":
    main()
