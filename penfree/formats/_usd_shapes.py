"""Conservative triangle meshes of USD's analytic colliders (Cube, Sphere, Capsule).

A step that is safe against a mesh that *contains* the shape is safe against the
shape itself, so every tessellation here encloses its shape: the cube exactly
(8 vertices, 12 triangles), the sphere by an icosphere whose every face plane
lies at least the radius from the centre, the capsule by the convex hull of two
such icospheres. An affine transform maps containment to containment, so the
world-space mesh still encloses the world-space shape (also under non-uniform
scale). The price is a slightly larger collider: :data:`SPHERE_SUBDIVISIONS`
= 2 puts the icosphere's vertices 1.8% of the radius outside the sphere.

Pure numpy (scipy for the capsule hull); no USD import.

>>> V, F = sphere(0.5)
>>> bool((face_plane_distances(V, F) >= 0.5).all())
True
"""

from __future__ import annotations

import numpy as np

#: Icosphere subdivision level: 162 vertices, 320 faces; vertices lie at 1.018 x the
#: radius so that every face plane clears the sphere (containment, not an approximation).
SPHERE_SUBDIVISIONS = 2
#: Relative padding on top of the exact clearance, against rounding of the vertex
#: coordinates (float64 rounding is ~1e-16 relative; this is a million times more).
CLEARANCE_PAD = 1e-9


def face_plane_distances(V: np.ndarray, F: np.ndarray, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Distance from `centre` to the plane of each face, ``(K,) float64``.

    For a convex mesh around `centre` this is the radius of the largest ball at
    `centre` that each face's half-space contains.
    """
    V = np.asarray(V, dtype=np.float64) - np.asarray(centre, dtype=np.float64)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1)[:, None]
    return np.abs(np.einsum("ij,ij->i", n, a))


def _icosphere(level: int):
    t = (1.0 + 5.0 ** 0.5) / 2.0
    V = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
         (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    F = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
         (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    V = [np.array(v, dtype=np.float64) / np.linalg.norm(v) for v in V]
    for _ in range(level):
        mid, F2 = {}, []

        def midpoint(i, j):
            key = (min(i, j), max(i, j))
            if key not in mid:
                m = V[i] + V[j]
                V.append(m / np.linalg.norm(m))
                mid[key] = len(V) - 1
            return mid[key]

        for a, b, c in F:
            ab, bc, ca = midpoint(a, b), midpoint(b, c), midpoint(c, a)
            F2 += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        F = F2
    return np.array(V), np.array(F, dtype=np.int64)


def sphere(radius: float, level: int = SPHERE_SUBDIVISIONS):
    """An icosphere that contains the ball of `radius` at the origin.

    Returns
    -------
    V : (M, 3) float64
    F : (K, 3) int64
        Outward-facing triangles.
    """
    V, F = _icosphere(level)
    clearance = face_plane_distances(V, F).min()
    return V * (radius / clearance * (1.0 + CLEARANCE_PAD)), F


def cube(size: float):
    """The cube of edge `size` centred at the origin (exact: the mesh is the shape)."""
    h = 0.5 * size
    V = np.array([[x, y, z] for x in (-h, h) for y in (-h, h) for z in (-h, h)], dtype=np.float64)
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], dtype=np.int64)
    return V, F


def capsule(radius: float, height: float, axis: str = "Z", level: int = SPHERE_SUBDIVISIONS):
    """A convex mesh containing the capsule: segment of length `height` along `axis`, swept by `radius`.

    The capsule is the convex hull of the balls at the segment's ends; the hull of
    two containing icospheres contains it.
    """
    from scipy.spatial import ConvexHull

    Vs, _ = sphere(radius, level)
    k = "XYZ".index(axis.upper())
    shift = np.zeros(3)
    shift[k] = 0.5 * height
    P = np.vstack([Vs + shift, Vs - shift])
    hull = ConvexHull(P)
    used = np.unique(hull.simplices)
    remap = np.full(len(P), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return P[used], remap[hull.simplices].astype(np.int64)
