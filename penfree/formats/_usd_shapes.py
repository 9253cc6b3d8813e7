"""Conservative triangle meshes of USD's analytic colliders (Cube, Sphere, Capsule, Cylinder, Cone).

A step that is safe against a mesh that *contains* the shape is safe against the
shape itself, so every tessellation here encloses its shape: the cube exactly
(8 vertices, 12 triangles), the sphere by an icosphere whose every face plane
lies at least the radius from the centre, the capsule by the convex hull of two
such icospheres (of two radii for ``Capsule_1``), the cylinder, cone and frustum
(``Cylinder_1``) by the hull of regular polygons that circumscribe their end
circles. An affine transform maps containment to containment, so the
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
#: Sides of the regular polygons circumscribing a cylinder's or cone's end circles: their
#: corners lie 0.5% of the radius outside the circle.
RING_SIDES = 32


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


def capsule(radius: float, height: float, axis: str = "Z", level: int = SPHERE_SUBDIVISIONS,
            radius_top: float | None = None):
    """A convex mesh containing the capsule: segment of length `height` along `axis`, swept by `radius`.

    The capsule is the convex hull of the balls at the segment's ends (radius
    `radius_top` at the +axis end when given, as ``Capsule_1``'s radiusTop); the
    hull of two containing icospheres contains it.
    """
    from scipy.spatial import ConvexHull

    Vs, _ = sphere(1.0, level)
    k = "XYZ".index(axis.upper())
    shift = np.zeros(3)
    shift[k] = 0.5 * height
    top = radius if radius_top is None else radius_top
    P = np.vstack([Vs * top + shift, Vs * radius - shift])
    hull = ConvexHull(P)
    used = np.unique(hull.simplices)
    remap = np.full(len(P), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return P[used], remap[hull.simplices].astype(np.int64)


def frustum(radius_bottom: float, radius_top: float, height: float, axis: str = "Z", sides: int = RING_SIDES):
    """A convex mesh containing a cylinder (equal radii), a cone (`radius_top` 0) or a frustum.

    The shape is the convex hull of its end discs, at ``-height/2`` (`radius_bottom`)
    and ``+height/2`` (`radius_top`) along `axis`. Each end becomes a regular polygon
    of `sides` sides whose edges touch the circle (apothem = radius), so the hull of
    the polygons contains the hull of the discs; an end of radius 0 is one vertex (the
    apex). Outward-facing triangles, a fixed topology for given zero/non-zero radii.
    """
    k = "XYZ".index(axis.upper())
    u, v = (k + 1) % 3, (k + 2) % 3  # e_u x e_v = e_k: the rings turn anticlockwise about +axis
    theta = 2.0 * np.pi * np.arange(sides) / sides
    corner = (1.0 + CLEARANCE_PAD) / np.cos(np.pi / sides)

    def ring(radius, z):
        if radius == 0.0:
            P = np.zeros((1, 3))
        else:
            P = np.zeros((sides, 3))
            P[:, u], P[:, v] = radius * corner * np.cos(theta), radius * corner * np.sin(theta)
        P[:, k] = z
        return P

    bottom, top = ring(radius_bottom, -0.5 * height), ring(radius_top, 0.5 * height)
    nb = len(bottom)
    i = np.arange(sides)
    j = (i + 1) % sides
    F = []
    if nb > 1 and len(top) > 1:
        F += [np.c_[i, j, nb + j], np.c_[i, nb + j, nb + i]]
    elif nb > 1:
        F.append(np.c_[i, j, np.full(sides, nb)])
    else:
        F.append(np.c_[np.zeros(sides, np.int64), 1 + j, 1 + i])
    fan = np.arange(1, sides - 1)
    if nb > 1:
        F.append(np.c_[np.zeros(sides - 2, np.int64), fan + 1, fan])
    if len(top) > 1:
        F.append(np.c_[np.full(sides - 2, nb), nb + fan, nb + fan + 1])
    return np.vstack([bottom, top]), np.vstack(F).astype(np.int64)
