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

On CUDA the model runs :func:`expression_tiles_resident`: the same passes with a fixed block of 256 threads,
each thread's items (its halo and one-ring slots, triangles and owned vertex) read from memory once per block
instead of once per pass, kept in registers across the block's frames; a pass then reads only the controls,
depths, shared tiles and CSR rows. With 4 frames per pass and 2 blocks per SM it gave 1.04–1.11× the
three-launch plan's batched frames/s at 1M vertices on an H200 (docs/notes/tiled_batch.md).

Launch: ``wp.launch_tiled`` over ``(frame groups, tiles)`` with any block size (the kernel strides by
``wp.block_dim()``; on the CPU a block is one thread). A pass over ``n`` items takes ``ceil(n / block)``
rounds in which every thread of the block writes at most one shared slot (``wp.tile_scatter_masked``,
which ends in the barrier). Per frame of a pass the shared tiles hold :data:`TILE_VERTICES` points,
:data:`TILE_TRIANGLES` triangle terms and :data:`TILE_OWNED` ratios (23 KB).
"""

import warp as wp

from ..kernels_surface import safe_normalize
from .kernels import MuscleEntry, WrinkleEntry, bulge_point, contraction_factor, jaw_blend, jaw_motion
from .kernels_fused import RingTriangle

# Per-frame hot path: no adjoints are ever taken, and -O3 measured faster than the CPU default -O2.
wp.set_module_options({"enable_backward": False, "optimization_level": 3})

__all__ = [
    "TILE_OWNED",
    "TILE_VERTICES",
    "TILE_TRIANGLES",
    "RESIDENT_SLOTS",
    "TileInfo",
    "expression_tiles",
    "expression_tiles_resident",
    "model_kernel",
]

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
        points = wp.tile_empty(
            shape=(F, TILE_VERTICES), dtype=wp.vec3, storage="shared"
        )  # x1, then x2 over the one-ring
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
                            rotation, slide = jaw_motion(
                                controls, wp.min(f + ff, last - 1) * control_count, jaw_first, hinge_axis, forward
                            )
                            x = jaw_blend(x, w, pivot, rotation, slide)
                    moved_points[ff] = x
                j = muscle_offsets[v]
                end = muscle_offsets[v + 1]
                if s >= info.halo:
                    end = j
                while j < end:
                    pull = muscle_entries[j]
                    for ff in range(F):
                        moved_points[ff] += (
                            controls[wp.min(f + ff, last - 1) * control_count + pull.muscle] * pull.weight
                        )
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
                    wp.tile_scatter_masked(
                        terms,
                        ff,
                        t,
                        wp.vec4(av[0], av[1], av[2], wp.length(av) / entry.rest_length),
                        t < info.triangles,
                    )
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
                    x1 = points[ff, slot]
                    point = bulge_point(x1, wp.vec3(total[0], total[1], total[2]), r, h)
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
                                heights[ff] += (
                                    depth[wp.min(f + ff, last - 1) * wrinkle_count + wrinkle.wrinkle]
                                    * wrinkle.shape
                                    * contraction_factor(ratio[ff, s], wrinkle.kr)
                                )
                            begin += 1
                    for ff in range(F):
                        if f + ff < last:
                            x = points[ff, s]
                            if wrinkled:
                                x = x + heights[ff] * safe_normalize(normals[ff])
                            final_points[(f + ff) * vertex_count + v] = x
                k += threads
            wp.tile_scatter_masked(
                ratio, 0, 0, 0.0, False
            )  # a barrier: pass E's reads end before the next pass's writes
            f += F

    return expression_tiles_kernel


@wp.func
def contraction_from_slope(r: float, kr: float, slope: float):
    """C(r) of :func:`~warpface.expression.kernels.contraction_factor` with its ``1 − 1/k_r`` given (the same bits)."""
    if r <= 1.0:
        return (kr - 1.0) * r + 1.0
    if kr <= 0.0:
        return 0.0
    return kr * wp.exp(slope * (r - 1.0))


BATCH_BLOCKS_PER_SM = 2
"""Launch bounds of the resident kernel for batches: 256 threads, 2 blocks per SM (H200, 1M vertices, 4 frames per
pass: 3 or 4 blocks, or none, measured slower — 128 registers hold the thread's items and 4 frames' sums)."""
SINGLE_FRAME_BLOCKS_PER_SM = 4
"""Launch bounds of the strided kernel for single frames on CUDA (H200: 4 blocks of 256 threads per SM, 4–10 % more
than none, 2 or 3)."""
SINGLE_WAVE_SLOTS = (4, 6, 8)
"""Row entries (:data:`RESIDENT_SLOTS`) the resident kernel keeps in registers for a single frame whose tiles fit one
block per SM: all of a block's rig loads are issued before its first pass, instead of a chain of loads per pass.
H200, GPU time (CUDA events around a graph of the one kernel, medians): ICT face (52 tiles) 15.8 µs against 20.6 for
the strided kernel, 10k grid (40) 14.1 against 18.7, 30k grid (117) 15.0 against 19.0; other slot sets 0.1–1.6 µs
slower; bit-identical. At 100k (391 tiles) the strided kernel stays faster: 22.0 against 28.6 µs."""


def model_kernel(frames_per_block: int, frames_per_pass: int, tiles: int, *, device):
    """The tiled kernel an :class:`~warpface.expression.ExpressionModel` launches on ``device`` over ``tiles`` tiles,
    ``frames_per_pass`` capped by ``frames_per_block``: on CUDA the resident kernel (blocks of 256 threads) when a
    block evaluates several frames, or a single frame whose tiles are at most one block per SM (one wave:
    latency-bound, see :data:`SINGLE_WAVE_SLOTS`); the strided one for other single frames (each reads its rig data
    once then; H200, 1M vertices: 0.15 against 0.18 ms); on the CPU the strided one (blocks of one thread)."""
    frames = min(frames_per_pass, frames_per_block)
    if not device.is_cuda:
        return expression_tiles(frames)
    if frames_per_block == 1:
        if tiles <= device.sm_count:
            return expression_tiles_resident(1, int(TILE_OWNED), None, SINGLE_WAVE_SLOTS)
        return expression_tiles(1, blocks_per_sm=SINGLE_FRAME_BLOCKS_PER_SM)
    return expression_tiles_resident(frames, int(TILE_OWNED), BATCH_BLOCKS_PER_SM)


RESIDENT_SLOTS = (0, 0, 0)
"""Row entries the resident kernel keeps in registers: muscle entries per halo vertex, incident triangles per
one-ring vertex, wrinkle entries per owned vertex (a longer row continues over the CSR in memory). None by
default: on an H200 (1M vertices, 2 frames per pass) keeping (3, 6, 4) gave 0.89×, (1, 6, 2) 0.93×, (0, 6, 0)
1.03×, (1, 0, 0) 0.99× the frames/s of (0, 0, 0) — the registers cost more than the loads they save."""


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
    The passes are those of :func:`expression_tiles` with the same operations in the same order (same bits).
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
        """As :func:`expression_tiles`'s kernel (same arguments), the thread's rig data read once per block."""
        group, tile, lane = wp.tid()
        info = tiles[tile]
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
            v = tile_vertices[vertex_start + wp.min(s, info.halo - 1)]
            slot_vertex[k] = v
            x_rest[k] = rest[v]
            if jaw_first >= 0:
                w_jaw[k] = jaw_weight[v]
            j = muscle_offsets[v]
            end = muscle_offsets[v + 1]
            if s >= info.halo:
                end = j
            muscle_first[k] = j
            muscle_end[k] = end
            for m in range(MS):
                if j + m < end:
                    pull = muscle_entries[j + m]
                    muscle_weight[k * MS + m] = pull.weight
                    muscle_index[k * MS + m] = pull.muscle
            slot = wp.min(s, info.ring - 1)
            u = tile_vertices[vertex_start + slot]
            j = tile_adjacency_offsets[vertex_start + slot]
            end = tile_adjacency_offsets[vertex_start + slot + 1]
            ring_first[k] = j
            ring_end[k] = end
            for m in range(RS):
                if j + m < end:
                    ring_triangle[k * RS + m] = tile_adjacency[j + m]
            ring_count[k] = counts[u]
            ring_thickness[k] = thickness[u]
        corner0 = triangle_ints()
        corner1 = triangle_ints()
        corner2 = triangle_ints()
        weight = triangle_values()
        rest_length = triangle_values()
        for k in range(TR):
            entry = tile_triangles[triangle_start + wp.min(k * B + lane, info.triangles - 1)]
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
        wrinkle_slope = wrinkle_values()  # 1 − 1/k_r of C(r) above 1, divided once per block instead of per frame
        for k in range(OR):
            s = k * B + lane
            v = tile_vertices[vertex_start + wp.min(s, info.halo - 1)]
            j = wrinkle_offsets[v]
            end = wrinkle_offsets[v + 1]
            if s >= info.owned:
                end = j
            wrinkle_first[k] = j
            wrinkle_end[k] = end
            for m in range(WS):
                if j + m < end:
                    wrinkle = wrinkle_entries[j + m]
                    wrinkle_index[k * WS + m] = wrinkle.wrinkle
                    wrinkle_shape[k * WS + m] = wrinkle.shape
                    wrinkle_kr[k * WS + m] = wrinkle.kr
                    if wrinkle.kr > 0.0:
                        wrinkle_slope[k * WS + m] = 1.0 - 1.0 / wrinkle.kr

        points = wp.tile_empty(
            shape=(F, TILE_VERTICES), dtype=wp.vec3, storage="shared"
        )  # x1, then x2 over the one-ring
        terms = wp.tile_empty(shape=(F, TILE_TRIANGLES), dtype=wp.vec4, storage="shared")
        ratio = wp.tile_empty(shape=(F, TILE_OWNED), dtype=wp.float32, storage="shared")
        f = group * frames_per_block
        last = wp.min(f + frames_per_block, frame_count)
        while f < last:
            # A: x1 of the two-ring (muscle entries in the CSR's order: the kept ones, then the row's rest)
            for k in range(HR):
                if k * B < info.halo:
                    s = k * B + lane
                    moved_points = frame_points()
                    for ff in range(F):
                        x = x_rest[k]
                        if jaw_first >= 0:
                            w = w_jaw[k]
                            if w > 0.0:
                                rotation, slide = jaw_motion(
                                    controls, wp.min(f + ff, last - 1) * control_count, jaw_first, hinge_axis, forward
                                )
                                x = jaw_blend(x, w, pivot, rotation, slide)
                        moved_points[ff] = x
                    for m in range(MS):
                        if muscle_first[k] + m < muscle_end[k]:
                            for ff in range(F):
                                moved_points[ff] += (
                                    controls[wp.min(f + ff, last - 1) * control_count + muscle_index[k * MS + m]]
                                    * muscle_weight[k * MS + m]
                                )
                    j = muscle_first[k] + MS
                    while j < muscle_end[k]:
                        pull = muscle_entries[j]
                        for ff in range(F):
                            moved_points[ff] += (
                                controls[wp.min(f + ff, last - 1) * control_count + pull.muscle] * pull.weight
                            )
                        j += 1
                    for ff in range(F):
                        wp.tile_scatter_masked(points, ff, s, moved_points[ff], s < info.halo)
            # B: area vector and S'/S of every triangle touching the one-ring
            for k in range(TR):
                if k * B < info.triangles:
                    t = k * B + lane
                    for ff in range(F):
                        p0 = points[ff, corner0[k]]
                        av = weight[k] * wp.cross(points[ff, corner1[k]] - p0, points[ff, corner2[k]] - p0)
                        wp.tile_scatter_masked(
                            terms,
                            ff,
                            t,
                            wp.vec4(av[0], av[1], av[2], wp.length(av) / rest_length[k]),
                            t < info.triangles,
                        )
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
                        triangle = tile_adjacency[j]
                        for ff in range(F):
                            totals[ff] += terms[ff, triangle]
                        j += 1
                    count = ring_count[k]
                    h = ring_thickness[k]
                    for ff in range(F):
                        total = totals[ff]
                        r = float(1.0)
                        if count > 0.0:
                            r = total[3] / count
                        x1 = points[ff, slot]
                        point = bulge_point(x1, wp.vec3(total[0], total[1], total[2]), r, h)
                        if s < info.owned and keep_stages != 0 and f + ff < last:
                            out = (f + ff) * vertex_count + slot_vertex[k]
                            muscle_points[out] = x1
                            stretch[out] = r
                            bulge_points[out] = point
                        wp.tile_scatter_masked(ratio, ff, s, r, s < info.owned)
                        wp.tile_scatter_masked(points, ff, s, point, s < info.ring)
            # D: area vectors of x2 of the triangles touching an owned vertex (over the stretch terms, read in C)
            for k in range(TR):
                if k * B < info.near:
                    t = k * B + lane
                    for ff in range(F):
                        p0 = points[ff, corner0[k]]
                        av = weight[k] * wp.cross(points[ff, corner1[k]] - p0, points[ff, corner2[k]] - p0)
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
                            triangle = tile_adjacency[j]
                            for ff in range(F):
                                term = terms[ff, triangle]
                                normals[ff] += wp.vec3(term[0], term[1], term[2])
                            j += 1
                        for m in range(WS):
                            if wrinkle_first[k] + m < wrinkle_end[k]:
                                for ff in range(F):
                                    heights[ff] += (
                                        depth[wp.min(f + ff, last - 1) * wrinkle_count + wrinkle_index[k * WS + m]]
                                        * wrinkle_shape[k * WS + m]
                                        * contraction_from_slope(
                                            ratio[ff, s], wrinkle_kr[k * WS + m], wrinkle_slope[k * WS + m]
                                        )
                                    )
                        j = wrinkle_first[k] + WS
                        while j < wrinkle_end[k]:
                            wrinkle = wrinkle_entries[j]
                            for ff in range(F):
                                heights[ff] += (
                                    depth[wp.min(f + ff, last - 1) * wrinkle_count + wrinkle.wrinkle]
                                    * wrinkle.shape
                                    * contraction_factor(ratio[ff, s], wrinkle.kr)
                                )
                            j += 1
                    for ff in range(F):
                        if f + ff < last:
                            x = points[ff, s]
                            if wrinkled:
                                x = x + heights[ff] * safe_normalize(normals[ff])
                            final_points[(f + ff) * vertex_count + slot_vertex[k]] = x
            wp.tile_scatter_masked(
                ratio, 0, 0, 0.0, False
            )  # a barrier: pass E's reads end before the next pass's writes
            f += F

    return expression_tiles_resident_kernel
