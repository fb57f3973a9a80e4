"""The tiled plan's register-resident kernel: each thread's rig data read once per block, not once per pass.

With a fixed block of threads, thread ``lane`` always handles the same items of its tile, so their rig
data (vertex ids, rest points, jaw weights, local triangles, counts, thickness, the first entries of
their muscle, incident-triangle and wrinkle rows) stays in registers across all the frames the block
evaluates. Used on CUDA for batches and for single frames whose tiles fit one wave of blocks
(:func:`~warpface.expression.kernels_tiled.model_kernel`); the passes and formulas are those of
:mod:`~warpface.expression.kernels_tiled`.
"""

import warp as wp

from .formulas import (
    area_vector,
    bulge_point,
    contraction_factor_from_rate,
    contraction_rate,
    muscle_pull,
    stretch_ratio,
    wrinkle_point,
    wrinkle_term,
)
from .kernels import STRETCH_FLOOR, jaw_point, muscle_entry_pull, stretch_term, wrinkle_entry_height
from .tiling import TILE_OWNED, TILE_TRIANGLES, TILE_VERTICES, FrameBatch, TiledRig, block_frames, live_row

# Per-frame hot path: no adjoints are ever taken, and -O3 measured faster than the CPU default -O2.
wp.set_module_options({"enable_backward": False, "optimization_level": 3})

__all__ = ["RESIDENT_SLOTS", "expression_tiles_resident"]

_kernels: dict = {}


RESIDENT_SLOTS = (0, 0, 0)
"""Row entries the resident kernel keeps in registers: muscle entries per halo vertex, incident triangles per
one-ring vertex, wrinkle entries per owned vertex (a longer row continues over the CSR in memory). None by
default for batches: the registers cost more than the loads they save (benchmarks/README.md)."""


def expression_tiles_resident(
    frames_per_pass: int = 1,
    block_dim: int = 256,
    blocks_per_sm: int | None = None,
    slots: tuple[int, int, int] = RESIDENT_SLOTS,
):
    """The tiled frame with each thread's rig data loaded ONCE per block (``block_dim`` threads, fixed) and kept
    in registers for all of the block's frames; built once per key.

    With a fixed block, thread ``lane`` always handles the same items: halo slots, triangles and one-ring slots
    ``k·block_dim + lane`` (k < capacity / block_dim), the owned slot ``lane``. So its vertex ids, rest points,
    jaw weights, first muscle entries, local triangles, first local incident triangles, vertex counts and
    thickness, and first wrinkle entries (``slots``: how many of each row) are read once, before the frame
    loop; a pass then reads only the controls, the depths, the shared tiles and the rare row remainders.
    The passes are those of :func:`~warpface.expression.kernels_tiled.expression_tiles` with the same
    operations in the same order (same bits).
    Must be launched with ``block_dim`` threads per block.
    """
    key = ("resident", int(frames_per_pass), int(block_dim), blocks_per_sm, tuple(int(s) for s in slots))
    if key not in _kernels:
        _kernels[key] = _build_resident_kernel(*key[1:])
    return _kernels[key]


def _build_resident_kernel(
    frames_per_pass: int, block_dim: int, blocks_per_sm: int | None, slots: tuple[int, int, int]
):
    F, B = frames_per_pass, block_dim
    MS, RS, WS = slots
    HR = -(-int(TILE_VERTICES) // B)  # halo (and one-ring) rounds per thread
    TR = -(-int(TILE_TRIANGLES) // B)
    OR = -(-int(TILE_OWNED) // B)
    frame_points = wp.types.matrix(shape=(F, 3), dtype=wp.float32)
    frame_terms = wp.types.matrix(shape=(F, 4), dtype=wp.float32)
    frame_values = wp.types.vector(length=F, dtype=wp.float32)
    halo_points = wp.types.matrix(shape=(HR, 3), dtype=wp.float32)
    halo_ints = wp.types.vector(length=HR, dtype=wp.int32)
    halo_values = wp.types.vector(length=HR, dtype=wp.float32)
    muscle_weights = wp.types.matrix(shape=(max(1, HR * MS), 3), dtype=wp.float32)
    muscle_ints = wp.types.vector(length=max(1, HR * MS), dtype=wp.int32)
    triangle_ints = wp.types.vector(length=TR, dtype=wp.int32)
    triangle_values = wp.types.vector(length=TR, dtype=wp.float32)
    ring_ints = wp.types.vector(length=max(1, HR * RS), dtype=wp.int32)
    owned_ints = wp.types.vector(length=OR, dtype=wp.int32)
    wrinkle_ints = wp.types.vector(length=max(1, OR * WS), dtype=wp.int32)
    wrinkle_values = wp.types.vector(length=max(1, OR * WS), dtype=wp.float32)
    bounds = None if blocks_per_sm is None else (B, int(blocks_per_sm))

    @wp.kernel(enable_backward=False, module="unique", module_options={"optimization_level": 3}, launch_bounds=bounds)
    def expression_tiles_resident_kernel(
        rig: TiledRig,
        controls: wp.array(dtype=wp.float32),
        depth: wp.array(dtype=wp.float32),
        batch: FrameBatch,
        final_points: wp.array(dtype=wp.vec3),
    ):
        """As :func:`expression_tiles`'s kernel (same arguments), the thread's rig data read once per block."""
        group, tile, lane = wp.tid()
        info = rig.tiles[tile]
        vertex_start = info.vertex_start
        triangle_start = info.triangle_start
        # the thread's rig data, once per block
        slot_vertex = halo_ints()
        x_rest = halo_points()
        w_jaw = halo_values()
        muscle_first = halo_ints()
        muscle_end = halo_ints()
        muscle_weight = muscle_weights()
        muscle_index = muscle_ints()
        ring_first = halo_ints()
        ring_end = halo_ints()
        ring_triangle = ring_ints()
        ring_count = halo_values()
        ring_thickness = halo_values()
        for k in range(HR):
            s = k * B + lane
            v = rig.tile_vertices[vertex_start + wp.min(s, info.halo - 1)]
            slot_vertex[k] = v
            x_rest[k] = rig.rest[v]
            if rig.jaw_first >= 0:
                w_jaw[k] = rig.jaw_weight[v]
            j, end = live_row(rig.muscle_offsets, v, s < info.halo)
            muscle_first[k] = j
            muscle_end[k] = end
            for m in range(MS):
                if j + m < end:
                    pull = rig.muscle_entries[j + m]
                    muscle_weight[k * MS + m] = pull.weight
                    muscle_index[k * MS + m] = pull.muscle
            slot = wp.min(s, info.ring - 1)
            u = rig.tile_vertices[vertex_start + slot]
            j = rig.tile_adjacency_offsets[vertex_start + slot]
            end = rig.tile_adjacency_offsets[vertex_start + slot + 1]
            ring_first[k] = j
            ring_end[k] = end
            for m in range(RS):
                if j + m < end:
                    ring_triangle[k * RS + m] = rig.tile_adjacency[j + m]
            ring_count[k] = rig.counts[u]
            ring_thickness[k] = rig.thickness[u]
        corner0 = triangle_ints()
        corner1 = triangle_ints()
        corner2 = triangle_ints()
        weight = triangle_values()
        rest_length = triangle_values()
        for k in range(TR):
            entry = rig.tile_triangles[triangle_start + wp.min(k * B + lane, info.triangles - 1)]
            corner0[k] = entry.corners[0]
            corner1[k] = entry.corners[1]
            corner2[k] = entry.corners[2]
            weight[k] = entry.weight
            rest_length[k] = entry.rest_length
        wrinkle_first = owned_ints()
        wrinkle_end = owned_ints()
        wrinkle_index = wrinkle_ints()
        wrinkle_shape = wrinkle_values()
        wrinkle_kr = wrinkle_values()
        wrinkle_rate = wrinkle_values()  # 1 − 1/k_r of C(r) above 1, divided once per block instead of per frame
        for k in range(OR):  # owned slot k·B + lane is halo slot k·B + lane (OR ≤ HR)
            j, end = live_row(rig.wrinkle_offsets, slot_vertex[k], k * B + lane < info.owned)
            wrinkle_first[k] = j
            wrinkle_end[k] = end
            for m in range(WS):
                if j + m < end:
                    wrinkle = rig.wrinkle_entries[j + m]
                    wrinkle_index[k * WS + m] = wrinkle.wrinkle
                    wrinkle_shape[k * WS + m] = wrinkle.shape
                    wrinkle_kr[k * WS + m] = wrinkle.kr
                    wrinkle_rate[k * WS + m] = contraction_rate(wrinkle.kr)

        # x1, then x2 over the one-ring
        points = wp.tile_empty(shape=(F, TILE_VERTICES), dtype=wp.vec3, storage="shared")
        terms = wp.tile_empty(shape=(F, TILE_TRIANGLES), dtype=wp.vec4, storage="shared")
        ratio = wp.tile_empty(shape=(F, TILE_OWNED), dtype=wp.float32, storage="shared")
        f, last = block_frames(batch, group)
        while f < last:
            # A: x1 of the two-ring (muscle entries in the CSR's order: the kept ones, then the row's rest)
            for k in range(HR):
                if k * B < info.halo:
                    s = k * B + lane
                    moved_points = frame_points()
                    for ff in range(F):
                        row = wp.min(f + ff, last - 1) * batch.control_count
                        moved_points[ff] = jaw_point(
                            x_rest[k], w_jaw[k], controls, row, rig.jaw_first, rig.pivot, rig.hinge_axis, rig.forward
                        )
                    for m in range(MS):
                        if muscle_first[k] + m < muscle_end[k]:
                            for ff in range(F):
                                moved_points[ff] = muscle_pull(
                                    moved_points[ff],
                                    controls[wp.min(f + ff, last - 1) * batch.control_count + muscle_index[k * MS + m]],
                                    muscle_weight[k * MS + m],
                                )
                    j = muscle_first[k] + MS
                    while j < muscle_end[k]:
                        pull = rig.muscle_entries[j]
                        for ff in range(F):
                            row = wp.min(f + ff, last - 1) * batch.control_count
                            moved_points[ff] = muscle_entry_pull(moved_points[ff], controls, row, pull)
                        j += 1
                    for ff in range(F):
                        wp.tile_scatter_masked(points, ff, s, moved_points[ff], s < info.halo)
            # B: area vector and S'/S of every triangle touching the one-ring
            for k in range(TR):
                if k * B < info.triangles:
                    t = k * B + lane
                    for ff in range(F):
                        term = stretch_term(
                            points[ff, corner0[k]],
                            points[ff, corner1[k]],
                            points[ff, corner2[k]],
                            weight[k],
                            rest_length[k],
                        )
                        wp.tile_scatter_masked(terms, ff, t, term, t < info.triangles)
            # C: r and x2 of the one-ring (x2 over x1 in place: a slot is read and written by one thread only)
            for k in range(HR):
                if k * B < info.ring:
                    s = k * B + lane
                    slot = wp.min(s, info.ring - 1)
                    totals = frame_terms()
                    for m in range(RS):
                        if ring_first[k] + m < ring_end[k]:
                            for ff in range(F):
                                totals[ff] += terms[ff, ring_triangle[k * RS + m]]
                    j = ring_first[k] + RS
                    while j < ring_end[k]:
                        triangle = rig.tile_adjacency[j]
                        for ff in range(F):
                            totals[ff] += terms[ff, triangle]
                        j += 1
                    count = ring_count[k]
                    h = ring_thickness[k]
                    for ff in range(F):
                        total = totals[ff]
                        r = stretch_ratio(total[3], count)
                        normal_sum = wp.vec3(total[0], total[1], total[2])
                        point = bulge_point(points[ff, slot], normal_sum, r, h, STRETCH_FLOOR)
                        wp.tile_scatter_masked(ratio, ff, s, r, s < info.owned)
                        wp.tile_scatter_masked(points, ff, s, point, s < info.ring)
            # D: area vectors of x2 of the triangles touching an owned vertex (over the stretch terms, read in C)
            for k in range(TR):
                if k * B < info.near:
                    t = k * B + lane
                    for ff in range(F):
                        av = area_vector(
                            points[ff, corner0[k]], points[ff, corner1[k]], points[ff, corner2[k]], weight[k]
                        )
                        wp.tile_scatter_masked(terms, ff, t, wp.vec4(av[0], av[1], av[2], 0.0), t < info.near)
            # E: wrinkles of the owned vertices (owned slot k·B + lane is one-ring slot k·B + lane)
            for k in range(OR):
                s = k * B + lane
                if s < info.owned:
                    normals = frame_points()
                    heights = frame_values()
                    wrinkled = wrinkle_first[k] < wrinkle_end[k]
                    if wrinkled:
                        for m in range(RS):
                            if ring_first[k] + m < ring_end[k]:
                                for ff in range(F):
                                    term = terms[ff, ring_triangle[k * RS + m]]
                                    normals[ff] += wp.vec3(term[0], term[1], term[2])
                        j = ring_first[k] + RS
                        while j < ring_end[k]:
                            triangle = rig.tile_adjacency[j]
                            for ff in range(F):
                                term = terms[ff, triangle]
                                normals[ff] += wp.vec3(term[0], term[1], term[2])
                            j += 1
                        for m in range(WS):
                            if wrinkle_first[k] + m < wrinkle_end[k]:
                                for ff in range(F):
                                    heights[ff] += wrinkle_term(
                                        depth[
                                            wp.min(f + ff, last - 1) * batch.wrinkle_count + wrinkle_index[k * WS + m]
                                        ],
                                        wrinkle_shape[k * WS + m],
                                        contraction_factor_from_rate(
                                            ratio[ff, s], wrinkle_kr[k * WS + m], wrinkle_rate[k * WS + m]
                                        ),
                                    )
                        j = wrinkle_first[k] + WS
                        while j < wrinkle_end[k]:
                            wrinkle = rig.wrinkle_entries[j]
                            for ff in range(F):
                                row = wp.min(f + ff, last - 1) * batch.wrinkle_count
                                heights[ff] += wrinkle_entry_height(depth, row, wrinkle, ratio[ff, s])
                            j += 1
                    for ff in range(F):
                        if f + ff < last:
                            x = points[ff, s]
                            if wrinkled:
                                x = wrinkle_point(x, heights[ff], normals[ff])
                            final_points[(f + ff) * rig.vertex_count + slot_vertex[k]] = x
            # a barrier: pass E's reads end before the next pass's writes
            wp.tile_scatter_masked(ratio, 0, 0, 0.0, False)
            f += F

    return expression_tiles_resident_kernel
