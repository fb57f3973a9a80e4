"""The expression frame (SPEC §1) in ONE Warp kernel: vertex tiles with a two-ring halo in shared memory.

The fused plans of :mod:`~warpface.expression.kernels_fused` keep one launch boundary (a wrinkle needs
N(x2), so x2 of the one-ring, so x1 of the two-ring) and gather every incident triangle's corners from
memory, computing each triangle three times. Here a block of threads owns a spatially compact tile of
vertices (:mod:`~warpface.expression.tiling`) and evaluates it for a group of consecutive frames; per
frame, with a barrier after each pass::

    A  x1 of every vertex of the tile's two-ring halo (jaw, then muscles)   → shared x1
    B  area vector and S'/S of every triangle touching the one-ring          → shared terms (vec4)
    C  r and x2 = x1 + (1/r − 1)·h·N(x1) of the one-ring                     → shared x2, r
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
which ends in the barrier). The shared tiles hold :data:`TILE_VERTICES` points and
:data:`TILE_TRIANGLES` triangle terms (29 KB).
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


@wp.kernel
def expression_tiles(
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
    x1 = wp.tile_empty(shape=TILE_VERTICES, dtype=wp.vec3, storage="shared")
    x2 = wp.tile_empty(shape=TILE_VERTICES, dtype=wp.vec3, storage="shared")
    terms = wp.tile_empty(shape=TILE_TRIANGLES, dtype=wp.vec4, storage="shared")
    ratio = wp.tile_empty(shape=TILE_OWNED, dtype=wp.float32, storage="shared")
    f = group * frames_per_block
    last = wp.min(f + frames_per_block, frame_count)
    while f < last:
        first = f * control_count
        rotation = wp.quat_identity()
        slide = wp.vec3(0.0, 0.0, 0.0)
        if jaw_first >= 0:
            rotation = wp.quat_from_axis_angle(hinge_axis, controls[first + jaw_first])
            slide = controls[first + jaw_first + 1] * forward + controls[first + jaw_first + 2] * hinge_axis
        # A: x1 of the two-ring
        k = int(0)
        while k < info.halo:
            s = k + lane
            point = wp.vec3(0.0, 0.0, 0.0)
            if s < info.halo:
                v = tile_vertices[vertex_start + s]
                x = rest[v]
                if jaw_first >= 0:
                    w = jaw_weight[v]
                    if w > 0.0:
                        moved = wp.quat_rotate(rotation, x - pivot) + pivot + slide
                        x = x + w * (moved - x)
                point = add_muscles(x, controls, first, muscle_offsets, muscle_entries, v)
            wp.tile_scatter_masked(x1, s, point, s < info.halo)
            k += threads
        # B: area vector and S'/S of every triangle touching the one-ring
        k = int(0)
        while k < info.triangles:
            t = k + lane
            term = wp.vec4(0.0, 0.0, 0.0, 0.0)
            if t < info.triangles:
                entry = tile_triangles[triangle_start + t]
                p0 = x1[entry.corners[0]]
                av = entry.weight * wp.cross(x1[entry.corners[1]] - p0, x1[entry.corners[2]] - p0)
                term = wp.vec4(av[0], av[1], av[2], wp.length(av) / entry.rest_length)
            wp.tile_scatter_masked(terms, t, term, t < info.triangles)
            k += threads
        # C: r and x2 of the one-ring
        k = int(0)
        while k < info.ring:
            s = k + lane
            point = wp.vec3(0.0, 0.0, 0.0)
            r = float(1.0)
            if s < info.ring:
                v = tile_vertices[vertex_start + s]
                total = wp.vec4(0.0, 0.0, 0.0, 0.0)
                j = tile_adjacency_offsets[vertex_start + s]
                end = tile_adjacency_offsets[vertex_start + s + 1]
                while j < end:
                    total += terms[tile_adjacency[j]]
                    j += 1
                if counts[v] > 0.0:
                    r = total[3] / counts[v]
                growth = 1.0 / wp.max(r, STRETCH_FLOOR) - 1.0
                normal = safe_normalize(wp.vec3(total[0], total[1], total[2]))
                point = x1[s] + (growth * thickness[v]) * normal
                if s < info.owned and keep_stages != 0:
                    out = f * vertex_count + v
                    muscle_points[out] = x1[s]
                    stretch[out] = r
                    bulge_points[out] = point
            wp.tile_scatter_masked(ratio, s, r, s < info.owned)
            wp.tile_scatter_masked(x2, s, point, s < info.ring)
            k += threads
        # D: area vectors of x2 of the triangles touching an owned vertex (over the stretch terms, read in C)
        k = int(0)
        while k < info.near:
            t = k + lane
            term = wp.vec4(0.0, 0.0, 0.0, 0.0)
            if t < info.near:
                entry = tile_triangles[triangle_start + t]
                p0 = x2[entry.corners[0]]
                av = entry.weight * wp.cross(x2[entry.corners[1]] - p0, x2[entry.corners[2]] - p0)
                term = wp.vec4(av[0], av[1], av[2], 0.0)
            wp.tile_scatter_masked(terms, t, term, t < info.near)
            k += threads
        # E: wrinkles of the owned vertices; the next frame's pass A may start once all have read the tiles
        k = int(0)
        while k < info.owned:
            s = k + lane
            if s < info.owned:
                v = tile_vertices[vertex_start + s]
                x = x2[s]
                begin = wrinkle_offsets[v]
                end = wrinkle_offsets[v + 1]
                if begin < end:
                    normal_sum = wp.vec3(0.0, 0.0, 0.0)
                    j = tile_adjacency_offsets[vertex_start + s]
                    stop = tile_adjacency_offsets[vertex_start + s + 1]
                    while j < stop:
                        term = terms[tile_adjacency[j]]
                        normal_sum += wp.vec3(term[0], term[1], term[2])
                        j += 1
                    r = ratio[s]
                    first_wrinkle = f * wrinkle_count
                    height = float(0.0)
                    while begin < end:
                        wrinkle = wrinkle_entries[begin]
                        height += depth[first_wrinkle + wrinkle.wrinkle] * wrinkle.shape * contraction_factor(r, wrinkle.kr)
                        begin += 1
                    x = x + height * safe_normalize(normal_sum)
                final_points[f * vertex_count + v] = x
            k += threads
        wp.tile_scatter_masked(ratio, 0, 0.0, False)  # a barrier: pass E's reads end before the next frame's writes
        f += 1
