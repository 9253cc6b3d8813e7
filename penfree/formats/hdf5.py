"""HDF5 layout version 1, the primary format (SPEC section 2).

``positions (T, N, 3)`` float32/float64, one frame per chunk; ``edges``,
``faces``, ``weights``, ``components``; attrs ``penfree_format``, ``dt``,
``thickness`` (hard minimum separation), ``contact_radius`` (the simulator's contact
distance; never a separation), ``source``; obstacles in ``obstacles/<name>/`` as
meshes ``{positions|vertices, faces, edges}`` or half-spaces ``{normal, offset}``; a mesh
obstacle that stands for an analytic collider keeps its exact solid in ``shape/`` (attrs
``source``, ``axis`` X/Y/Z; ``profile (5,) / (T, 5)``, ``transform (4, 3) / (T, 4, 3)``).

Errors name the file and the dataset: ``frames.h5:/positions``.

>>> from penfree.formats import read_sequence
>>> seq = read_sequence("samples/rods.h5")        # doctest: +SKIP
>>> seq.positions.shape, seq.kind                   # doctest: +SKIP
((40, 2048, 3), 'segments')
"""

from __future__ import annotations

import errno
import json
import os
from contextlib import contextmanager

import h5py
import numpy as np

from ..constants import FORMAT_VERSION
from ..errors import FormatError, InputError
from ._json import json_default
from ..sequence import (OBSTACLE_FORMS, PROFILE_FIELDS, AnalyticShape, Obstacle, Sequence, check_obstacle_name,
                        check_shape)
from ._registry import register
from .atomic import atomic_file, write_error
from .chunks import read_frames, write_positions
from .frames import StoredFrames

H5_MAGIC = b"\x89HDF\r\n\x1a\n"
#: Attributes with a meaning of their own; everything else is carried in ``Sequence.attrs``.
RESERVED_ATTRS = ("penfree_format", "dt", "thickness", "contact_radius", "source")


def has_h5_magic(path) -> bool:
    try:
        with open(path, "rb") as fh:
            return fh.read(8) == H5_MAGIC
    except OSError:
        return False


def check_readable(path) -> None:
    """InputError naming `path` when it cannot be opened for reading (permissions, ...)."""
    try:
        with open(path, "rb"):
            pass
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror or exc}") from None


@contextmanager
def open_h5(path, mode="r"):
    """``h5py.File`` with OS errors mapped to one-line InputError/FormatError naming the file."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise InputError(f"no such file: {path}")
    if os.path.isdir(path):
        raise InputError(f"{path} is a directory; expected an HDF5 file")
    check_readable(path)
    try:
        f = h5py.File(path, mode)
    except OSError as exc:
        if has_h5_magic(path):
            raise FormatError(f"{path} is a truncated or damaged HDF5 file ({_h5_reason(exc)}); expected a complete HDF5 file") from None
        raise FormatError(f"{path} is not an HDF5 file (no HDF5 signature); expected HDF5 layout v1") from None
    try:
        yield f
    except (OSError, KeyError, RuntimeError) as exc:  # damage or a dangling link found while reading
        raise FormatError(f"{path} is damaged or holds a broken link: {_h5_reason(exc)}; "
                          f"expected a complete HDF5 file") from None
    finally:
        f.close()


class _Sink:
    """The file HDF5 writes an output through (h5py's ``fileobj`` driver): positional
    reads and writes on `path`'s descriptor, until a write fails. From then on writes are
    not sent to the file and `error` keeps the first failure; HDF5 never sees one.

    After the failure HDF5 goes on (the output is lost anyway) and may read back what it
    wrote since: its metadata and heaps, which it must find intact or it may crash.
    Writes of up to `KEPT` bytes are therefore kept in memory and read back from there;
    larger ones (raw chunks of frames) are dropped and read back as zeros, which HDF5
    does not interpret.
    """

    KEPT = 1 << 16

    def __init__(self, path):
        self.fd = os.open(path, os.O_RDWR)
        self.pos = 0
        self.error = None
        self.kept = []  # (offset, bytes) written after the failure, in order

    def end(self):
        """The file's end as HDF5 wrote it: on disk, or beyond it in what was kept."""
        return max([os.fstat(self.fd).st_size] + [o + len(b) for o, b in self.kept])

    def seek(self, pos, whence=0):
        self.pos = pos if whence == 0 else self.pos + pos if whence == 1 else self.end() + pos
        return self.pos

    def tell(self):
        return self.pos

    def write(self, data):
        view = memoryview(data).cast("B")
        done = 0
        while self.error is None and done < len(view):
            try:
                n = os.pwrite(self.fd, view[done:], self.pos + done)
                if n == 0:
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                done += n
            except OSError as exc:
                self.error = exc
        if self.error is not None and len(view) <= self.KEPT:
            self.kept.append((self.pos, bytes(view)))
        self.pos += len(view)
        return len(view)

    def readinto(self, buf):
        view = memoryview(buf).cast("B")
        size = len(view)
        try:
            n = os.preadv(self.fd, [view], self.pos)
        except OSError as exc:  # what a failed write left: the run fails below
            self.error = self.error or exc
            n = 0
        view[n:] = bytes(size - n)  # past the file's end: zeros, as HDF5's own drivers read them
        for off, data in self.kept:  # what HDF5 wrote there after the failure, in order
            lo, hi = max(off, self.pos), min(off + len(data), self.pos + size)
            if lo < hi:
                view[lo - self.pos:hi - self.pos] = data[lo - off:hi - off]
        self.pos += size
        return size

    def read(self, size=-1):  # h5py takes an object with `read` for a file; its driver calls `readinto`
        buf = bytearray(size if size >= 0 else max(self.end() - self.pos, 0))
        self.readinto(buf)
        return bytes(buf)

    def truncate(self, size=None):
        size = self.pos if size is None else size
        if self.error is None:
            try:
                os.ftruncate(self.fd, size)
            except OSError as exc:
                self.error = exc
        return size

    def flush(self):
        pass  # every write went to the descriptor at once


@contextmanager
def new_h5(tmp, output):
    """``h5py.File`` writing the atomic output `output` into `tmp` (`atomic_file`'s
    temporary): a write that fails (a full disk, a quota, a file-size limit) is an
    InputError naming `output`, never a damaged file, a crash or a traceback.

    Why not ``with h5py.File(tmp, "w")``: h5py ignores errors when it closes a file or an
    object (it prints them and goes on), so a write that failed there left a truncated
    file to be renamed into place; and once a write has failed, HDF5 crashes (SIGSEGV)
    when the file or an object is closed. Here HDF5 writes through `_Sink`, which keeps
    the first failure and sends nothing more to the file, so HDF5 never sees one and
    closes cleanly. The failure is raised once the file is closed (an error the body met
    after it is its consequence), and `atomic_file` removes the temporary.
    """
    sink = _Sink(tmp)
    try:
        f = h5py.File(sink, "w")
        try:
            yield f
        except Exception:
            if sink.error is None:
                raise
        finally:
            try:
                f.close()
            except Exception:
                if sink.error is None:
                    raise
    finally:
        os.close(sink.fd)
    if sink.error is not None:
        raise write_error(os.fspath(output), sink.error)


def _h5_reason(exc) -> str:
    msg = str(exc).split("(", 1)[-1].rstrip(")") if "(" in str(exc) else str(exc)
    return " ".join(msg.split())[:160]


# --- attributes ----------------------------------------------------------------

def encode_attr(value):
    """A Python value -> something h5py stores; dicts, lists and None become ``"json:..."``."""
    if isinstance(value, (bool, np.bool_)):
        return np.bool_(value)
    if isinstance(value, str):
        return "json:" + json.dumps(value) if value.startswith("json:") else value
    if isinstance(value, (int, float, np.integer, np.floating)):
        return value
    if isinstance(value, np.ndarray) and value.dtype.kind in "biuf":
        return value
    return "json:" + json.dumps(value, default=json_default)


def _utf8(text: str) -> str:
    """`text` as UTF-8 can write it. h5py hands a stored string whose bytes are not UTF-8
    back with those bytes as lone surrogates, which no UTF-8 writer accepts: they become
    U+FFFD, as undecodable bytes do."""
    try:
        text.encode("utf-8")
        return text
    except UnicodeEncodeError:
        try:
            raw = text.encode("utf-8", "surrogateescape")  # h5py's escapes: the bytes back
        except UnicodeEncodeError:
            raw = text.encode("utf-8", "surrogatepass")
        return raw.decode("utf-8", "replace")


def decode_attr(value, where="<attribute>"):
    """The inverse of :func:`encode_attr` (numpy scalars become Python scalars).

    Raises FormatError naming `where` (``file:@name``) for a ``"json:..."`` string that is not JSON.
    """
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    if isinstance(value, str):
        value = _utf8(value)
        if not value.startswith("json:"):
            return value
        try:
            return json.loads(value[5:])
        except ValueError:
            raise FormatError(f"attribute starting with 'json:' must hold JSON; got {value[:40]!r} in {where}") from None
    if isinstance(value, np.generic):
        return value.item()
    return value


def write_attrs(obj, attrs: dict) -> None:
    for key, value in attrs.items():
        obj.attrs[key] = encode_attr(value)


def read_attrs(obj, where="") -> dict:
    return {k: decode_attr(v, f"{where}:@{k}") for k, v in obj.attrs.items()}


# --- reading -----------------------------------------------------------------

def _dataset(f, name, where, prefix=""):
    try:
        obj = f.get(name)
    except (KeyError, OSError, RuntimeError) as exc:  # dangling soft or external link
        raise FormatError(f"{prefix}{name} cannot be opened ({_h5_reason(exc)}) in {where}:/{prefix}{name}") from None
    if obj is None:
        if f.get(name, getlink=True) is not None:  # the name exists, its target does not
            raise FormatError(f"{prefix}{name} is a link to nothing in {where}:/{prefix}{name}")
        return None
    if not isinstance(obj, h5py.Dataset):
        what = "a group" if isinstance(obj, h5py.Group) else type(obj).__name__
        raise FormatError(f"{prefix}{name} must be a dataset; got {what} in {where}:/{prefix}{name}")
    return obj


def read_positions(ds, where, name="positions", window=None) -> np.ndarray:
    """Read ``(T, N, 3)`` frame by frame into one array, naming the first non-finite frame.

    `window` ``(start, stop)`` reads only those frames (`frame_window`); frame numbers in
    messages stay those of the file.
    """
    frames = StoredFrames(ds, where, name)  # shape and dtype checked; each frame checked finite
    if ds.shape[0] < 2 and name == "positions":
        raise InputError(f"positions must hold at least 2 frames; got {ds.shape[0]} in {where}:/positions")
    start, stop = frame_window(window, ds.shape[0], where)
    out = np.empty((stop - start,) + frames.shape[1:], dtype=frames.dtype)
    if not read_frames(ds, range(start, stop), out):
        for s in range(start, stop):
            out[s - start] = frames.frame(s)
        return out
    for s in range(start, stop):
        frames.check(s, out[s - start])
    return out


def frame_window(window, T, where) -> tuple:
    """``(start, stop)`` of a frame window within ``T`` frames (stop clipped to T, as a slice
    would); None is every frame. A window must hold at least 2 frames."""
    if window is None:
        return 0, T
    start, stop = int(window[0]), min(int(window[1]), T)
    if not (start >= 0 and stop - start >= 2):
        raise InputError(f"frame window {window[0]}:{window[1]} must hold at least 2 of the {T} frames of {where}")
    return start, stop


def _read_array(g, name, where, kind, prefix=""):
    full = prefix + name
    ds = _dataset(g, name, where, prefix)
    if ds is None:
        return None
    a = ds[()]
    if not isinstance(a, np.ndarray) or a.dtype.kind not in kind:
        what = {"iu": "integer", "iuf": "numeric", "f": "float"}.get(kind, kind)
        got = getattr(a, "dtype", type(a).__name__)
        raise FormatError(f"{full} must be a {what} array; got {got} in {where}:/{full}")
    return a


def _scalar_attr(attrs, key, where):
    if key not in attrs:
        return None
    value = decode_attr(attrs[key], f"{where}:@{key}")
    if isinstance(value, np.ndarray) and value.size == 1:
        value = value.reshape(()).item()
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise InputError(f"attribute {key} must be a finite number; got {value!r} in {where}:@{key}")
    return float(value)


def read_from_h5(f: h5py.File, where: str, window=None) -> Sequence:
    """The layout-v1 sequence held by an open file (not yet validated).

    `window` ``(start, stop)``: only those frames of the positions and of per-frame
    obstacles (a frame range's task of `penfree.scaleout` reads just what its steps need).
    """
    version = f.attrs.get("penfree_format")
    if version is not None:
        version = decode_attr(version, f"{where}:@penfree_format")
        if not isinstance(version, int) or isinstance(version, bool):
            raise FormatError(f"penfree_format must be an integer; got {version!r} in {where}:@penfree_format")
        if version > FORMAT_VERSION or version < 1:
            raise FormatError(
                f"unsupported penfree_format {version} in {where}:@penfree_format; this penfree reads version {FORMAT_VERSION}"
            )
    ds = _dataset(f, "positions", where)
    if ds is None:
        raise FormatError(f"missing dataset positions (T, N, 3) in {where}:/positions")
    seq = Sequence(
        positions=read_positions(ds, where, window=window),
        edges=_read_array(f, "edges", where, "iuf"),
        faces=_read_array(f, "faces", where, "iuf"),
        weights=_read_array(f, "weights", where, "iuf"),
        components=_read_array(f, "components", where, "iu"),
        origin=where,
    )
    attrs = f.attrs
    seq.thickness = _scalar_attr(attrs, "thickness", where) or 0.0
    seq.contact_radius = _scalar_attr(attrs, "contact_radius", where) or 0.0
    seq.dt = _scalar_attr(attrs, "dt", where)
    if seq.dt is not None and not seq.dt > 0:
        raise InputError(f"attribute dt must be > 0; got {seq.dt!r} in {where}:@dt")
    if "source" in attrs:
        seq.source = str(decode_attr(attrs["source"], f"{where}:@source"))
    seq.attrs = {k: decode_attr(v, f"{where}:@{k}") for k, v in attrs.items() if k not in RESERVED_ATTRS}
    obs = f.get("obstacles")
    if obs is not None:
        if not isinstance(obs, h5py.Group):
            raise FormatError(f"obstacles must be a group of obstacles/<name> groups ({OBSTACLE_FORMS}) in {where}:/obstacles")
        for name in obs:  # h5py gives a name that is not UTF-8 as bytes, which do not sort with str
            check_obstacle_name(name, where)
        for name in sorted(obs):
            seq.obstacles.append(_read_obstacle(obs[name], f"obstacles/{name}", name, where, window, ds.shape[0]))
    return seq


def _read_obstacle(g, path, name, where, window=None, T=None) -> Obstacle:
    """A mesh obstacle (positions or vertices, with faces or edges) or a half-space (normal, offset)."""
    keys = set(g) if isinstance(g, h5py.Group) else set()
    mesh = [k for k in ("positions", "vertices") if k in keys]
    if isinstance(g, h5py.Group) and "normal" in keys and not mesh:
        if "shape" in keys:
            raise InputError(f"a half-space has no analytic shape; found a shape group in {where}:/{path}/shape")
        return _read_half_space(g, path, name, where)
    if not mesh or len(mesh) > 1 or not ({"faces", "edges"} & keys):
        got = "a dataset" if not isinstance(g, h5py.Group) else f"members {sorted(keys) or 'none'}"
        raise FormatError(f"obstacle {name!r} has an unknown form ({got}); expected {OBSTACLE_FORMS} "
                          f"in {where}:/{path}")
    ds_name = f"{path}/{mesh[0]}"
    ds = _dataset(g, mesh[0], where, prefix=path + "/")
    if ds is None:  # a dangling link
        raise FormatError(f"obstacle {mesh[0]} must be a dataset (T, M, 3) or (M, 3) in {where}:/{ds_name}")
    if ds.ndim == 2:
        pos = ds[()]
        if pos.shape[-1] != 3 or pos.dtype.kind not in "fiu":
            raise FormatError(f"{ds_name} must be (T, M, 3) or (M, 3) float; got {pos.shape} {pos.dtype} in {where}:/{ds_name}")
    else:  # per frame: the sequence's window of its T frames
        if window is not None and not (ds.ndim == 3 and ds.shape[0] == T and ds.shape[2] == 3):
            # `Sequence.validate`'s message, with the file's frame count (not the window's)
            raise InputError(f"obstacle positions must be ({T}, M, 3) or (M, 3); got {ds.shape} "
                             f"in {where}:/obstacles/{name}/positions")
        pos = read_positions(ds, where, ds_name, window)
    return Obstacle(
        name=name,
        positions=pos,
        faces=_read_array(g, "faces", where, "iuf", prefix=path + "/"),
        edges=_read_array(g, "edges", where, "iuf", prefix=path + "/"),
        shape=read_shape(g, path, where, window, T) if "shape" in keys else None,
    )


#: A shape's per-frame datasets: name, the trailing shape of one frame, what that holds.
_SHAPE_DATASETS = (("profile", (5,), f"({', '.join(PROFILE_FIELDS)})"),
                   ("transform", (4, 3), "(the linear part's rows, then the translation)"))


def read_shape(g, path, where, window=None, T=None) -> AnalyticShape:
    """The `AnalyticShape` of the obstacle group `g` (``<path>/shape``); `window` slices its
    per-frame rows as `read_positions` slices frames. Values are `Sequence.validate`'s."""
    full = f"{path}/shape"
    sg = g.get("shape")
    if not isinstance(sg, h5py.Group):
        raise InputError(f"shape must be a group with attrs source, axis and datasets profile, transform "
                         f"in {where}:/{full}")
    axis = decode_attr(sg.attrs["axis"], f"{where}:/{full}:@axis") if "axis" in sg.attrs else None
    if not isinstance(axis, str) or axis.upper() not in ("X", "Y", "Z"):
        raise InputError(f"shape attribute axis must be X, Y or Z; got {axis!r} in {where}:/{full}:@axis")
    source = decode_attr(sg.attrs["source"], f"{where}:/{full}:@source") if "source" in sg.attrs else None
    if not isinstance(source, str):
        raise InputError(f"shape attribute source must be a string (e.g. Sphere); got {source!r} "
                         f"in {where}:/{full}:@source")
    values = []
    for key, one, holds in _SHAPE_DATASETS:
        ds = _dataset(sg, key, where, prefix=full + "/")
        if ds is None:
            raise InputError(f"shape needs a dataset {key} {one} or (T, {', '.join(map(str, one))}) {holds} "
                             f"in {where}:/{full}/{key}")
        if ds.dtype.kind not in "iuf" or (ds.shape != one and ds.shape[1:] != one):
            raise InputError(f"shape {key} must be numeric {one} or (T, {', '.join(map(str, one))}) {holds}; "
                             f"got {ds.shape} {ds.dtype} in {where}:/{full}/{key}")
        if ds.shape == one or window is None:
            values.append(ds[()])
            continue
        if ds.shape[0] != T:
            raise InputError(f"shape {key} must be {one} or ({T}, {', '.join(map(str, one))}) {holds}; "
                             f"got {ds.shape} in {where}:/{full}/{key}")
        start, stop = frame_window(window, T, where)
        values.append(ds[start:stop])
    return AnalyticShape(source=source, axis="XYZ".index(axis.upper()), profile=values[0], transform=values[1])


def read_whole_shape(f, name, where, T) -> AnalyticShape:
    """``obstacles/<name>/shape`` of an open file, every one of its `T` frames, checked as
    `Sequence.validate` checks it (a merge validates the sequence read in a 2-frame window,
    then takes the per-frame data whole)."""
    shape = read_shape(f[f"obstacles/{name}"], f"obstacles/{name}", where)
    check_shape(shape, T, where, f"obstacles/{name}/shape")
    return shape


def _read_half_space(g, path, name, where) -> Obstacle:
    normal = _read_array(g, "normal", where, "iuf", prefix=path + "/")
    if "offset" in g:
        ds = _dataset(g, "offset", where, prefix=path + "/")
        if ds is None:
            raise FormatError(f"half-space offset must be a dataset or an attribute in {where}:/{path}/offset")
        offset = ds[()]
        if np.asarray(offset).dtype.kind not in "iuf":
            raise FormatError(f"half-space offset must be a number; got {np.asarray(offset).dtype} "
                              f"in {where}:/{path}/offset")
    elif "offset" in g.attrs:
        offset = decode_attr(g.attrs["offset"])
    else:
        raise FormatError(f"half-space obstacle {name!r} needs an offset (attribute or dataset) next to its "
                          f"normal in {where}:/{path}/offset")
    if np.size(offset) != 1:
        raise FormatError(f"half-space offset must be a scalar; got shape {np.shape(offset)} in {where}:/{path}/offset")
    try:
        offset = float(np.asarray(offset).reshape(()))
    except (TypeError, ValueError):
        raise FormatError(f"half-space offset must be a number; got {offset!r} in {where}:/{path}/offset") from None
    return Obstacle(name=name, normal=np.asarray(normal), offset=offset)


def read_hdf5(path: str, frame_window=None) -> Sequence:
    """Read a layout-v1 file; `frame_window` ``(start, stop)`` reads only those frames."""
    with open_h5(path) as f:
        return read_from_h5(f, path, frame_window)


# --- writing -----------------------------------------------------------------

def write_to_h5(f: h5py.File, seq: Sequence) -> None:
    """Write `seq` as layout v1 into an open, empty file (the frames' chunks copied from
    the file `seq` was read from where they hold the same frames: `write_positions`)."""
    write_positions(f, "positions", seq.positions, source=seq.origin)
    for name in ("edges", "faces", "components"):
        a = getattr(seq, name)
        if a is not None:
            f.create_dataset(name, data=np.asarray(a, dtype=np.int64))
    if seq.weights is not None:
        f.create_dataset("weights", data=np.asarray(seq.weights, dtype=np.float64))
    write_attrs(f, {k: v for k, v in seq.attrs.items() if k not in RESERVED_ATTRS})
    f.attrs["penfree_format"] = FORMAT_VERSION
    f.attrs["thickness"] = float(seq.thickness or 0.0)
    f.attrs["contact_radius"] = float(seq.contact_radius or 0.0)
    if seq.dt is not None:
        f.attrs["dt"] = float(seq.dt)
    if seq.source is not None:
        f.attrs["source"] = str(seq.source)
    for ob in seq.obstacles:
        g = f.create_group(f"obstacles/{ob.name}")
        if ob.is_half_space:
            g.create_dataset("normal", data=np.asarray(ob.normal, dtype=np.float64))
            g.attrs["offset"] = float(ob.offset)
            continue
        if np.ndim(ob.positions) == 3:
            write_positions(g, "positions", ob.positions)
        else:
            g.create_dataset("positions", data=np.asarray(ob.positions))
        for name in ("faces", "edges"):
            a = getattr(ob, name)
            if a is not None and len(a):
                g.create_dataset(name, data=np.asarray(a, dtype=np.int64))
        if ob.shape is not None:
            sg = g.create_group("shape")
            sg.attrs["source"] = encode_attr(str(ob.shape.source))
            sg.attrs["axis"] = "XYZ"[ob.shape.axis]
            sg.create_dataset("profile", data=np.asarray(ob.shape.profile, dtype=np.float64))
            sg.create_dataset("transform", data=np.asarray(ob.shape.transform, dtype=np.float64))


def write_hdf5(path: str, seq: Sequence, overwrite: bool = False) -> None:
    with atomic_file(path, overwrite) as tmp:
        with new_h5(tmp, path) as f:
            write_to_h5(f, seq)


def _sniff(path: str, writing: bool = False) -> bool:
    # Content wins over the name for existing inputs (an HDF5 file called frames.dat).
    return not writing and os.path.isfile(path) and has_h5_magic(path)


register("hdf5", (".h5", ".hdf5", ".he5"), read_hdf5, write_hdf5, sniff=_sniff, options=("frame_window",))
