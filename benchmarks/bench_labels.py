"""Benchmark: per-vertex separations of a scene whose vertex labels carry no locality,
against the same scene in its own labels and against IPC Toolkit, in one process.

A remesher, a tet mesher's surface or a hash map may number a mesh's vertices in any
order. For each 64K reference scene (``samples/generate.py yarn-bundle`` and
``cloth-ref``) and a copy with its vertex labels, edges and faces shuffled (seeded),
the OGC query of SPEC section 7 at frame s with ``r_q = thickness + max |x_pred - x|``
over consecutive frames:

- ``penfree``: a `SeparationQuery` (the scene relabelled along a Morton curve when its
  labels carry no locality, `penfree.core.contact.locality`);
- ``penfree, own order``: the same with relabelling turned off (the shuffled scene as
  given);
- ``ipctk``: ``Candidates.build(mesh, x, r_q / 2)`` + ``compute_per_vertex_safe_distances``.

Medians per query and the shuffled / own ratio. The shuffled scene's separations with
and without relabelling are checked equal bit for bit; against the own scene's (taken
to the shuffled labels) they differ by at most a few ulps where a triangle scene's edges,
built from its faces with the smaller label first, point the other way (the edge-edge
kernels see their endpoints in the other order; a segment scene's edges keep theirs).
With ``--write DIR``
the shuffled recordings are also written as ``DIR/<scene>-shuffled.h5`` (and the own ones
as ``DIR/<scene>.h5``) for the CLI rows (`penfree deform`, `verify`, `report`).

    .venv/bin/python benchmarks/bench_labels.py [--frames 12] [--no-ipctk] [--write DIR]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numba
import numpy as np

from penfree.core.contact import locality
from penfree.core.contact.proximity import SeparationQuery
from penfree.core.trust.bounds import scene_arrays
from penfree.core.trust.stats import query_radius

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "samples"))
import generate  # noqa: E402
from bench_neighbours import ipctk_separations  # noqa: E402


def shuffled(pos, topo, seed=0):
    """The recording with its vertex labels and its edge / face rows shuffled:
    ``(pos, topo, perm)``, new vertex k being old vertex ``perm[k]``."""
    rng = np.random.default_rng(seed)
    n = pos.shape[1]
    perm = rng.permutation(n)
    inv = np.empty(n, dtype=np.int64)
    inv[perm] = np.arange(n)
    out = {k: (None if v is None else np.ascontiguousarray(inv[v][rng.permutation(len(v))]))
           for k, v in topo.items()}
    return np.ascontiguousarray(pos[:, perm]), out, perm


def median_ms(fn, states):
    ts, res = [], []
    for x, r in states:
        t0 = time.perf_counter()
        res.append(fn(x, r))
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts[1:])), res


def write(path, pos, topo, attrs, note):
    """The recording as `samples/generate.py` writes it (float32)."""
    generate.write_h5(path, pos, {k: v for k, v in topo.items() if v is not None}, attrs, "float32",
                      source=f"{attrs['description']}; {note}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--vertices", type=int, default=65536)
    ap.add_argument("--no-ipctk", action="store_true")
    ap.add_argument("--write", metavar="DIR", help="also write the own and shuffled recordings here")
    args = ap.parse_args(argv)
    print(f"numba threads {numba.get_num_threads()}, load average {os.getloadavg()[0]:.1f}, {args.frames} frames")
    hdr = f"{'scene':<12} {'method':<20} {'own ms':>8} {'shuffled ms':>12} {'shuffled/own':>13}  notes"
    print(hdr)
    print("-" * len(hdr))
    for scene in ("yarn-bundle", "cloth-ref"):
        pos, topo, attrs = generate.generate(scene, vertices=args.vertices, frames=args.frames)
        pos = np.asarray(pos, dtype=np.float64)
        pos_s, topo_s, perm = shuffled(pos, {k: topo.get(k) for k in ("edges", "faces")})
        if args.write:
            os.makedirs(args.write, exist_ok=True)
            write(os.path.join(args.write, f"{scene}.h5"), pos, topo, attrs, "benchmarks/bench_labels.py")
            write(os.path.join(args.write, f"{scene}-shuffled.h5"), pos_s, topo_s, attrs,
                  "its vertex labels, edges and faces shuffled by benchmarks/bench_labels.py")
        h = float(attrs["thickness"])
        runs = {}
        for name, p, t in (("own", pos, topo), ("shuffled", pos_s, topo_s)):
            _, E, F = scene_arrays(p[0], t.get("edges"), t.get("faces"))
            states = [(p[s], query_radius(p[s], 2.0 * p[s] - p[s - 1], h)) for s in range(1, p.shape[0])]
            runs[name] = (E, F, states)
        rows = []
        results = {}
        for method, relabel in (("penfree", True), ("penfree, own order", False)):
            times = {}
            for name, (E, F, states) in runs.items():
                saved = locality.GAP_MIN
                if not relabel:
                    locality.GAP_MIN = np.inf  # never relabel: the scene as given
                try:
                    q = SeparationQuery(E, F)
                    times[name], results[method, name] = median_ms(q, states)
                    times[name, "relabelled"] = q.info["relabelled"]
                finally:
                    locality.GAP_MIN = saved
            dev = max(float(np.max(np.abs(a[perm] - b) / np.maximum(a[perm], 1e-300)))
                      for a, b in zip(results[method, "own"], results[method, "shuffled"]))
            rows.append((method, times["own"], times["shuffled"],
                         f"relabelled: own {times['own', 'relabelled']}, shuffled {times['shuffled', 'relabelled']}; "
                         f"shuffled vs own: max rel. difference {dev:.1e}"))
        same = all(np.array_equal(a, b) for a, b in zip(results["penfree", "shuffled"],
                                                        results["penfree, own order", "shuffled"]))
        rows[0] = rows[0][:3] + (rows[0][3] + f"; = own order bit for bit: {same}",)
        if not args.no_ipctk:
            times = {}
            for name, (E, F, states) in runs.items():
                times[name], _ = median_ms(ipctk_separations(states[0][0], E, F), states)
            rows.append(("ipctk (r/2)", times["own"], times["shuffled"], ""))
        for method, t_own, t_shuf, note in rows:
            print(f"{scene:<12} {method:<20} {t_own:8.1f} {t_shuf:12.1f} {t_shuf / t_own:12.2f}x  {note}")
    print("ms: median per query (the first, with its set-up, left out); shuffled/own > 1: slower on shuffled labels")


if __name__ == "__main__":
    main()
