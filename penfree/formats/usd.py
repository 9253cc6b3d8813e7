"""USD stages (``.usd``, ``.usda``, ``.usdc``) in and out, through the optional ``usd-core``.

Reading (``read_usd``):

- **Scene.** Every ``UsdGeomMesh`` and linear ``UsdGeomBasisCurves`` whose points
  or world transform are time-sampled, or exactly the prims named with
  ``prims=`` (CLI ``--prim PATH``, repeatable). Meshes give triangles (quads and
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
  plane's axis); ``UsdGeomCube``, ``UsdGeomSphere`` and ``UsdGeomCapsule`` become
  triangle meshes that *contain* the shape (see ``_usd_shapes``: a step safe
  against the mesh is safe against the shape); meshes with ``PhysicsCollisionAPI``
  whose points do not deform (simulated cloth often carries the API too: deforming
  points make it scene) and prims named with ``obstacles=`` (``--obstacle PATH``)
  become mesh obstacles. A time-varying world transform gives a kinematic obstacle.
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
import re
from contextlib import suppress
from dataclasses import dataclass, field

import numpy as np

from ..errors import FormatError, InputError
from ..sequence import Obstacle, Sequence
from . import _usd_shapes as shapes
from ._registry import register
from .atomic import atomic_file

EXTENSIONS = (".usd", ".usda", ".usdc")
INSTALL_HINT = "USD support needs the optional package usd-core: pip install 'penfree[usd]'"
#: Custom attribute holding float64 positions beside the float32 ``points``.
POINTS64 = "penfree:points"
#: Custom attribute marking a prim written by penfree ("recorded" or "deformed").
ROLE = "penfree:role"
ANALYTIC = ("Plane", "Cube", "Sphere", "Capsule")
DISTANCES = ("thickness", "contact_radius")
#: Relative tolerance for "the time codes are evenly spaced" (dt is then defined).
SPACING_RTOL = 1e-9


def _pxr(path):
    try:
        from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, Vt
    except ImportError:
        raise InputError(f"cannot read or write {path}: {INSTALL_HINT}") from None
    return Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, Vt


def _tf_message(exc) -> str:
    found = re.findall(r"'([^'\n]*)'\s*$", str(exc), flags=re.M)
    return (found[-1] if found else " ".join(str(exc).split()))[:200]


# --- selection -------------------------------------------------------------------

@dataclass
class PrimEntry:
    """One geometric prim of a stage and what the reader makes of it."""

    path: str
    type: str
    role: str  # "scene", "obstacle" or "ignored"
    detail: str


@dataclass
class StageScan:
    """A stage opened and sorted into scene prims, obstacle prims and ignored prims."""

    path: str
    stage: object
    scene: list = field(default_factory=list)
    obstacles: list = field(default_factory=list)
    entries: list = field(default_factory=list)
    times: list = field(default_factory=list)
    meters_per_unit: float = 1.0
    meters_per_unit_authored: bool = True
    time_codes_per_second: float = 24.0
    start_end: tuple | None = None
    up_axis: str = "Y"

    @property
    def dt(self):
        if len(self.times) < 2:
            return None
        steps = np.diff(np.asarray(self.times, dtype=np.float64))
        if np.ptp(steps) > SPACING_RTOL * steps.max():
            return None
        return float(steps.mean() / self.time_codes_per_second)

    def where(self, prim) -> str:
        return f"{self.path}:{prim.GetPath()}"


def open_stage(path: str, prims=(), obstacles=()) -> StageScan:
    """Open `path` and decide which prims are the scene and which are obstacles.

    Raises
    ------
    InputError
        Missing usd-core, missing file, a named prim that does not exist or has
        the wrong type, or no usable scene prim; one line naming file and prim.
    """
    Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, Vt = _pxr(path)
    if not os.path.isfile(path):
        raise InputError(f"no such file: {path}")
    try:
        stage = Usd.Stage.Open(path, Usd.Stage.LoadAll)
    except Tf.ErrorException as exc:
        raise FormatError(f"{path} is not a readable USD stage ({_tf_message(exc)}); expected .usd/.usda/.usdc") from None
    if stage is None:
        raise FormatError(f"{path} is not a readable USD stage; expected .usd/.usda/.usdc")
    scan = StageScan(path=path, stage=stage)
    scan.meters_per_unit = float(UsdGeom.GetStageMetersPerUnit(stage))
    scan.meters_per_unit_authored = bool(UsdGeom.StageHasAuthoredMetersPerUnit(stage))
    if not scan.meters_per_unit > 0:
        raise InputError(f"metersPerUnit must be > 0; got {scan.meters_per_unit} in {path}:/ (stage metadata)")
    scan.time_codes_per_second = float(stage.GetTimeCodesPerSecond())
    if not scan.time_codes_per_second > 0:
        raise InputError(f"timeCodesPerSecond must be > 0; got {scan.time_codes_per_second} in {path}:/ (stage metadata)")
    scan.up_axis = str(UsdGeom.GetStageUpAxis(stage))
    if stage.HasAuthoredTimeCodeRange():
        scan.start_end = (float(stage.GetStartTimeCode()), float(stage.GetEndTimeCode()))

    named_scene, named_obstacles = [str(p) for p in prims], [str(p) for p in obstacles]
    for p in named_scene + named_obstacles:
        if not Sdf.Path.IsValidPathString(p) or not stage.GetPrimAtPath(p).IsValid():
            raise InputError(f"no prim {p} in {path}; `penfree info {path}` lists the prims")
    both = set(named_scene) & set(named_obstacles)
    if both:
        raise InputError(f"prim {sorted(both)[0]} in {path} is named both with --prim and --obstacle; choose one")
    for p in named_scene:
        prim = stage.GetPrimAtPath(p)
        if not (prim.IsA(UsdGeom.Mesh) or prim.IsA(UsdGeom.BasisCurves)):
            raise InputError(f"--prim {p} in {path} is a {prim.GetTypeName() or 'typeless prim'}; expected a Mesh or BasisCurves")
    for p in named_obstacles:
        prim = stage.GetPrimAtPath(p)
        if not (prim.IsA(UsdGeom.Mesh) or prim.IsA(UsdGeom.BasisCurves) or prim.GetTypeName() in ANALYTIC):
            raise InputError(f"--obstacle {p} in {path} is a {prim.GetTypeName() or 'typeless prim'}; "
                             f"expected a Mesh, BasisCurves, Plane, Cube, Sphere or Capsule")

    candidates = set(named_scene) | set(named_obstacles)
    for prim in stage.Traverse():
        p = str(prim.GetPath())
        if not (prim.IsA(UsdGeom.Gprim) or p in candidates):
            continue
        kind = prim.GetTypeName()
        role, detail = _classify(scan, prim, kind, p, named_scene, named_obstacles, UsdGeom, UsdPhysics)
        scan.entries.append(PrimEntry(p, kind, role, detail))
        if role == "scene":
            scan.scene.append(prim)
        elif role == "obstacle":
            scan.obstacles.append(prim)
    if named_scene:  # the order the user gave, which is the order of the components
        scan.scene.sort(key=lambda prim: named_scene.index(str(prim.GetPath())))
    if not scan.scene:
        found = ", ".join(f"{e.path} ({e.type}: {e.detail})" for e in scan.entries) or "no geometric prims"
        raise InputError(f"no usable prim in {path}:/ ; expected a Mesh or linear BasisCurves with time-sampled "
                         f"points or transform; found {found}")
    scan.times = _frame_times(scan, UsdGeom)
    return scan


def _classify(scan, prim, kind, p, named_scene, named_obstacles, UsdGeom, UsdPhysics):
    if p in named_obstacles:
        return "obstacle", "named with --obstacle"
    if p in named_scene:
        return "scene", "named with --prim"
    if kind in ANALYTIC:
        return "obstacle", "half-space" if kind == "Plane" else "analytic collider, tessellated conservatively"
    role = prim.GetAttribute(ROLE)
    role = role.Get() if role.IsValid() else None
    deforming = prim.GetAttribute("points").IsValid() and prim.GetAttribute("points").GetNumTimeSamples() > 1
    if role == "obstacle":
        return "obstacle", "penfree obstacle"
    if prim.IsA(UsdGeom.Mesh) and prim.HasAPI(UsdPhysics.CollisionAPI) and not deforming:
        return "obstacle", "mesh with PhysicsCollisionAPI"
    if not (prim.IsA(UsdGeom.Mesh) or prim.IsA(UsdGeom.BasisCurves)):
        return "ignored", "unsupported prim type"
    if named_scene:
        return "ignored", "not named with --prim"
    if role == "deformed":
        return "ignored", "penfree deformed states (choose with --prim)"
    if len(_sample_times(prim, UsdGeom)) < 2:
        return "ignored", "static (name it with --prim or --obstacle)"
    if prim.HasAPI(UsdPhysics.CollisionAPI):
        # Simulated cloth often carries the collision API too; its points deform, a collider's do not.
        return "scene", "time-sampled points (deforming, so read as scene despite PhysicsCollisionAPI; " \
                        "--obstacle makes it a collider)"
    return "scene", "time-sampled"


def _sample_times(prim, UsdGeom) -> list:
    """Authored time samples of the points and of every transform up to the root."""
    times = set()
    pts = prim.GetAttribute("points")
    if pts.IsValid():
        times.update(pts.GetTimeSamples())
    p = prim
    while p.IsValid() and not p.IsPseudoRoot():
        if p.IsA(UsdGeom.Xformable):
            times.update(UsdGeom.Xformable(p).GetTimeSamples())
        p = p.GetParent()
    return sorted(times)


def _frame_times(scan: StageScan, UsdGeom) -> list:
    times = sorted({t for prim in scan.scene for t in _sample_times(prim, UsdGeom)})
    if scan.start_end is not None:
        lo, hi = scan.start_end
        times = [t for t in times if lo <= t <= hi]
    if len(times) < 2:
        names = ", ".join(str(prim.GetPath()) for prim in scan.scene)
        span = "" if scan.start_end is None else f" within startTimeCode..endTimeCode {scan.start_end[0]:g}..{scan.start_end[1]:g}"
        raise InputError(f"prim {names} in {scan.path} has {len(times)} time sample(s){span}; "
                         f"expected at least 2 (time-sampled points or transform)")
    return times


# --- reading -------------------------------------------------------------------------

def _world(scan, prim, t, UsdGeom):
    """Local-to-world ``(3, 3)`` linear part (row-vector convention) and ``(3,)`` translation, in metres."""
    M = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(t), dtype=np.float64)
    return M[:3, :3] * scan.meters_per_unit, M[3, :3] * scan.meters_per_unit


def _is_identity(L, c) -> bool:
    return bool(np.array_equal(L, np.eye(3)) and not c.any())


def _points(scan, prim, times, UsdGeom):
    """World positions ``(T, n, 3)`` of a point-based prim at `times`."""
    attr = prim.GetAttribute("points")
    p64 = prim.GetAttribute(POINTS64)
    frames, n0 = [], None
    for t in times:
        pts = attr.Get(t)
        if pts is None:
            raise InputError(f"prim has no points at time code {t:g} in {scan.where(prim)}; expected authored points")
        x = np.asarray(pts)
        if n0 is None:
            n0 = len(x)
        elif len(x) != n0:
            raise InputError(f"point count changes over time: {n0} at time code {times[0]:g}, {len(x)} at {t:g} "
                             f"in {scan.where(prim)}; expected a fixed point count (remeshing is not supported)")
        if p64.IsValid() and p64.Get(t) is not None:
            x64 = np.asarray(p64.Get(t), dtype=np.float64)
            if x64.shape == x.shape and np.array_equal(x64.astype(x.dtype), x):
                x = x64
        frames.append(x)
    X = np.stack(frames) if frames else np.zeros((0, 0, 3))
    if X.ndim != 3 or X.shape[-1] != 3:
        raise InputError(f"points must be (n, 3); got {X.shape[1:]} in {scan.where(prim)}")
    out = X
    for k, t in enumerate(times):
        L, c = _world(scan, prim, t, UsdGeom)
        if not _is_identity(L, c):
            if out is X:
                out = X.astype(np.float64)
            out[k] = X[k].astype(np.float64) @ L + c
    return out


def _mesh_topology(scan, prim, UsdGeom, t):
    mesh = UsdGeom.Mesh(prim)
    counts = mesh.GetFaceVertexCountsAttr()
    indices = mesh.GetFaceVertexIndicesAttr()
    for attr in (counts, indices):
        samples = attr.GetTimeSamples()
        if len(samples) > 1 and any(attr.Get(s) != attr.Get(samples[0]) for s in samples[1:]):
            raise InputError(f"{attr.GetName()} changes over time in {scan.where(prim)}; expected fixed topology")
    C = np.asarray(counts.Get(t) if counts.Get(t) is not None else [], dtype=np.int64)
    I = np.asarray(indices.Get(t) if indices.Get(t) is not None else [], dtype=np.int64)
    if C.sum() != len(I) or (C < 3).any():
        raise InputError(f"faceVertexCounts (sum {C.sum()}, min {C.min() if len(C) else '-'}) do not match "
                         f"faceVertexIndices ({len(I)}) in {scan.where(prim)}; expected polygons of >= 3 vertices")
    holes = np.asarray(mesh.GetHoleIndicesAttr().Get(t) or [], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(C)[:-1]])
    keep = np.ones(len(C), dtype=bool)
    keep[holes[(holes >= 0) & (holes < len(C))]] = False
    tris = []
    for k in range(1, int(C.max()) - 1 if len(C) else 1):
        sel = keep & (C >= k + 2)
        s = starts[sel]
        tris.append(np.stack([I[s], I[s + k], I[s + k + 1]], axis=1))
    F = np.concatenate(tris) if tris else np.zeros((0, 3), dtype=np.int64)
    # Fan order: interleave so that each polygon's triangles stay together.
    if len(F):
        owner = np.concatenate([np.flatnonzero(keep & (C >= k + 2)) for k in range(1, int(C.max()) - 1)])
        F = F[np.argsort(owner, kind="stable")]
    if mesh.GetOrientationAttr().Get() == "leftHanded":
        F = F[:, [0, 2, 1]]
    return F, int((keep & (C > 3)).sum())


def _curve_topology(scan, prim, UsdGeom, t):
    curves = UsdGeom.BasisCurves(prim)
    ctype = curves.GetTypeAttr().Get()
    if ctype != "linear":
        basis = curves.GetBasisAttr().Get()
        raise InputError(f"{ctype} curves (basis {basis}) are not supported in {scan.where(prim)}; expected "
                         f"type = \"linear\": resample them to polylines first (Houdini: Resample + Convert to "
                         f"polygon; Blender: Curve > Convert to Mesh)")
    C = np.asarray(curves.GetCurveVertexCountsAttr().Get(t) or [], dtype=np.int64)
    if (C < 2).any():
        raise InputError(f"curveVertexCounts must be >= 2 for linear curves; got {int(C.min())} in {scan.where(prim)}")
    periodic = curves.GetWrapAttr().Get() == "periodic"
    starts = np.concatenate([[0], np.cumsum(C)[:-1]]).astype(np.int64)
    E, labels = [], []
    for k, (s, c) in enumerate(zip(starts, C)):
        a = np.arange(s, s + c - 1)
        E.append(np.stack([a, a + 1], axis=1))
        if periodic and c > 2:
            E.append(np.array([[s + c - 1, s]]))
        labels.append(np.full(c, k))
    E = np.concatenate(E) if E else np.zeros((0, 2), dtype=np.int64)
    return E, (np.concatenate(labels) if labels else np.zeros(0, dtype=np.int64)), int(C.sum())


def _distance(scan, key, UsdGeom):
    """thickness / contact_radius in metres: a scene prim's attribute, else the layer metadata."""
    found = {}
    for prim in scan.scene:
        for name in (f"penfree:{key}", key):
            attr = prim.GetAttribute(name)
            if attr.IsValid() and attr.HasValue():
                found[str(prim.GetPath())] = (attr.Get(), f"{scan.where(prim)}.{name}")
                break
    if found:
        values = {_number(v, where) for v, where in found.values()}
        if len(values) > 1:
            raise InputError(f"{key} differs between scene prims ({', '.join(found)}) in {scan.path}; expected one value")
        return values.pop() * scan.meters_per_unit
    data = dict(scan.stage.GetRootLayer().customLayerData)
    sub = data.get("penfree")
    if isinstance(sub, dict) and key in sub:
        return _number(sub[key], f"{scan.path}:customLayerData.penfree.{key}") * scan.meters_per_unit
    if key in data:
        return _number(data[key], f"{scan.path}:customLayerData.{key}") * scan.meters_per_unit
    return 0.0


def _number(value, where) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if not np.isfinite(v) or v < 0:
        raise InputError(f"expected a finite number >= 0; got {value!r} in {where}")
    return v


def _obstacle(scan, prim, names, UsdGeom) -> Obstacle:
    kind = prim.GetTypeName()
    name = prim.GetName()
    if name in names:
        name = str(prim.GetPath()).strip("/").replace("/", ".")
    names.add(name)
    times = scan.times
    if kind == "Plane":
        Ls = [_world(scan, prim, t, UsdGeom) for t in times]
        if any(not (np.array_equal(L, Ls[0][0]) and np.array_equal(c, Ls[0][1])) for L, c in Ls):
            raise InputError(f"a Plane with a time-varying transform cannot be a half-space in {scan.where(prim)}; "
                             f"expected a static plane (give a moving floor as a Mesh with PhysicsCollisionAPI)")
        L, c = Ls[0]
        axis = np.zeros(3)
        axis["XYZ".index(UsdGeom.Plane(prim).GetAxisAttr().Get())] = 1.0
        n = np.linalg.solve(L, axis)  # normals transform by the inverse transpose (row-vector convention)
        n /= np.linalg.norm(n)
        return Obstacle(name, normal=n, offset=float(n @ c))
    if kind in ("Cube", "Sphere", "Capsule"):
        if kind == "Cube":
            V, F = shapes.cube(float(UsdGeom.Cube(prim).GetSizeAttr().Get()))
        elif kind == "Sphere":
            V, F = shapes.sphere(float(UsdGeom.Sphere(prim).GetRadiusAttr().Get()))
        else:
            cap = UsdGeom.Capsule(prim)
            V, F = shapes.capsule(float(cap.GetRadiusAttr().Get()), float(cap.GetHeightAttr().Get()),
                                  str(cap.GetAxisAttr().Get()))
        X = np.stack([V @ L + c for L, c in (_world(scan, prim, t, UsdGeom) for t in times)])
        return Obstacle(name, positions=X[0] if (X == X[0]).all() else X, faces=F)
    X = _points(scan, prim, times, UsdGeom).astype(np.float64)
    if prim.IsA(UsdGeom.BasisCurves):
        E, _, _ = _curve_topology(scan, prim, UsdGeom, times[0])
        return Obstacle(name, positions=X[0] if (X == X[0]).all() else X, edges=E)
    F, _ = _mesh_topology(scan, prim, UsdGeom, times[0])
    return Obstacle(name, positions=X[0] if (X == X[0]).all() else X, faces=F)


def read_usd(path: str, prims=(), obstacles=()) -> Sequence:
    """Read a USD stage as a sequence (not yet validated; see the module docstring).

    Parameters
    ----------
    path : str
    prims : iterable of str
        Scene prim paths (``--prim``); empty: every time-sampled Mesh/BasisCurves.
    obstacles : iterable of str
        Extra obstacle prim paths (``--obstacle``), besides the colliders found.
    """
    Tf = _pxr(path)[2]
    try:
        return _read(path, prims, obstacles)
    except Tf.ErrorException as exc:
        raise FormatError(f"{path} is a damaged USD stage ({_tf_message(exc)}); expected a readable .usd/.usda/.usdc") from None


def _read(path, prims, obstacles) -> Sequence:
    Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, Vt = _pxr(path)
    scan = open_stage(path, prims, obstacles)
    times = scan.times
    parts, faces, edges, labels = [], [], [], []
    n, label, triangulated = 0, 0, 0
    for prim in scan.scene:
        X = _points(scan, prim, times, UsdGeom)
        if prim.IsA(UsdGeom.Mesh):
            F, split = _mesh_topology(scan, prim, UsdGeom, times[0])
            if len(F) and F.max() >= X.shape[1]:
                raise InputError(f"faceVertexIndices reach {int(F.max())} but the prim has {X.shape[1]} points "
                                 f"in {scan.where(prim)}")
            faces.append(F + n)
            triangulated += split
            labels.append(np.full(X.shape[1], label))
            label += 1
        else:
            E, lab, used = _curve_topology(scan, prim, UsdGeom, times[0])
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
        thickness=_distance(scan, "thickness", UsdGeom),
        contact_radius=_distance(scan, "contact_radius", UsdGeom),
        dt=scan.dt,
        source=str(sub["source"]) if "source" in sub else f"USD stage {os.path.basename(path)}",
        obstacles=[_obstacle(scan, prim, names, UsdGeom) for prim in scan.obstacles],
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
    _, _, _, _, UsdGeom, _, _ = _pxr(path)
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


# --- writing -------------------------------------------------------------------------

def _chains(edges, n, where):
    """Edges as consecutive-vertex chains (BasisCurves have no index buffer): counts and wrap."""
    E = np.unique(np.sort(np.asarray(edges, dtype=np.int64), axis=1), axis=0)
    link = np.zeros(max(n - 1, 0), dtype=bool)
    step = E[:, 1] == E[:, 0] + 1
    link[E[step, 0]] = True
    cuts = np.flatnonzero(~link) + 1
    starts = np.concatenate([[0], cuts])
    ends = np.concatenate([cuts, [n]])
    closing = {(int(a), int(b)) for a, b in E[~step]}
    runs = {(int(s), int(e - 1)) for s, e in zip(starts, ends)}
    if not closing <= runs or (closing and closing != {r for r in runs if r[1] - r[0] >= 2}):
        raise InputError(f"edges of {where} are not chains of consecutive vertices (all open or all closed); "
                         f"USD BasisCurves cannot store them")
    counts = ends - starts
    if (counts < 2).any():
        v = int(starts[np.flatnonzero(counts < 2)[0]])
        raise InputError(f"vertex {v} of {where} belongs to no edge; USD BasisCurves cannot store it")
    return counts, "periodic" if closing else "nonperiodic"


def _check_edges_in_faces(seq):
    if seq.edges is None or not len(seq.edges):
        return
    F = seq.faces
    face_edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    extra = np.sort(seq.edges, axis=1)
    known = {tuple(e) for e in face_edges.tolist()}
    lone = [e for e in extra.tolist() if tuple(e) not in known]
    if lone:
        raise InputError(f"{seq.origin} has {len(lone)} edge(s) outside its faces (e.g. {lone[0]}); a USD Mesh "
                         f"cannot store them: write the faces and the edges as separate sequences")


def _set_points(prim_schema, X, codes, Vt, Sdf, where):
    """Time-sampled points (float32 by schema; float64 also as ``penfree:points``) and extents."""
    pts = prim_schema.GetPointsAttr()
    ext = prim_schema.GetExtentAttr()
    p64 = None
    if X.dtype == np.float64:
        p64 = prim_schema.GetPrim().CreateAttribute(POINTS64, Sdf.ValueTypeNames.Double3Array, custom=True)
    for x, t in zip(X, codes):
        pts.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(x, dtype=np.float32)), t)
        ext.Set(Vt.Vec3fArray.FromNumpy(np.stack([x.min(axis=0), x.max(axis=0)]).astype(np.float32)), t)
        if p64 is not None:
            p64.Set(Vt.Vec3dArray.FromNumpy(np.ascontiguousarray(x)), t)


def _define_shape(stage, path, X, codes, seq, mods, role=None):
    Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, Vt = mods
    if seq.faces is not None and len(seq.faces):
        _check_edges_in_faces(seq)
        geom = UsdGeom.Mesh.Define(stage, path)
        geom.CreateSubdivisionSchemeAttr("none")  # viewers must not smooth the triangles
        geom.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(seq.faces), 3, dtype=np.int32)))
        geom.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(seq.faces.astype(np.int32).ravel()))
    elif seq.edges is not None and len(seq.edges):
        counts, wrap = _chains(seq.edges, X.shape[1], seq.origin)
        geom = UsdGeom.BasisCurves.Define(stage, path)
        geom.CreateTypeAttr("linear")
        geom.CreateWrapAttr(wrap)
        geom.CreateCurveVertexCountsAttr(Vt.IntArray.FromNumpy(counts.astype(np.int32)))
        x0 = X[0].astype(np.float64)
        width = max(2.0 * float(seq.thickness or 0.0), 1e-3 * float(np.ptp(x0, axis=0).max() or 1.0))
        geom.CreateWidthsAttr(Vt.FloatArray([width]))
        geom.SetWidthsInterpolation(UsdGeom.Tokens.constant)
    else:
        raise InputError(f"{seq.origin} has neither faces nor edges; USD output needs a Mesh or BasisCurves topology")
    _set_points(geom, X, codes, Vt, Sdf, path)
    if role is not None:
        geom.GetPrim().CreateAttribute(ROLE, Sdf.ValueTypeNames.String, custom=True).Set(role)
    return geom


def _define_obstacle(stage, ob, codes, extent, mods):
    Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, Vt = mods
    path = f"/World/Obstacles/{Tf.MakeValidIdentifier(ob.name)}"
    if ob.is_half_space:
        n = np.asarray(ob.normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        plane = UsdGeom.Plane.Define(stage, path)
        k = int(np.argmax(np.abs(n)))
        size = 4.0 * extent + 2.0 * abs(float(ob.offset))
        plane.CreateWidthAttr(size)
        plane.CreateLengthAttr(size)
        xf = UsdGeom.Xformable(plane)
        if np.count_nonzero(n) == 1 and n[k] > 0:  # axis-aligned: an exact translate, no rotation
            plane.CreateAxisAttr("XYZ"[k])
            xf.AddTranslateOp().Set(Gf.Vec3d(*(n * float(ob.offset))))
        else:
            plane.CreateAxisAttr("Z")
            rot = Gf.Rotation(Gf.Vec3d(0, 0, 1), Gf.Vec3d(*n))
            xf.AddTranslateOp().Set(Gf.Vec3d(*(n * float(ob.offset))))
            xf.AddOrientOp(UsdGeom.XformOp.PrecisionDouble).Set(rot.GetQuat())
        UsdPhysics.CollisionAPI.Apply(plane.GetPrim())
        plane.GetPrim().CreateAttribute(ROLE, Sdf.ValueTypeNames.String, custom=True).Set("obstacle")
        return
    X = np.asarray(ob.positions, dtype=np.float64)
    if X.ndim == 2:
        X, codes = X[None], [Usd.TimeCode.Default()]
    if ob.faces is not None and len(ob.faces):
        geom = UsdGeom.Mesh.Define(stage, path)
        geom.CreateSubdivisionSchemeAttr("none")
        geom.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(ob.faces), 3, dtype=np.int32)))
        geom.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.asarray(ob.faces, dtype=np.int32).ravel()))
        UsdPhysics.CollisionAPI.Apply(geom.GetPrim())
    else:
        counts, wrap = _chains(ob.edges, X.shape[1], f"obstacle {ob.name}")
        geom = UsdGeom.BasisCurves.Define(stage, path)
        geom.CreateTypeAttr("linear")
        geom.CreateWrapAttr(wrap)
        geom.CreateCurveVertexCountsAttr(Vt.IntArray.FromNumpy(counts.astype(np.int32)))
    _set_points(geom, X, codes, Vt, Sdf, path)
    geom.GetPrim().CreateAttribute(ROLE, Sdf.ValueTypeNames.String, custom=True).Set("obstacle")


def _time_codes(seq) -> list:
    codes = seq.attrs.get("usd_time_codes") if isinstance(seq.attrs, dict) else None
    if isinstance(codes, (list, tuple)) and len(codes) == seq.n_frames and np.all(np.diff(codes) > 0):
        return [float(c) for c in codes]
    return [float(s) for s in range(seq.n_frames)]


def _write_stage(path, seq, overwrite, shapes_to_write):
    """One stage with the given ``(prim path, positions, time codes, role)`` shapes plus `seq`'s obstacles."""
    mods = _pxr(path)
    Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, Vt = mods
    ext = os.path.splitext(path)[1].lower()
    if ext not in EXTENSIONS:
        raise InputError(f"cannot write USD to {path}; expected one of {', '.join(EXTENSIONS)}")
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    up = seq.attrs.get("usd_up_axis") if isinstance(seq.attrs, dict) else None
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if up == "Z" else UsdGeom.Tokens.y)
    codes = _time_codes(seq)
    stage.SetStartTimeCode(codes[0])
    stage.SetEndTimeCode(codes[-1])
    if seq.dt:
        steps = np.diff(codes)
        stage.SetTimeCodesPerSecond(float(steps.mean() / seq.dt))
        stage.SetFramesPerSecond(float(steps.mean() / seq.dt))
    meta = {"thickness": float(seq.thickness or 0.0), "contact_radius": float(seq.contact_radius or 0.0)}
    if seq.source:
        meta["source"] = str(seq.source)
    stage.GetRootLayer().customLayerData = {"penfree": meta}
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    for prim_path, X, prim_codes, role in shapes_to_write:
        _define_shape(stage, prim_path, X, [codes[c] for c in prim_codes], seq, mods, role)
    extent = float(np.ptp(seq.positions[0].astype(np.float64), axis=0).max() or 1.0)
    if seq.obstacles:
        UsdGeom.Xform.Define(stage, "/World/Obstacles")
    for ob in seq.obstacles:
        _define_obstacle(stage, ob, codes, extent, mods)
    with atomic_file(path, overwrite) as tmp:
        staged = tmp + ext  # USD picks the file format from the extension
        try:
            stage.GetRootLayer().Export(staged)
            os.replace(staged, tmp)
        finally:
            with suppress(OSError):
                os.unlink(staged)


def write_usd(path: str, seq: Sequence, overwrite: bool = False) -> None:
    """Write `seq` as ``/World/Scene`` (Mesh or BasisCurves) with time-sampled points.

    Time codes are ``attrs["usd_time_codes"]`` when a USD input supplied them, else
    0, 1, ...; ``timeCodesPerSecond`` makes ``dt``. Obstacles go under ``/World/Obstacles``.
    """
    _write_stage(path, seq, overwrite, [("/World/Scene", seq.positions, range(seq.n_frames), "recorded")])


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
    _write_stage(path, seq, overwrite, shapes_to_write)


register("usd", EXTENSIONS, read_usd, write_usd, options=("prims", "obstacles"))
