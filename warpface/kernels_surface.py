"""Warp kernels for per-frame surface quantities: triangle area vectors and vertex normals.

Frame layout: per-frame quantities live in flat 1-D arrays, frame after frame (``frames × count``),
and kernels are launched over ``frames × count`` threads. One code path serves a single frame and a
batch, and every array is 1-D, so Warp's CPU backend compiles the contiguous-array fast path (fixed
strides, no per-thread unravelling of a 2-D launch). Vertex quantities are *gathered* over the
vertex→triangle CSR (no atomics), so results are deterministic, with the same summation order on CPU
and CUDA (the two agree to float32 rounding: their compilers fuse multiply-adds differently).
"""

import warp as wp

# Per-frame hot path: no adjoints are ever taken, and -O3 measured faster than the CPU default -O2.
wp.set_module_options({"enable_backward": False, "optimization_level": 3})

__all__ = [
    "FrameSizes",
    "frame_sizes",
    "struct_of",
    "frame_and_element",
    "incident_area_sum",
    "triangle_area_vectors",
    "stretch_reference_lengths",
    "vertex_normals_kernel",
    "safe_normalize",
]


@wp.struct
class FrameSizes:
    """A frame's vertex and triangle counts: the strides of the per-frame vertex and triangle arrays."""

    vertex_count: int
    triangle_count: int


def struct_of(kind, **fields):
    """An instance of the Warp struct ``kind`` with ``fields`` set (Warp structs take no constructor arguments)."""
    value = kind()
    for name, field in fields.items():
        setattr(value, name, field)
    return value


def frame_sizes(vertex_count: int, triangle_count: int) -> FrameSizes:
    """A :class:`FrameSizes` of a mesh with ``vertex_count`` vertices and ``triangle_count`` triangles."""
    return struct_of(FrameSizes, vertex_count=vertex_count, triangle_count=triangle_count)


@wp.func
def frame_and_element(i: int, count: int):
    """``(frame, element)`` of flat thread index ``i`` over ``frames × count``.

    Frame 0 — the whole single-frame path — takes no integer division.
    """
    if i < count:
        return 0, i
    frame = i / count
    return frame, i - frame * count


@wp.func
def safe_normalize(v: wp.vec3) -> wp.vec3:
    """``v / |v|``, or the zero vector when ``|v|`` is 0 (an isolated or fully collapsed vertex)."""
    length = wp.length(v)
    if length > 0.0:
        return v / length
    return wp.vec3(0.0, 0.0, 0.0)


@wp.func
def triangle_area_vector(points: wp.array(dtype=wp.vec3), first_vertex: int, triangle: wp.vec3i, weight: float):
    """``weight · (p1 − p0) × (p2 − p0)`` for one triangle of the frame whose points start at ``first_vertex``."""
    p0 = points[first_vertex + triangle[0]]
    return weight * wp.cross(points[first_vertex + triangle[1]] - p0, points[first_vertex + triangle[2]] - p0)


@wp.func
def incident_area_sum(
    area_vectors: wp.array(dtype=wp.vec3),
    first_triangle: int,
    adjacency_offsets: wp.array(dtype=wp.int32),
    adjacency_triangles: wp.array(dtype=wp.int32),
    v: int,
):
    """Sum of the area vectors of vertex ``v``'s incident triangles, in the frame starting at ``first_triangle``."""
    total = wp.vec3(0.0, 0.0, 0.0)
    k = adjacency_offsets[v]
    end = adjacency_offsets[v + 1]
    while k < end:  # a while loop: Warp's range() iterator costs about twice as much per entry on CPU
        total += area_vectors[first_triangle + adjacency_triangles[k]]
        k += 1
    return total


@wp.kernel
def triangle_area_vectors(
    points: wp.array(dtype=wp.vec3),
    triangles: wp.array(dtype=wp.vec3i),
    triangle_weight: wp.array(dtype=wp.float32),
    sizes: FrameSizes,
    area_vectors: wp.array(dtype=wp.vec3),
):
    """``(p1 − p0) × (p2 − p0)`` per triangle and frame: twice the area times the unit normal.

    ``points`` is (frames·V,), ``area_vectors`` (frames·T,). Ignored (degenerate-at-rest) triangles
    get weight 0 and so contribute nothing downstream.
    """
    i = wp.tid()
    f, t = frame_and_element(i, sizes.triangle_count)
    area_vectors[i] = triangle_area_vector(points, f * sizes.vertex_count, triangles[t], triangle_weight[t])


@wp.kernel
def stretch_reference_lengths(
    area_vectors: wp.array(dtype=wp.vec3),
    triangle_weight: wp.array(dtype=wp.float32),
    lengths: wp.array(dtype=wp.float32),
):
    """``|area vector|`` of counted rest triangles, the denominator of S'/S; 1 for ignored triangles.

    Ignored triangles have zero area vectors in every frame, so their ratio is 0 without a branch.
    """
    t = wp.tid()
    length = float(1.0)
    if triangle_weight[t] > 0.0:
        length = wp.length(area_vectors[t])
    lengths[t] = length


@wp.kernel
def vertex_normals_kernel(
    area_vectors: wp.array(dtype=wp.vec3),
    adjacency_offsets: wp.array(dtype=wp.int32),
    adjacency_triangles: wp.array(dtype=wp.int32),
    sizes: FrameSizes,
    normals: wp.array(dtype=wp.vec3),
):
    """Area-weighted unit vertex normal: normalised sum of incident triangles' area vectors, (frames·V,)."""
    i = wp.tid()
    f, v = frame_and_element(i, sizes.vertex_count)
    normals[i] = safe_normalize(
        incident_area_sum(area_vectors, f * sizes.triangle_count, adjacency_offsets, adjacency_triangles, v)
    )
