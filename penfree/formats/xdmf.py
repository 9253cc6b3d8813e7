"""XDMF time series that ParaView animates: geometry per step, topology shared.

meshio's ``TimeSeriesWriter`` writes the geometry once and only point data per
step, so it cannot show moving vertices; this module writes the XDMF 2 XML
itself. ``out.xdmf`` holds a Temporal collection ``penfree`` of Uniform grids,
one per frame, each with its ``<Time>``, its own Geometry DataItem and the
same Topology DataItem; the arrays live in ``out.xdmf.h5`` beside it (not
``out.h5``, which is often the very input being converted). Obstacles are
further Temporal collections named ``obstacle:<name>``; half-space obstacles
(no grid to draw), thickness, contact radius, dt, source and other attributes sit in an ``<Information Name="penfree">`` JSON
element that viewers ignore; a mesh obstacle's exact analytic solid sits in an
``<Information Name="penfree_shape">`` JSON element inside its collection (``source``,
``axis`` X/Y/Z, ``profile`` 5 / T x 5 numbers, ``transform`` 4 x 3 / T x 4 x 3, as HDF5's
``shape`` group).

The reader takes these files, hand-written ones (XDMF 2 or 3 spelling; frames
in ``<Time>`` order when every grid has one, Topology ``BaseOffset`` honoured,
XY geometry padded with z = 0) and meshio TimeSeriesWriter files, whose moving
geometry must be the ``positions`` point data: a file without it (FEniCS'
``u`` / ``displacement``) is refused rather than read as a motionless scene.

>>> write_sequence("cloth.xdmf", seq)   # then File > Open cloth.xdmf in ParaView  # doctest: +SKIP
"""

from __future__ import annotations

import json
import os
import xml.etree.ElementTree as ET
from contextlib import ExitStack

import h5py
import numpy as np

from ..errors import FormatError, InputError
from ..sequence import AnalyticShape, Obstacle, Sequence
from ._registry import register
from .atomic import atomic_file
from ._json import json_default
from .hdf5 import new_h5, open_h5
from ._mesh_file import topology_from_cells

MAIN_GRID = "penfree"
OBSTACLE_PREFIX = "obstacle:"
#: Name of the Information element holding an obstacle collection's analytic shape (JSON).
SHAPE_INFO = "penfree_shape"


def heavy_path(path: str) -> str:
    """``out.xdmf`` -> ``out.xdmf.h5``, the HDF5 file holding the arrays."""
    return path + ".h5"


def _outputs(path: str) -> list:
    return [path, heavy_path(path)]


def input_files(path: str) -> list:
    """The XML and every HDF5 file its DataItems reference (``sim.h5:/data0``, relative to the XML).

    meshio's TimeSeriesWriter names its heavy data ``sim.h5`` for ``sim.xdmf``, and
    hand-written files may reference any name: each is an input that no output may replace.
    ``path.h5`` (penfree's own name) is listed too, referenced or not.
    """
    files = [path, heavy_path(path)]
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError, UnicodeDecodeError):
        return files  # the reader reports what is wrong with the file
    base = os.path.dirname(os.path.abspath(path))
    for item in root.iter("DataItem"):
        if item.get("Format") == "HDF":
            fname = (item.text or "").strip().partition(":")[0].strip()
            full = os.path.join(base, fname)
            if fname and full not in files:
                files.append(full)
    return files


# --- writing -----------------------------------------------------------------

def _data_item(parent, ref, shape, dtype):
    kind = "Float" if np.dtype(dtype).kind == "f" else "Int"
    item = ET.SubElement(parent, "DataItem", Dimensions=" ".join(map(str, shape)), NumberType=kind,
                         Precision=str(np.dtype(dtype).itemsize), Format="HDF")
    item.text = ref
    return item


def _topology(grid, h5name, f, prefix, faces, edges, n):
    if faces is not None and len(faces):
        el = ET.SubElement(grid, "Topology", TopologyType="Triangle", NumberOfElements=str(len(faces)))
        _data_item(el, f"{h5name}:/{prefix}/faces", faces.shape, np.int64)
    elif edges is not None and len(edges):
        el = ET.SubElement(grid, "Topology", TopologyType="Polyline", NodesPerElement="2",
                           NumberOfElements=str(len(edges)))
        _data_item(el, f"{h5name}:/{prefix}/edges", edges.shape, np.int64)
    else:
        el = ET.SubElement(grid, "Topology", TopologyType="Polyvertex", NumberOfElements=str(n))
        if f"{prefix}/vertices" not in f:
            f.create_dataset(f"{prefix}/vertices", data=np.arange(n, dtype=np.int64))
        _data_item(el, f"{h5name}:/{prefix}/vertices", (n,), np.int64)


def _collection(domain, f, h5name, name, prefix, positions, faces, edges, times, node_data=()):
    for key, a in (("faces", faces), ("edges", edges)):
        if a is not None and len(a):
            f.create_dataset(f"{prefix}/{key}", data=np.asarray(a, dtype=np.int64))
    for key, a in node_data:
        f.create_dataset(f"{prefix}/{key}", data=a)
    static = positions.ndim == 2
    if static:
        f.create_dataset(f"{prefix}/geometry/static", data=positions)
    coll = ET.SubElement(domain, "Grid", Name=name, GridType="Collection", CollectionType="Temporal")
    n = positions.shape[-2]
    for s, t in enumerate(times):
        grid = ET.SubElement(coll, "Grid", Name=f"{name}_{s:06d}", GridType="Uniform")
        ET.SubElement(grid, "Time", Value=repr(float(t)))
        _topology(grid, h5name, f, prefix, faces, edges, n)
        geo = ET.SubElement(grid, "Geometry", GeometryType="XYZ")
        if static:
            ref = f"{prefix}/geometry/static"
        else:
            ref = f"{prefix}/geometry/{s:06d}"
            f.create_dataset(ref, data=positions[s])
        _data_item(geo, f"{h5name}:/{ref}", (n, 3), positions.dtype)
        for key, a in node_data:
            att = ET.SubElement(grid, "Attribute", Name=key, AttributeType="Scalar", Center="Node")
            _data_item(att, f"{h5name}:/{prefix}/{key}", a.shape, a.dtype)
    return coll


def write_xdmf(path: str, seq: Sequence, overwrite: bool = False) -> None:
    h5name = os.path.basename(heavy_path(path))
    times = np.arange(seq.n_frames) * (seq.dt if seq.dt else 1.0)
    root = ET.Element("Xdmf", Version="2.0")
    domain = ET.SubElement(root, "Domain")
    info = {
        "penfree_format": 1, "thickness": seq.thickness, "contact_radius": seq.contact_radius,
        "dt": seq.dt, "source": seq.source,
        "half_spaces": [{"name": ob.name, "normal": [float(v) for v in ob.normal], "offset": float(ob.offset)}
                        for ob in seq.obstacles if ob.is_half_space],
        "attrs": seq.attrs, "extra_edges": bool(seq.faces is not None and len(seq.faces)
                                                and seq.edges is not None and len(seq.edges)),
    }
    ET.SubElement(domain, "Information", Name="penfree", Value=json.dumps(info, default=json_default))
    node_data = []
    if seq.weights is not None:
        node_data.append(("weights", np.asarray(seq.weights, dtype=np.float64)))
    if seq.components is not None:
        node_data.append(("components", np.asarray(seq.components, dtype=np.int64)))
    with ExitStack() as stack:
        # Inner context (heavy data) is renamed first, so the XML never points at nothing.
        tmp_xml = stack.enter_context(atomic_file(path, overwrite))
        tmp_h5 = stack.enter_context(atomic_file(heavy_path(path), overwrite))
        with new_h5(tmp_h5, heavy_path(path)) as f:
            _collection(domain, f, h5name, MAIN_GRID, "main", seq.positions, seq.faces, seq.edges, times, node_data)
            if info["extra_edges"]:
                f.create_dataset("main/extra_edges", data=np.asarray(seq.edges, dtype=np.int64))
            for k, ob in enumerate(seq.obstacles):
                if ob.is_half_space:  # no grid: carried in the penfree Information
                    continue
                coll = _collection(domain, f, h5name, OBSTACLE_PREFIX + ob.name, f"obstacle_{k}",
                                   np.asarray(ob.positions), ob.faces, ob.edges, times)
                if ob.shape is not None:
                    coll.insert(0, ET.Element("Information", Name=SHAPE_INFO, Value=json.dumps({
                        "source": str(ob.shape.source), "axis": "XYZ"[ob.shape.axis],
                        "profile": np.asarray(ob.shape.profile, dtype=np.float64).tolist(),
                        "transform": np.asarray(ob.shape.transform, dtype=np.float64).tolist()})))
        ET.indent(root)
        with open(tmp_xml, "w", encoding="utf-8") as fh:
            fh.write('<?xml version="1.0" ?>\n<!DOCTYPE Xdmf SYSTEM "Xdmf.dtd" []>\n')
            fh.write(ET.tostring(root, encoding="unicode"))
            fh.write("\n")


# --- reading -----------------------------------------------------------------

class _Items:
    """Reads DataItems (HDF references or inline XML), keeping HDF5 files open once."""

    def __init__(self, path, stack):
        self.path, self.stack, self.files = path, stack, {}
        self.base = os.path.dirname(os.path.abspath(path))

    def read(self, item, what):
        if item is None:
            raise FormatError(f"{what} has no DataItem in {self.path}")
        fmt = item.get("Format", "XML")
        dims = tuple(int(d) for d in item.get("Dimensions", "").split())
        text = (item.text or "").strip()
        if fmt == "HDF":
            fname, _, dset = text.partition(":")
            full = os.path.join(self.base, fname)
            if full not in self.files:
                self.files[full] = self.stack.enter_context(open_h5(full))
            obj = self.files[full].get(dset)
            if not isinstance(obj, h5py.Dataset):
                raise FormatError(f"{what} refers to a missing dataset in {fname}:{dset} (from {self.path})")
            a = obj[()]
            a = a.astype(a.dtype.newbyteorder("=")) if a.dtype.kind in "fiu" else a
        elif fmt == "XML":
            kind = item.get("NumberType", item.get("DataType", "Float"))  # XDMF 2 / XDMF 3
            prec = int(item.get("Precision", "4"))
            dtype = np.dtype(f"f{prec}") if kind == "Float" else np.dtype(f"i{prec}") if kind == "Int" else np.dtype(f"u{prec}")
            try:
                a = np.array(text.split(), dtype=dtype)
            except ValueError:
                raise FormatError(f"{what} holds non-numeric inline data in {self.path}") from None
        else:
            raise FormatError(f"{what} has DataItem Format={fmt} in {self.path}; expected HDF or XML")
        if dims and int(np.prod(dims)) != a.size:
            raise FormatError(f"{what} has {a.size} values, Dimensions says {dims} in {self.path}")
        return a.reshape(dims) if dims else a


def _grid_topology(grid, items, path):
    top = grid.find("Topology")
    if top is None:
        raise FormatError(f"grid {grid.get('Name')} has no Topology in {path}")
    kind = top.get("TopologyType", top.get("Type", ""))
    key = (kind, ET.tostring(top))
    if kind.lower() == "polyvertex":
        return key, None, None
    if kind.lower() == "triangle":
        width = 3
    elif kind.lower() == "polyline" and top.get("NodesPerElement", "2") == "2":
        width = 2
    else:
        raise FormatError(f"Topology {kind} in {path}; expected Triangle, Polyline (2 nodes) or Polyvertex")
    try:
        base = int(top.get("BaseOffset", "0"))
    except ValueError:
        raise FormatError(f"Topology BaseOffset={top.get('BaseOffset')!r} in {path}; expected an integer") from None
    # BaseOffset is the index of the first vertex (1 for 1-based connectivity).
    cells = items.read(top.find("DataItem"), "Topology").reshape(-1, width) - base
    return key, (cells if width == 2 else None), (cells if width == 3 else None)


def _grid_name(grid, s):
    return f"grid {grid.get('Name')!r}" if grid.get("Name") else f"grid {s}"


def _time_order(grids, items, path, what):
    """The grids sorted by their ``<Time>``: every grid must have one, else document order is kept."""
    times = []
    for s, grid in enumerate(grids):
        el = grid.find("Time")
        if el is None or (el.get("Value") is None and el.find("DataItem") is None):
            return grids
        if el.get("Value") is not None:
            shown = el.get("Value")
            try:
                t = float(shown)
            except ValueError:
                t = np.nan
        else:  # <Time><DataItem>0.5</DataItem></Time>
            a = items.read(el.find("DataItem"), f"Time of {_grid_name(grid, s)} of {what}")
            shown, t = str(a.tolist()), float(a.item()) if a.size == 1 else np.nan
        if not np.isfinite(t):
            raise InputError(f"Time {shown!r} of {_grid_name(grid, s)} of {what} in {path} is not a number; "
                             f"expected one finite time value per grid")
        times.append(t)
    order = sorted(range(len(grids)), key=lambda k: times[k])
    for k0, k1 in zip(order, order[1:]):
        if times[k0] == times[k1]:
            raise InputError(f"{_grid_name(grids[k0], k0)} and {_grid_name(grids[k1], k1)} of {what} have the same "
                             f"Time {times[k0]!r} in {path}; expected one grid per time value")
    return [grids[k] for k in order]


def _read_collection(coll, items, path, what, moving=False):
    """Frames ``(T, N, 3)`` (``(N, 3)`` if every grid shares one HDF5 geometry and not `moving`), edges, faces, grids."""
    grids = _time_order(coll.findall("Grid"), items, path, what)
    if not grids:
        raise FormatError(f"{what} holds no grids in {path}")
    frames, topo = [], None
    for s, grid in enumerate(grids):
        geo = grid.find("Geometry")
        # XDMF 2 says GeometryType, XDMF 3 Type: one value decides both the check and the reshape.
        gtype = None if geo is None else geo.get("GeometryType", geo.get("Type", "XYZ"))
        if gtype not in ("XYZ", "XY"):
            raise FormatError(f"{_grid_name(grid, s)} of {what} has Geometry {gtype or 'none'} in {path}; "
                              f"expected an XYZ or XY Geometry")
        width = 3 if gtype == "XYZ" else 2
        pts = items.read(geo.find("DataItem"), f"Geometry of {_grid_name(grid, s)} of {what}")
        if pts.size % width or (pts.ndim > 1 and pts.shape[-1] != width):
            raise InputError(f"Geometry {gtype} of {_grid_name(grid, s)} of {what} holds an array of shape "
                             f"{pts.shape} in {path}; expected (N, {width})")
        pts = pts.reshape(-1, width)
        if width == 2:
            pts = np.column_stack([pts, np.zeros(len(pts), pts.dtype)])
        if frames and pts.shape != frames[0].shape:
            raise InputError(f"{_grid_name(grid, s)} of {what} has {len(pts)} vertices, {_grid_name(grids[0], 0)} "
                             f"has {len(frames[0])} in {path}")
        frames.append(pts)
        key = ET.tostring(grid.find("Topology")) if grid.find("Topology") is not None else None
        if topo is None:
            topo = _grid_topology(grid, items, path)
        elif key != topo[0][1]:
            _, e, f = _grid_topology(grid, items, path)
            if not (_eq(e, topo[1]) and _eq(f, topo[2])):
                raise InputError(f"{_grid_name(grid, s)} of {what} has a different topology than "
                                 f"{_grid_name(grids[0], 0)} in {path}")
    refs = {(g.find("Geometry/DataItem").text or "").strip() for g in grids}
    if len(grids) > 1 and len(refs) == 1 and grids[0].find("Geometry/DataItem").get("Format") == "HDF":
        if moving:
            fields = sorted({a.get("Name", "?") for g in grids for a in g.findall("Attribute")})
            carried = f" (its grids carry the attributes {', '.join(fields)})" if fields else ""
            raise InputError(f"the {len(grids)} grids of {what} in {path} share one Geometry dataset {refs.pop()}, so "
                             f"the scene does not move{carried}; expected one Geometry per frame (penfree reads "
                             f"motion from the geometry)")
        return frames[0], topo[1], topo[2], grids  # a static obstacle: one dataset for every frame
    return np.stack(frames), topo[1], topo[2], grids


def _eq(a, b):
    return (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))


def read_xdmf(path: str) -> Sequence:
    try:
        return _read_xdmf(path)
    except InputError:
        raise
    except (ValueError, KeyError, AttributeError, TypeError, IndexError) as exc:
        # Hand-edited or foreign XML that the structure checks above did not anticipate.
        msg = " ".join(str(exc).split())[:120]
        raise FormatError(f"{path} is a malformed XDMF file ({type(exc).__name__}: {msg})") from None


def _read_xdmf(path: str) -> Sequence:
    if not os.path.isfile(path):
        raise InputError(f"no such file: {path}")
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError, UnicodeDecodeError) as exc:
        raise FormatError(f"{path} is not an XDMF (XML) file ({exc}); expected an Xdmf document") from None
    if root.tag != "Xdmf" or root.find("Domain") is None:
        raise FormatError(f"{path} is XML but not XDMF; expected <Xdmf><Domain>")
    domain = root.find("Domain")
    if any(el.tag.endswith("}include") for el in root.iter()):  # XInclude (2001 or 2003 namespace)
        return _read_meshio_series(path)
    colls = [g for g in domain.findall("Grid") if g.get("CollectionType") == "Temporal"]
    main = next((c for c in colls if c.get("Name") == MAIN_GRID), colls[0] if colls else None)
    if main is None:
        raise FormatError(f"{path} has no Temporal grid collection; expected one grid per frame")
    info_el = domain.find("Information[@Name='penfree']")
    info = json.loads(info_el.get("Value")) if info_el is not None else {}
    if not isinstance(info, dict) or not isinstance(info.get("attrs") or {}, dict):
        raise FormatError(f"the penfree Information element must hold a JSON object with an object 'attrs' in {path}")
    with ExitStack() as stack:
        items = _Items(path, stack)
        positions, edges, faces, grids = _read_collection(main, items, path, "the main collection", moving=True)
        seq = Sequence(positions=positions, edges=edges, faces=faces, origin=path,
                       thickness=info.get("thickness") or 0.0, contact_radius=info.get("contact_radius") or 0.0,
                       dt=info.get("dt"), source=info.get("source"),
                       attrs=info.get("attrs") or {})
        for att in grids[0].findall("Attribute"):
            if att.get("Name") in ("weights", "components"):
                setattr(seq, att.get("Name"), items.read(att.find("DataItem"), f"Attribute {att.get('Name')}"))
        if info.get("extra_edges"):
            ref = grids[0].find("Geometry/DataItem").text.strip().split(":")[0]
            item = ET.Element("DataItem", Format="HDF")
            item.text = f"{ref}:/main/extra_edges"
            seq.edges = items.read(item, "extra edges").reshape(-1, 2)
        for c in colls:
            name = c.get("Name", "")
            if c is main or not name.startswith(OBSTACLE_PREFIX):
                continue
            pos, e, f, _ = _read_collection(c, items, path, f"collection {name}")
            el = c.find(f"Information[@Name='{SHAPE_INFO}']")
            shape = None if el is None else _read_shape(el, path, f"collection {name}")
            seq.obstacles.append(Obstacle(name[len(OBSTACLE_PREFIX):], pos, faces=f, edges=e, shape=shape))
        for hs in info.get("half_spaces") or []:
            if not isinstance(hs, dict) or not {"name", "normal", "offset"} <= set(hs):
                raise FormatError(f"penfree Information half_spaces entries must be {{name, normal, offset}}; "
                                  f"got {hs!r} in {path}")
            seq.obstacles.append(Obstacle(str(hs["name"]), normal=np.asarray(hs["normal"]), offset=hs["offset"]))
    return seq


def _read_shape(el, path, what) -> AnalyticShape:
    """An obstacle collection's ``<Information Name="penfree_shape">``; values are checked by
    `Sequence.validate`."""
    where = f"the {SHAPE_INFO} Information of {what} in {path}"
    try:
        d = json.loads(el.get("Value") or "")
    except ValueError:
        d = None
    if not isinstance(d, dict) or not {"source", "axis", "profile", "transform"} <= set(d):
        raise FormatError(f"{where} must hold a JSON object {{source, axis, profile, transform}}")
    if d["axis"] not in ("X", "Y", "Z") or not isinstance(d["source"], str):
        raise InputError(f"shape axis must be X, Y or Z and source a string; got axis {d['axis']!r}, "
                         f"source {d['source']!r} in {where}")
    arrays = {}
    for key, one in (("profile", (5,)), ("transform", (4, 3))):
        try:
            a = np.asarray(d[key], dtype=np.float64)
        except (TypeError, ValueError):
            a = None
        if a is None or (a.shape != one and a.shape[1:] != one):
            raise InputError(f"shape {key} must be numbers {one} or (T, {', '.join(map(str, one))}); "
                             f"got {d[key]!r:.60} in {where}")
        arrays[key] = a
    return AnalyticShape(d["source"], "XYZ".index(d["axis"]), arrays["profile"], arrays["transform"])


def _read_meshio_series(path: str) -> Sequence:
    import meshio

    try:
        with meshio.xdmf.TimeSeriesReader(path) as reader:
            points, cells = reader.read_points_cells()
            frames, fields = [], {}
            for k in range(reader.num_steps):
                _, point_data, _ = reader.read_data(k)
                frames.append(point_data.get("positions"))
                fields.update(dict.fromkeys(point_data))
    except (Exception, SystemExit) as exc:
        raise FormatError(f"cannot read XDMF time series {path} ({type(exc).__name__}: {exc})") from None
    # The mesh written once is the reference configuration; the motion must be spelled out per step.
    if frames and all(p is None for p in frames):
        raise InputError(f"no step of the XDMF time series {path} has a point field named 'positions' (point fields: "
                         f"{', '.join(fields) or 'none'}); penfree reads the motion from 'positions' "
                         f"(positions = points + displacement) and does not guess it from other fields")
    missing = [k for k, p in enumerate(frames) if p is None]
    if missing:
        raise InputError(f"step {missing[0]} of the XDMF time series {path} has no point field 'positions' while "
                         f"other steps have one; expected 'positions' in every step")
    edges, faces = topology_from_cells(cells, len(points), path)
    return Sequence(positions=np.stack([np.asarray(p)[:, :3] for p in frames]) if frames else np.empty((0, 0, 3)),
                    faces=faces, edges=edges, origin=path)


register("xdmf", (".xdmf", ".xmf"), read_xdmf, write_xdmf, outputs=_outputs, input_files=input_files)
