"""Shared surface math, written once for every part of warpface.

* :mod:`~warpface.geometry.funcs` — ``@wp.func`` closest point on a segment and on a triangle
  (generic over float32/float64), smoothstep.
* :mod:`~warpface.geometry.mesh_index` — :class:`TriangleMeshIndex` (BVH) and :func:`closest_points`.
* :mod:`~warpface.geometry.triangles` — NumPy triangle cross products, areas, unit normals and
  area-weighted vertex normals, taking optional precomputed inputs.
"""

from .funcs import closest_point_on_segment, closest_point_on_triangle, smoothstep, vec3_any
from .mesh_index import TriangleMeshIndex, closest_points
from .triangles import (
    area_weighted_vertex_normals,
    triangle_areas,
    triangle_corners,
    triangle_crosses,
    triangle_normals,
)

__all__ = [
    "closest_point_on_segment",
    "closest_point_on_triangle",
    "smoothstep",
    "vec3_any",
    "TriangleMeshIndex",
    "closest_points",
    "triangle_corners",
    "triangle_crosses",
    "triangle_areas",
    "triangle_normals",
    "area_weighted_vertex_normals",
]
