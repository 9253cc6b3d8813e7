"""USD stages (``.usd``, ``.usda``, ``.usdc``) in and out, through the optional ``usd-core``.

Reading (``read_usd``):

- **Scene.** Every ``UsdGeomMesh`` and linear ``UsdGeomBasisCurves`` whose
  time-sampled points change (deform), or exactly the prims named with ``prims=``
  (CLI ``--prim PATH``, repeatable, in that order). Static and rigidly moving
  meshes and ``PointInstancer`` prototypes are ignored (``_usd_stage`` decides). Meshes give triangles (quads and
  n-gons are fan-triangulated; ``attrs["usd_triangulated"]`` counts the polygons
  split); curves give segments. Each mesh prim is one component, each curve one
  component. Cubic curves are refused (resample them to linear first).
- **Time.** The frames are the authored time samples of the scene prims (points
  and transforms, ancestors included) within the stage's ``startTimeCode`` ..
  ``endTimeCode`` when those are authored; ``dt`` = time-code spacing /
  ``timeCodesPerSecond``. The time codes are kept in ``attrs["usd_time_codes"]``.
- **Units.** Positions are world-space and in metres: points times the prim's
  local-to-world transform times ``metersPerUnit`` (USD's fallback, 0.01, when the
  stage does not author it). Without a transform or scale the float32 points are
  kept bit for bit.
- **Obstacles.** ``UsdGeomPlane`` becomes a half-space (free side along the
  plane's axis; infinite, as physics engines treat a ground plane, whatever its
  width and length); ``UsdGeomCube``, ``Sphere``, ``Capsule``, ``Capsule_1``,
  ``Cylinder``, ``Cylinder_1`` and ``Cone`` become triangle meshes that *contain*
  the shape (see ``_usd_shapes``), and every one but the cube (whose mesh is exact)
  also keeps its exact solid (`penfree.sequence.AnalyticShape`), which deform and
  verify check instead of the mesh; their sizes read at each frame (time samples
  included). A mesh penfree wrote for such a solid carries it in ``penfree:shape:*``
  attributes, which the reader restores; meshes with
  ``PhysicsCollisionAPI`` whose points do not deform (simulated cloth often carries
  the API too: deforming points make it scene), skinned meshes with it (posed by
  their ``UsdSkel`` skeleton at each frame: linear blend skinning, in the skeleton's
  world frame) and prims named with ``obstacles=`` (``--obstacle PATH``) become mesh
  obstacles. A time-varying world transform gives a kinematic obstacle. Colliders
  inside instanced references (Omniverse props) are read through their instance
  proxies. A prim of another type with ``PhysicsCollisionAPI`` is refused.
- **Ignored.** Guide-purpose prims without ``PhysicsCollisionAPI`` (helpers, hidden
  duplicates), static and rigidly moving meshes, skinned meshes without the API and
  ``PointInstancer`` prototypes; ``penfree info`` says why, and ``--prim`` /
  ``--obstacle`` choose them explicitly.
- **Distances.** ``thickness`` and ``contact_radius`` come from a custom
  attribute of a scene prim (``penfree:thickness`` or ``thickness``, likewise
  ``contact_radius``), else from the root layer's ``customLayerData`` (top level
  or under ``penfree``); in stage units, converted to metres.

Writing (``write_usd``, ``write_usd_result``): one ``UsdGeomMesh`` (triangles) or
linear ``UsdGeomBasisCurves`` with time-sampled points, obstacles as meshes with
``PhysicsCollisionAPI`` or planes, ``metersPerUnit = 1``: standard schemas only,
for usdview and Blender. float64 positions also go into a custom ``double3[]``
attribute ``penfree:points`` (``points`` is float32 by schema), which the reader
prefers while it agrees with ``points``, so positions round-trip exactly in both
dtypes.

>>> seq = read_sequence("samples/cloth_drop.usda")     # doctest: +SKIP
>>> write_sequence("cloth.usda", seq, overwrite=True)  # doctest: +SKIP
"""

from __future__ import annotations

import os

import numpy as np

from ..errors import FormatError, InputError
from ..sequence import Sequence
from ._registry import register
from ._usd_read import curve_topology, distance, mesh_topology, obstacle, points
from ._usd_stage import EXTENSIONS, INSTALL_HINT, open_stage, pxr_modules, tf_message  # noqa: F401
from ._usd_write import write_stage


def read_usd(path: str, prims=(), obstacles=()) -> Sequence:
    """Read a USD stage as a sequence (not yet validated; see the module docstring).

    Parameters
    ----------
    path : str
    prims : iterable of str
        Scene prim paths (``--prim``); empty: every deforming Mesh/linear BasisCurves.
    obstacles : iterable of str
        Extra obstacle prim paths (``--obstacle``), besides the colliders found.
    """
    Tf = pxr_modules(path)[2]
    try:
        return _read(path, prims, obstacles)
    except Tf.ErrorException as exc:
        raise FormatError(f"{path} is a damaged USD stage ({tf_message(exc)}); expected a readable .usd/.usda/.usdc") from None


def _read(path, prims, obstacles) -> Sequence:
    Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, Vt = pxr_modules(path)
    scan = open_stage(path, prims, obstacles)
    times = scan.times
    parts, faces, edges, labels = [], [], [], []
    n, label, triangulated = 0, 0, 0
    for prim in scan.scene:
        X = points(scan, prim, times, UsdGeom)
        if prim.IsA(UsdGeom.Mesh):
            F, split = mesh_topology(scan, prim, UsdGeom, times[0])
            if len(F) and F.max() >= X.shape[1]:
                raise InputError(f"faceVertexIndices reach {int(F.max())} but the prim has {X.shape[1]} points "
                                 f"in {scan.where(prim)}")
            faces.append(F + n)
            triangulated += split
            labels.append(np.full(X.shape[1], label))
            label += 1
        else:
            E, lab, used = curve_topology(scan, prim, UsdGeom, times[0])
            if used != X.shape[1]:
                raise InputError(f"curveVertexCounts sum to {used} but the prim has {X.shape[1]} points "
                                 f"in {scan.where(prim)}")
            edges.append(E + n)
            labels.append(lab + label)
            label += int(lab.max()) + 1 if len(lab) else 0
        parts.append(X)
        n += X.shape[1]
    dtypes = {X.dtype for X in parts}
    positions = np.concatenate(parts, axis=1) if len(dtypes) == 1 else np.concatenate(
        [X.astype(np.float64) for X in parts], axis=1)
    names = set()
    data = dict(scan.stage.GetRootLayer().customLayerData)
    sub = data.get("penfree") if isinstance(data.get("penfree"), dict) else {}
    seq = Sequence(
        positions=positions,
        faces=np.concatenate(faces) if faces else None,
        edges=np.concatenate(edges) if edges else None,
        components=np.concatenate(labels) if label > 1 else None,
        thickness=distance(scan, "thickness", UsdGeom),
        contact_radius=distance(scan, "contact_radius", UsdGeom),
        dt=scan.dt,
        source=str(sub["source"]) if "source" in sub else f"USD stage {os.path.basename(path)}",
        obstacles=[obstacle(scan, prim, names, UsdGeom) for prim in scan.obstacles],
        origin=path,
        attrs={
            "usd_prims": [str(p.GetPath()) for p in scan.scene],
            "usd_time_codes": [float(t) for t in times],
            "usd_meters_per_unit": scan.meters_per_unit,
            "usd_up_axis": scan.up_axis,
            "usd_triangulated": triangulated,
        },
    )
    return seq


def describe_stage(path: str, prims=(), obstacles=()) -> dict:
    """What ``read_usd`` would take from `path`: prims and roles, frames, units, dt (for ``penfree info``)."""
    scan = open_stage(path, prims, obstacles)
    _, _, _, _, UsdGeom, _, _ = pxr_modules(path)
    for e in scan.entries:
        prim = scan.stage.GetPrimAtPath(e.path)
        if e.role == "scene" and prim.IsA(UsdGeom.Mesh):
            C = np.asarray(UsdGeom.Mesh(prim).GetFaceVertexCountsAttr().Get(scan.times[0]) or [])
            if (C > 3).any():
                e.detail += f"; {int((C > 3).sum())} of {len(C)} polygons fan-triangulated"
    return {
        "prims": [e.__dict__.copy() for e in scan.entries],
        "time_codes": {"first": scan.times[0], "last": scan.times[-1], "count": len(scan.times)},
        "stage_start_end": None if scan.start_end is None else list(scan.start_end),
        "time_codes_per_second": scan.time_codes_per_second,
        "dt": scan.dt,
        "meters_per_unit": scan.meters_per_unit,
        "meters_per_unit_authored": scan.meters_per_unit_authored,
        "up_axis": scan.up_axis,
    }


def write_usd(path: str, seq: Sequence, overwrite: bool = False) -> None:
    """Write `seq` as ``/World/Scene`` (Mesh or BasisCurves) with time-sampled points.

    Time codes are ``attrs["usd_time_codes"]`` when a USD input supplied them, else
    0, 1, ...; ``timeCodesPerSecond`` makes ``dt``. Obstacles go under ``/World/Obstacles``.
    """
    write_stage(path, seq, overwrite, [("/World/Scene", seq.positions, range(seq.n_frames), "recorded")])


def write_usd_result(path: str, result, overwrite: bool = False) -> None:
    """A deform result as two prims: ``/World/Recorded`` (every frame) and ``/World/Deformed``.

    The deformed state of step s (which starts from frame s) is sampled at frame s's
    time code, so scrubbing the timeline shows each frame beside where penfree moved it.
    ``/World/Deformed`` carries ``penfree:role = "deformed"``, so reading the file
    back takes the recorded frames unless ``--prim /World/Deformed`` is given.
    """
    seq = result.sequence
    frames = [int(f) for f in result.steps["frame"]]
    shapes_to_write = [("/World/Recorded", seq.positions, range(seq.n_frames), "recorded")]
    if frames:
        deformed = np.asarray(result.steps["deformed"]).astype(seq.positions.dtype, copy=False)
        shapes_to_write.append(("/World/Deformed", deformed, frames, "deformed"))
    write_stage(path, seq, overwrite, shapes_to_write)


register("usd", EXTENSIONS, read_usd, write_usd, options=("prims", "obstacles"))
