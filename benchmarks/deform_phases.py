"""Where a `penfree deform` run's time goes: the CLI's calls in one process, each timed.

    .venv/bin/python benchmarks/deform_phases.py frames.h5 [--model auto] [--repeats 2]

Reads the file, runs `deform_sequence` and `write_result` as `penfree deform` does
(freed blocks kept in the heap, as the CLI keeps them) and prints the time of each part:
the steps, recording them, the first JIT-cached call, allocation and strategy set-up,
and writing. "total" is deform + write, the CLI's "total ... steps/s incl. I/O"; reading
and imports are printed apart. The result is written to a temporary directory and removed.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

from penfree.core.memory import retain_freed_memory

PHASES = ("make_strategy", "_allocate", "_warm_up", "run_step", "_record")


def _timed(module, name, totals):
    fn = getattr(module, name)

    def wrapper(*args, **kwargs):
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            totals[name] = totals.get(name, 0.0) + time.perf_counter() - t

    setattr(module, name, wrapper)
    return fn


def run(path, model, out_dir):
    import penfree.core.pipeline.deform as deform
    from penfree.formats import read_sequence
    from penfree.formats.result import write_result

    t0 = time.perf_counter()
    seq = read_sequence(path)
    t_read = time.perf_counter() - t0
    totals = {}
    originals = {name: _timed(deform, name, totals) for name in PHASES}
    try:
        t1 = time.perf_counter()
        res = deform.deform_sequence(seq, model=model)
        t2 = time.perf_counter()
        out = os.path.join(out_dir, "result.h5")
        write_result(out, seq, res.steps, {}, groups=res.groups, overwrite=True)
        t3 = time.perf_counter()
    finally:
        for name, fn in originals.items():
            setattr(deform, name, fn)
    steps = res.n_steps if hasattr(res, "n_steps") else len(res.steps["frame"])
    total = t3 - t1
    parts = "  ".join(f"{k} {v:.3f}" for k, v in totals.items())
    print(f"{os.path.basename(path)}: read {t_read:.2f} s | {parts} | deform {t2 - t1:.2f} | write "
          f"{t3 - t2:.2f} | total {total:.2f} s ({steps / total:.1f} steps/s), {steps} steps")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("inputs", nargs="+", help="penfree HDF5 recordings")
    ap.add_argument("--model", default="auto")
    ap.add_argument("--repeats", type=int, default=2, help="runs per input, in one process")
    args = ap.parse_args(argv)
    t = time.perf_counter()
    retain_freed_memory()
    import penfree.core.pipeline.deform  # noqa: F401  (imports timed apart)

    print(f"imports {time.perf_counter() - t:.2f} s")
    with tempfile.TemporaryDirectory() as tmp:
        for path in args.inputs:
            for _ in range(args.repeats):
                run(path, args.model, tmp)


if __name__ == "__main__":
    main()
