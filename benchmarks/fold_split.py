"""Where a separation query's time goes: the grid fold against a fold over the same pairs
listed, and why a list does not outlive a step (issue 13).

For consecutive frames of a recording, at the reach that `SeparationQuery` picks (the
query `deform --model auto` runs every step), in alternating rounds in one process:

- ``grid``: `per_vertex_separation` at the reach (the grids' builds, the row scans and
  the distances, as every step pays);
- ``build``: a `NeighbourList` with skin 0 built at the same state and radius (the same
  grids and scans, the pairs stored instead of folded);
- ``listed``: the fold over those listed pairs only (box bound and distances, no scan).

``listed`` equals ``grid`` bit for bit (checked). It then prints the pairs a list
holds at larger skins and the motion per step, raw and after the step's affine fit
(`neighbours.affine_residual`): a list built at one state answers the next only when
its skin is at least twice that motion.

    .venv/bin/python benchmarks/fold_split.py /tmp/big/cloth.h5 /tmp/big/yarn.h5 [--states 4] [--rounds 4]

(``samples/generate.py cloth-ref|yarn-bundle --frames 100 -o ...`` makes the 64K files.)
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from penfree.core.contact.neighbours import NeighbourList, affine_residual, max_displacement
from penfree.core.contact.proximity import SeparationQuery, per_vertex_separation
from penfree.core.trust.bounds import scene_arrays
from penfree.formats import read_sequence

SKINS_REL = (0.0, 0.25, 0.5)


def _ms(fn):
    t = time.perf_counter()
    out = fn()
    return out, 1e3 * (time.perf_counter() - t)


def run(path, n_states, rounds):
    seq = read_sequence(path)
    _, E, F = scene_arrays(seq.positions[0], seq.edges, seq.faces)
    # two warm-up states, then n_states from the middle of the recording
    s0 = max(0, min(seq.n_frames // 2 - n_states - 2, seq.n_frames - n_states - 2))
    X = [np.ascontiguousarray(seq.positions[s], np.float64) for s in range(s0, min(seq.n_frames, s0 + n_states + 2))]
    if len(X) < 4:
        raise SystemExit(f"{path}: needs at least 4 frames; has {seq.n_frames}")
    q = SeparationQuery(E, F)
    q(X[0], 1.0)
    q(X[1], 1.0)  # the reach of a run in progress
    rho, cells = q.reach, q.info["cells"]
    X = X[2:]
    times = {"grid": [], "build": [], "listed": []}
    for _ in range(rounds):
        for x in X:
            d, t = _ms(lambda: per_vertex_separation(x, E, F, rho, cells=cells))
            times["grid"].append(t)
            nl = NeighbourList(E, F, skin=0.0)
            _, t = _ms(lambda: nl.ensure(x, rho, need_list=True))
            times["build"].append(t)
            d_l, t = _ms(lambda: nl.listed_separations(x, rho))
            times["listed"].append(t)
            if not np.array_equal(d, d_l):
                raise SystemExit(f"{path}: listed separations differ from the grid's")
    med = {k: float(np.median(v)) for k, v in times.items()}
    print(f"{path}: {seq.n_vertices} vertices, reach {rho:.3g}, cells {cells}, "
          f"{n_states} states x {rounds} rounds (medians)")
    print(f"  grid fold {med['grid']:.1f} ms | list build {med['build']:.1f} ms | listed fold "
          f"{med['listed']:.1f} ms | grid / listed {med['grid'] / med['listed']:.2f}x")
    counts = []
    for rel in SKINS_REL:
        nl = NeighbourList(E, F, skin=rel * rho)
        nl.ensure(X[0], rho, need_list=True)
        counts.append(f"skin {rel:g} reach: {nl.info['n_pairs']:,}")
    print("  pairs listed: " + ", ".join(counts))
    disp = [max_displacement(X[k], X[k + 1]) for k in range(len(X) - 1)]
    res = [fit[1] for fit in (affine_residual(X[k], X[k + 1]) for k in range(len(X) - 1)) if fit is not None]
    # the radius at frame s that holds every pair within the reach at s + 1 (the list's own rule)
    need = [nl.reach(X[k + 1], rho, X[k]) / rho for k in range(len(X) - 1)]
    print(f"  motion per step: largest displacement {min(disp):.3g}-{max(disp):.3g}, "
          f"after the affine fit {min(res, default=np.nan):.3g}-{max(res, default=np.nan):.3g}: a list "
          f"lasting one step needs a build radius of {max(need):.2f}x the reach "
          f"(raw motion: {(rho + 2.0 * max(disp)) / rho:.2f}x)")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--states", type=int, default=4)
    ap.add_argument("--rounds", type=int, default=4)
    args = ap.parse_args()
    for path in args.files:
        run(path, args.states, args.rounds)


if __name__ == "__main__":
    main()
