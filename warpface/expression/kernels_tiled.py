"""The expression frame (SPEC §1) in ONE Warp kernel: vertex tiles with a two-ring halo in shared memory.

The fused plans of :mod:`~warpface.expression.kernels_fused` keep one launch boundary (a wrinkle needs
N(x2), so x2 of the one-ring, so x1 of the two-ring) and gather every incident triangle's corners from
memory, computing each triangle three times. Here a block of threads owns a spatially compact tile of
vertices (:mod:`~warpface.expression.tiling`) and evaluates it for a group of consecutive frames, a few
frames per pass (their rig data loaded once); per pass, with barriers between::

    A  x1 of every vertex of the tile's two-ring halo (jaw, then muscles)   → shared x1
    B  area vector and S'/S of every triangle touching the one-ring          → shared terms (vec4)
    C  r and x2 = x1 + (1/r − 1)·h·N(x1) of the one-ring                     → shared x2 (over x1), r
    D  area vector of x2 of every triangle touching an owned vertex         → shared terms (reused)
    E  x3 = x2 + Σ k_d·s·C(r)·N(x2) of the owned vertices                   → memory

so each triangle is computed once per tile and pass, intermediates never leave the chip, and a frame
writes only its final positions (and, on request, the stages). Halo vertices and triangles are computed
by every tile that needs them (the cost of the halo: ~1.5× the vertices at 256 owned per tile).

Every sum runs over the vertex's incident triangles in the order of the mesh's vertex → triangle CSR,
with the operations of the five-kernel sequence of :mod:`~warpface.expression.kernels`, so the results
equal it bit for bit on the same device (on CUDA up to the compiler's choice of FMA contraction).

Launch: ``wp.launch_tiled`` over ``(frame groups, tiles)`` with any block size (the kernel strides by
``wp.block_dim()``; on the CPU a block is one thread). A pass over ``n`` items takes ``ceil(n / block)``
rounds in which every thread of the block writes at most one shared slot (``wp.tile_scatter_masked``,
which ends in the barrier). Per frame of a pass the shared tiles hold :data:`TILE_VERTICES` points,
:data:`TILE_TRIANGLES` triangle terms and :data:`TILE_OWNED` ratios (23 KB).
"""

import warp as wp

from ..kernels_surface import safe_normalize
from .kernels import STRETCH_FLOOR, MuscleEntry, WrinkleEntry, add_muscles, contraction_factor
from .kernels_fused import RingTriangle

# Per-frame hot path: no adjoints are ever taken, and -O3 measured faster than the CPU default -O2.
wp.set_module_options({"enable_backward": False, "optimization_level": 3})

__all__ = ["TILE_OWNED", "TILE_VERTICES", "TILE_TRIANGLES", "TileInfo", "expression_tiles"]

TILE_OWNED = wp.constant(256)
"""Most vertices one tile owns (evaluates and writes)."""
TILE_VERTICES = wp.constant(512)
"""Most vertices of a tile's two-ring halo (owned vertices included): the shared x1 and x2 tiles."""
TILE_TRIANGLES = wp.constant(1024)
"""Most triangles touching a tile's one-ring: the shared triangle-term tile."""


@wp.struct
class TileInfo:
    """Where one tile's local tables start and how many of each kind it has.

    Local vertex slots ``[vertex_start, vertex_start + halo)`` of the tile tables hold, in order, the owned
    vertices, the rest of their one-ring, and the rest of the two-ring; local triangles
    ``[triangle_start, triangle_start + triangles)`` hold first the ``near`` triangles touching an owned
    vertex, then the rest of those touching the one-ring.
    """

    vertex_start: wp.int32
    owned: wp.int32
    ring: wp.int32
    """Owned vertices plus the rest of their one-ring."""
    halo: wp.int32
    """All local vertices (the two-ring)."""
    triangle_start: wp.int32
    near: wp.int32
    triangles: wp.int32


_kernels: dict = {}


def expression_tiles(frames_per_pass: int = 1, blocks_per_sm: int | None = None):
    """The tiled frame kernel evaluating ``frames_per_pass`` frames in each pass (built once per value);
    ``blocks_per_sm``: CUDA launch bounds of 256 threads and that many resident blocks (register cap).

    A pass loads each item's rig data (vertex, muscle and wrinkle entries, local triangle, adjacency) once
    and applies it to all of its frames, accumulating per frame in registers in the same order as the
    five-kernel sequence; the shared tiles hold one slice per frame of the pass.
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
        tiles: wp.array(dtype=TileInfo),
        tile_vertices: wp.array(dtype=wp.int32),
        tile_adjacency_offsets: wp.array(dtype=wp.int32),
        tile_adjacency: wp.array(dtype=wp.int32),
        tile_triangles: wp.array(dtype=RingTriangle),
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
        counts: wp.array(dtype=wp.float32),
        thickness: wp.array(dtype=wp.float32),
        wrinkle_offsets: wp.array(dtype=wp.int32),
        wrinkle_entries: wp.array(dtype=WrinkleEntry),
        depth: wp.array(dtype=wp.float32),
        wrinkle_count: int,
        vertex_count: int,
        frame_count: int,
        frames_per_block: int,
        keep_stages: int,
        muscle_points: wp.array(dtype=wp.vec3),
        stretch: wp.array(dtype=wp.float32),
        bulge_points: wp.array(dtype=wp.vec3),
        final_points: wp.array(dtype=wp.vec3),
    ):
        """x3 of a tile's owned vertices for ``frames_per_block`` consecutive frames (block = (frame group, tile)).

        Local adjacency (``tile_adjacency_offsets`` per local vertex slot, entries = local triangle indices)
        lists a one-ring vertex's incident triangles in the mesh CSR's order; ``tile_triangles`` holds local
        corners, weight and rest length. With ``keep_stages`` ≠ 0, x1, r and x2 of owned vertices are written too.
        """
        group, tile, lane = wp.tid()
        threads = wp.block_dim()
        info = tiles[tile]
        vertex_start = info.vertex_start
        triangle_start = info.triangle_start
        points = wp.tile_empty(shape=(F, TILE_VERTICES), dtype=wp.vec3, storage="shared")  # x1, then x2 over the one-ring
        terms = wp.tile_empty(shape=(F, TILE_TRIANGLES), dtype=wp.vec4, storage="shared")
        ratio = wp.tile_empty(shape=(F, TILE_OWNED), dtype=wp.float32, storage="shared")
        f = group * frames_per_block
        last = wp.min(f + frames_per_block, frame_count)
        while f < last:
            # A: x1 of the two-ring; a pass's frames past the last one repeat it (computed, never written)
            k = int(0)
            while k < info.halo:
                s = k + lane
                v = int(0)
                if s < info.halo:
                    v = tile_vertices[vertex_start + s]
                x_rest = rest[v]
                moved_points = frame_points()
                for ff in range(F):
                    x = x_rest
                    if jaw_first >= 0:
                        w = jaw_weight[v]
                        if w > 0.0:
                            first = wp.min(f + ff, last - 1) * control_count
                            rotation = wp.quat_from_axis_angle(hinge_axis, controls[first + jaw_first])
                            slide = controls[first + jaw_first + 1] * forward + controls[first + jaw_first + 2] * hinge_axis
                            moved = wp.quat_rotate(rotation, x - pivot) + pivot + slide
                            x = x + w * (moved - x)
                    moved_points[ff] = x
                j = muscle_offsets[v]
                end = muscle_offsets[v + 1]
                if s >= info.halo:
                    end = j
                while j < end:
                    pull = muscle_entries[j]
                    for ff in range(F):
                        moved_points[ff] += controls[wp.min(f + ff, last - 1) * control_count + pull.muscle] * pull.weight
                    j += 1
                for ff in range(F):
                    wp.tile_scatter_masked(points, ff, s, moved_points[ff], s < info.halo)
                k += threads
            # B: area vector and S'/S of every triangle touching the one-ring
            k = int(0)
            while k < info.triangles:
                t = k + lane
                entry = tile_triangles[triangle_start + wp.min(t, info.triangles - 1)]
                for ff in range(F):
                    p0 = points[ff, entry.corners[0]]
                    av = entry.weight * wp.cross(points[ff, entry.corners[1]] - p0, points[ff, entry.corners[2]] - p0)
                    wp.tile_scatter_masked(terms, ff, t, wp.vec4(av[0], av[1], av[2], wp.length(av) / entry.rest_length), t < info.triangles)
                k += threads
            # C: r and x2 of the one-ring (x2 replaces x1 in place: a slot is read and written by one thread only)
            k = int(0)
            while k < info.ring:
                s = k + lane
                slot = wp.min(s, info.ring - 1)
                v = tile_vertices[vertex_start + slot]
                totals = frame_terms()
                j = tile_adjacency_offsets[vertex_start + slot]
                end = tile_adjacency_offsets[vertex_start + slot + 1]
                while j < end:
                    triangle = tile_adjacency[j]
                    for ff in range(F):
                        totals[ff] += terms[ff, triangle]
                    j += 1
                count = counts[v]
                h = thickness[v]
                for ff in range(F):
                    total = totals[ff]
                    r = float(1.0)
                    if count > 0.0:
                        r = total[3] / count
                    growth = 1.0 / wp.max(r, STRETCH_FLOOR) - 1.0
                    x1 = points[ff, slot]
                    point = x1 + (growth * h) * safe_normalize(wp.vec3(total[0], total[1], total[2]))
                    if s < info.owned and keep_stages != 0 and f + ff < last:
                        out = (f + ff) * vertex_count + v
                        muscle_points[out] = x1
                        stretch[out] = r
                        bulge_points[out] = point
                    wp.tile_scatter_masked(ratio, ff, s, r, s < info.owned)
                    wp.tile_scatter_masked(points, ff, s, point, s < info.ring)
                k += threads
            # D: area vectors of x2 of the triangles touching an owned vertex (over the stretch terms, read in C)
            k = int(0)
            while k < info.near:
                t = k + lane
                entry = tile_triangles[triangle_start + wp.min(t, info.near - 1)]
                for ff in range(F):
                    p0 = points[ff, entry.corners[0]]
                    av = entry.weight * wp.cross(points[ff, entry.corners[1]] - p0, points[ff, entry.corners[2]] - p0)
                    wp.tile_scatter_masked(terms, ff, t, wp.vec4(av[0], av[1], av[2], 0.0), t < info.near)
                k += threads
            # E: wrinkles of the owned vertices
            k = int(0)
            while k < info.owned:
                s = k + lane
                if s < info.owned:
                    v = tile_vertices[vertex_start + s]
                    begin = wrinkle_offsets[v]
                    end = wrinkle_offsets[v + 1]
                    normals = frame_points()
                    heights = frame_values()
                    wrinkled = begin < end
                    if wrinkled:
                        j = tile_adjacency_offsets[vertex_start + s]
                        stop = tile_adjacency_offsets[vertex_start + s + 1]
                        while j < stop:
                            triangle = tile_adjacency[j]
                            for ff in range(F):
                                term = terms[ff, triangle]
                                normals[ff] += wp.vec3(term[0], term[1], term[2])
                            j += 1
                        while begin < end:
                            wrinkle = wrinkle_entries[begin]
                            for ff in range(F):
                                heights[ff] += (depth[wp.min(f + ff, last - 1) * wrinkle_count + wrinkle.wrinkle] * wrinkle.shape
                                                * contraction_factor(ratio[ff, s], wrinkle.kr))
                            begin += 1
                    for ff in range(F):
                        if f + ff < last:
                            x = points[ff, s]
                            if wrinkled:
                                x = x + heights[ff] * safe_normalize(normals[ff])
                            final_points[(f + ff) * vertex_count + v] = x
                k += threads
            wp.tile_scatter_masked(ratio, 0, 0, 0.0, False)  # a barrier: pass E's reads end before the next pass's writes
            f += F

    return expression_tiles_kernel
