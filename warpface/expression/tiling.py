"""Vertex tiles with a two-ring halo for the tiled expression plan (:mod:`~warpface.expression.kernels_tiled`).

A tile is a spatially compact set of at most :data:`TILE_OWNED`
vertices: a run of the vertices sorted along a Morton (Z-order) curve of their rest positions. A tile
whose two-ring or triangle count exceeds the shared tiles' capacity is halved along the curve until it
fits. Everything is computed with whole-array NumPy operations (sorts and searches over (tile, item)
keys), so a 1M-vertex mesh tiles in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from .kernels import MuscleEntry, WrinkleEntry

__all__ = [
    "TILE_OWNED",
    "TILE_VERTICES",
    "TILE_TRIANGLES",
    "RingTriangle",
    "TileInfo",
    "TiledRig",
    "live_row",
    "FrameBatch",
    "block_frames",
    "VertexTiles",
    "vertex_tiles",
    "mesh_tiles",
    "morton_order",
]

TILE_OWNED = wp.constant(256)
"""Most vertices one tile owns (evaluates and writes)."""
TILE_VERTICES = wp.constant(512)
"""Most vertices of a tile's two-ring halo (owned vertices included): the shared x1 and x2 tiles."""
TILE_TRIANGLES = wp.constant(1024)
"""Most triangles touching a tile's one-ring: the shared triangle-term tile."""


@wp.struct
class RingTriangle:
    """One triangle of a tile, copied out of the mesh arrays so that one load brings it all."""

    corners: wp.vec3i
    """The triangle's corners (local vertex slots of the tile) in the mesh's order (its area vector's orientation)."""
    weight: wp.float32
    """1 for counted triangles, 0 for ignored (degenerate at rest) ones."""
    rest_length: wp.float32
    """Rest ``|(p1 − p0) × (p2 − p0)|`` (1 for ignored triangles)."""


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


@wp.struct
class TiledRig:
    """Everything of the rig the tiled kernels read, in one argument: the tiles (:meth:`VertexTiles.to_device`),
    the rest points, the jaw, the muscle and wrinkle CSRs, counted triangles and thickness per vertex."""

    tiles: wp.array(dtype=TileInfo)
    tile_vertices: wp.array(dtype=wp.int32)
    tile_adjacency_offsets: wp.array(dtype=wp.int32)
    tile_adjacency: wp.array(dtype=wp.int32)
    tile_triangles: wp.array(dtype=RingTriangle)
    rest: wp.array(dtype=wp.vec3)
    jaw_weight: wp.array(dtype=wp.float32)
    """Per vertex; not read when ``jaw_first`` < 0 (no jaw)."""
    pivot: wp.vec3
    hinge_axis: wp.vec3
    forward: wp.vec3
    jaw_first: wp.int32
    """Index of the jaw's first control in a frame's control row, or -1 without a jaw."""
    muscle_offsets: wp.array(dtype=wp.int32)
    muscle_entries: wp.array(dtype=MuscleEntry)
    counts: wp.array(dtype=wp.float32)
    thickness: wp.array(dtype=wp.float32)
    wrinkle_offsets: wp.array(dtype=wp.int32)
    wrinkle_entries: wp.array(dtype=WrinkleEntry)
    vertex_count: wp.int32


@wp.func
def live_row(offsets: wp.array(dtype=wp.int32), row: int, live: bool):
    """Entries ``[begin, end)`` of CSR row ``row``; empty for a slot past the tile's live items (``live`` False)."""
    begin = offsets[row]
    end = begin
    if live:
        end = offsets[row + 1]
    return begin, end


@wp.struct
class FrameBatch:
    """A tiled launch's frames: the row widths of the controls and of the depths, the frame count, and the
    consecutive frames each block group evaluates."""

    control_count: int
    wrinkle_count: int
    frame_count: int
    frames_per_block: int


@wp.func
def block_frames(batch: FrameBatch, group: int):
    """Frames ``[first, last)`` of block group ``group``."""
    first = group * batch.frames_per_block
    return first, wp.min(first + batch.frames_per_block, batch.frame_count)


_MORTON_BITS = 10
"""Bits per axis of the Morton code (a 1024³ lattice over the mesh's bounding box)."""


def morton_order(points: np.ndarray) -> np.ndarray:
    """Indices sorting ``points`` (V, 3) along a Z-order curve of cubic cells over their bounding box (stable
    for ties). A sheet-like point set (a face region: its thinnest principal extent under half the middle
    one) is first projected onto its two main principal axes, so that runs of the curve are compact patches
    of the surface rather than slabs cut by its relief."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    centred = points - points.mean(axis=0)
    if len(points) >= 3:
        _, spread, axes = np.linalg.svd(centred, full_matrices=False)
        if spread[2] < 0.5 * spread[1]:
            centred = np.c_[centred @ axes[:2].T, np.zeros(len(points))]
    lo, hi = centred.min(axis=0), centred.max(axis=0)
    scale = ((1 << _MORTON_BITS) - 1) / max(float(np.max(hi - lo)), 1e-30)  # one scale: cells stay cubes
    cells = np.clip(((centred - lo) * scale).astype(np.int64), 0, (1 << _MORTON_BITS) - 1)
    code = np.zeros(len(points), dtype=np.int64)
    for bit in range(_MORTON_BITS):
        for axis in range(3):
            code |= ((cells[:, axis] >> bit) & 1) << (3 * bit + axis)
    return np.argsort(code, kind="stable")


def _expand(rows: np.ndarray, offsets: np.ndarray, entries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each item of ``rows`` (indices into a CSR), the position of that item repeated per entry and the
    entries in CSR order: ``(which, entries[offsets[r]:offsets[r + 1]] for r in rows)`` flattened."""
    lengths = offsets[rows + 1] - offsets[rows]
    which = np.repeat(np.arange(len(rows)), lengths)
    starts = np.repeat(offsets[rows] - (np.cumsum(lengths) - lengths), lengths)
    return which, entries[starts + np.arange(len(which))]


def _unique(keys: np.ndarray) -> np.ndarray:
    """Sorted unique values (a sort and a mask: faster than ``np.unique``'s hashing on these large key arrays)."""
    keys = np.sort(keys)
    return keys[np.r_[True, keys[1:] != keys[:-1]]] if len(keys) else keys


@dataclass
class VertexTiles:
    """Host tables of a tiling (numpy); :meth:`to_device` gives the kernel's arrays.

    ``info`` (tiles,) of :class:`TileInfo`; ``vertices`` (S,) global vertex per local slot;
    ``adjacency_offsets`` (S + 1,) and ``adjacency`` local incident triangles of one-ring slots (CSR order);
    ``triangles`` (L,) of :class:`RingTriangle` with local corners.
    """

    info: np.ndarray
    vertices: np.ndarray
    adjacency_offsets: np.ndarray
    adjacency: np.ndarray
    triangles: np.ndarray

    @property
    def count(self) -> int:
        return len(self.info)

    def to_device(self, *, device=None) -> tuple[wp.array, ...]:
        """``(info, vertices, adjacency_offsets, adjacency, triangles)`` as Warp arrays on ``device``."""
        return (
            wp.array(self.info, dtype=TileInfo, device=device),
            wp.array(self.vertices, dtype=wp.int32, device=device),
            wp.array(self.adjacency_offsets, dtype=wp.int32, device=device),
            wp.array(self.adjacency, dtype=wp.int32, device=device),
            wp.array(self.triangles, dtype=RingTriangle, device=device),
        )


def _neighbour_csr(triangles: np.ndarray, vertex_count: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertex → vertex CSR: each vertex's triangle neighbours and itself (sorted, unique)."""
    corners = triangles.astype(np.int64)
    src = np.r_[np.repeat(corners, 3, axis=1).ravel(), np.arange(vertex_count)]
    dst = np.r_[np.tile(corners, (1, 3)).ravel(), np.arange(vertex_count)]
    keys = _unique(src * vertex_count + dst)
    offsets = np.searchsorted(keys // vertex_count, np.arange(vertex_count + 1))
    return offsets, keys % vertex_count


def _tile_sets(tile_of, neighbours, adjacency, vertex_count, triangle_count):
    """Sorted (tile, vertex) keys of every tile's one-ring and two-ring, (tile, triangle) keys of the
    triangles touching its one-ring and of those touching an owned vertex."""
    n_offsets, n_entries = neighbours
    a_offsets, a_entries = adjacency
    all_vertices = np.arange(vertex_count)
    which, near = _expand(all_vertices, n_offsets, n_entries)
    ring = _unique(tile_of[which] * vertex_count + near)
    ring_tile, ring_vertex = ring // vertex_count, ring % vertex_count
    which, far = _expand(ring_vertex, n_offsets, n_entries)
    halo = _unique(ring_tile[which] * vertex_count + far)
    which, touching = _expand(ring_vertex, a_offsets, a_entries)
    ring_triangles = _unique(ring_tile[which] * triangle_count + touching)
    which, owned_touching = _expand(all_vertices, a_offsets, a_entries)
    near_triangles = _unique(tile_of[which] * triangle_count + owned_touching)
    return ring, halo, ring_triangles, near_triangles


def vertex_tiles(
    points: np.ndarray,
    triangles: np.ndarray,
    triangle_weight: np.ndarray,
    rest_length: np.ndarray,
    adjacency_offsets: np.ndarray,
    adjacency_triangles: np.ndarray,
    *,
    max_owned: int = int(TILE_OWNED),
    max_halo: int = int(TILE_VERTICES),
    max_triangles: int = int(TILE_TRIANGLES),
) -> VertexTiles:
    """Tile a mesh: ``points`` (V, 3) rest positions, ``triangles`` (T, 3), per-triangle ``triangle_weight``
    and ``rest_length`` (T,), and the vertex → triangle CSR (``adjacency_offsets`` (V + 1,), ``adjacency_triangles``).
    ``max_owned``, ``max_halo`` and ``max_triangles`` bound a tile's owned vertices, two-ring and one-ring triangles
    (default: the kernel's shared tiles).

    Raises:
        ValueError: a single vertex's two-ring or its one-ring's triangles exceed the shared tiles.
    """
    vertex_count, triangle_count = len(points), len(triangles)
    adjacency = (np.asarray(adjacency_offsets, np.int64), np.asarray(adjacency_triangles, np.int64))
    neighbours = _neighbour_csr(np.asarray(triangles), vertex_count)
    rank = np.empty(vertex_count, dtype=np.int64)
    rank[morton_order(points)] = np.arange(vertex_count)
    cuts = np.arange(0, vertex_count, max_owned, dtype=np.int64)  # first rank of each tile
    while True:
        tile_of = np.searchsorted(cuts, rank, side="right") - 1
        tile_count = len(cuts)
        ring, halo, ring_triangles, near_triangles = _tile_sets(
            tile_of, neighbours, adjacency, vertex_count, triangle_count
        )
        halo_size = np.bincount(halo // vertex_count, minlength=tile_count)
        triangle_size = np.bincount(ring_triangles // triangle_count, minlength=tile_count)
        over = np.flatnonzero((halo_size > max_halo) | (triangle_size > max_triangles))
        if len(over) == 0:
            break
        sizes = np.diff(np.r_[cuts, vertex_count])
        if np.any(sizes[over] == 1):
            vertex = int(np.flatnonzero(tile_of == over[sizes[over] == 1][0])[0])
            raise ValueError(
                f"tiled plan: vertex {vertex}'s two-ring has more than {max_halo} vertices or its one-ring "
                f'more than {max_triangles} triangles; use plan="staged"'
            )
        cuts = np.sort(np.r_[cuts, cuts[over] + sizes[over] // 2])

    # local vertex order per tile: owned, rest of the one-ring, rest of the two-ring (each by vertex index)
    halo_tile, halo_vertex = halo // vertex_count, halo % vertex_count
    kind = np.where(tile_of[halo_vertex] == halo_tile, 0, np.where(np.isin(halo, ring, assume_unique=True), 1, 2))
    order = np.lexsort((halo_vertex, kind, halo_tile))
    slot_key, slot_kind = halo[order], kind[order]
    vertex_start = np.searchsorted(slot_key // vertex_count, np.arange(tile_count + 1))
    slot_of = np.empty(len(order), dtype=np.int64)  # flattened slot of sorted key i
    slot_of[order] = np.arange(len(order))
    # local triangle order per tile: those touching an owned vertex first
    tri_tile, tri = ring_triangles // triangle_count, ring_triangles % triangle_count
    tri_kind = np.where(np.isin(ring_triangles, near_triangles, assume_unique=True), 0, 1)
    tri_order = np.lexsort((tri, tri_kind, tri_tile))
    triangle_start = np.searchsorted(tri_tile[tri_order], np.arange(tile_count + 1))
    tri_slot_of = np.empty(len(tri_order), dtype=np.int64)
    tri_slot_of[tri_order] = np.arange(len(tri_order))

    corners = np.asarray(triangles, dtype=np.int64)[tri[tri_order]]
    owner = tri_tile[tri_order]
    corner_keys = owner[:, None] * vertex_count + corners
    local_corners = slot_of[np.searchsorted(halo, corner_keys)] - vertex_start[owner][:, None]
    packed = np.zeros(len(tri_order), dtype=RingTriangle.numpy_dtype())
    packed["corners"] = local_corners
    packed["weight"] = np.asarray(triangle_weight)[tri[tri_order]]
    packed["rest_length"] = np.asarray(rest_length)[tri[tri_order]]

    slot_tile, slot_vertex = slot_key // vertex_count, slot_key % vertex_count
    one_ring = np.flatnonzero(slot_kind <= 1)
    which, incident = _expand(slot_vertex[one_ring], *adjacency)
    owner = slot_tile[one_ring][which]
    local_triangles = (
        tri_slot_of[np.searchsorted(ring_triangles, owner * triangle_count + incident)] - triangle_start[owner]
    )
    lengths = np.zeros(len(slot_key), dtype=np.int64)
    lengths[one_ring] = np.diff(adjacency[0])[slot_vertex[one_ring]]

    info = np.zeros(tile_count, dtype=TileInfo.numpy_dtype())
    info["vertex_start"] = vertex_start[:-1]
    info["owned"] = np.bincount(slot_tile[slot_kind == 0], minlength=tile_count)
    info["ring"] = np.bincount(slot_tile[one_ring], minlength=tile_count)
    info["halo"] = np.diff(vertex_start)
    info["triangle_start"] = triangle_start[:-1]
    info["near"] = np.bincount(tri_tile[tri_kind == 0], minlength=tile_count)
    info["triangles"] = np.diff(triangle_start)
    return VertexTiles(
        info=info,
        vertices=slot_vertex.astype(np.int32),
        adjacency_offsets=np.r_[0, np.cumsum(lengths)].astype(np.int32),
        adjacency=local_triangles.astype(np.int32),
        triangles=packed,
    )


def mesh_tiles(mesh, buffers, *, device, required: bool = True, **caps) -> tuple[wp.array, ...] | None:
    """:func:`vertex_tiles` of a :class:`~warpface.FaceMesh` (``buffers``: its ``device_buffers``) as the kernel's
    device arrays (:meth:`VertexTiles.to_device`); ``caps`` as there. A mesh with a vertex that cannot fit a tile
    raises ``ValueError`` when ``required``, else gives ``None`` (the default plan then falls back to staged)."""
    try:
        tiles = vertex_tiles(
            mesh.points,
            mesh.triangles,
            buffers.triangle_weight.numpy(),
            buffers.rest_area_lengths.numpy(),
            mesh.adjacency.offsets,
            mesh.adjacency.triangles,
            **caps,
        )
    except ValueError:
        if required:
            raise
        return None
    return tiles.to_device(device=device)
