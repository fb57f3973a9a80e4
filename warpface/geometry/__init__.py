"""Shared surface math, written once for every part of warpface.

* :mod:`~warpface.geometry.funcs` — ``@wp.func`` closest point on a segment and on a triangle
  (generic over float32/float64), smoothstep.
* :mod:`~warpface.geometry.ramps` — :func:`smooth_ramp`, the NumPy smoothstep over arrays.
* :mod:`~warpface.geometry.mesh_index` — :class:`TriangleMeshIndex` (BVH) and :func:`closest_points`.
* :mod:`~warpface.geometry.triangles` — NumPy triangle corners, areas, unit normals and area-weighted
  vertex normals, taking optional precomputed inputs (the cross products they share are in that module).
* :mod:`~warpface.geometry.surface_checks` — boundary loops and self-intersections of a closed surface.
* :mod:`~warpface.geometry.bounds` — a BVH over padded float32 boxes of float64 triangles or tets.
"""

from .funcs import closest_point_on_segment, closest_point_on_triangle, smoothstep
from .mesh_index import TriangleMeshIndex, closest_points
from .ramps import smooth_ramp
from .triangles import (
    area_weighted_vertex_normals,
    triangle_areas,
    triangle_corners,
    triangle_normals,
)

__all__ = [
    "closest_point_on_segment",
    "closest_point_on_triangle",
    "smoothstep",
    "smooth_ramp",
    "TriangleMeshIndex",
    "closest_points",
    "triangle_corners",
    "triangle_areas",
    "triangle_normals",
    "area_weighted_vertex_normals",
]
