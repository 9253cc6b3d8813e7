"""Reading helpers of ``usd``: world-space points in metres, topology, distances, obstacles."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..sequence import AnalyticShape, Obstacle
from . import _usd_shapes as shapes
from ._usd_stage import ANALYTIC_SIZES, POINTS64, SHAPE_ATTRS, skinning_query

def _world(scan, prim, t, UsdGeom):
    """Local-to-world ``(3, 3)`` linear part (row-vector convention) and ``(3,)`` translation, in metres."""
    M = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(t), dtype=np.float64)
    return M[:3, :3] * scan.meters_per_unit, M[3, :3] * scan.meters_per_unit


def _is_identity(L, c) -> bool:
    return bool(np.array_equal(L, np.eye(3)) and not c.any())


def points(scan, prim, times, UsdGeom):
    """World positions ``(T, n, 3)`` of a point-based prim at `times` (posed by its skeleton if skinned)."""
    query = skinning_query(scan, prim)
    if query is not None:
        return _skinned_points(scan, prim, query, times, UsdGeom)
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


def _skinned_points(scan, prim, query, times, UsdGeom):
    """World positions ``(T, n, 3)`` of a skinned prim: UsdSkel's linear blend skinning at each time.

    Skinning gives skeleton-space points; the skeleton's local-to-world transform (not the
    prim's own, which skinning replaces) takes them to the world.
    """
    from pxr import UsdSkel, Vt

    if query.HasBlendShapes():
        raise InputError(f"skinned prim with blend shapes in {scan.where(prim)}; expected skinning without blend "
                         f"shapes (bake it into time-sampled points first, e.g. with UsdSkel.BakeSkinning)")
    skel = UsdSkel.BindingAPI(prim).GetInheritedSkeleton()
    skel_query = scan.skel_cache.GetSkelQuery(skel) if skel else None
    if not skel_query:
        raise InputError(f"skinned prim without a usable skeleton in {scan.where(prim)}; expected skel:skeleton to "
                         f"name a Skeleton under the same SkelRoot")
    attr = prim.GetAttribute("points")
    frames = []
    for t in times:
        pts = attr.Get(t)
        if pts is None:
            raise InputError(f"prim has no points at time code {t:g} in {scan.where(prim)}; expected authored points")
        xforms = skel_query.ComputeSkinningTransforms(t)
        if query.IsRigidlyDeformed():
            M = query.ComputeSkinnedTransform(xforms, t)
            x = None if M is None else np.asarray(pts, dtype=np.float64) @ np.array(M)[:3, :3] + np.array(M)[3, :3]
        else:
            posed = Vt.Vec3fArray(pts)
            x = np.asarray(posed, dtype=np.float64) if query.ComputeSkinnedPoints(xforms, posed, t) else None
        if x is None or (frames and x.shape != frames[0].shape):
            raise InputError(f"cannot pose skinned prim at time code {t:g} in {scan.where(prim)}; expected joint "
                             f"influences matching its points and a skeleton animation")
        L, c = _world(scan, skel.GetPrim(), t, UsdGeom)
        frames.append(x @ L + c)
    return np.stack(frames)


def _fixed(scan, prim, *attrs):
    """Refuse topology attributes whose time samples differ (remeshing is not supported)."""
    for attr in attrs:
        samples = attr.GetTimeSamples()
        if len(samples) > 1 and any(attr.Get(s) != attr.Get(samples[0]) for s in samples[1:]):
            raise InputError(f"{attr.GetName()} changes over time in {scan.where(prim)}; expected fixed topology")


def mesh_topology(scan, prim, UsdGeom, t):
    mesh = UsdGeom.Mesh(prim)
    counts = mesh.GetFaceVertexCountsAttr()
    indices = mesh.GetFaceVertexIndicesAttr()
    _fixed(scan, prim, counts, indices)
    C = np.asarray(counts.Get(t) if counts.Get(t) is not None else [], dtype=np.int64)
    I = np.asarray(indices.Get(t) if indices.Get(t) is not None else [], dtype=np.int64)
    if not len(C):
        raise InputError(f"Mesh without faces (no faceVertexCounts) in {scan.where(prim)}; expected polygons "
                         f"(a point cloud is not a mesh)")
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


def curve_topology(scan, prim, UsdGeom, t):
    curves = UsdGeom.BasisCurves(prim)
    ctype = curves.GetTypeAttr().Get()
    if ctype != "linear":
        basis = curves.GetBasisAttr().Get()
        raise InputError(f"{ctype} curves (basis {basis}) are not supported in {scan.where(prim)}; expected "
                         f"type = \"linear\": resample them to polylines first (Houdini: Resample + Convert to "
                         f"polygon; Blender: Curve > Convert to Mesh)")
    _fixed(scan, prim, curves.GetCurveVertexCountsAttr())
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


def distance(scan, key, UsdGeom):
    """thickness / contact_radius in metres: a scene prim's attribute, else the layer metadata."""
    found = {}
    for prim in scan.scene:
        for name in (f"penfree:{key}", key):
            attr = prim.GetAttribute(name)
            if attr.IsValid() and attr.HasValue():
                found[str(prim.GetPath())] = (_constant(attr, f"{scan.where(prim)}.{name}"), f"{scan.where(prim)}.{name}")
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


def _constant(attr, where):
    """An attribute's one value: its default, or its time samples when they all agree."""
    samples = attr.GetTimeSamples()
    if not samples:
        return attr.Get()
    values = {_number(attr.Get(t), where) for t in samples}
    if len(values) > 1:
        raise InputError(f"expected one value; got {len(values)} different time samples "
                         f"({min(values):g} .. {max(values):g}) in {where}")
    return values.pop()


def _number(value, where) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if not np.isfinite(v) or v < 0:
        raise InputError(f"expected a finite number >= 0; got {value!r} in {where}")
    return v


def _plane_normal(L, axis):
    """Unit normal of the plane ``axis . x = 0`` mapped by ``x -> x L`` (row vectors), or None.

    Normals map by ``L^-1`` (row-vector convention); the cofactor matrix ``det(L) L^-1``
    gives the same direction, and stays defined when a scale of 0 along the plane's axis
    makes L singular (the plane itself is still a plane; its free side is the one a
    positive scale would give). None when the plane's own axes collapse.
    """
    k = "XYZ".index(axis.upper())
    u, v = L[(k + 1) % 3], L[(k + 2) % 3]  # images of the in-plane axes, e_u x e_v = e_k
    n = np.cross(u, v)
    det = float(n @ L[k])
    if det < 0:
        n = -n
    norm = float(np.linalg.norm(n))
    if not norm > 0 or not np.isfinite(norm):
        return None
    return n / norm


def _analytic_size(scan, prim, kind, t):
    """The shape's size attributes at time code `t` (time samples included) and its axis."""
    values = []
    for name in ANALYTIC_SIZES[kind]:
        attr = prim.GetAttribute(name)
        raw = attr.Get(t) if attr.IsValid() else None
        try:
            value = float(raw)
        except (TypeError, ValueError):
            value = float("nan")
        # A capsule of height 0 is a ball and one end of a frustum may be a point; nothing else may vanish.
        positive = name in ("size", "radius") or (name == "height" and not kind.startswith("Capsule"))
        if not (np.isfinite(value) and (value > 0.0 if positive else value >= 0.0)):
            raise InputError(f"{kind} {name} must be a finite number {'> 0' if positive else '>= 0'}; got {raw!r} "
                             f"at time code {t:g} in {scan.where(prim)}")
        values.append(value)
    if kind in ("Capsule_1", "Cylinder_1") and values[0] == values[1] == 0.0:  # radiusBottom, radiusTop
        raise InputError(f"{kind} radii are both 0 at time code {t:g} in {scan.where(prim)}; expected a solid")
    axis = prim.GetAttribute("axis")
    return (*values, str(axis.Get(t)) if axis.IsValid() and axis.Get(t) else "Z")


def _analytic_mesh(kind, *size):
    """The containing mesh (V, F) of one analytic shape, in its local coordinates."""
    axis = size[-1]
    if kind == "Cube":
        return shapes.cube(size[0])
    if kind == "Sphere":
        return shapes.sphere(size[0])
    if kind == "Capsule":
        return shapes.capsule(size[0], size[1], axis)
    if kind == "Capsule_1":
        return shapes.capsule(size[0], size[2], axis, radius_top=size[1])
    if kind == "Cylinder":
        return shapes.frustum(size[0], size[0], size[1], axis)
    if kind == "Cone":
        return shapes.frustum(size[0], 0.0, size[1], axis)
    return shapes.frustum(size[0], size[1], size[2], axis)  # Cylinder_1


def _profile(kind, *size):
    """The `AnalyticShape` profile (height, disc_bottom, round_bottom, disc_top, round_top) of
    `_analytic_size`'s values: the solid that `_analytic_mesh` contains, bottom end at
    ``-height/2`` along the axis."""
    if kind == "Sphere":
        return (0.0, 0.0, size[0], 0.0, size[0])
    if kind == "Capsule":
        return (size[1], 0.0, size[0], 0.0, size[0])
    if kind == "Capsule_1":
        return (size[2], 0.0, size[0], 0.0, size[1])
    if kind == "Cylinder":
        return (size[1], size[0], 0.0, size[0], 0.0)
    if kind == "Cone":  # apex at +height/2, as `shapes.frustum(radius, 0.0, ...)`
        return (size[1], size[0], 0.0, 0.0, 0.0)
    return (size[2], size[0], 0.0, size[1], 0.0)  # Cylinder_1


def _one_or_all(rows: np.ndarray) -> np.ndarray:
    """Per-frame rows ``(T, ...)``, or their one row when every frame has the same (as positions)."""
    return rows[0] if (rows == rows[0]).all() else rows


def _analytic(scan, prim, kind, UsdGeom):
    """``(X (T, M, 3), F, shape)`` of an analytic collider: its containing mesh in world
    coordinates at every frame, and its exact solid (None for the Cube, whose mesh is exact)."""
    times = scan.times
    keys = [_analytic_size(scan, prim, kind, t) for t in times]
    cache = {}
    for key in keys:
        if key not in cache:
            cache[key] = _analytic_mesh(kind, *key)
    meshes = [cache[key] for key in keys]
    F = meshes[0][1]
    if any(not np.array_equal(f, F) for _, f in meshes[1:]):
        raise InputError(f"the {kind}'s size changes over time so that its tessellation changes in "
                         f"{scan.where(prim)}; expected a fixed shape (give it as a Mesh with PhysicsCollisionAPI)")
    world = [_world(scan, prim, t, UsdGeom) for t in times]
    X = np.stack([V @ L + c for (V, _), (L, c) in zip(meshes, world)])
    if kind == "Cube":
        return X, F, None
    axes = {key[-1].upper() for key in keys}
    if kind != "Sphere" and len(axes) > 1:
        raise InputError(f"the {kind}'s axis changes over time ({', '.join(sorted(axes))}) in {scan.where(prim)}; "
                         f"expected a fixed axis")
    profile = np.array([_profile(kind, *key[:-1]) for key in keys], dtype=np.float64)
    transform = np.stack([np.vstack([L, c]) for L, c in world])
    shape = AnalyticShape(source=kind, axis="XYZ".index(keys[0][-1].upper()),
                          profile=_one_or_all(profile), transform=_one_or_all(transform))
    return X, F, shape


def _stored_shape(scan, prim, UsdGeom):
    """The exact solid penfree's writer kept on an obstacle prim (`SHAPE_ATTRS`), or None.

    The stored transform maps the shape into the prim's own coordinates (those of its
    points); the prim's local-to-world transform (and metersPerUnit) follows it.
    """
    attrs = {key: prim.GetAttribute(name) for key, name in SHAPE_ATTRS.items()}
    if not attrs["profile"].IsValid() or not attrs["profile"].HasValue():
        return None
    where = scan.where(prim)
    source, axis = attrs["source"].Get() if attrs["source"].IsValid() else None, \
        attrs["axis"].Get() if attrs["axis"].IsValid() else None
    if str(axis) not in ("X", "Y", "Z"):
        raise InputError(f"{SHAPE_ATTRS['axis']} must be X, Y or Z; got {axis!r} in {where}.{SHAPE_ATTRS['axis']}")
    profiles, transforms = [], []
    for t in scan.times:
        p = attrs["profile"].Get(t)
        m = attrs["transform"].Get(t) if attrs["transform"].IsValid() else None
        p = np.asarray(p if p is not None else [], dtype=np.float64)
        if p.shape != (5,):
            raise InputError(f"{SHAPE_ATTRS['profile']} must hold 5 numbers; got {p.shape} at time code {t:g} "
                             f"in {where}.{SHAPE_ATTRS['profile']}")
        if m is None:
            raise InputError(f"{SHAPE_ATTRS['transform']} (matrix4d) is missing at time code {t:g} "
                             f"in {where}.{SHAPE_ATTRS['transform']}")
        m = np.array(m, dtype=np.float64)
        L, c = _world(scan, prim, t, UsdGeom)
        if not _is_identity(L, c):
            m = m @ np.block([[L, np.zeros((3, 1))], [c, np.ones(1)]])
        profiles.append(p)
        transforms.append(np.vstack([m[:3, :3], m[3, :3]]))
    return AnalyticShape(source=str(source or "shape"), axis="XYZ".index(str(axis)),
                         profile=_one_or_all(np.stack(profiles)), transform=_one_or_all(np.stack(transforms)))


def obstacle(scan, prim, names, UsdGeom) -> Obstacle:
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
        n = _plane_normal(L, str(UsdGeom.Plane(prim).GetAxisAttr().Get()))
        if n is None:
            raise InputError(f"a Plane whose transform flattens it to a line or a point in {scan.where(prim)}; "
                             f"expected a scale that keeps both of the plane's own axes nonzero")
        return Obstacle(name, normal=n, offset=float(n @ c))
    if kind in ANALYTIC_SIZES:
        X, F, shape = _analytic(scan, prim, kind, UsdGeom)
        return Obstacle(name, positions=_one_or_all(X), faces=F, shape=shape)
    X = points(scan, prim, times, UsdGeom).astype(np.float64)
    shape = _stored_shape(scan, prim, UsdGeom)
    if prim.IsA(UsdGeom.BasisCurves):
        E, _, _ = curve_topology(scan, prim, UsdGeom, times[0])
        return Obstacle(name, positions=_one_or_all(X), edges=E, shape=shape)
    F, _ = mesh_topology(scan, prim, UsdGeom, times[0])
    return Obstacle(name, positions=_one_or_all(X), faces=F, shape=shape)
