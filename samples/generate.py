"""Generate the sample sequences and the 64K reference scenes.

Importable (``sys.path.insert(0, "samples"); import generate``) and a script::

    python samples/generate.py SCENE -o OUT.h5 [--vertices N] [--frames T]
        [--seed S] [--dtype float32|float64]
    python samples/generate.py SCENE -o OUT_DIR --mesh obj|ply ...

Scenes: rods, cloth, twisting-cloth, twisting-cloth-contact, cables, twisted-cables,
cloth-drape-box, falling-stack, carried-stack, swinging-coil (fast coherent motion with
self-contact) (simulated, ``scenes.py``),
yarn-bundle, cloth-ref (kinematic 64K reference scenes, ``reference.py``).
Every scene function returns ``(positions, topology, attrs)``; `write_h5`
writes the SPEC section 2 layout and `write_mesh_sequence` numbered OBJ
polyline / PLY triangle files. Generation is seeded and deterministic.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import reference  # noqa: E402
import scenes  # noqa: E402

#: HDF5 layout version (SPEC section 2; penfree.constants.FORMAT_VERSION).
FORMAT_VERSION = 1

SCENES = {
    "rods": scenes.rods,
    "cloth": scenes.cloth,
    "twisting-cloth": scenes.twisting_cloth,
    "cables": scenes.cables,
    "twisting-cloth-contact": scenes.twisting_cloth_contact,
    "twisted-cables": scenes.twisted_cables,
    "cloth-drape-box": scenes.cloth_drape_box,
    "falling-stack": scenes.falling_stack,
    "carried-stack": scenes.carried_stack,
    "swinging-coil": scenes.swinging_coil,
    "yarn-bundle": reference.yarn_bundle,
    "cloth-ref": reference.cloth_ref,
}


def generate(scene, vertices=None, frames=None, seed=0):
    """Run scene `scene` (a key of `SCENES`); None keeps the scene's default size.

    Returns
    -------
    positions : (T, N, 3) float64
    topology : dict
        ``edges`` (E, 2) and/or ``faces`` (F, 3) int64, optional ``components`` (N,).
    attrs : dict
        ``dt``, ``thickness``, ``description``.
    """
    kw = {"seed": seed}
    if vertices is not None:
        kw["vertices"] = vertices
    if frames is not None:
        kw["frames"] = frames
    return SCENES[scene](**kw)


def write_h5(path, positions, topology, attrs, dtype="float32", source=None):
    """Write a sequence in the penfree HDF5 layout (format version 1).

    Parameters
    ----------
    path : str
    positions : (T, N, 3) float
        Stored as `dtype`, one frame per chunk, gzip + shuffle.
    topology : dict
        ``edges`` / ``faces`` / ``components``, stored as int32; ``obstacles``
        ``{name: {"vertices", "faces"} or {"normal", "offset"}}`` (SPEC section 2).
    attrs : dict
        ``dt`` and ``thickness`` (and ``contact_radius`` when the scene has one);
        ``description`` becomes ``source`` unless `source` is given.
    """
    import h5py

    positions = np.asarray(positions, dtype=dtype)
    T, N, _ = positions.shape
    # track_times=False keeps the bytes reproducible from run to run.
    with h5py.File(path, "w", track_order=True) as f:
        f.create_dataset("positions", data=positions, chunks=(1, N, 3), compression="gzip",
                         compression_opts=6, shuffle=True, track_times=False)
        for key in ("edges", "faces", "components"):
            if topology.get(key) is not None:
                f.create_dataset(key, data=np.asarray(topology[key], dtype=np.int32),
                                 compression="gzip", shuffle=True, track_times=False)
        f.attrs["penfree_format"] = FORMAT_VERSION
        f.attrs["dt"] = float(attrs["dt"])
        f.attrs["thickness"] = float(attrs["thickness"])
        if "contact_radius" in attrs:
            f.attrs["contact_radius"] = float(attrs["contact_radius"])
        f.attrs["source"] = source or attrs["description"]
        for name, ob in (topology.get("obstacles") or {}).items():
            g = f.create_group(f"obstacles/{name}", track_order=True)
            if "normal" in ob:
                g.create_dataset("normal", data=np.asarray(ob["normal"], dtype=np.float64), track_times=False)
                g.attrs["offset"] = float(ob["offset"])
            else:
                g.create_dataset("vertices", data=np.asarray(ob["vertices"], dtype=np.float64), track_times=False)
                g.create_dataset("faces", data=np.asarray(ob["faces"], dtype=np.int32), track_times=False)


def write_mesh_sequence(directory, positions, topology, kind, digits=4):
    """Write numbered ``frame_0000.obj`` polylines or ``frame_0000.ply`` triangles.

    OBJ files hold one ``l`` polyline per connected chain of `edges`; PLY
    files are ASCII with a ``face`` element. Both are written by hand (meshio
    stamps the date into its files, and its OBJ writer has no lines).
    """
    os.makedirs(directory, exist_ok=True)
    for s, x in enumerate(np.asarray(positions, dtype=np.float64)):
        name = os.path.join(directory, f"frame_{s:0{digits}d}.{kind}")
        vs = "".join(f"{p[0]:.7g} {p[1]:.7g} {p[2]:.7g}\n" for p in x)
        with open(name, "w", newline="\n") as fh:
            if kind == "obj":
                fh.write("# penfree sample polyline frame\n")
                fh.write("".join("v " + line for line in vs.splitlines(True)))
                for chain in _chains(topology["edges"]):
                    fh.write("l " + " ".join(str(i + 1) for i in chain) + "\n")
            else:
                F = topology["faces"]
                fh.write(f"ply\nformat ascii 1.0\nelement vertex {len(x)}\n"
                         "property float x\nproperty float y\nproperty float z\n"
                         f"element face {len(F)}\nproperty list uchar int vertex_indices\n"
                         "end_header\n")
                fh.write(vs)
                fh.write("".join(f"3 {a} {b} {c}\n" for a, b, c in F))


def _chains(edges):
    """Split edges (i, i+1 runs, as the rod scenes emit them) into vertex chains."""
    chains, cur = [], [int(edges[0, 0]), int(edges[0, 1])]
    for a, b in edges[1:]:
        if a == cur[-1]:
            cur.append(int(b))
        else:
            chains.append(cur)
            cur = [int(a), int(b)]
    chains.append(cur)
    return chains


def main(argv=None):
    ap = argparse.ArgumentParser(description="Generate a penfree sample sequence.")
    ap.add_argument("scene", choices=sorted(SCENES))
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--vertices", type=int, default=None)
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--dtype", choices=("float32", "float64"), default="float32")
    ap.add_argument("--mesh", choices=("obj", "ply"), default=None,
                    help="write a numbered mesh-file sequence into OUTPUT (a directory)")
    a = ap.parse_args(argv)
    t = time.perf_counter()
    X, topo, attrs = generate(a.scene, a.vertices, a.frames, a.seed)
    cmd = "python samples/generate.py " + " ".join(argv if argv is not None else sys.argv[1:])
    if a.mesh:
        write_mesh_sequence(a.output, X, topo, a.mesh)
    else:
        write_h5(a.output, X, topo, attrs, a.dtype,
                 source=f"{attrs['description']}; generated by: {cmd}")
    print(f"{a.scene}: T={X.shape[0]} N={X.shape[1]} thickness={attrs['thickness']:.4g} "
          f"-> {a.output} in {time.perf_counter() - t:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
