"""Warp kernels for per-frame surface quantities: triangle area vectors and vertex normals.

All kernels are launched over ``(frames, elements)`` so one code path serves a single frame and a
batch of frames. Vertex quantities are *gathered* over the vertex→triangle CSR (no atomics), so
results are deterministic and identical on CPU and CUDA.
"""

import warp as wp

__all__ = ["triangle_area_vectors", "vertex_normals_kernel", "safe_normalize"]


@wp.func
def safe_normalize(v: wp.vec3) -> wp.vec3:
    """``v / |v|``, or the zero vector when ``|v|`` is 0 (an isolated or fully collapsed vertex)."""
    length = wp.length(v)
    if length > 0.0:
        return v / length
    return wp.vec3(0.0, 0.0, 0.0)


@wp.kernel
def triangle_area_vectors(
    points: wp.array2d(dtype=wp.vec3),
    triangles: wp.array2d(dtype=wp.int32),
    triangle_weight: wp.array(dtype=wp.float32),
    area_vectors: wp.array2d(dtype=wp.vec3),
):
    """``(p1 − p0) × (p2 − p0)`` per triangle and frame: twice the area times the unit normal.

    Ignored (degenerate-at-rest) triangles get weight 0 and so contribute nothing downstream.
    """
    f, t = wp.tid()
    p0 = points[f, triangles[t, 0]]
    p1 = points[f, triangles[t, 1]]
    p2 = points[f, triangles[t, 2]]
    area_vectors[f, t] = triangle_weight[t] * wp.cross(p1 - p0, p2 - p0)


@wp.kernel
def vertex_normals_kernel(
    area_vectors: wp.array2d(dtype=wp.vec3),
    adjacency_offsets: wp.array(dtype=wp.int32),
    adjacency_triangles: wp.array(dtype=wp.int32),
    normals: wp.array2d(dtype=wp.vec3),
):
    """Area-weighted unit vertex normal: normalised sum of incident triangles' area vectors."""
    f, v = wp.tid()
    total = wp.vec3(0.0, 0.0, 0.0)
    for k in range(adjacency_offsets[v], adjacency_offsets[v + 1]):
        total += area_vectors[f, adjacency_triangles[k]]
    normals[f, v] = safe_normalize(total)
