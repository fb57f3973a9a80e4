"""Closest points on a triangle mesh: a BVH-backed index (``wp.Mesh``) and the one-shot :func:`closest_points`.

Candidates come from the BVH; the exact answer from :func:`~warpface.geometry.closest_point_on_triangle`
(Voronoi-region classification). Used by tracking (sparse ↔ dense correspondence) and by the FEM
(sampling surface values at the closest points of another surface).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .._validate import as_device, as_points, as_triangles
from .funcs import closest_point_on_triangle

__all__ = ["TriangleMeshIndex", "closest_points"]


@wp.func
def _candidate(points: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32), t: int, p: wp.vec3):
    """Barycentric weights of the point of triangle ``t`` closest to ``p``, and its squared distance to ``p``."""
    a = points[indices[3 * t]]
    b = points[indices[3 * t + 1]]
    c = points[indices[3 * t + 2]]
    w = closest_point_on_triangle(p, a, b, c)
    return w, wp.length_sq(p - (w[0] * a + w[1] * b + w[2] * c))


@wp.func
def _closest_point(mesh: wp.uint64, p: wp.vec3, box_center: wp.vec3, box_radius: float):
    """Closest triangle to ``p``, the barycentric weights and the distance of its closest point to ``p``:
    BVH bound → AABB candidates → exact Voronoi-region test."""
    surface = wp.mesh_get(mesh)
    # Every triangle lies within this distance of p, so it bounds the answer from above.
    bound = wp.length(p - box_center) + box_radius
    hit = wp.mesh_query_point_no_sign(mesh, p, bound * 1.001 + 1.0e-6)
    if hit.result:
        bound = wp.min(bound, wp.length(p - wp.mesh_eval_position(mesh, hit.face, hit.u, hit.v)))
    # Any triangle at least as close as the bound overlaps this box; pad for rounding.
    r = bound * 1.0001 + 1.0e-6 * box_radius + 1.0e-12
    reach = wp.vec3(r, r, r)

    best_t = int(-1)
    best_d = float(0.0)
    best_w = wp.vec3(1.0, 0.0, 0.0)
    query = wp.mesh_query_aabb(mesh, p - reach, p + reach)
    t = int(0)
    while wp.mesh_query_next(query, t):
        w, d = _candidate(surface.points, surface.indices, t, p)
        # The first candidate is always taken: no sentinel distance can reject a far query.
        if best_t < 0 or d < best_d or (d == best_d and t < best_t):
            best_d = d
            best_t = t
            best_w = w
    if best_t < 0:
        # Unreachable for valid input (the bound guarantees a candidate); exhaustive as a safety net.
        for s in range(surface.indices.shape[0] // 3):
            w, d = _candidate(surface.points, surface.indices, s, p)
            if best_t < 0 or d < best_d:
                best_d = d
                best_t = s
                best_w = w
    return best_t, best_w, wp.sqrt(best_d)


class TriangleMeshIndex:
    """A triangle mesh uploaded once with its BVH, for repeated closest-point queries.

    Coordinates are shifted to the mesh's bounding-box centre before conversion to float32, so
    precision does not depend on where the mesh sits (e.g. 0.6 m in front of a camera).

    Args:
        vertices: mesh points [m], shape (V, 3), every coordinate within ±:data:`~warpface._validate.MAX_COORDINATE`.
        triangles: vertex indices, shape (T, 3), integer, T ≥ 1.
        device: Warp device; Warp's preferred device when ``None``.

    Raises:
        ValueError: wrong shapes, non-numeric or non-integer input, non-finite or out-of-range
            coordinates, indices out of range.
    """

    def __init__(self, vertices, triangles, *, device=None):
        verts = as_points(vertices, "vertices", min_count=1)
        tri = as_triangles(triangles, verts.shape[0], "triangles")
        self.device = as_device(device)
        lo, hi = verts.min(axis=0), verts.max(axis=0)
        self.center = 0.5 * (lo + hi)
        """Coordinate shift [m], shape (3,): the bounding-box centre."""
        self.radius = float(0.5 * np.linalg.norm(hi - lo))
        """Bounding-sphere radius about :attr:`center` [m]."""
        self._vertices = wp.array((verts - self.center).astype(np.float32), dtype=wp.vec3, device=self.device)
        self._indices = wp.array(tri.reshape(-1), dtype=wp.int32, device=self.device)
        self._mesh = wp.Mesh(points=self._vertices, indices=self._indices)
        self.triangle_count = int(tri.shape[0])

    def query(self, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest point on the mesh for each of ``points`` (shape (Q, 3)); see :func:`closest_points`."""
        q = as_points(points, "query")
        if q.shape[0] == 0:
            return np.zeros(0, np.int32), np.zeros((0, 3), np.float32), np.zeros(0, np.float32)
        queries = wp.array((q - self.center).astype(np.float32), dtype=wp.vec3, device=self.device)
        bounds = (wp.vec3(0.0, 0.0, 0.0), max(self.radius, 1e-12))
        triangle, bary, dist = wp.map(_closest_point, wp.uint64(self._mesh.id), queries, *bounds, device=self.device)
        return triangle.numpy(), bary.numpy().reshape(-1, 3), dist.numpy()


def closest_points(query, vertices, triangles, *, device=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest point on a triangle mesh for every query point.

    Args:
        query: query points [m], shape (Q, 3).
        vertices: mesh points [m], shape (V, 3).
        triangles: vertex indices, shape (T, 3), integer, T ≥ 1.
        device: Warp device; Warp's preferred device when ``None``.

    All coordinates must lie within ±:data:`~warpface._validate.MAX_COORDINATE` (1e6): the search
    runs in float32.

    Returns:
        ``(triangle, barycentric, distance)``: closest triangle per query, shape (Q,), int32, always a
        valid index; barycentric coordinates of the closest point in that triangle (≥ 0, summing to
        1), shape (Q, 3), float32, so the point is ``Σ_j barycentric[:, j] · vertices[triangles[triangle, j]]``;
        distance from the query to it [m], shape (Q,), float32. Ties between triangles at exactly
        equal distance go to the lower triangle index.

    Raises:
        ValueError: wrong shapes, non-numeric or non-integer input, non-finite or out-of-range
            coordinates, or indices out of range.
    """
    return TriangleMeshIndex(vertices, triangles, device=device).query(query)
