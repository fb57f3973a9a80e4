"""The tiled plan: the expression frame (SPEC §1) in ONE Warp kernel, vertex tiles with a two-ring halo.

A wrinkle needs N(x2), so x2 of the one-ring, so x1 of the two-ring. Here a block of threads owns a
spatially compact tile of vertices (:mod:`~warpface.expression.tiling`) and evaluates it for a group of
consecutive frames, a few frames per pass (their rig data loaded once); per pass, with barriers between::

    A  x1 of every vertex of the tile's two-ring halo (jaw, then muscles)   → shared x1
    B  area vector and S'/S of every triangle touching the one-ring          → shared terms (vec4)
    C  r and x2 = x1 + (1/r − 1)·h·N(x1) of the one-ring                     → shared x2 (over x1), r
    D  area vector of x2 of every triangle touching an owned vertex         → shared terms (reused)
    E  x3 = x2 + Σ k_d·s·C(r)·N(x2) of the owned vertices                   → memory

so each triangle is computed once per tile and pass, intermediates never leave the chip, and a frame
writes only its final positions. Halo vertices and triangles are computed by every tile that needs them.

Every sum runs over the vertex's incident triangles in the order of the mesh's vertex → triangle CSR,
with the formulas of :mod:`~warpface.expression.formulas` that the staged plan
(:mod:`~warpface.expression.kernels`) calls, so the two plans give the same bits on the same device (on
CUDA up to the compiler's choice of FMA contraction).

Two kernels run the passes: :func:`expression_tiles` strides over a tile's items by the block size (any
block size; on the CPU a block is one thread), and
:func:`~warpface.expression.kernels_resident.expression_tiles_resident` keeps each thread's rig data in
registers across a block's frames (CUDA batches and small single frames);
:func:`model_kernel` picks one. A pass over ``n`` items takes ``ceil(n / block)`` rounds in which every
thread of the block writes at most one shared slot (``wp.tile_scatter_masked``, which ends in the barrier).
"""

import warp as wp

from .formulas import (
    area_vector,
    bulge_point,
    stretch_ratio,
    wrinkle_point,
)
from .kernels import STRETCH_FLOOR, jaw_point, muscle_entry_pull, stretch_term, wrinkle_entry_height
from .kernels_resident import expression_tiles_resident
from .tiling import TILE_OWNED, TILE_TRIANGLES, TILE_VERTICES, FrameBatch, TiledRig, block_frames, live_row

# Per-frame hot path: no adjoints are ever taken, and -O3 measured faster than the CPU default -O2.
wp.set_module_options({"enable_backward": False, "optimization_level": 3})

__all__ = ["expression_tiles", "model_kernel"]

_kernels: dict = {}


def expression_tiles(frames_per_pass: int = 1, blocks_per_sm: int | None = None):
    """The tiled frame kernel evaluating ``frames_per_pass`` frames in each pass (built once per value);
    ``blocks_per_sm``: CUDA launch bounds of 256 threads and that many resident blocks (register cap).

    A pass loads each item's rig data (vertex, muscle and wrinkle entries, local triangle, adjacency) once
    and applies it to all of its frames, accumulating per frame in registers in the same order as the
    staged plan; the shared tiles hold one slice per frame of the pass.
    """
    frames = int(frames_per_pass)
    if frames < 1:
        raise ValueError(f"frames_per_pass: expected a positive count, got {frames_per_pass!r}")
    key = (frames, blocks_per_sm)
    if key not in _kernels:
        _kernels[key] = _build_kernel(frames, blocks_per_sm)
    return _kernels[key]


def _build_kernel(frames_per_pass: int, blocks_per_sm: int | None):
    F = frames_per_pass
    frame_points = wp.types.matrix(shape=(F, 3), dtype=wp.float32)
    frame_terms = wp.types.matrix(shape=(F, 4), dtype=wp.float32)
    frame_values = wp.types.vector(length=F, dtype=wp.float32)

    bounds = None if blocks_per_sm is None else (256, int(blocks_per_sm))

    @wp.kernel(enable_backward=False, module="unique", module_options={"optimization_level": 3}, launch_bounds=bounds)
    def expression_tiles_kernel(
        rig: TiledRig,
        controls: wp.array(dtype=wp.float32),
        depth: wp.array(dtype=wp.float32),
        batch: FrameBatch,
        final_points: wp.array(dtype=wp.vec3),
    ):
        """x3 of a tile's owned vertices for ``batch.frames_per_block`` consecutive frames (block: frame group, tile).

        Local adjacency (``tile_adjacency_offsets`` per local vertex slot, entries = local triangle indices)
        lists a one-ring vertex's incident triangles in the mesh CSR's order; ``tile_triangles`` holds local
        corners, weight and rest length.
        """
        group, tile, lane = wp.tid()
        threads = wp.block_dim()
        info = rig.tiles[tile]
        vertex_start = info.vertex_start
        triangle_start = info.triangle_start
        # x1, then x2 over the one-ring
        points = wp.tile_empty(shape=(F, TILE_VERTICES), dtype=wp.vec3, storage="shared")
        terms = wp.tile_empty(shape=(F, TILE_TRIANGLES), dtype=wp.vec4, storage="shared")
        ratio = wp.tile_empty(shape=(F, TILE_OWNED), dtype=wp.float32, storage="shared")
        f, last = block_frames(batch, group)
        while f < last:
            # A: x1 of the two-ring; a pass's frames past the last one repeat it (computed, never written)
            k = int(0)
            while k < info.halo:
                s = k + lane
                v = int(0)
                if s < info.halo:
                    v = rig.tile_vertices[vertex_start + s]
                x_rest = rig.rest[v]
                w = float(0.0)
                if rig.jaw_first >= 0:
                    w = rig.jaw_weight[v]
                moved_points = frame_points()
                for ff in range(F):
                    row = wp.min(f + ff, last - 1) * batch.control_count
                    moved_points[ff] = jaw_point(
                        x_rest, w, controls, row, rig.jaw_first, rig.pivot, rig.hinge_axis, rig.forward
                    )
                j, end = live_row(rig.muscle_offsets, v, s < info.halo)
                while j < end:
                    pull = rig.muscle_entries[j]
                    for ff in range(F):
                        row = wp.min(f + ff, last - 1) * batch.control_count
                        moved_points[ff] = muscle_entry_pull(moved_points[ff], controls, row, pull)
                    j += 1
                for ff in range(F):
                    wp.tile_scatter_masked(points, ff, s, moved_points[ff], s < info.halo)
                k += threads
            # B: area vector and S'/S of every triangle touching the one-ring
            k = int(0)
            while k < info.triangles:
                t = k + lane
                entry = rig.tile_triangles[triangle_start + wp.min(t, info.triangles - 1)]
                c = entry.corners
                for ff in range(F):
                    term = stretch_term(
                        points[ff, c[0]], points[ff, c[1]], points[ff, c[2]], entry.weight, entry.rest_length
                    )
                    wp.tile_scatter_masked(terms, ff, t, term, t < info.triangles)
                k += threads
            # C: r and x2 of the one-ring (x2 replaces x1 in place: a slot is read and written by one thread only)
            k = int(0)
            while k < info.ring:
                s = k + lane
                slot = wp.min(s, info.ring - 1)
                v = rig.tile_vertices[vertex_start + slot]
                totals = frame_terms()
                j = rig.tile_adjacency_offsets[vertex_start + slot]
                end = rig.tile_adjacency_offsets[vertex_start + slot + 1]
                while j < end:
                    triangle = rig.tile_adjacency[j]
                    for ff in range(F):
                        totals[ff] += terms[ff, triangle]
                    j += 1
                count = rig.counts[v]
                h = rig.thickness[v]
                for ff in range(F):
                    total = totals[ff]
                    r = stretch_ratio(total[3], count)
                    point = bulge_point(points[ff, slot], wp.vec3(total[0], total[1], total[2]), r, h, STRETCH_FLOOR)
                    wp.tile_scatter_masked(ratio, ff, s, r, s < info.owned)
                    wp.tile_scatter_masked(points, ff, s, point, s < info.ring)
                k += threads
            # D: area vectors of x2 of the triangles touching an owned vertex (over the stretch terms, read in C)
            k = int(0)
            while k < info.near:
                t = k + lane
                entry = rig.tile_triangles[triangle_start + wp.min(t, info.near - 1)]
                c = entry.corners
                for ff in range(F):
                    av = area_vector(points[ff, c[0]], points[ff, c[1]], points[ff, c[2]], entry.weight)
                    wp.tile_scatter_masked(terms, ff, t, wp.vec4(av[0], av[1], av[2], 0.0), t < info.near)
                k += threads
            # E: wrinkles of the owned vertices
            k = int(0)
            while k < info.owned:
                s = k + lane
                if s < info.owned:
                    v = rig.tile_vertices[vertex_start + s]
                    begin = rig.wrinkle_offsets[v]
                    end = rig.wrinkle_offsets[v + 1]
                    normals = frame_points()
                    heights = frame_values()
                    wrinkled = begin < end
                    if wrinkled:
                        j = rig.tile_adjacency_offsets[vertex_start + s]
                        stop = rig.tile_adjacency_offsets[vertex_start + s + 1]
                        while j < stop:
                            triangle = rig.tile_adjacency[j]
                            for ff in range(F):
                                term = terms[ff, triangle]
                                normals[ff] += wp.vec3(term[0], term[1], term[2])
                            j += 1
                        while begin < end:
                            wrinkle = rig.wrinkle_entries[begin]
                            for ff in range(F):
                                row = wp.min(f + ff, last - 1) * batch.wrinkle_count
                                heights[ff] += wrinkle_entry_height(depth, row, wrinkle, ratio[ff, s])
                            begin += 1
                    for ff in range(F):
                        if f + ff < last:
                            x = points[ff, s]
                            if wrinkled:
                                x = wrinkle_point(x, heights[ff], normals[ff])
                            final_points[(f + ff) * rig.vertex_count + v] = x
                k += threads
            # a barrier: pass E's reads end before the next pass's writes
            wp.tile_scatter_masked(ratio, 0, 0, 0.0, False)
            f += F

    return expression_tiles_kernel


BATCH_BLOCKS_PER_SM = 2
"""Launch bounds of the resident kernel for batches: 256 threads, 2 blocks per SM (the fastest on an H200,
benchmarks/README.md: 128 registers hold the thread's items and 4 frames' sums)."""
SINGLE_FRAME_BLOCKS_PER_SM = 4
"""Launch bounds of the strided kernel for single frames on CUDA: 4 blocks of 256 threads per SM."""
SINGLE_WAVE_SLOTS = (4, 6, 8)
"""Row entries (:data:`~warpface.expression.kernels_resident.RESIDENT_SLOTS`) the resident kernel keeps in
registers for a single frame whose tiles fit one block per SM: all of a block's rig loads are issued before its
first pass, instead of a chain of loads per pass (a latency-bound frame)."""


def model_kernel(frames_per_block: int, frames_per_pass: int, tiles: int, *, device):
    """The tiled kernel an :class:`~warpface.expression.ExpressionModel` launches on ``device`` over ``tiles`` tiles,
    ``frames_per_pass`` capped by ``frames_per_block``: on CUDA the resident kernel (blocks of 256 threads) when a
    block evaluates several frames, or a single frame whose tiles are at most one block per SM (one wave:
    latency-bound); the strided one for other single frames (each reads its rig data once then); on the CPU the
    strided one (blocks of one thread)."""
    frames = min(frames_per_pass, frames_per_block)
    if not device.is_cuda:
        return expression_tiles(frames)
    if frames_per_block == 1:
        if tiles <= device.sm_count:
            return expression_tiles_resident(1, int(TILE_OWNED), None, SINGLE_WAVE_SLOTS)
        return expression_tiles(1, blocks_per_sm=SINGLE_FRAME_BLOCKS_PER_SM)
    return expression_tiles_resident(frames, int(TILE_OWNED), BATCH_BLOCKS_PER_SM)
