"""The validated in-memory sequence that every reader produces (SPEC section 2)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from .errors import InputError

#: Supported magnitudes: the largest |coordinate| of a scene, and the largest weight, lie in
#: [SCALE_MIN, SCALE_MAX]. Inside it, squared distances and the cubic CCD / certificate terms
#: stay normal float64 numbers; outside it a scene is refused (rescale it) rather than misjudged.
SCALE_MIN, SCALE_MAX = 1e-100, 1e100


def check_scale(a, where, name) -> None:
    """Refuse values whose largest magnitude lies outside [SCALE_MIN, SCALE_MAX] (all-zero passes)."""
    a = np.asarray(a)
    if not np.size(a):
        big = 0.0
    elif a.dtype.kind == "f":
        # max |a| without an |a| temporary (0.27 s for 64K x 100 frames): exact, NaN propagates
        big = float(np.maximum(a.max(), -a.min()))
    else:
        big = float(np.max(np.abs(a.astype(np.float64))))
    if big != 0.0 and not SCALE_MIN <= big <= SCALE_MAX:
        raise InputError(f"{name} must have its largest magnitude in the supported range [{SCALE_MIN:g}, "
                         f"{SCALE_MAX:g}]; got {big:.3g} in {where}:/{name} (rescale the scene)")


def first_nonfinite_frame(pos):
    """The first frame of ``(T, N, 3)`` `pos` holding NaN or Inf, or None.

    One frame at a time into one reused mask: a whole-array mask is a (T, N, 3) bool
    temporary (19 MB for 64K x 100 frames), and fresh memory costs more to touch than
    the test itself (90 ms against 3.5 ms on the benchmark machine, issue 13).
    """
    mask = np.empty(pos.shape[1:], dtype=np.bool_)
    for s in range(pos.shape[0]):
        if not np.isfinite(pos[s], out=mask).all():
            return s
    return None


def check_weights(w, n, where) -> np.ndarray:
    """Per-vertex fit weights: ``(n,)``, numeric, finite, >= 0, not all zero, in the supported range."""
    w = np.asarray(w)
    if w.dtype.kind not in "biuf":
        raise InputError(f"weights must be numeric; got {w.dtype} in {where}")
    w = w.astype(np.float64)
    if w.shape != (n,):
        raise InputError(f"weights must be ({n},) to match positions; got {w.shape} in {where}")
    if not np.isfinite(w).all():
        raise InputError(f"weights must be finite and >= 0; found NaN or Inf in {where}")
    if (w < 0).any():
        raise InputError(f"weights must be finite and >= 0; got min {w.min():g} in {where}")
    if not w.max() > 0:
        raise InputError(f"weights must not all be zero in {where}")
    if not SCALE_MIN <= w.max() <= SCALE_MAX:
        raise InputError(f"weights must have their largest value in the supported range [{SCALE_MIN:g}, "
                         f"{SCALE_MAX:g}]; got {w.max():.3g} in {where} (rescale them)")
    return w


#: The obstacle group forms every reader accepts (quoted in its error messages).
OBSTACLE_FORMS = ("positions or vertices (M, 3) / (T, M, 3) with faces (K, 3) or edges (K, 2); "
                  "or normal (3,) with offset (attribute or dataset)")


#: The order of an `AnalyticShape`'s profile values.
PROFILE_FIELDS = ("height", "disc_bottom", "round_bottom", "disc_top", "round_top")


@dataclass
class AnalyticShape:
    """The exact solid of an analytic collider, kept beside the mesh that contains it.

    Every analytic collider penfree reads (USD's Sphere, Capsule, Capsule_1,
    Cylinder, Cylinder_1 and Cone) is, in its local coordinates, the convex hull
    of two *rounded discs* centred on a local axis: at ``-height/2`` the disc of
    radius ``disc_bottom`` swept by a ball of radius ``round_bottom``, at
    ``+height/2`` the same with ``disc_top`` and ``round_top``. A sphere of
    radius r is ``(0, 0, r, 0, r)``, a capsule ``(h, 0, r, 0, r)``, a cylinder
    ``(h, r, 0, r, 0)``, a cone ``(h, r, 0, 0, 0)``. The world solid is the
    image under ``world = local @ L + c``.

    Attributes
    ----------
    source : str
        What the shape was in its file (``"Sphere"``, ...), for messages only.
    axis : int
        The local axis of revolution: 0, 1 or 2 (X, Y, Z).
    profile : (5,) or (T, 5) float64
        `PROFILE_FIELDS` per frame (or one row for all frames), each >= 0.
    transform : (4, 3) or (T, 4, 3) float64
        Rows 0-2 the linear part ``L`` (nonsingular), row 3 the translation ``c``.
    """

    source: str
    axis: int
    profile: np.ndarray
    transform: np.ndarray

    def at(self, s: int):
        """``(profile (5,), L (3, 3), c (3,))`` at frame `s`."""
        p = self.profile if self.profile.ndim == 1 else self.profile[s]
        m = self.transform if self.transform.ndim == 2 else self.transform[s]
        return p, m[:3], m[3]

    def take(self, frames) -> "AnalyticShape":
        """The shape over the frames `frames` (an index array or slice) of its sequence."""
        p = self.profile if self.profile.ndim == 1 else self.profile[frames]
        m = self.transform if self.transform.ndim == 2 else self.transform[frames]
        return AnalyticShape(self.source, self.axis, p, m)


@dataclass
class Obstacle:
    """A collider the scene must not enter: a mesh (kinematic or static) or a half-space.

    Attributes
    ----------
    name : str
    positions : (T, M, 3) or (M, 3) float, or None
        Mesh obstacles; static obstacles may give one frame; `frame(s)` hides the
        difference. None for a half-space.
    faces : (K, 3) int64 or None
    edges : (K, 2) int64 or None
    normal : (3,) float64 or None
        Half-space obstacles: the plane ``normal . x = offset``; the free side is
        ``normal . x > offset``.
    offset : float or None
    shape : AnalyticShape or None
        Mesh obstacles that stand for an analytic collider: its exact solid. The
        mesh is its containing tessellation; the checks use both (the solid decides
        the primitives that start between the shape and its mesh).
    """

    name: str
    positions: Optional[np.ndarray] = None
    faces: Optional[np.ndarray] = None
    edges: Optional[np.ndarray] = None
    normal: Optional[np.ndarray] = None
    offset: Optional[float] = None
    shape: Optional[AnalyticShape] = None

    @property
    def is_half_space(self) -> bool:
        return self.normal is not None

    def frame(self, s: int) -> np.ndarray:
        """Positions `(M, 3)` at frame `s` (the same array for a static obstacle; mesh obstacles only)."""
        if self.positions.ndim == 2:
            return self.positions
        return self.positions[s]


@dataclass
class Sequence:
    """`T >= 2` frames of `N` vertices plus fixed topology.

    Attributes
    ----------
    positions : (T, N, 3) float32 or float64
        Kept in the input dtype; every computation converts to float64.
    edges : (E, 2) int64 or None
        Segment topology (rods, yarn, hair, cables).
    faces : (F, 3) int64 or None
        Triangle topology (cloth, shells).
    weights : (N,) float64 or None
        Non-negative per-vertex weights of the fit (e.g. masses).
    components : (N,) int64 or None
        Object labels.
    thickness : float
        Hard minimum separation that deform guarantees and verify checks; 0 (the
        default) means intersection-free.
    contact_radius : float
        The simulator's contact / offset distance; sizes the trust-region query only,
        never a separation requirement. 0 when the file gives none.
    dt : float or None
    source : str or None
        Free text from the file (simulator, scene).
    obstacles : list of Obstacle
    origin : str
        Where the sequence came from, for error messages (a path).
    attrs : dict
        Other file attributes, carried through.
    """

    positions: np.ndarray
    edges: Optional[np.ndarray] = None
    faces: Optional[np.ndarray] = None
    weights: Optional[np.ndarray] = None
    components: Optional[np.ndarray] = None
    thickness: float = 0.0
    contact_radius: float = 0.0
    dt: Optional[float] = None
    source: Optional[str] = None
    obstacles: list = field(default_factory=list)
    origin: str = "<memory>"
    attrs: dict = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_vertices(self) -> int:
        return int(self.positions.shape[1])

    @property
    def dtype(self) -> np.dtype:
        return self.positions.dtype

    @property
    def kind(self) -> str:
        """``"triangles"``, ``"segments"`` or ``"points"`` (no topology)."""
        if self.faces is not None and len(self.faces):
            return "triangles"
        if self.edges is not None and len(self.edges):
            return "segments"
        return "points"

    def validate(self) -> "Sequence":
        """Check shapes, dtypes, finiteness and index ranges; normalise dtypes in place.

        Raises
        ------
        InputError
            One line naming ``origin``, the dataset and what was expected.
        """
        where = self.origin
        pos = np.asarray(self.positions)
        if pos.ndim != 3 or pos.shape[2] != 3:
            raise InputError(f"positions must be (T, N, 3); got {pos.shape} in {where}:/positions")
        if pos.dtype.kind == "f" and pos.dtype.itemsize in (4, 8) and not pos.dtype.isnative:
            pos = pos.astype(pos.dtype.newbyteorder("="))  # big-endian float32 stays float32
        if pos.dtype not in (np.float32, np.float64):
            if not np.issubdtype(pos.dtype, np.number) or np.iscomplexobj(pos):
                raise InputError(f"positions must be float32 or float64; got {pos.dtype} in {where}:/positions")
            pos = pos.astype(np.float64)
        if pos.shape[0] < 2:
            raise InputError(f"positions must hold at least 2 frames; got {pos.shape[0]} in {where}:/positions")
        if pos.shape[1] < 1:
            raise InputError(f"positions must hold at least 1 vertex; got 0 in {where}:/positions")
        s = first_nonfinite_frame(pos)
        if s is not None:
            raise InputError(f"positions must be finite; frame {s} holds NaN or Inf in {where}:/positions")
        self.positions = pos
        n = pos.shape[1]
        self.edges = _check_topology(self.edges, 2, n, where, "edges")
        self.faces = _check_topology(self.faces, 3, n, where, "faces")
        check_scale(pos, where, "positions")
        if self.weights is not None:
            self.weights = check_weights(self.weights, n, f"{where}:/weights")
        if self.components is not None:
            c = np.asarray(self.components)
            if c.shape != (n,) or not np.issubdtype(c.dtype, np.integer):
                raise InputError(
                    f"components must be ({n},) integer to match positions; got {c.shape} {c.dtype} in {where}:/components"
                )
            self.components = c.astype(np.int64)
        self.thickness = _distance(self.thickness, where, "thickness")
        self.contact_radius = _distance(self.contact_radius, where, "contact_radius")
        if self.dt is not None:
            try:
                dt = float(self.dt)
            except (TypeError, ValueError):
                dt = float("nan")
            if not (np.isfinite(dt) and dt > 0):
                raise InputError(f"dt must be a finite number > 0; got {self.dt!r} in {where}:@dt")
            self.dt = dt
        for ob in self.obstacles:
            _check_obstacle(ob, pos.shape[0], where)
        return self


def _check_topology(arr, k, n, where, name):
    if arr is None:
        return None
    a = np.asarray(arr)
    if a.size == 0:
        return np.zeros((0, k), dtype=np.int64)
    if a.ndim != 2 or a.shape[1] != k:
        raise InputError(f"{name} must be (M, {k}); got {a.shape} in {where}:/{name}")
    if not np.issubdtype(a.dtype, np.integer):
        if not (np.issubdtype(a.dtype, np.floating) and np.all(np.isfinite(a)) and np.all(a == np.round(a))):
            raise InputError(f"{name} must be integer indices; got {a.dtype} in {where}:/{name}")
    # before the int64 cast: report a uint64 index as given, not wrapped, and a whole float as
    # given (1e308 has no int64)
    lo, hi = a.min(), a.max()
    if lo < 0 or hi >= n:
        bad = lo if lo < 0 else hi
        bad = f"{float(bad):g}" if a.dtype.kind == "f" else int(bad)
        raise InputError(f"{name} indices must be in [0, {n - 1}] for {n} vertices; found {bad} in {where}:/{name}")
    a = a.astype(np.int64)
    if (a[:, :, None] == a[:, None, :])[:, ~np.eye(k, dtype=bool)].any():
        row = int(np.flatnonzero((a[:, :, None] == a[:, None, :])[:, ~np.eye(k, dtype=bool)].any(axis=1))[0])
        raise InputError(f"{name} must not repeat a vertex within a row; row {row} is {a[row].tolist()} in {where}:/{name}")
    return np.ascontiguousarray(a)


def _distance(value, where, name):
    """A file distance attribute: finite and >= 0 (None reads as 0)."""
    try:
        t = float(value or 0.0)
    except (TypeError, ValueError):
        t = float("nan")
    if not np.isfinite(t) or t < 0:
        raise InputError(f"{name} must be finite and >= 0; got {value!r} in {where}:@{name}")
    if t > SCALE_MAX:
        raise InputError(f"{name} must be at most {SCALE_MAX:g} (the supported range); got {t:g} in {where}:@{name}")
    return t


def check_obstacle_name(name, where: str) -> None:
    """InputError unless `name` can name an obstacle group (`where`: the file)."""
    if not isinstance(name, str) or not name or "/" in name or name in (".", ".."):
        raise InputError(f"obstacle names must be non-empty UTF-8 text without '/' (nor '.' or '..'); got "
                         f"{name!r} in {where}:/obstacles")


def _check_obstacle(ob: Obstacle, T: int, where: str):
    check_obstacle_name(ob.name, where)
    ds = f"{where}:/obstacles/{ob.name}"
    if ob.normal is not None or ob.offset is not None:
        _check_half_space(ob, ds)
        return
    if ob.positions is None:
        raise InputError(f"obstacle needs positions (or vertices) with faces or edges, or a normal (3,) "
                         f"with an offset, in {ds}")
    p = np.asarray(ob.positions)
    if p.ndim == 2 and p.shape[1] == 3:
        pass
    elif p.ndim == 3 and p.shape[2] == 3 and p.shape[0] == T:
        pass
    else:
        raise InputError(f"obstacle positions must be ({T}, M, 3) or (M, 3); got {p.shape} in {ds}/positions")
    if p.dtype.kind not in "biuf":
        raise InputError(f"obstacle positions must be numeric; got {p.dtype} in {ds}/positions")
    if not np.isfinite(p).all():
        raise InputError(f"obstacle positions must be finite in {ds}/positions")
    check_scale(p, where, f"obstacles/{ob.name}/positions")
    ob.positions = p.astype(np.float64)
    m = p.shape[-2]
    ob.faces = _check_topology(ob.faces, 3, m, where, f"obstacles/{ob.name}/faces")
    ob.edges = _check_topology(ob.edges, 2, m, where, f"obstacles/{ob.name}/edges")
    if (ob.faces is None or not len(ob.faces)) and (ob.edges is None or not len(ob.edges)):
        raise InputError(f"obstacle needs faces or edges in {ds}")
    if ob.shape is not None:
        check_shape(ob.shape, T, where, f"obstacles/{ob.name}/shape")


def check_shape(sh: AnalyticShape, T: int, where: str, name: str) -> None:
    """An analytic solid: axis 0-2, profile (5,) / (T, 5) finite and >= 0 and not all 0,
    transform (4, 3) / (T, 4, 3) finite with a nonsingular linear part."""
    ds = f"{where}:/{name}"
    if sh.axis not in (0, 1, 2):
        raise InputError(f"shape axis must be X, Y or Z; got {sh.axis!r} in {ds}")
    p = np.asarray(sh.profile)
    if p.dtype.kind not in "biuf" or p.shape not in ((5,), (T, 5)):
        raise InputError(f"shape profile must be numeric (5,) or ({T}, 5) ({', '.join(PROFILE_FIELDS)}); "
                         f"got {p.shape} {p.dtype} in {ds}/profile")
    p = p.astype(np.float64)
    if not np.isfinite(p).all() or (p < 0).any():
        raise InputError(f"shape profile must be finite and >= 0 in {ds}/profile")
    if not (p.reshape(-1, 5)[:, 1:].max(axis=1) > 0).all():
        raise InputError(f"shape profile must give a solid (a disc or rounding radius > 0) in every frame in {ds}/profile")
    check_scale(p, where, f"{name}/profile")
    m = np.asarray(sh.transform)
    if m.dtype.kind not in "biuf" or m.shape not in ((4, 3), (T, 4, 3)):
        raise InputError(f"shape transform must be numeric (4, 3) or ({T}, 4, 3) (the linear part's rows, then the "
                         f"translation); got {m.shape} {m.dtype} in {ds}/transform")
    m = m.astype(np.float64)
    if not np.isfinite(m).all():
        raise InputError(f"shape transform must be finite in {ds}/transform")
    check_scale(m, where, f"{name}/transform")
    L = m.reshape(-1, 4, 3)[:, :3]
    sv = np.linalg.svd(L, compute_uv=False)
    if not (sv[:, -1] > 1e-12 * sv[:, 0]).all():
        raise InputError(f"shape transform must have a nonsingular linear part in every frame in {ds}/transform")
    sh.profile, sh.transform = np.ascontiguousarray(p), np.ascontiguousarray(m)


def _check_half_space(ob: Obstacle, ds: str):
    """A half-space: ``normal`` (3,) finite and non-zero, ``offset`` a finite scalar, nothing else."""
    if ob.positions is not None or ob.faces is not None or ob.edges is not None or ob.shape is not None:
        raise InputError(f"obstacle must be either a mesh (positions + faces/edges) or a half-space "
                         f"(normal + offset), not both, in {ds}")
    n = np.asarray(ob.normal if ob.normal is not None else np.zeros(0))
    if n.shape != (3,) or n.dtype.kind not in "fiu" or not np.isfinite(n).all() or not np.any(n):
        raise InputError(f"half-space normal must be a finite non-zero (3,) vector; got shape {n.shape} in {ds}/normal")
    try:
        o = float(np.asarray(ob.offset).reshape(()))
    except (TypeError, ValueError):
        o = float("nan")
    if ob.offset is None or not np.isfinite(o):
        raise InputError(f"half-space offset must be a finite scalar (attribute or dataset); got {ob.offset!r} "
                         f"in {ds}/offset")
    for name, big in (("normal", float(np.max(np.abs(n.astype(np.float64))))), ("offset", abs(o))):
        if big != 0.0 and not SCALE_MIN <= big <= SCALE_MAX:  # a normal of 1e-300 overflowed the distances
            raise InputError(f"half-space {name} must have its largest magnitude in the supported range "
                             f"[{SCALE_MIN:g}, {SCALE_MAX:g}]; got {big:.3g} in {ds}/{name} (rescale it)")
    ob.normal = n.astype(np.float64)
    ob.offset = o
