"""The expression frame (SPEC §1) in two or three fused Warp kernels, launched over ``frames × vertices``.

The five-kernel sequence of :mod:`warpface.expression.kernels` writes every intermediate (muscle
points, per-triangle stretch terms, per-triangle area vectors) to memory and reads it back in the next
launch. On a GPU a ~10k-vertex frame is then bound by launch latency and by chains of dependent loads,
a large one by bytes. Here a frame is::

    two launches    muscles_and_bulge_from_ring   x1 of the vertex and of its one-ring (jaw, then muscles,
                                                  recomputed instead of stored), the incident triangles'
                                                  area vectors and S'/S, r, N(x1), x2      → r, x2
                    wrinkles_from_ring            N(x2) from the incident triangles of x2, x3 = x2 +
                                                  Σ k_d·s·C(r)·N(x2)                        → x3
    three launches  muscle_points_over_frames (→ x1), bulge_from_ring (x1 → r, x2), wrinkles_from_ring

(Storing x1 and x2 as vec4, x2 with r in w, measured slower on an H200 — 20 % fewer frames/s batched —:
Warp's vec4 is 4-byte aligned, so a gathered point stays three loads, now of 16 bytes instead of 12.)

A wrinkle needs N(x2), which needs x2 of the one-ring and so x1 of the two-ring: that dependency is the
one launch boundary kept.

**Slot tables.** Walking a CSR row is a chain of dependent loads per entry (row offset → entry →
what it points at), one entry after the other. Here the first entries of every row are copied into
fixed-width tables, slot-major (slot ``j`` of vertex ``v`` at ``j·V + v``, so a warp's loads of one slot
are contiguous): :data:`RING_SLOTS` incident triangles (corners, weight, rest length), :data:`MUSCLE_SLOTS`
muscle entries, :data:`WRINKLE_SLOTS` wrinkle entries. A slot loop has a constant trip count and no
branch, so the compiler unrolls it and issues every slot's loads at once. Unused slots hold zero entries
(a triangle ``(v, v, v)`` of weight 0, a muscle weight or wrinkle shape of 0): they add exactly zero. A
row longer than its slots continues over the CSR after them. Every sum is taken in the CSR's order with
the operations of the five-kernel sequence, so all plans agree bit for bit on the same device (up to the
compiler's choice of FMA contraction on CUDA).

``jaw_first`` < 0 means the rig has no jaw (its arrays are then not read). With ``frames_per_thread`` =
G > 1 one thread evaluates the same vertex in G consecutive frames, so the rig data a vertex reads is
fetched from memory once per G frames: the launch is then over ``ceil(frames / G) × vertices`` threads.
"""

import numpy as np
import warp as wp

from ..kernels_surface import safe_normalize, triangle_area_vector
from .kernels import MuscleEntry, WrinkleEntry, add_muscles, bulge_point, contraction_factor, jaw_blend, jaw_motion

# Per-frame hot path: no adjoints are ever taken, and -O3 measured faster than the CPU default -O2.
wp.set_module_options({"enable_backward": False, "optimization_level": 3})

__all__ = [
    "RING_SLOTS",
    "MUSCLE_SLOTS",
    "WRINKLE_SLOTS",
    "RingTriangle",
    "ring_table",
    "slot_table",
    "muscle_points_over_frames",
    "muscles_and_bulge_from_ring",
    "bulge_from_ring",
    "wrinkles_from_ring",
]

RING_SLOTS = wp.constant(6)
"""Incident triangles per vertex held in the fixed-width table (valence 6 on a regular mesh)."""
MUSCLE_SLOTS = wp.constant(4)
"""Muscle entries per vertex held in slots (the rest, if any, is walked over the CSR)."""
WRINKLE_SLOTS = wp.constant(6)
"""Wrinkle entries per vertex held in slots (the rest, if any, is walked over the CSR)."""


@wp.struct
class RingTriangle:
    """One incident triangle of a vertex, copied out of the mesh arrays so that one load brings it all."""

    corners: wp.vec3i
    """The triangle's corners in the mesh's order (its area vector's orientation)."""
    weight: wp.float32
    """1 for counted triangles, 0 for ignored (degenerate at rest) ones and for unused slots."""
    rest_length: wp.float32
    """Rest ``|(p1 − p0) × (p2 − p0)|`` (1 for ignored triangles and unused slots)."""


def ring_table(
    triangles: np.ndarray,
    weight: np.ndarray,
    rest_length: np.ndarray,
    offsets: np.ndarray,
    incident: np.ndarray,
    *,
    device,
) -> wp.array:
    """The slot-major table, shape (RING_SLOTS·V,), from the vertex → triangle CSR (``offsets`` (V + 1,),
    ``incident`` (nnz,)) and per-triangle ``triangles`` (T, 3), ``weight`` (T,), ``rest_length`` (T,)."""
    slots = int(RING_SLOTS)
    vertex_count = len(offsets) - 1
    packed = np.zeros(slots * vertex_count, dtype=RingTriangle.numpy_dtype())
    table = packed.reshape(slots, vertex_count)
    table["corners"] = np.arange(vertex_count, dtype=np.int32)[None, :, None]
    table["rest_length"] = 1.0
    counts = np.diff(offsets)
    for slot in range(slots):
        filled = np.flatnonzero(counts > slot)
        t = incident[offsets[filled] + slot]
        table["corners"][slot, filled] = triangles[t]
        table["weight"][slot, filled] = weight[t]
        table["rest_length"][slot, filled] = rest_length[t]
    return wp.array(packed, dtype=RingTriangle, device=device)


def slot_table(struct, offsets: np.ndarray, entries: np.ndarray, slots: int, *, device) -> wp.array:
    """The first ``slots`` entries of each CSR row, slot-major (slot ``j`` of row ``v`` at ``j·V + v``),
    shape (slots·V,); ``entries`` is the CSR's structured array of ``struct``. Unused slots are zero
    entries (index 0, weight/shape 0), which add exactly nothing to the sums that read them."""
    vertex_count = len(offsets) - 1
    packed = np.zeros(slots * vertex_count, dtype=struct.numpy_dtype())
    table = packed.reshape(slots, vertex_count)
    counts = np.diff(offsets)
    for slot in range(slots):
        filled = np.flatnonzero(counts > slot)
        table[slot, filled] = entries[offsets[filled] + slot]
    return wp.array(packed, dtype=struct, device=device)


@wp.func
def add_muscle_slots(
    x: wp.vec3,
    controls: wp.array(dtype=wp.float32),
    first: int,
    slots: wp.array(dtype=MuscleEntry),
    vertex_count: int,
    offsets: wp.array(dtype=wp.int32),
    entries: wp.array(dtype=MuscleEntry),
    u: int,
):
    """``x + Σ K[m]·w_m(u)`` over vertex ``u``'s muscle entries: its slots (all loads issued at once), then the CSR's rest."""
    for j in range(MUSCLE_SLOTS):
        entry = slots[j * vertex_count + u]
        x += controls[first + entry.muscle] * entry.weight
    k = offsets[u] + MUSCLE_SLOTS
    end = offsets[u + 1]
    while k < end:
        entry = entries[k]
        x += controls[first + entry.muscle] * entry.weight
        k += 1
    return x


@wp.func
def muscle_point_from_slots(
    u: int,
    rest: wp.array(dtype=wp.vec3),
    jaw_weight: wp.array(dtype=wp.float32),
    jaw_first: int,
    pivot: wp.vec3,
    rotation: wp.quat,
    slide: wp.vec3,
    slots: wp.array(dtype=MuscleEntry),
    vertex_count: int,
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
            x = jaw_blend(x, w, pivot, rotation, slide)
    return add_muscle_slots(x, controls, first, slots, vertex_count, offsets, entries, u)


@wp.func
def wrinkle_height(
    r: float,
    depth: wp.array(dtype=wp.float32),
    first_wrinkle: int,
    slots: wp.array(dtype=WrinkleEntry),
    vertex_count: int,
    offsets: wp.array(dtype=wp.int32),
    entries: wp.array(dtype=WrinkleEntry),
    v: int,
    begin: int,
    end: int,
):
    """Σ_w k_d·s_w·C_w(r) over vertex ``v``'s wrinkle entries: its slots, then the CSR's rest."""
    height = float(0.0)
    for j in range(WRINKLE_SLOTS):
        entry = slots[j * vertex_count + v]
        height += depth[first_wrinkle + entry.wrinkle] * entry.shape * contraction_factor(r, entry.kr)
    k = begin + WRINKLE_SLOTS
    while k < end:
        entry = entries[k]
        height += depth[first_wrinkle + entry.wrinkle] * entry.shape * contraction_factor(r, entry.kr)
        k += 1
    return height


@wp.kernel
def muscle_points_over_frames(
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
    vertex_count: int,
    frame_count: int,
    frames_per_thread: int,
    muscle_points: wp.array(dtype=wp.vec3),
):
    """x1 per vertex and frame (the first kernel of the three-launch plan), ``frames_per_thread``
    consecutive frames per thread: the values of :data:`~warpface.expression.kernels.apply_jaw_and_muscles`
    (``apply_muscles`` without a jaw). The muscle entries are walked over the CSR: a vertex has few, and
    padded slots would cost a batch more loads than they save a single frame (measured on an H200)."""
    i = wp.tid()
    group = i / vertex_count
    v = i - group * vertex_count
    f = group * frames_per_thread
    last = wp.min(f + frames_per_thread, frame_count)
    x_rest = rest[v]
    w = float(0.0)
    if jaw_first >= 0:
        w = jaw_weight[v]
    while f < last:
        first = f * control_count
        x = x_rest
        if w > 0.0:
            rotation, slide = jaw_motion(controls, first, jaw_first, hinge_axis, forward)
            x = jaw_blend(x, w, pivot, rotation, slide)
        muscle_points[f * vertex_count + v] = add_muscles(x, controls, first, muscle_offsets, muscle_entries, v)
        f += 1


@wp.func
def recomputed_area(
    corners: wp.vec3i,
    weight: float,
    x1: wp.vec3,
    v: int,
    rest: wp.array(dtype=wp.vec3),
    jaw_weight: wp.array(dtype=wp.float32),
    jaw_first: int,
    pivot: wp.vec3,
    rotation: wp.quat,
    slide: wp.vec3,
    slots: wp.array(dtype=MuscleEntry),
    vertex_count: int,
    offsets: wp.array(dtype=wp.int32),
    entries: wp.array(dtype=MuscleEntry),
    controls: wp.array(dtype=wp.float32),
    first: int,
):
    """``weight · (p1 − p0) × (p2 − p0)`` of a triangle of vertex ``v`` (x1 given) with its other corners' x1 recomputed."""
    p0 = x1
    if corners[0] != v:
        p0 = muscle_point_from_slots(
            corners[0],
            rest,
            jaw_weight,
            jaw_first,
            pivot,
            rotation,
            slide,
            slots,
            vertex_count,
            offsets,
            entries,
            controls,
            first,
        )
    p1 = x1
    if corners[1] != v:
        p1 = muscle_point_from_slots(
            corners[1],
            rest,
            jaw_weight,
            jaw_first,
            pivot,
            rotation,
            slide,
            slots,
            vertex_count,
            offsets,
            entries,
            controls,
            first,
        )
    p2 = x1
    if corners[2] != v:
        p2 = muscle_point_from_slots(
            corners[2],
            rest,
            jaw_weight,
            jaw_first,
            pivot,
            rotation,
            slide,
            slots,
            vertex_count,
            offsets,
            entries,
            controls,
            first,
        )
    return weight * wp.cross(p1 - p0, p2 - p0)


@wp.kernel
def muscles_and_bulge_from_ring(
    rest: wp.array(dtype=wp.vec3),
    jaw_weight: wp.array(dtype=wp.float32),
    pivot: wp.vec3,
    hinge_axis: wp.vec3,
    forward: wp.vec3,
    jaw_first: int,
    muscle_offsets: wp.array(dtype=wp.int32),
    muscle_entries: wp.array(dtype=MuscleEntry),
    muscle_slots: wp.array(dtype=MuscleEntry),
    controls: wp.array(dtype=wp.float32),
    control_count: int,
    ring: wp.array(dtype=RingTriangle),
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
    """The first kernel of the two-launch plan: x1 of the vertex and of its one-ring recomputed from the
    slots (no stored x1 to wait for), r and x2 = x1 + (1/r − 1)·h·N(x1); x1 is written only with
    ``keep_muscle_points`` ≠ 0 (the stages of one frame)."""
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
        x1 = muscle_point_from_slots(
            v,
            rest,
            jaw_weight,
            jaw_first,
            pivot,
            rotation,
            slide,
            muscle_slots,
            vertex_count,
            muscle_offsets,
            muscle_entries,
            controls,
            first,
        )
        normal_sum = wp.vec3(0.0, 0.0, 0.0)
        ratio_sum = float(0.0)
        for j in range(RING_SLOTS):
            entry = ring[j * vertex_count + v]
            area = recomputed_area(
                entry.corners,
                entry.weight,
                x1,
                v,
                rest,
                jaw_weight,
                jaw_first,
                pivot,
                rotation,
                slide,
                muscle_slots,
                vertex_count,
                muscle_offsets,
                muscle_entries,
                controls,
                first,
            )
            normal_sum += area
            ratio_sum += wp.length(area) / entry.rest_length
        k = begin + RING_SLOTS
        while k < end:
            t = adjacency_triangles[k]
            area = recomputed_area(
                triangles[t],
                triangle_weight[t],
                x1,
                v,
                rest,
                jaw_weight,
                jaw_first,
                pivot,
                rotation,
                slide,
                muscle_slots,
                vertex_count,
                muscle_offsets,
                muscle_entries,
                controls,
                first,
            )
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
        bulge_points[out] = bulge_point(x1, normal_sum, r, h)
        f += 1


@wp.func
def ring_sums(
    points: wp.array(dtype=wp.vec3),
    first_vertex: int,
    ring: wp.array(dtype=RingTriangle),
    vertex_count: int,
    v: int,
    triangles: wp.array(dtype=wp.vec3i),
    triangle_weight: wp.array(dtype=wp.float32),
    rest_area_lengths: wp.array(dtype=wp.float32),
    incident: wp.array(dtype=wp.int32),
    begin: int,
    end: int,
):
    """Σ area vectors and Σ |area|/rest length over vertex ``v``'s incident triangles (slots, then the CSR's rest)."""
    normal_sum = wp.vec3(0.0, 0.0, 0.0)
    ratio_sum = float(0.0)
    for j in range(RING_SLOTS):
        entry = ring[j * vertex_count + v]
        area = triangle_area_vector(points, first_vertex, entry.corners, entry.weight)
        normal_sum += area
        ratio_sum += wp.length(area) / entry.rest_length
    k = begin + RING_SLOTS
    while k < end:
        t = incident[k]
        area = triangle_area_vector(points, first_vertex, triangles[t], triangle_weight[t])
        normal_sum += area
        ratio_sum += wp.length(area) / rest_area_lengths[t]
        k += 1
    return normal_sum, ratio_sum


@wp.func
def ring_normal_sum(
    points: wp.array(dtype=wp.vec3),
    first_vertex: int,
    ring: wp.array(dtype=RingTriangle),
    vertex_count: int,
    v: int,
    triangles: wp.array(dtype=wp.vec3i),
    triangle_weight: wp.array(dtype=wp.float32),
    incident: wp.array(dtype=wp.int32),
    begin: int,
    end: int,
):
    """Σ area vectors over vertex ``v``'s incident triangles (slots, then the CSR's rest)."""
    normal_sum = wp.vec3(0.0, 0.0, 0.0)
    for j in range(RING_SLOTS):
        entry = ring[j * vertex_count + v]
        normal_sum += triangle_area_vector(points, first_vertex, entry.corners, entry.weight)
    k = begin + RING_SLOTS
    while k < end:
        t = incident[k]
        normal_sum += triangle_area_vector(points, first_vertex, triangles[t], triangle_weight[t])
        k += 1
    return normal_sum


@wp.kernel
def bulge_from_ring(
    muscle_points: wp.array(dtype=wp.vec3),
    ring: wp.array(dtype=RingTriangle),
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
    """Per vertex and frame from stored x1: r (mean S'/S of the counted incident triangles, 1 without any)
    and x2 = x1 + (1/r − 1)·h·N(x1); ``frames_per_thread`` consecutive frames per thread."""
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
        normal_sum, ratio_sum = ring_sums(
            muscle_points,
            first_vertex,
            ring,
            vertex_count,
            v,
            triangles,
            triangle_weight,
            rest_area_lengths,
            adjacency_triangles,
            begin,
            end,
        )
        r = float(1.0)
        if count > 0.0:
            r = ratio_sum / count
        out = first_vertex + v
        stretch[out] = r
        bulge_points[out] = bulge_point(muscle_points[out], normal_sum, r, h)
        f += 1


@wp.kernel
def wrinkles_from_ring(
    bulge_points: wp.array(dtype=wp.vec3),
    stretch: wp.array(dtype=wp.float32),
    ring: wp.array(dtype=RingTriangle),
    triangles: wp.array(dtype=wp.vec3i),
    triangle_weight: wp.array(dtype=wp.float32),
    adjacency_offsets: wp.array(dtype=wp.int32),
    adjacency_triangles: wp.array(dtype=wp.int32),
    offsets: wp.array(dtype=wp.int32),
    entries: wp.array(dtype=WrinkleEntry),
    wrinkle_slots: wp.array(dtype=WrinkleEntry),
    depth: wp.array(dtype=wp.float32),
    wrinkle_count: int,
    vertex_count: int,
    frame_count: int,
    frames_per_thread: int,
    final_points: wp.array(dtype=wp.vec3),
):
    """x3 = x2 + Σ_w k_d·s_w·C_w(r)·N(x2), N(x2) from the incident triangles' area vectors of x2 (the last
    kernel of the two- and three-launch plans)."""
    i = wp.tid()
    group = i / vertex_count
    v = i - group * vertex_count
    f = group * frames_per_thread
    last = wp.min(f + frames_per_thread, frame_count)
    begin = offsets[v]
    end = offsets[v + 1]
    ring_begin = adjacency_offsets[v]
    ring_end = adjacency_offsets[v + 1]
    while f < last:
        first_vertex = f * vertex_count
        out = first_vertex + v
        x = bulge_points[out]
        if begin == end:
            final_points[out] = x
        else:
            normal_sum = ring_normal_sum(
                bulge_points,
                first_vertex,
                ring,
                vertex_count,
                v,
                triangles,
                triangle_weight,
                adjacency_triangles,
                ring_begin,
                ring_end,
            )
            height = wrinkle_height(
                stretch[out], depth, f * wrinkle_count, wrinkle_slots, vertex_count, offsets, entries, v, begin, end
            )
            final_points[out] = x + height * safe_normalize(normal_sum)
        f += 1
