"""The staged plan: the expression frame (SPEC §1) as five Warp kernels over ``frames × elements``.

The sequence for one frame is::

    apply_muscles      x1 = x_rest + Σ K·w                      (vertices)
    triangle_stretch   area vectors of x1, S'/S                 (triangles)
    stretch_and_bulge  r, N(x1), x2 = x1 + (1/r − 1)·h·N(x1)    (vertices)
    triangle_area_vectors(x2)                                   (triangles)
    apply_wrinkles     x3 = x2 + Σ k_d·s·C(r)·N(x2)             (vertices)

Per-frame arrays are flat, frame after frame (the layout of :mod:`warpface.kernels_surface`):
points (frames·V,), triangle values (frames·T,), contractions (frames·M,), depths (frames·W,).
Inputs come first and outputs last in every signature; nothing allocates, so the sequence can be
captured in a CUDA graph. Every formula comes from :mod:`~warpface.expression.formulas` (the tiled plan
and the solver call the same functions). CSR rows are walked with ``while`` loops: Warp's ``range()``
iterator handles both step signs and costs more per entry on the CPU.
"""

import warp as wp

from ..kernels_surface import FrameSizes, frame_and_element, incident_area_sum
from .formulas import (
    area_ratio,
    area_vector,
    bulge_point,
    contraction_factor,
    jaw_blend,
    jaw_rotation,
    jaw_slide,
    muscle_pull,
    stretch_ratio,
    wrinkle_point,
    wrinkle_term,
)

# Per-frame hot path: no adjoints are ever taken, and -O3 measured faster than the CPU default -O2.
wp.set_module_options({"enable_backward": False, "optimization_level": 3})

__all__ = [
    "MuscleEntry",
    "WrinkleEntry",
    "apply_muscles",
    "apply_jaw_and_muscles",
    "triangle_stretch",
    "stretch_and_bulge",
    "apply_wrinkles",
    "add_muscles",
    "muscle_entry_pull",
    "wrinkle_entry_height",
    "jaw_motion",
    "jaw_point",
    "stretch_term",
    "STRETCH_FLOOR",
]

STRETCH_FLOOR = wp.constant(1.0e-4)
"""Lower bound on ``r`` before ``1/r`` in the bulge: fully collapsed skin stays finite."""


@wp.func
def jaw_motion(controls: wp.array(dtype=wp.float32), first: int, jaw_first: int, hinge_axis: wp.vec3, forward: wp.vec3):
    """The frame's jaw rotation (about ``hinge_axis`` by θ) and slide (protrusion, lateral) from its control row."""
    rotation = jaw_rotation(controls[first + jaw_first], hinge_axis)
    slide = jaw_slide(controls[first + jaw_first + 1], controls[first + jaw_first + 2], forward, hinge_axis)
    return rotation, slide


@wp.func
def jaw_point(
    x: wp.vec3,
    w: float,
    controls: wp.array(dtype=wp.float32),
    first: int,
    jaw_first: int,
    pivot: wp.vec3,
    hinge_axis: wp.vec3,
    forward: wp.vec3,
):
    """``x`` moved by the frame's jaw (SPEC §6.2) when the rig has one (``jaw_first`` ≥ 0) and ``w`` > 0."""
    if jaw_first >= 0 and w > 0.0:
        rotation, slide = jaw_motion(controls, first, jaw_first, hinge_axis, forward)
        return jaw_blend(x, w, pivot, rotation, slide)
    return x


@wp.func
def stretch_term(p0: wp.vec3, p1: wp.vec3, p2: wp.vec3, weight: float, rest_length: float):
    """A triangle's area vector (xyz) and area ratio S'/S (w), packed: one 16-byte read per neighbour."""
    av = area_vector(p0, p1, p2, weight)
    return wp.vec4(av[0], av[1], av[2], area_ratio(av, rest_length))


@wp.struct
class MuscleEntry:
    """One muscle's pull on one vertex (a row entry of the vertex → muscle CSR), packed for one load."""

    weight: wp.vec3
    """Displacement per unit contraction [mesh units]."""
    muscle: wp.int32
    """Index of the muscle (column of the contraction row)."""


@wp.struct
class WrinkleEntry:
    """One furrow's profile at one vertex (a row entry of the vertex → wrinkle CSR), packed for one load."""

    wrinkle: wp.int32
    """Index of the wrinkle (column of the depth row)."""
    shape: wp.float32
    """``s = (d/k_w − 1)·exp(−d/k_w)`` at the vertex's distance d to the furrow."""
    kr: wp.float32
    """The wrinkle's k_r (repeated per entry: saves a dependent load per entry)."""


@wp.func
def muscle_entry_pull(x: wp.vec3, controls: wp.array(dtype=wp.float32), first: int, entry: MuscleEntry):
    """``x`` moved by one muscle entry's pull, ``first`` indexing the frame's controls."""
    return muscle_pull(x, controls[first + entry.muscle], entry.weight)


@wp.func
def wrinkle_entry_height(depth: wp.array(dtype=wp.float32), first: int, entry: WrinkleEntry, r: float):
    """One wrinkle entry's height ``k_d·s·C(r)`` at stretch ``r``, ``first`` indexing the frame's depths."""
    return wrinkle_term(depth[first + entry.wrinkle], entry.shape, contraction_factor(r, entry.kr))


@wp.func
def add_muscles(
    x: wp.vec3,
    controls: wp.array(dtype=wp.float32),
    first: int,
    offsets: wp.array(dtype=wp.int32),
    entries: wp.array(dtype=MuscleEntry),
    v: int,
):
    """``x + Σ K[m]·w_m(v)`` over the muscle entries of vertex ``v``; ``first`` indexes the frame's controls."""
    k = offsets[v]
    end = offsets[v + 1]
    while k < end:
        x = muscle_entry_pull(x, controls, first, entries[k])
        k += 1
    return x


@wp.kernel
def apply_muscles(
    rest: wp.array(dtype=wp.vec3),
    offsets: wp.array(dtype=wp.int32),
    entries: wp.array(dtype=MuscleEntry),
    contraction: wp.array(dtype=wp.float32),
    muscle_count: int,
    vertex_count: int,
    muscle_points: wp.array(dtype=wp.vec3),
):
    """x1 = x_rest + Σ_m K_m · w_m(x_rest) over the muscles that reach the vertex."""
    i = wp.tid()
    f, v = frame_and_element(i, vertex_count)
    first = f * muscle_count
    muscle_points[i] = add_muscles(rest[v], contraction, first, offsets, entries, v)


@wp.kernel
def apply_jaw_and_muscles(
    rest: wp.array(dtype=wp.vec3),
    jaw_weight: wp.array(dtype=wp.float32),
    pivot: wp.vec3,
    hinge_axis: wp.vec3,
    forward: wp.vec3,
    offsets: wp.array(dtype=wp.int32),
    entries: wp.array(dtype=MuscleEntry),
    controls: wp.array(dtype=wp.float32),
    control_count: int,
    jaw_first: int,
    vertex_count: int,
    muscle_points: wp.array(dtype=wp.vec3),
):
    """SPEC §6.2 then §1.1: ``x_jaw = x + w·(R(θ)(x − p) + p + t − x)``, ``x1 = x_jaw + Σ_m K_m·w_m(x_rest)``.

    A frame's control row holds the muscle contractions, then at ``jaw_first`` the jaw's opening
    angle θ [rad], protrusion (along ``forward``) and lateral slide (along ``hinge_axis``).
    """
    i = wp.tid()
    f, v = frame_and_element(i, vertex_count)
    first = f * control_count
    x = jaw_point(rest[v], jaw_weight[v], controls, first, jaw_first, pivot, hinge_axis, forward)
    muscle_points[i] = add_muscles(x, controls, first, offsets, entries, v)


@wp.kernel
def triangle_stretch(
    points: wp.array(dtype=wp.vec3),
    triangles: wp.array(dtype=wp.vec3i),
    triangle_weight: wp.array(dtype=wp.float32),
    rest_area_lengths: wp.array(dtype=wp.float32),
    sizes: FrameSizes,
    stretch_terms: wp.array(dtype=wp.vec4),
):
    """Per triangle: ``(p1 − p0) × (p2 − p0)`` in xyz and the area ratio S'/S in w (0 for ignored triangles).

    One packed vec4 per triangle: the vertex pass that consumes it reads one 16-byte value per neighbour.
    """
    i = wp.tid()
    f, t = frame_and_element(i, sizes.triangle_count)
    first = f * sizes.vertex_count
    c = triangles[t]
    stretch_terms[i] = stretch_term(
        points[first + c[0]], points[first + c[1]], points[first + c[2]], triangle_weight[t], rest_area_lengths[t]
    )


@wp.kernel
def stretch_and_bulge(
    muscle_points: wp.array(dtype=wp.vec3),
    stretch_terms: wp.array(dtype=wp.vec4),
    counts: wp.array(dtype=wp.float32),
    adjacency_offsets: wp.array(dtype=wp.int32),
    adjacency_triangles: wp.array(dtype=wp.int32),
    thickness: wp.array(dtype=wp.float32),
    sizes: FrameSizes,
    stretch: wp.array(dtype=wp.float32),
    bulge_points: wp.array(dtype=wp.vec3),
):
    """Stretch ratio r (eq. 1: mean of S'/S over incident triangles) and the bulge x1 + (1/r − 1)·h·N(x1).

    ``counts`` is the number of counted (non-degenerate) incident triangles; a vertex with none has r = 1.
    """
    i = wp.tid()
    f, v = frame_and_element(i, sizes.vertex_count)
    first = f * sizes.triangle_count
    total = wp.vec4(0.0, 0.0, 0.0, 0.0)
    k = adjacency_offsets[v]
    end = adjacency_offsets[v + 1]
    while k < end:
        total += stretch_terms[first + adjacency_triangles[k]]
        k += 1
    r = stretch_ratio(total[3], counts[v])
    stretch[i] = r
    bulge_points[i] = bulge_point(
        muscle_points[i], wp.vec3(total[0], total[1], total[2]), r, thickness[v], STRETCH_FLOOR
    )


@wp.kernel
def apply_wrinkles(
    bulge_points: wp.array(dtype=wp.vec3),
    area_vectors: wp.array(dtype=wp.vec3),
    adjacency_offsets: wp.array(dtype=wp.int32),
    adjacency_triangles: wp.array(dtype=wp.int32),
    stretch: wp.array(dtype=wp.float32),
    offsets: wp.array(dtype=wp.int32),
    entries: wp.array(dtype=WrinkleEntry),
    depth: wp.array(dtype=wp.float32),
    wrinkle_count: int,
    sizes: FrameSizes,
    final_points: wp.array(dtype=wp.vec3),
):
    """x3 = x2 + Σ_w k_d·s_w·C_w(r)·N(x2), with s_w = (d/k_w − 1)·exp(−d/k_w) precomputed."""
    i = wp.tid()
    f, v = frame_and_element(i, sizes.vertex_count)
    x = bulge_points[i]
    begin = offsets[v]
    end = offsets[v + 1]
    if begin == end:
        final_points[i] = x
        return
    normal_sum = incident_area_sum(area_vectors, f * sizes.triangle_count, adjacency_offsets, adjacency_triangles, v)
    r = stretch[i]
    first_wrinkle = f * wrinkle_count
    height = float(0.0)
    k = begin
    while k < end:
        height += wrinkle_entry_height(depth, first_wrinkle, entries[k], r)
        k += 1
    final_points[i] = wrinkle_point(x, height, normal_sum)
