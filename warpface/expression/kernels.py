"""Per-frame Warp kernels of the expression model (SPEC §1), launched over ``(frames, elements)``.

The sequence for one frame is::

    apply_muscles      x1 = x_rest + Σ K·w                      (vertices)
    triangle_stretch   area vectors of x1, S'/S                 (triangles)
    stretch_and_bulge  r, N(x1), x2 = x1 + (1/r − 1)·h·N(x1)    (vertices)
    triangle_area_vectors(x2)                                   (triangles)
    apply_wrinkles     x3 = x2 + Σ k_d·s·C(r)·N(x2)             (vertices)

Inputs come first and outputs last in every signature; nothing allocates, so the sequence can be
captured in a CUDA graph.
"""

import warp as wp

from ..kernels_surface import safe_normalize

__all__ = ["apply_muscles", "triangle_stretch", "stretch_and_bulge", "apply_wrinkles", "contraction_factor", "STRETCH_FLOOR"]

STRETCH_FLOOR = wp.constant(1.0e-4)
"""Lower bound on ``r`` before ``1/r`` in the bulge: fully collapsed skin stays finite."""


@wp.func
def contraction_factor(r: float, kr: float):
    """C(r) (SPEC eq. 5): ``(k_r − 1)·r + 1`` for r ≤ 1, ``k_r·exp((1 − 1/k_r)(r − 1))`` above, 0 there if k_r = 0."""
    if r <= 1.0:
        return (kr - 1.0) * r + 1.0
    if kr <= 0.0:
        return 0.0
    return kr * wp.exp((1.0 - 1.0 / kr) * (r - 1.0))


@wp.kernel
def apply_muscles(
    rest: wp.array(dtype=wp.vec3),
    offsets: wp.array(dtype=wp.int32),
    muscle: wp.array(dtype=wp.int32),
    weight: wp.array(dtype=wp.vec3),
    contraction: wp.array2d(dtype=wp.float32),
    muscle_points: wp.array2d(dtype=wp.vec3),
):
    """x1 = x_rest + Σ_m K_m · w_m(x_rest) over the muscles that reach the vertex."""
    f, v = wp.tid()
    x = rest[v]
    for k in range(offsets[v], offsets[v + 1]):
        x += contraction[f, muscle[k]] * weight[k]
    muscle_points[f, v] = x


@wp.kernel
def triangle_stretch(
    points: wp.array2d(dtype=wp.vec3),
    triangles: wp.array2d(dtype=wp.int32),
    triangle_weight: wp.array(dtype=wp.float32),
    rest_area_vectors: wp.array(dtype=wp.vec3),
    area_vectors: wp.array2d(dtype=wp.vec3),
    area_ratio: wp.array2d(dtype=wp.float32),
):
    """Per triangle: ``(p1 − p0) × (p2 − p0)`` and the area ratio S'/S (0 for ignored triangles)."""
    f, t = wp.tid()
    p0 = points[f, triangles[t, 0]]
    weight = triangle_weight[t]
    av = weight * wp.cross(points[f, triangles[t, 1]] - p0, points[f, triangles[t, 2]] - p0)
    area_vectors[f, t] = av
    ratio = float(0.0)
    if weight > 0.0:
        ratio = wp.length(av) / wp.length(rest_area_vectors[t])
    area_ratio[f, t] = ratio


@wp.kernel
def stretch_and_bulge(
    muscle_points: wp.array2d(dtype=wp.vec3),
    area_vectors: wp.array2d(dtype=wp.vec3),
    area_ratio: wp.array2d(dtype=wp.float32),
    counts: wp.array(dtype=wp.float32),
    adjacency_offsets: wp.array(dtype=wp.int32),
    adjacency_triangles: wp.array(dtype=wp.int32),
    thickness: wp.array(dtype=wp.float32),
    stretch: wp.array2d(dtype=wp.float32),
    bulge_points: wp.array2d(dtype=wp.vec3),
):
    """Stretch ratio r (eq. 1: mean of S'/S over incident triangles) and the bulge x1 + (1/r − 1)·h·N(x1).

    ``counts`` is the number of counted (non-degenerate) incident triangles; a vertex with none has r = 1.
    """
    f, v = wp.tid()
    ratio_sum = float(0.0)
    normal_sum = wp.vec3(0.0, 0.0, 0.0)
    for k in range(adjacency_offsets[v], adjacency_offsets[v + 1]):
        t = adjacency_triangles[k]
        normal_sum += area_vectors[f, t]
        ratio_sum += area_ratio[f, t]
    r = float(1.0)
    if counts[v] > 0.0:
        r = ratio_sum / counts[v]
    stretch[f, v] = r
    growth = 1.0 / wp.max(r, STRETCH_FLOOR) - 1.0
    bulge_points[f, v] = muscle_points[f, v] + (growth * thickness[v]) * safe_normalize(normal_sum)


@wp.kernel
def apply_wrinkles(
    bulge_points: wp.array2d(dtype=wp.vec3),
    area_vectors: wp.array2d(dtype=wp.vec3),
    adjacency_offsets: wp.array(dtype=wp.int32),
    adjacency_triangles: wp.array(dtype=wp.int32),
    stretch: wp.array2d(dtype=wp.float32),
    offsets: wp.array(dtype=wp.int32),
    wrinkle: wp.array(dtype=wp.int32),
    shape: wp.array(dtype=wp.float32),
    kr: wp.array(dtype=wp.float32),
    depth: wp.array2d(dtype=wp.float32),
    final_points: wp.array2d(dtype=wp.vec3),
):
    """x3 = x2 + Σ_w k_d·s_w·C_w(r)·N(x2), with s_w = (d/k_w − 1)·exp(−d/k_w) precomputed."""
    f, v = wp.tid()
    x = bulge_points[f, v]
    begin = offsets[v]
    end = offsets[v + 1]
    if begin == end:
        final_points[f, v] = x
        return
    normal_sum = wp.vec3(0.0, 0.0, 0.0)
    for k in range(adjacency_offsets[v], adjacency_offsets[v + 1]):
        normal_sum += area_vectors[f, adjacency_triangles[k]]
    r = stretch[f, v]
    height = float(0.0)
    for k in range(begin, end):
        w = wrinkle[k]
        height += depth[f, w] * shape[k] * contraction_factor(r, kr[w])
    final_points[f, v] = x + height * safe_normalize(normal_sum)
