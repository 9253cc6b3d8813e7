"""USD stage scan: open a stage and sort its prims into scene, obstacles and ignored (for ``usd``).

One place decides which prim is read as what; ``read_usd`` and ``penfree info`` both
use :func:`open_stage`. usd-core is imported lazily (:func:`pxr_modules`), so the
core install works without it.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field

import numpy as np

from ..errors import FormatError, InputError

EXTENSIONS = (".usd", ".usda", ".usdc")
INSTALL_HINT = "USD support needs the optional package usd-core: pip install 'penfree[usd]'"
#: Custom attribute holding float64 positions beside the float32 ``points``.
POINTS64 = "penfree:points"
#: Custom attribute marking a prim written by penfree ("recorded" or "deformed").
ROLE = "penfree:role"
#: Custom attributes of an obstacle prim written by penfree that keep its exact analytic solid
#: (`sequence.AnalyticShape`) beside its mesh: the transform maps the solid into the prim's own
#: coordinates (USD's row-vector convention), profile and transform time-sampled when they change.
SHAPE_ATTRS = {"source": "penfree:shape:source", "axis": "penfree:shape:axis",
               "profile": "penfree:shape:profile", "transform": "penfree:shape:transform"}
#: The analytic colliders read as containing meshes (``_usd_shapes``) and their size attributes;
#: a ``Plane`` is a half-space.
ANALYTIC_SIZES = {
    "Cube": ("size",),
    "Sphere": ("radius",),
    "Capsule": ("radius", "height"),
    "Capsule_1": ("radiusBottom", "radiusTop", "height"),
    "Cylinder": ("radius", "height"),
    "Cylinder_1": ("radiusBottom", "radiusTop", "height"),
    "Cone": ("radius", "height"),
}
ANALYTIC = ("Plane", *ANALYTIC_SIZES)
#: Relative tolerance for "the time codes are evenly spaced" (dt is then defined).
SPACING_RTOL = 1e-9


def pxr_modules(path):
    try:
        from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, Vt
    except ImportError:
        raise InputError(f"cannot read or write {path}: {INSTALL_HINT}") from None
    return Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, Vt


def tf_message(exc) -> str:
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
    skel_cache: object = None  # UsdSkel.Cache, populated per skeleton root on first use
    skel_roots: set = field(default_factory=set)

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
    Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, Vt = pxr_modules(path)
    if not os.path.isfile(path):
        raise InputError(f"no such file: {path}")
    try:
        stage = Usd.Stage.Open(path, Usd.Stage.LoadAll)
    except Tf.ErrorException as exc:
        raise FormatError(f"{path} is not a readable USD stage ({tf_message(exc)}); expected .usd/.usda/.usdc") from None
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
                             f"expected a Mesh, BasisCurves or one of {', '.join(ANALYTIC)}")

    candidates = set(named_scene) | set(named_obstacles)
    for prim in stage.Traverse(Usd.TraverseInstanceProxies()):  # instanced props' colliders too
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
        raise InputError(f"no usable prim in {path}:/ ; expected a Mesh or linear BasisCurves whose time-sampled "
                         f"points deform (or name prims with --prim); found {found}")
    scan.times = _frame_times(scan, UsdGeom)
    return scan


def _classify(scan, prim, kind, p, named_scene, named_obstacles, UsdGeom, UsdPhysics):
    """``(role, detail)`` of one prim; the one place that decides what a prim is read as."""
    if p in named_obstacles:
        return "obstacle", "named with --obstacle"
    if p in named_scene:
        return "scene", "named with --prim"
    if _in_point_instancer(prim, UsdGeom):
        # Prototypes are templates (Newton's viewer draws joints and contacts this way), not placed geometry.
        return "ignored", "prototype of a PointInstancer (instances are not read)"
    collider = prim.HasAPI(UsdPhysics.CollisionAPI)
    if not collider and UsdGeom.Imageable(prim).ComputePurpose() == UsdGeom.Tokens.guide:
        return "ignored", "guide purpose (name it with --prim or --obstacle)"
    if kind in ANALYTIC:
        if kind in ("Plane", "Cube"):
            return "obstacle", "half-space" if kind == "Plane" else "analytic collider, an exact mesh"
        return "obstacle", "analytic collider, tessellated conservatively; its exact shape is kept too"
    role = prim.GetAttribute(ROLE)
    role = role.Get() if role.IsValid() else None
    if role == "obstacle":
        kept = prim.GetAttribute(SHAPE_ATTRS["source"])
        return "obstacle", (f"penfree obstacle (mesh of a {kept.Get()}; its exact shape is kept too)"
                            if kept.IsValid() and kept.HasValue() else "penfree obstacle")
    if not (prim.IsA(UsdGeom.Mesh) or prim.IsA(UsdGeom.BasisCurves)):
        if collider:
            raise InputError(f"prim {p} in {scan.path} has PhysicsCollisionAPI but is a {kind or 'typeless prim'}, "
                             f"which penfree cannot check a step against; expected a Mesh, BasisCurves or one of "
                             f"{', '.join(ANALYTIC)} (convert it to a Mesh)")
        return "ignored", "unsupported prim type"
    if skinning_query(scan, prim) is not None:
        if collider:
            return "obstacle", "skinned mesh with PhysicsCollisionAPI (posed by its skeleton)"
        if named_scene:
            return "ignored", "not named with --prim"
        return "ignored", "skinned, posed by a skeleton (name it with --obstacle or --prim)"
    deforming = _points_change(scan, prim)
    if prim.IsA(UsdGeom.Mesh) and collider and not deforming:
        return "obstacle", "mesh with PhysicsCollisionAPI"
    if named_scene:
        return "ignored", "not named with --prim"
    if role == "deformed":
        return "ignored", "penfree deformed states (choose with --prim)"
    if not deforming:
        if _transform_changes(prim, _sample_times(prim, UsdGeom), UsdGeom):
            return "ignored", "moves rigidly (fixed points, time-sampled transform): name it with --prim or --obstacle"
        return "ignored", "static (name it with --prim or --obstacle)"
    if collider:
        # Simulated cloth often carries the collision API too; its points deform, a collider's do not.
        return "scene", "deforming points (read as scene despite PhysicsCollisionAPI; --obstacle makes it a collider)"
    return "scene", "deforming points"


def skinning_query(scan, prim):
    """The ``UsdSkel`` skinning query of a prim bound to a skeleton with joint influences, else None."""
    from pxr import Usd, UsdSkel

    if not prim.HasAPI(UsdSkel.BindingAPI):
        return None
    root = UsdSkel.Root.Find(prim)
    if not root:
        return None
    if scan.skel_cache is None:
        scan.skel_cache = UsdSkel.Cache()
    key = str(root.GetPrim().GetPath())
    if key not in scan.skel_roots:
        scan.skel_cache.Populate(root, Usd.TraverseInstanceProxies())
        scan.skel_roots.add(key)
    query = scan.skel_cache.GetSkinningQuery(prim)
    return query if query and query.HasJointInfluences() else None


def _in_point_instancer(prim, UsdGeom) -> bool:
    p = prim.GetParent()
    while p.IsValid() and not p.IsPseudoRoot():
        if p.IsA(UsdGeom.PointInstancer):
            return True
        p = p.GetParent()
    return False


def _transform_changes(prim, times, UsdGeom) -> bool:
    xf = UsdGeom.Xformable(prim)
    first = xf.ComputeLocalToWorldTransform(times[0]) if times else None
    return any(xf.ComputeLocalToWorldTransform(t) != first for t in times[1:])


def _points_change(scan, prim) -> bool:
    """True if the authored points differ between time samples (within the stage's range)."""
    attr = prim.GetAttribute("points")
    if not attr.IsValid():
        return False
    times = attr.GetTimeSamples()
    if scan.start_end is not None:
        times = [t for t in times if scan.start_end[0] <= t <= scan.start_end[1]]
    if len(times) < 2:
        return False
    first = np.asarray(attr.Get(times[0]))
    for t in times[1:]:
        x = np.asarray(attr.Get(t))
        if x.shape != first.shape or not np.array_equal(x, first):
            return True
    return False


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


