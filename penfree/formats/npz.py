"""NumPy ``.npz`` archives: ``positions`` (or ``vertices_seq``) ``(T, N, 3)`` plus topology.

Optional arrays: ``faces``, ``edges``, ``weights``, ``components``, 0-d
``thickness`` (hard minimum separation), ``contact_radius`` (the simulator's contact
distance), ``dt``, ``source``, ``attrs_json`` (other attributes as one JSON string), and
obstacles as ``obstacles/<name>/positions`` (or ``vertices``) with ``.../faces`` or
``.../edges``, or half-spaces ``obstacles/<name>/normal`` (3,) with ``.../offset``; a mesh
obstacle's exact analytic solid as ``obstacles/<name>/shape/{source, axis}`` (0-d strings,
axis X/Y/Z) with ``.../shape/profile`` (5,) / (T, 5) and ``.../shape/transform`` (4, 3) /
(T, 4, 3), as the HDF5 layout's ``shape`` group.
Archives are read with ``allow_pickle=False``.

>>> import numpy as np
>>> np.savez("drop.npz", vertices_seq=np.zeros((2, 3, 3)), faces=[[0, 1, 2]])  # doctest: +SKIP
>>> read_sequence("drop.npz").kind                                           # doctest: +SKIP
'triangles'
"""

from __future__ import annotations

import json
import os
import zipfile
import zlib

import numpy as np

from ..errors import FormatError, InputError
from ..sequence import OBSTACLE_FORMS, AnalyticShape, Obstacle, Sequence
from ._registry import register
from .atomic import atomic_file
from ._json import json_default

POSITION_KEYS = ("positions", "vertices_seq")


def _scalar(z, key, where):
    if key not in z:
        return None
    a = z[key]
    if a.size != 1 or a.dtype.kind not in "iuf" or not np.isfinite(a).all():
        raise InputError(f"{key} must be one finite number; got shape {a.shape} {a.dtype} in {where}:/{key}")
    return float(a.reshape(()))


def read_npz(path: str) -> Sequence:
    if not os.path.isfile(path):
        raise InputError(f"no such file: {path}")
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise FormatError(f"{path} is not a readable .npz archive ({type(exc).__name__}); expected numpy savez output") from None
    if not hasattr(z, "files"):
        raise FormatError(f"{path} holds a single array, not an .npz archive; expected positions (T, N, 3) and topology")
    with z:
        return _read(_Members(z, path), path)


#: What reading one damaged member raises: numpy (short data, bad header), zipfile (bad CRC), zlib, I/O.
MEMBER_ERRORS = (ValueError, EOFError, OSError, zipfile.BadZipFile, zlib.error)


class _Members:
    """The archive's arrays by name; a member that cannot be read is a FormatError naming it.

    ``np.load`` reads members lazily, so damage shows only when an array is read.
    """

    def __init__(self, z, path):
        self.z, self.path, self.files = z, path, z.files

    def __contains__(self, key):
        return key in self.files

    def __getitem__(self, key):
        where = f"{self.path}:/{key}"
        try:
            a = self.z[key]
        except MEMBER_ERRORS as exc:
            if isinstance(exc, ValueError) and "pickle" in str(exc):
                raise FormatError(f"{where} holds pickled objects; expected plain numeric arrays") from None
            msg = " ".join(str(exc).split())[:120]
            raise FormatError(f"cannot read array {where}: damaged .npy member ({type(exc).__name__}: {msg}); "
                              f"expected numpy savez output") from None
        if not isinstance(a, np.ndarray):  # numpy hands back the raw bytes of a member that is not .npy
            raise FormatError(f"{where} is not a .npy array (no NUMPY header); expected numpy savez output")
        return a


def _read(z, path) -> Sequence:
    key = next((k for k in POSITION_KEYS if k in z.files), None)
    if key is None:
        raise FormatError(f"missing array positions (or vertices_seq) (T, N, 3) in {path}:/positions; found {sorted(z.files)}")
    pos = z[key]
    if pos.ndim == 3 and pos.shape[-1] == 3 and pos.dtype.kind == "f":
        for s in range(pos.shape[0]):  # name the first bad frame
            if not np.isfinite(pos[s]).all():
                raise InputError(f"{key} must be finite; frame {s} holds NaN or Inf in {path}:/{key}")
    elif pos.ndim != 3 or pos.shape[-1] != 3:
        raise InputError(f"{key} must be (T, N, 3); got {pos.shape} in {path}:/{key}")
    seq = Sequence(
        positions=pos,
        edges=z["edges"] if "edges" in z.files else None,
        faces=z["faces"] if "faces" in z.files else None,
        weights=z["weights"] if "weights" in z.files else None,
        components=z["components"] if "components" in z.files else None,
        thickness=_scalar(z, "thickness", path) or 0.0,
        contact_radius=_scalar(z, "contact_radius", path) or 0.0,
        dt=_scalar(z, "dt", path),
        source=str(z["source"]) if "source" in z.files else None,
        origin=path,
    )
    if "attrs_json" in z.files:
        try:
            seq.attrs = json.loads(str(z["attrs_json"]))
        except ValueError:
            seq.attrs = None
        if not isinstance(seq.attrs, dict):
            raise FormatError(f"attrs_json must be a JSON object in {path}:/attrs_json")
    names = sorted({k.split("/")[1] for k in z.files if k.startswith("obstacles/")})
    for name in names:
        seq.obstacles.append(_read_obstacle(z, name, path))
    return seq


def _read_obstacle(z, name, path) -> Obstacle:
    p = f"obstacles/{name}/"
    keys = {k[len(p):] for k in z.files if k.startswith(p)}
    mesh = [k for k in ("positions", "vertices") if k in keys]
    shaped = any(k.startswith("shape/") for k in keys)
    if "normal" in keys and not mesh and "offset" in keys:
        if shaped:
            raise InputError(f"a half-space has no analytic shape; found arrays {p}shape/... in {path}:/{p}shape")
        return Obstacle(name, normal=z[p + "normal"], offset=_scalar(z, p + "offset", path))
    if len(mesh) != 1 or not ({"faces", "edges"} & keys):
        raise FormatError(f"obstacle {name!r} has an unknown form (arrays {sorted(keys) or 'none'}); "
                          f"expected {OBSTACLE_FORMS} in {path}:/{p[:-1]}")
    return Obstacle(
        name, z[p + mesh[0]],
        faces=z[p + "faces"] if p + "faces" in z.files else None,
        edges=z[p + "edges"] if p + "edges" in z.files else None,
        shape=_read_shape(z, p + "shape/", path) if shaped else None,
    )


def _read_shape(z, p, path) -> AnalyticShape:
    """``<p>{source, axis, profile, transform}``; values are checked by `Sequence.validate`."""
    text = {}
    for key in ("source", "axis"):
        a = z[p + key] if p + key in z else None
        if a is None or a.shape != () or a.dtype.kind != "U":
            got = "nothing" if a is None else f"{a.shape} {a.dtype}"
            raise InputError(f"shape {key} must be a 0-d string{' X, Y or Z' if key == 'axis' else ''}; "
                             f"got {got} in {path}:/{p}{key}")
        text[key] = str(a)
    if text["axis"].upper() not in ("X", "Y", "Z"):
        raise InputError(f"shape axis must be X, Y or Z; got {text['axis']!r} in {path}:/{p}axis")
    arrays = {}
    for key, one in (("profile", (5,)), ("transform", (4, 3))):
        a = z[p + key] if p + key in z else None
        if a is None or a.dtype.kind not in "iuf" or (a.shape != one and a.shape[1:] != one):
            got = "nothing" if a is None else f"{a.shape} {a.dtype}"
            raise InputError(f"shape {key} must be numeric {one} or (T, {', '.join(map(str, one))}); got {got} "
                             f"in {path}:/{p}{key}")
        arrays[key] = a
    return AnalyticShape(text["source"], "XYZ".index(text["axis"].upper()), arrays["profile"], arrays["transform"])


def write_npz(path: str, seq: Sequence, overwrite: bool = False) -> None:
    arrays = {"positions": seq.positions, "thickness": np.float64(seq.thickness or 0.0),
              "contact_radius": np.float64(seq.contact_radius or 0.0)}
    for name in ("edges", "faces", "weights", "components"):
        if getattr(seq, name) is not None:
            arrays[name] = getattr(seq, name)
    if seq.dt is not None:
        arrays["dt"] = np.float64(seq.dt)
    if seq.source is not None:
        arrays["source"] = np.str_(seq.source)
    if seq.attrs:
        arrays["attrs_json"] = np.str_(json.dumps(seq.attrs, default=json_default))
    for ob in seq.obstacles:
        if ob.is_half_space:
            arrays[f"obstacles/{ob.name}/normal"] = np.asarray(ob.normal, dtype=np.float64)
            arrays[f"obstacles/{ob.name}/offset"] = np.float64(ob.offset)
            continue
        arrays[f"obstacles/{ob.name}/positions"] = ob.positions
        for name in ("faces", "edges"):
            if getattr(ob, name) is not None and len(getattr(ob, name)):
                arrays[f"obstacles/{ob.name}/{name}"] = getattr(ob, name)
        if ob.shape is not None:
            p = f"obstacles/{ob.name}/shape/"
            arrays[p + "source"], arrays[p + "axis"] = np.str_(ob.shape.source), np.str_("XYZ"[ob.shape.axis])
            arrays[p + "profile"] = np.asarray(ob.shape.profile, dtype=np.float64)
            arrays[p + "transform"] = np.asarray(ob.shape.transform, dtype=np.float64)
    with atomic_file(path, overwrite) as tmp:
        # A file object, not a name: savez appends ".npz" to names that lack it.
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)


register("npz", (".npz",), read_npz, write_npz)
