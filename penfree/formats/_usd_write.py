"""Writing helpers of ``usd``: standard-schema prims with time-sampled points, obstacles, the stage."""

from __future__ import annotations

import os
from contextlib import suppress

import numpy as np

from ..errors import InputError
from ._usd_stage import EXTENSIONS, POINTS64, ROLE, SHAPE_ATTRS, pxr_modules
from .atomic import atomic_file

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
    frame_codes = codes
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
    if ob.shape is not None:
        _set_shape(geom.GetPrim(), ob.shape, frame_codes, mods)


def _set_shape(prim, shape, codes, mods):
    """`shape` as `SHAPE_ATTRS` on the mesh that contains it (its points are world
    coordinates: the stored transform is the shape's own), time-sampled where it changes."""
    Gf, Sdf, Tf, Usd, UsdGeom, UsdPhysics, Vt = mods
    prim.CreateAttribute(SHAPE_ATTRS["source"], Sdf.ValueTypeNames.String, custom=True).Set(str(shape.source))
    prim.CreateAttribute(SHAPE_ATTRS["axis"], Sdf.ValueTypeNames.Token, custom=True).Set("XYZ"[shape.axis])
    profile = prim.CreateAttribute(SHAPE_ATTRS["profile"], Sdf.ValueTypeNames.DoubleArray, custom=True)
    transform = prim.CreateAttribute(SHAPE_ATTRS["transform"], Sdf.ValueTypeNames.Matrix4d, custom=True)
    P = np.asarray(shape.profile, dtype=np.float64)
    M = np.asarray(shape.transform, dtype=np.float64)
    M = np.concatenate([M, np.broadcast_to([[0.0], [0.0], [0.0], [1.0]], M.shape[:-1] + (1,))], axis=-1)  # (.., 4, 4)

    def matrix(m):
        return Gf.Matrix4d(*[float(v) for v in m.ravel()])

    if P.ndim == 1:
        profile.Set(Vt.DoubleArray([float(v) for v in P]))
    else:
        for p, t in zip(P, codes):
            profile.Set(Vt.DoubleArray([float(v) for v in p]), t)
    if M.ndim == 2:
        transform.Set(matrix(M))
    else:
        for m, t in zip(M, codes):
            transform.Set(matrix(m), t)


def _time_codes(seq) -> list:
    codes = seq.attrs.get("usd_time_codes") if isinstance(seq.attrs, dict) else None
    if isinstance(codes, (list, tuple)) and len(codes) == seq.n_frames and np.all(np.diff(codes) > 0):
        return [float(c) for c in codes]
    return [float(s) for s in range(seq.n_frames)]


def write_stage(path, seq, overwrite, shapes_to_write):
    """One stage with the given ``(prim path, positions, time codes, role)`` shapes plus `seq`'s obstacles."""
    mods = pxr_modules(path)
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


