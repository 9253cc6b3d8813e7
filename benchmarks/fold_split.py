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

Last, the one list design that a shell of pairs just beyond the reach does not defeat:
per-vertex windows, the pairs within each of their vertices' own separation plus ``2 S``
(every vertex's nearest pair at the next state is among them when no pair's distance
moved by more than ``S``). What moves a pair's distance is the relative motion of its
vertices, and it prints the largest over vertex pairs within ``r + 2 l`` (r the reach,
l the longest edge: every vertex pair of two primitives within r) against a bound that
can be computed without a neighbour query: the diameter of the displacements' boxes of
two neighbouring cells of side ``r + 2 l`` (1, 2 and 3 steps from the first state).

    .venv/bin/python benchmarks/fold_split.py /tmp/big/cloth.h5 /tmp/big/yarn.h5 [--states 4] [--rounds 4]

(``samples/generate.py cloth-ref|yarn-bundle --frames 100 -o ...`` makes the 64K files.)
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.spatial import cKDTree

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
    windows(E, F, X, rho)


def _window_counts(x, E, F, d, skins):
    """Pairs (ee + vf) within the larger of their vertices' separations `d` plus ``2 S``,
    for each S of `skins`: one list at the largest window, counted per skin."""
    nl = NeighbourList(E, F, skin=0.0)
    nl.ensure(x, float(d.max()) + 2.0 * max(skins), need_list=True)
    d_ee, d_vf = (np.sqrt(a) for a in nl.pair_sq(x))
    P, V = nl.P_ee, nl.P_vf
    w_ee = np.max(d[E[P].reshape(-1, 4)], axis=1) if P.size else np.zeros(0)
    w_vf = np.maximum(d[V[:, 0]], np.max(d[F[V[:, 1]]], axis=1)) if V.size else np.zeros(0)
    return [int(np.sum(d_ee <= w_ee + 2.0 * S)) + int(np.sum(d_vf <= w_vf + 2.0 * S)) for S in skins]


def _cell_bound(x0, x1, L):
    """Largest diameter of the union of two neighbouring cells' displacement boxes (cells
    of side L at x0): a bound on |D_i - D_j| for every vertex pair within L at x0."""
    D = x1 - x0
    key = np.floor((x0 - x0.min(axis=0)) / L).astype(np.int64)
    dims = key.max(axis=0) + 1
    lin = (key[:, 0] * dims[1] + key[:, 1]) * dims[2] + key[:, 2]
    cells, inv = np.unique(lin, return_inverse=True)
    lo = np.full((cells.size, 3), np.inf)
    hi = np.full((cells.size, 3), -np.inf)
    np.minimum.at(lo, inv, D)
    np.maximum.at(hi, inv, D)
    ck = np.stack([cells // (dims[1] * dims[2]), (cells // dims[2]) % dims[1], cells % dims[2]], axis=1)
    best = 0.0
    for off in np.ndindex(3, 3, 3):
        nb = ck + np.asarray(off) - 1
        ok = np.all((nb >= 0) & (nb < dims), axis=1)
        nlin = (nb[:, 0] * dims[1] + nb[:, 1]) * dims[2] + nb[:, 2]
        j = np.minimum(np.searchsorted(cells, nlin), cells.size - 1)
        i = np.flatnonzero(ok & (cells[j] == nlin))
        span = np.maximum(hi[i], hi[j[i]]) - np.minimum(lo[i], lo[j[i]])
        best = max(best, float(np.sqrt((span ** 2).sum(axis=1)).max(initial=0.0)))
    return best


def windows(E, F, X, rho):
    """Per-vertex window lists and the relative motion that decides their life."""
    x = X[0]
    d = per_vertex_separation(x, E, F, rho)
    skins = (0.0, 0.05 * rho, 0.1 * rho, 0.2 * rho)
    counts = [f"S {S / rho:g} reach: {n:,}" for S, n in zip(skins, _window_counts(x, E, F, d, skins))]
    print("  per-vertex windows, pairs listed: " + ", ".join(counts))
    ell = float(np.linalg.norm(x[E[:, 0]] - x[E[:, 1]], axis=1).max())
    L = rho + 2.0 * ell
    pairs = cKDTree(x).query_pairs(L, output_type="ndarray")
    rows = []
    for k in (1, 2, 3):
        if k >= len(X):
            break
        D = X[k] - x
        true = float(np.linalg.norm(D[pairs[:, 0]] - D[pairs[:, 1]], axis=1).max(initial=0.0))
        rows.append(f"{k} step(s) {true / rho:.3f} / {_cell_bound(x, X[k], L) / rho:.3f}")
    print(f"  relative motion within r + 2 l = {L:.3g}, in reaches, largest / cell bound: " + ", ".join(rows))


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
