"""The expression frame (SPEC §1) in two fused Warp kernels, launched over ``frames × vertices``.

The five-kernel sequence of :mod:`warpface.expression.kernels` writes every intermediate (muscle
points, per-triangle stretch terms, per-triangle area vectors) to memory and reads it back in the
next launch. On a GPU a ~10k-vertex frame is then bound by launch latency, and a large one by the
bytes of those intermediates. Here a frame is two launches::

    muscles_and_bulge   x1 of the vertex and of its one-ring (jaw, then muscles, recomputed per
                        incident triangle instead of stored), the incident triangles' area vectors
                        and S'/S, r, N(x1), x2 = x1 + (1/r − 1)·h·N(x1)          → r, x2
    wrinkles_on_bulge   N(x2) from the incident triangles of x2 (computed in place), x3 = x2 +
                        Σ k_d·s·C(r)·N(x2); vertices without a furrow copy x2  → x3

A wrinkle needs N(x2), which needs x2 of the one-ring and so x1 of the two-ring: that dependency is
the one launch boundary kept. A three-launch plan stores x1 instead of recomputing it (the muscle
kernel of :mod:`~warpface.expression.kernels`, then :data:`bulge_from_muscle_points`, then the
wrinkles): one launch more, shorter chains of dependent loads per thread. Every value is computed with the same operations in the same order as
the five-kernel sequence, so the two paths agree bit for bit on the same device.

``jaw_first`` < 0 means the rig has no jaw (its arrays are then not read). With
``frames_per_thread`` = G > 1 one thread evaluates the same vertex in G consecutive frames, so the
rig data a vertex reads (its CSR rows, rest point, weights) is fetched once per G frames: the launch
is then over ``ceil(frames / G) × vertices`` threads.
"""

import warp as wp

from ..kernels_surface import safe_normalize, triangle_area_vector
from .kernels import STRETCH_FLOOR, MuscleEntry, WrinkleEntry, add_muscles, contraction_factor

# Per-frame hot path: no adjoints are ever taken, and -O3 measured faster than the CPU default -O2.
wp.set_module_options({"enable_backward": False, "optimization_level": 3})

__all__ = ["muscles_and_bulge", "bulge_from_muscle_points", "wrinkles_on_bulge", "muscle_point"]


@wp.func
def jaw_motion(controls: wp.array(dtype=wp.float32), first: int, jaw_first: int, hinge_axis: wp.vec3, forward: wp.vec3):
    """The frame's jaw rotation (about ``hinge_axis`` by θ) and slide (protrusion, lateral)."""
    rotation = wp.quat_from_axis_angle(hinge_axis, controls[first + jaw_first])
    slide = controls[first + jaw_first + 1] * forward + controls[first + jaw_first + 2] * hinge_axis
    return rotation, slide


@wp.func
def muscle_point(
    u: int,
    rest: wp.array(dtype=wp.vec3),
    jaw_weight: wp.array(dtype=wp.float32),
    jaw_first: int,
    pivot: wp.vec3,
    rotation: wp.quat,
    slide: wp.vec3,
    offsets: wp.array(dtype=wp.int32),
    entries: wp.array(dtype=MuscleEntry),
    controls: wp.array(dtype=wp.float32),
    first: int,
):
    """x1 of vertex ``u``: the jaw's rigid motion blended by its weight (SPEC §6.2), then Σ_m K_m·w_m."""
    x = rest[u]
    if jaw_first >= 0:
        w = jaw_weight[u]
        if w > 0.0:
            moved = wp.quat_rotate(rotation, x - pivot) + pivot + slide
            x = x + w * (moved - x)
    return add_muscles(x, controls, first, offsets, entries, u)


@wp.kernel
def muscles_and_bulge(
    rest: wp.array(dtype=wp.vec3),
    jaw_weight: wp.array(dtype=wp.float32),
    pivot: wp.vec3,
    hinge_axis: wp.vec3,
    forward: wp.vec3,
    jaw_first: int,
    muscle_offsets: wp.array(dtype=wp.int32),
    muscle_entries: wp.array(dtype=MuscleEntry),
    controls: wp.array(dtype=wp.float32),
    control_count: int,
    triangles: wp.array(dtype=wp.vec3i),
    triangle_weight: wp.array(dtype=wp.float32),
    rest_area_lengths: wp.array(dtype=wp.float32),
    adjacency_offsets: wp.array(dtype=wp.int32),
    adjacency_triangles: wp.array(dtype=wp.int32),
    counts: wp.array(dtype=wp.float32),
    thickness: wp.array(dtype=wp.float32),
    vertex_count: int,
    frame_count: int,
    frames_per_thread: int,
    keep_muscle_points: int,
    muscle_points: wp.array(dtype=wp.vec3),
    stretch: wp.array(dtype=wp.float32),
    bulge_points: wp.array(dtype=wp.vec3),
):
    """Per vertex and frame: x1, the stretch ratio r (mean S'/S of the counted incident triangles, 1
    without any) and the bulge x2 = x1 + (1/r − 1)·h·N(x1). ``muscle_points`` (x1) is written only
    with ``keep_muscle_points`` ≠ 0 (the stages of one frame)."""
    i = wp.tid()
    group = i / vertex_count
    v = i - group * vertex_count
    f = group * frames_per_thread
    last = wp.min(f + frames_per_thread, frame_count)
    begin = adjacency_offsets[v]
    end = adjacency_offsets[v + 1]
    count = counts[v]
    h = thickness[v]
    while f < last:
        first = f * control_count
        rotation = wp.quat_identity()
        slide = wp.vec3(0.0, 0.0, 0.0)
        if jaw_first >= 0:
            rotation, slide = jaw_motion(controls, first, jaw_first, hinge_axis, forward)
        x1 = muscle_point(v, rest, jaw_weight, jaw_first, pivot, rotation, slide, muscle_offsets, muscle_entries, controls, first)
        normal_sum = wp.vec3(0.0, 0.0, 0.0)
        ratio_sum = float(0.0)
        k = begin
        while k < end:
            t = adjacency_triangles[k]
            corners = triangles[t]
            p0 = x1
            if corners[0] != v:
                p0 = muscle_point(corners[0], rest, jaw_weight, jaw_first, pivot, rotation, slide, muscle_offsets, muscle_entries, controls, first)
            p1 = x1
            if corners[1] != v:
                p1 = muscle_point(corners[1], rest, jaw_weight, jaw_first, pivot, rotation, slide, muscle_offsets, muscle_entries, controls, first)
            p2 = x1
            if corners[2] != v:
                p2 = muscle_point(corners[2], rest, jaw_weight, jaw_first, pivot, rotation, slide, muscle_offsets, muscle_entries, controls, first)
            area = triangle_weight[t] * wp.cross(p1 - p0, p2 - p0)
            normal_sum += area
            ratio_sum += wp.length(area) / rest_area_lengths[t]
            k += 1
        r = float(1.0)
        if count > 0.0:
            r = ratio_sum / count
        out = f * vertex_count + v
        if keep_muscle_points != 0:
            muscle_points[out] = x1
        stretch[out] = r
        growth = 1.0 / wp.max(r, STRETCH_FLOOR) - 1.0
        bulge_points[out] = x1 + (growth * h) * safe_normalize(normal_sum)
        f += 1


@wp.kernel
def bulge_from_muscle_points(
    muscle_points: wp.array(dtype=wp.vec3),
    triangles: wp.array(dtype=wp.vec3i),
    triangle_weight: wp.array(dtype=wp.float32),
    rest_area_lengths: wp.array(dtype=wp.float32),
    adjacency_offsets: wp.array(dtype=wp.int32),
    adjacency_triangles: wp.array(dtype=wp.int32),
    counts: wp.array(dtype=wp.float32),
    thickness: wp.array(dtype=wp.float32),
    vertex_count: int,
    frame_count: int,
    frames_per_thread: int,
    stretch: wp.array(dtype=wp.float32),
    bulge_points: wp.array(dtype=wp.vec3),
):
    """As :data:`muscles_and_bulge`, from stored muscle points x1 (the three-launch plan: x1 by
    :data:`~warpface.expression.kernels.apply_jaw_and_muscles` first, nothing recomputed)."""
    i = wp.tid()
    group = i / vertex_count
    v = i - group * vertex_count
    f = group * frames_per_thread
    last = wp.min(f + frames_per_thread, frame_count)
    begin = adjacency_offsets[v]
    end = adjacency_offsets[v + 1]
    count = counts[v]
    h = thickness[v]
    while f < last:
        first_vertex = f * vertex_count
        normal_sum = wp.vec3(0.0, 0.0, 0.0)
        ratio_sum = float(0.0)
        k = begin
        while k < end:
            t = adjacency_triangles[k]
            area = triangle_area_vector(muscle_points, first_vertex, triangles[t], triangle_weight[t])
            normal_sum += area
            ratio_sum += wp.length(area) / rest_area_lengths[t]
            k += 1
        r = float(1.0)
        if count > 0.0:
            r = ratio_sum / count
        out = first_vertex + v
        stretch[out] = r
        growth = 1.0 / wp.max(r, STRETCH_FLOOR) - 1.0
        bulge_points[out] = muscle_points[out] + (growth * h) * safe_normalize(normal_sum)
        f += 1


@wp.kernel
def wrinkles_on_bulge(
    bulge_points: wp.array(dtype=wp.vec3),
    stretch: wp.array(dtype=wp.float32),
    triangles: wp.array(dtype=wp.vec3i),
    triangle_weight: wp.array(dtype=wp.float32),
    adjacency_offsets: wp.array(dtype=wp.int32),
    adjacency_triangles: wp.array(dtype=wp.int32),
    offsets: wp.array(dtype=wp.int32),
    entries: wp.array(dtype=WrinkleEntry),
    depth: wp.array(dtype=wp.float32),
    wrinkle_count: int,
    vertex_count: int,
    frame_count: int,
    frames_per_thread: int,
    final_points: wp.array(dtype=wp.vec3),
):
    """x3 = x2 + Σ_w k_d·s_w·C_w(r)·N(x2), N(x2) from the incident triangles' area vectors of x2."""
    i = wp.tid()
    group = i / vertex_count
    v = i - group * vertex_count
    f = group * frames_per_thread
    last = wp.min(f + frames_per_thread, frame_count)
    begin = offsets[v]
    end = offsets[v + 1]
    while f < last:
        first_vertex = f * vertex_count
        out = first_vertex + v
        x = bulge_points[out]
        if begin == end:
            final_points[out] = x
        else:
            normal_sum = wp.vec3(0.0, 0.0, 0.0)
            k = adjacency_offsets[v]
            ring_end = adjacency_offsets[v + 1]
            while k < ring_end:
                t = adjacency_triangles[k]
                normal_sum += triangle_area_vector(bulge_points, first_vertex, triangles[t], triangle_weight[t])
                k += 1
            r = stretch[out]
            first_wrinkle = f * wrinkle_count
            height = float(0.0)
            k = begin
            while k < end:
                entry = entries[k]
                height += depth[first_wrinkle + entry.wrinkle] * entry.shape * contraction_factor(r, entry.kr)
                k += 1
            final_points[out] = x + height * safe_normalize(normal_sum)
        f += 1
