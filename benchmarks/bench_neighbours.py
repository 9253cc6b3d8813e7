"""Benchmark: per-vertex separations over consecutive frames, fresh queries against
reused neighbour lists (issue 13) and IPC Toolkit, in one process.

For every step s of the 64K reference scenes (``samples/generate.py yarn-bundle`` and
``cloth-ref``), the OGC query of SPEC section 7 at x = frame s with
``r_q = thickness + max |x_pred - x|``, plus (``--deformed``) a second query at a
deformed state of the step (x moved by the step's affine fit toward x_pred, as
report visits x_def):

- ``fresh``: `per_vertex_separation` from scratch every query;
- ``reach``: a `SeparationQuery` for the whole run: each query at the reach of the
  last one's largest separation, the vertices left at it completed (same values);
- ``lists``: one `NeighbourList` for the whole run (automatic skin);
- ``lists skin=k r``: fixed skins, to show the trade-off;
- ``ipctk``: ``Candidates.build(mesh, x, r_q / 2)`` + ``compute_per_vertex_safe_distances``
  (the like-for-like configuration of bench_bounds.py), every query.

Totals over all queries (amortised: builds included) and ratios; the listed results are
checked equal to the fresh ones bit for bit.

    .venv/bin/python benchmarks/bench_neighbours.py [--frames 40] [--deformed] [--no-ipctk]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numba
import numpy as np

from penfree.core.fit.models import fit_moments
from penfree.core.contact.neighbours import NeighbourList
from penfree.core.contact.proximity import SeparationQuery
from penfree.core.trust.stats import query_radius
from penfree.core.trust.bounds import per_vertex_separation, scene_arrays

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "samples"))
import generate  # noqa: E402


def queries(pos, thickness, deformed):
    """[(x, r_q)] for every step (and its deformed state)."""
    out = []
    for s in range(1, pos.shape[0]):
        x = np.ascontiguousarray(pos[s], dtype=np.float64)
        x_prev = np.asarray(pos[s - 1], dtype=np.float64)
        r = query_radius(x, 2 * x - x_prev, thickness)
        out.append((x, r))
        if deformed:
            m = fit_moments(x_prev, x)
            D = np.linalg.lstsq(m.C, m.G.T, rcond=None)[0].T
            out.append((np.ascontiguousarray(x + (x - m.c) @ D.T + m.u), r))
    return out


def run(fn, qs):
    t0 = time.perf_counter()
    res = [fn(x, r) for x, r in qs]
    return time.perf_counter() - t0, res


def ipctk_separations(x0, E, F):
    """IPC Toolkit's per-vertex safe distances of the scene (rest state `x0`) as
    ``peer(x, r)``: ``Candidates.build(mesh, x, r / 2)`` + ``compute_per_vertex_safe_distances``."""
    import ipctk

    Vf = np.asfortranarray(x0)
    if F.shape[0]:
        mesh = ipctk.CollisionMesh(Vf, ipctk.edges(np.asfortranarray(F.astype(np.int32))),
                                   np.asfortranarray(F.astype(np.int32)))
    else:
        mesh = ipctk.CollisionMesh(Vf, np.asfortranarray(E.astype(np.int32)),
                                   np.zeros((0, 3), dtype=np.int32, order="F"))

    def peer(x, r):
        xf = np.asfortranarray(x)
        C = ipctk.Candidates()
        C.build(mesh, xf, 0.5 * r)
        return np.asarray(C.compute_per_vertex_safe_distances(mesh, xf, r, 0.0)).ravel()

    return peer


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--vertices", type=int, default=65536)
    ap.add_argument("--deformed", action="store_true", help="also query a deformed state per step")
    ap.add_argument("--no-ipctk", action="store_true")
    ap.add_argument("--skins", type=float, nargs="*", default=[0.25, 1.0], help="fixed skins, x r_q")
    args = ap.parse_args(argv)
    print(f"numba threads {numba.get_num_threads()}, load average {os.getloadavg()[0]:.1f}, "
          f"{args.frames} frames, deformed states: {args.deformed}")
    hdr = f"{'scene':<12} {'method':<18} {'total s':>8} {'ms/query':>9} {'vs fresh':>9} {'vs ipctk':>9}  notes"
    print(hdr)
    print("-" * len(hdr))
    for scene in ("yarn-bundle", "cloth-ref"):
        pos, topo, attrs = generate.generate(scene, vertices=args.vertices, frames=args.frames)
        h = float(attrs["thickness"])
        _, E, F = scene_arrays(pos[0], topo.get("edges"), topo.get("faces"))
        qs = queries(pos, h, args.deformed)
        per_vertex_separation(qs[0][0][:64], E[:0], F[:0], 0.0)  # JIT outside the timings
        t_fresh, ref = run(lambda x, r: per_vertex_separation(x, E, F, r), qs)
        rows = [("fresh", t_fresh, "")]
        sq = SeparationQuery(E, F)
        t, res = run(sq, qs)
        same = all(np.array_equal(a, b) for a, b in zip(res, ref))
        rows.append(("reach", t, f"below the radius {sq.info['reached']} of {sq.info['queries']}, "
                                 f"completed {sq.info['completed']} vertices, equal {same}"))
        methods = [("lists (auto)", None)] + [(f"lists skin={k:g} r", k) for k in args.skins]
        r_max = max(r for _, r in qs)
        for name, k in methods:
            nl = NeighbourList(E, F, skin=None if k is None else k * r_max)
            t, res = run(nl.separations, qs)
            same = all(np.array_equal(a, b) for a, b in zip(res, ref))
            info = nl.info
            rows.append((name, t, f"builds {info['builds']}, reused {info['reused']}, fresh {info['fresh']}, "
                                  f"skin {info['skin']:.3g}, pairs {info['n_pairs']}, equal {same}"))
        t_ip = None
        if not args.no_ipctk:
            peer = ipctk_separations(qs[0][0], E, F)
            peer(*qs[0])
            t_ip, res_ip = run(peer, qs)
            dev = max(float(np.max(np.abs(np.minimum(a, r) - b))) for (x, r), a, b in zip(qs, res_ip, ref))
            rows.append(("ipctk (r/2)", t_ip, f"max |d_ipctk - d| {dev:.1e}"))
        for name, t, note in rows:
            vs_ip = f"{t_ip / t:8.2f}x" if t_ip else f"{'':>9}"
            print(f"{scene:<12} {name:<18} {t:8.2f} {t / len(qs) * 1e3:9.1f} {t_fresh / t:8.2f}x {vs_ip}  {note}")
    print("vs fresh / vs ipctk: time of that method / this one (> 1: this one faster); totals include builds")


if __name__ == "__main__":
    main()
