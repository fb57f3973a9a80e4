"""The two evaluation plans of an expression frame: which kernels run, over what, with which arrays.

``"staged"`` is the readable reference and the CPU default: five kernels (:mod:`~warpface.expression.kernels`)
that store every intermediate (x1, the triangle terms, r, x2, the area vectors of x2), so each stage can be
inspected. ``"tiled"`` is the CUDA default: one kernel over vertex tiles with a two-ring halo in shared memory
(:mod:`~warpface.expression.kernels_tiled`), no intermediate in memory. Both call the formulas of
:mod:`~warpface.expression.formulas` in the same order, so they agree bit for bit on the same device (on CUDA up
to the compiler's FMA contraction). A plan here is a list of ``(kernel, dim, inputs, outputs)`` launches.
"""

from __future__ import annotations

import warp as wp

from ..kernels_surface import frame_sizes, struct_of, triangle_area_vectors
from .frame_buffers import FrameBuffers
from .kernels import apply_jaw_and_muscles, apply_muscles, apply_wrinkles, stretch_and_bulge, triangle_stretch
from .kernels_tiled import model_kernel
from .tiling import FrameBatch, TiledRig

__all__ = ["PLANS", "TILE_FRAMES_PER_PASS", "TILE_FRAMES_PER_BLOCK", "plan_launches", "staged_launches", "tiled_rig"]

PLANS = ("staged", "tiled")
"""The plan names an :class:`~warpface.expression.ExpressionModel` accepts (its ``plan`` argument)."""

TILE_FRAMES_PER_PASS = 4
"""Frames each pass of the tiled plan evaluates at once (their rig data loaded once per pass)."""
TILE_FRAMES_PER_BLOCK = 16
"""Frames one block of the tiled plan evaluates (its tile's rig data loaded once per block)."""


def plan_launches(
    model, buffers: FrameBuffers, frames: int, controls: wp.array, depths: wp.array, final_points: wp.array
) -> list:
    """The ``model``'s plan over ``frames`` frames: reads ``controls`` (frames·C,) and ``depths`` (frames·W,),
    writes ``final_points`` (frames·V,), with ``buffers``' intermediates."""
    if model.plan == "staged":
        return staged_launches(model, buffers, frames, controls, depths, final_points)
    return [_tiled_launch(model, buffers, frames, controls, depths, final_points)]


def _jaw_inputs(model) -> list:
    """Jaw weight, pivot, hinge axis, forward axis and the first jaw control; without a jaw, placeholders and -1."""
    jaw = model.jaw
    if jaw is None:
        return [model._counts, wp.vec3(), wp.vec3(), wp.vec3(), -1]  # the weight array is never read
    return [model._jaw_weight, wp.vec3(*jaw.pivot), wp.vec3(*jaw.axis), wp.vec3(*jaw.forward), len(model.muscles)]


def tiled_rig(model, tiles: tuple) -> TiledRig:
    """The :class:`~warpface.expression.tiling.TiledRig` of ``model``'s arrays and its ``tiles`` (device arrays)."""
    rig = TiledRig()
    (rig.tiles, rig.tile_vertices, rig.tile_adjacency_offsets, rig.tile_adjacency, rig.tile_triangles) = tiles
    rig.rest = model._mesh_buffers.rest_points
    rig.jaw_weight, rig.pivot, rig.hinge_axis, rig.forward, rig.jaw_first = _jaw_inputs(model)
    rig.muscle_offsets, rig.muscle_entries = model._muscle_offsets, model._muscle_entries
    rig.counts, rig.thickness = model._counts, model._thickness
    rig.wrinkle_offsets, rig.wrinkle_entries = model._wrinkle_offsets, model._wrinkle_entries
    rig.vertex_count = model.mesh.vertex_count
    return rig


def _tiled_launch(model, buffers, frames, controls, depths, final_points):
    """The one tiled kernel, blocks over (frame groups, tiles) of ``model.block_dim`` threads."""
    per_block = min(TILE_FRAMES_PER_BLOCK, frames)
    tile_count = len(model._tiled_rig.tiles)
    kernel = model_kernel(per_block, TILE_FRAMES_PER_PASS, tile_count, device=model.device)
    widths = dict(control_count=buffers.muscle_width, wrinkle_count=buffers.wrinkle_width)
    batch = struct_of(FrameBatch, **widths, frame_count=frames, frames_per_block=per_block)
    inputs = [model._tiled_rig, controls, depths, batch]
    return (kernel, (-(-frames // per_block), tile_count, model.block_dim), inputs, [final_points])


def staged_launches(model, buffers: FrameBuffers, frames: int, controls, depths, final_points) -> list:
    """The five staged kernels (muscles, triangle stretch, stretch and bulge, area vectors of x2, wrinkles);
    x1, r and x2 stay in ``buffers`` (``muscle_points``, ``stretch``, ``bulge_points``)."""
    mesh = model._mesh_buffers
    vertex_count, triangle_count = model.mesh.vertex_count, model.mesh.triangle_count
    vertices, triangles = frames * vertex_count, frames * triangle_count
    counts = frame_sizes(vertex_count, triangle_count)
    muscles = [model._muscle_offsets, model._muscle_entries, controls, buffers.muscle_width]
    if model.jaw is None:
        first = (apply_muscles, vertices, [mesh.rest_points, *muscles, vertex_count], [buffers.muscle_points])
    else:
        *jaw_inputs, jaw_first = _jaw_inputs(model)
        first = (
            apply_jaw_and_muscles,
            vertices,
            [mesh.rest_points, *jaw_inputs, *muscles, jaw_first, vertex_count],
            [buffers.muscle_points],
        )
    adjacency = [mesh.adjacency_offsets, mesh.adjacency_triangles]
    return [
        first,
        (
            triangle_stretch,
            triangles,
            [buffers.muscle_points, mesh.triangles, mesh.triangle_weight, mesh.rest_area_lengths, counts],
            [buffers.stretch_terms],
        ),
        (
            stretch_and_bulge,
            vertices,
            [buffers.muscle_points, buffers.stretch_terms, model._counts, *adjacency, model._thickness, counts],
            [buffers.stretch, buffers.bulge_points],
        ),
        (
            triangle_area_vectors,
            triangles,
            [buffers.bulge_points, mesh.triangles, mesh.triangle_weight, counts],
            [buffers.area_vectors],
        ),
        (
            apply_wrinkles,
            vertices,
            [
                buffers.bulge_points,
                buffers.area_vectors,
                *adjacency,
                buffers.stretch,
                model._wrinkle_offsets,
                model._wrinkle_entries,
                depths,
                buffers.wrinkle_width,
                counts,
            ],
            [final_points],
        ),
    ]
