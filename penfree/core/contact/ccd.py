"""Conservative continuous collision detection (narrow phase), one function per pair.

Method
------
Inclusion-based branch and bound on the contact function, in the spirit of
Tight Inclusion (Wang et al. 2021), with a proven floating-point error bound
and a convex-hull exclusion test. For linear motion, the vector between the
two parametrised points,

    edge-edge:    F(t, u, v) = ea(t, u) - eb(t, v),        (t, u, v) in [0, t_max] x [0, 1]^2
    vertex-face:  F(t, u, v) = p(t) - f(t, u, v),          u, v >= 0, u + v <= 1

is multilinear in (t, u, v), so its exact image over a box is the convex hull
of its 8 corner values. The primitives come within `thickness` at some time
iff |F| <= thickness somewhere in the domain. Starting from the whole domain,
boxes are searched depth first, earlier time half first; a box is discarded
only when its corner hull, widened by a proven bound on the rounding of the
corners, lies farther than `thickness` from the origin along one of five
directions (the three axes, the hull's centroid, the geometric normal at the
box's mid-time). Otherwise it is split in the dimension along which F varies
most. Once a contact box is found, the boxes left that start earlier are
split in time only, to raise the lower bound of the time of impact.

Guarantees
----------
- No false negatives, in floating point. Every corner value is computed from
  the float64 inputs by at most ~20 rounded operations on numbers of
  magnitude <= 6 M (M the largest coordinate magnitude of the query); the
  error is below 56 u M (u = 2^-53), bounded by `CCD_ERR_REL * M` (128 u M)
  plus `CCD_ERR_ABS` for underflow. The directional test adds the rounding
  of the dot product and of the norm (see `ccd_kernels._dir_margin`). Box
  bounds are dyadic and split exactly at midpoints; the test ``u + v > 1``
  uses the monotonicity of rounding. A query is reported collision-free only
  when every box has been discarded by such a proven inequality.
- `toi` is a lower bound of the earliest time at which the closed primitives
  are within `thickness` (0 if they already are at t = 0): every point of
  contact lies in a box that was not discarded, and toi is the smallest start
  time of those (boxes starting after the current bound are dropped since
  they cannot lower it). `toi = inf` where no hit. Its accuracy is
  `CCD_TOI_TOL * t_max` when the contact is well separated from other
  near-contacts.
- False positives are bounded: a hit is reported either when a box whose
  image is narrower than `tol = max(CCD_TOL_REL * extent, 4 err)` and whose
  time span is at most `CCD_TOI_TOL * t_max` cannot be discarded (then the
  primitives are within ``sqrt(3) (thickness + tol + 2 err)`` at the box's
  start time, returned as `witness` by `ccd_details`; extent is the largest
  side of the bounding box of the 8 input points), or
  when `CCD_MAX_BOXES` boxes have been examined (or a box can no longer be
  split in floating point, or a coordinate exceeds 1e150) without a decision
  (status `BUDGET`; rare; a conservative hit).
- Exact decision for thickness 0 (``exact=True``, the default): the queries
  the float kernel flags (near-misses closer than its tolerance, and real
  contacts) are decided exactly in rational arithmetic by `ccd_exact`
  (roots of the coplanarity cubic isolated with Sturm sequences, exact sign
  tests at those roots). The float64 inputs are exact rationals, so the
  answer is exact: on the Wang et al. 2021 handcrafted benchmark and the IPC
  Toolkit cases it has no false negatives and no false positives. It costs
  a few milliseconds per flagged query (Python), and only flagged queries pay;
  at most `CCD_MAX_EXACT` per call are decided exactly, the others stay
  flagged (conservative).
  With thickness > 0 the float verdict stands (false positives bounded as above).

Notes
-----
Assumes straight-line motion between x_t0 and x_t1 (each vertex moves at
constant velocity over [0, t_max]); the primitives are closed (an endpoint or
a triangle edge touching counts). Distances are Euclidean; the discarding test
is rigorous for the Euclidean distance because it bounds a projection of F.
"""

import numpy as np

from ...constants import CCD_MAX_EXACT, REDUCTION_CHUNKS
from ...errors import InputError
from .ccd_exact import exact_edge_edge, exact_vertex_face
from .ccd_kernels import BUDGET, CLOSE, SEPARATED, ccd_batch, ccd_batch_indexed

__all__ = ["ccd_edge_edge", "ccd_vertex_face", "ccd_details", "ccd_indexed", "SEPARATED", "CLOSE", "BUDGET"]


def _as_queries(x, name):
    a = np.asarray(x)
    if a.ndim == 2 and a.shape == (4, 3):
        a = a[None]
    if a.ndim != 3 or a.shape[1:] != (4, 3):
        raise InputError(f"{name} must be (Q, 4, 3); got {a.shape}")
    if not np.issubdtype(a.dtype, np.number):
        raise InputError(f"{name} must be numeric; got {a.dtype}")
    a = np.ascontiguousarray(a, dtype=np.float64)
    if not np.isfinite(a).all():
        raise InputError(f"{name} must be finite; found NaN or Inf")
    return a


def ccd_details(x_t0, x_t1, kind, thickness=0.0, *, t_max=1.0, exact=True):
    """Run the CCD of `kind` ("ee" or "vf"); returns (status, toi, sep, witness).

    Parameters
    ----------
    x_t0, x_t1 : (Q, 4, 3) float
        Rows ea0, ea1, eb0, eb1 (``"ee"``) or p, f0, f1, f2 (``"vf"``).
    kind : {"ee", "vf"}
    thickness : float >= 0
    t_max : float in (0, 1]
        Only [0, t_max] of the motion x_t0 -> x_t1 is checked.
    exact : bool
        With thickness 0, decide the flagged queries exactly (`ccd_exact`).

    Returns
    -------
    status : (Q,) int8
        `SEPARATED` (0, certified no contact), `CLOSE` (1, within the
        tolerance at toi) or `BUDGET` (2, undecided, a conservative hit).
    toi : (Q,) float64
        Lower bound of the earliest contact time; inf where status is 0.
    sep : (Q,) float64
        Where status is 0: a certified lower bound of the distance between
        the primitives over [0, t_max] (>= thickness; 0 when the separation
        was proven by the exact path, which gives no distance); 0 elsewhere.
    witness : (Q,) float64
        Where status is `CLOSE`: a time at which the primitives are within
        ``sqrt(3) (thickness + tol + 2 err)`` (see the module docstring); NaN elsewhere.
    """
    if kind not in ("ee", "vf"):
        raise InputError(f"kind must be 'ee' or 'vf'; got {kind!r}")
    a = _as_queries(x_t0, "x_t0")
    b = _as_queries(x_t1, "x_t1")
    if a.shape != b.shape:
        raise InputError(f"x_t0 and x_t1 must have the same shape; got {a.shape} and {b.shape}")
    thickness = float(thickness)
    if not (np.isfinite(thickness) and thickness >= 0.0):
        raise InputError(f"thickness must be finite and >= 0; got {thickness!r}")
    t_max = float(t_max)
    if not (0.0 < t_max <= 1.0):
        raise InputError(f"t_max must be in (0, 1]; got {t_max!r}")
    q = a.shape[0]
    if q == 0:
        return np.zeros(0, np.int8), np.zeros(0), np.zeros(0), np.zeros(0)
    n_chunks = max(1, min(q, REDUCTION_CHUNKS))
    status, toi, sep, witness = ccd_batch(a, b, kind == "vf", thickness, t_max, n_chunks)
    if exact and thickness == 0.0:
        decide = exact_vertex_face if kind == "vf" else exact_edge_edge
        for i in np.flatnonzero(status != SEPARATED)[:CCD_MAX_EXACT]:
            if not decide(a[i], b[i], t_max):
                status[i], toi[i], sep[i], witness[i] = SEPARATED, np.inf, 0.0, np.nan
    return status, toi, sep, witness


def ccd_indexed(V_t0, V_t1, idx, kind, thickness=0.0, *, exact=True):
    """`ccd_details` on queries given by vertex indices (no (Q, 4, 3) copies).

    Parameters
    ----------
    V_t0, V_t1 : (N, 3) float64, C-contiguous
        Validated positions (callers inside penfree validate once).
    idx : (Q, 4) int64
        Rows ea0, ea1, eb0, eb1 (``"ee"``) or p, f0, f1, f2 (``"vf"``), indices into V.
    kind : {"ee", "vf"}
    thickness : float >= 0
    exact : bool

    Returns
    -------
    status, toi, sep, witness : (Q,) arrays as in `ccd_details` (t_max = 1).
    """
    V_t0 = np.ascontiguousarray(V_t0, dtype=np.float64)
    V_t1 = np.ascontiguousarray(V_t1, dtype=np.float64)
    idx = np.ascontiguousarray(idx, dtype=np.int64)
    q = idx.shape[0]
    if q == 0:
        return np.zeros(0, np.int8), np.zeros(0), np.zeros(0), np.zeros(0)
    status, toi, sep, witness = ccd_batch_indexed(
        V_t0, V_t1, idx, kind == "vf", float(thickness), 1.0, max(1, min(q, REDUCTION_CHUNKS)))
    if exact and thickness == 0.0:
        decide = exact_vertex_face if kind == "vf" else exact_edge_edge
        for i in np.flatnonzero(status != SEPARATED)[:CCD_MAX_EXACT]:
            if not decide(V_t0[idx[i]], V_t1[idx[i]], 1.0):
                status[i], toi[i], sep[i], witness[i] = SEPARATED, np.inf, 0.0, np.nan
    return status, toi, sep, witness


def ccd_edge_edge(x_t0, x_t1, thickness=0.0, *, t_max=1.0, exact=True):
    """Conservative edge-edge CCD over a batch of queries.

    Parameters
    ----------
    x_t0, x_t1 : (Q, 4, 3) float
        Rows ea0, ea1, eb0, eb1 at t = 0 and t = 1 (a single (4, 3) query is
        accepted); converted to float64.
    thickness : float, default 0
        Contact distance: a hit is any time the closed segments are within it.
    t_max : float in (0, 1], keyword-only, default 1
        Check only [0, t_max] of the motion.
    exact : bool, keyword-only, default True
        With thickness 0, decide flagged queries exactly (no false positives
        either); False keeps the float verdict (faster on many contacts).

    Returns
    -------
    hit : (Q,) bool
        False only when no contact is proven (never a false negative).
    toi : (Q,) float64
        Lower bound of the earliest time of contact (0 if already within
        `thickness` at t = 0); inf where `hit` is False.

    Notes
    -----
    See the module docstring for the method and its guarantees. With
    thickness > 0 (or ``exact=False``), near-misses closer than about 1e-10
    of the query's extent may be reported as hits.

    Examples
    --------
    >>> import numpy as np
    >>> x0 = np.array([[-1, 0, 1], [1, 0, 1], [0, -1, -1], [0, 1, -1.0]])
    >>> x1 = x0.copy(); x1[:2, 2] = -2.0
    >>> hit, toi = ccd_edge_edge(x0[None], x1[None])
    >>> bool(hit[0]), bool(toi[0] <= 2 / 3)
    (True, True)
    """
    status, toi, _, _ = ccd_details(x_t0, x_t1, "ee", thickness, t_max=t_max, exact=exact)
    return status != SEPARATED, toi


def ccd_vertex_face(x_t0, x_t1, thickness=0.0, *, t_max=1.0, exact=True):
    """Conservative vertex-face (point-triangle) CCD over a batch of queries.

    Parameters
    ----------
    x_t0, x_t1 : (Q, 4, 3) float
        Rows p, f0, f1, f2 at t = 0 and t = 1 (a single (4, 3) query is
        accepted); converted to float64.
    thickness : float, default 0
    t_max : float in (0, 1], keyword-only, default 1
    exact : bool, keyword-only, default True

    Returns
    -------
    hit : (Q,) bool
    toi : (Q,) float64
        Lower bound of the earliest contact time; inf where `hit` is False.

    Notes
    -----
    Same method and guarantees as `ccd_edge_edge`; the triangle is closed
    (its edges and corners count) and may be degenerate.

    Examples
    --------
    >>> import numpy as np
    >>> x0 = np.array([[0.2, 0.2, 1], [0, 0, 0], [1, 0, 0], [0, 1, 0.0]])
    >>> x1 = x0.copy(); x1[0, 2] = -1.0
    >>> hit, toi = ccd_vertex_face(x0, x1)
    >>> bool(hit[0]), bool(0.499 < toi[0] <= 0.5)
    (True, True)
    """
    status, toi, _, _ = ccd_details(x_t0, x_t1, "vf", thickness, t_max=t_max, exact=exact)
    return status != SEPARATED, toi
