"""Checks of triangle surfaces: orientation and manifoldness, boundary loops, self-intersections.

Pure geometry on NumPy arrays and Warp kernels (a BVH of triangle bounds with an exact float64
triangle–triangle test); used by the tissue mesher (:mod:`warpface.fem.volume`) and the tissue proxy.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .._validate import as_device
from .bounds import padded_element_bvh
from .triangles import triangle_areas, triangle_corners

__all__ = ["as_surface", "boundary_loops", "check_surface", "directed_edges", "find_self_intersections"]


@wp.func
def _shares_vertex(a: wp.vec3i, b: wp.vec3i) -> bool:
    for i in range(3):
        for j in range(3):
            if a[i] == b[j]:
                return True
    return False


@wp.kernel
def _self_intersections(
    bvh: wp.uint64,
    points: wp.array(dtype=wp.vec3d),
    triangles: wp.array(dtype=wp.vec3i),
    lowers: wp.array(dtype=wp.vec3),
    uppers: wp.array(dtype=wp.vec3),
    count: wp.array(dtype=wp.int32),
    pairs: wp.array(dtype=wp.vec2i),
):
    """Pairs ``(i, j)``, ``i < j``, of triangles sharing no vertex that intersect (exact test in float64)."""
    i = wp.tid()
    ti = triangles[i]
    a0 = points[ti[0]]
    a1 = points[ti[1]]
    a2 = points[ti[2]]
    query = wp.bvh_query_aabb(bvh, lowers[i], uppers[i])
    j = int(0)
    while wp.bvh_query_next(query, j):
        if j > i:
            tj = triangles[j]
            if not _shares_vertex(ti, tj):
                # Moeller's test compares plane distances with an absolute epsilon (1e-6), far above the
                # distances of a few-millimetre triangle in metres: test in a frame where edges are ~1
                b0 = points[tj[0]]
                b1 = points[tj[1]]
                b2 = points[tj[2]]
                size = wp.max(
                    wp.max(wp.length(a1 - a0), wp.length(a2 - a0)), wp.max(wp.length(b1 - b0), wp.length(b2 - b0))
                )
                s = wp.float64(1.0) / size
                hit = wp.intersect_tri_tri(
                    wp.vec3d(0.0, 0.0, 0.0), (a1 - a0) * s, (a2 - a0) * s, (b0 - a0) * s, (b1 - a0) * s, (b2 - a0) * s
                )
                if hit != 0:
                    slot = wp.atomic_add(count, 0, 1)
                    if slot < pairs.shape[0]:
                        pairs[slot] = wp.vec2i(i, j)


# ---------------------------------------------------------------------------------------------- topology


def as_surface(surface) -> tuple[np.ndarray, np.ndarray]:
    """``(points (V, 3) float64, triangles (T, 3) int64)`` from a FaceMesh or a ``(points, triangles)`` pair."""
    if hasattr(surface, "points") and hasattr(surface, "triangles"):
        points, triangles = surface.points, surface.triangles
    else:
        try:
            points, triangles = surface
        except (TypeError, ValueError) as exc:
            raise type(exc)(
                f"surface: expected a FaceMesh or a (points, triangles) pair, got {type(surface).__name__}"
            ) from None
    points = np.asarray(points, dtype=np.float64)
    triangles = np.asarray(triangles)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 3:
        raise ValueError(f"surface points must have shape (V, 3) with V >= 3, got {points.shape}")
    bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
    if bad.size:
        raise ValueError(f"surface point {bad[0]} is not finite: {points[bad[0]].tolist()}")
    if triangles.ndim != 2 or triangles.shape[1] != 3 or len(triangles) == 0:
        raise ValueError(f"surface triangles must have shape (T, 3) with T >= 1, got {triangles.shape}")
    if not np.issubdtype(triangles.dtype, np.integer):
        raise ValueError(f"surface triangles must hold integer vertex indices, got dtype {triangles.dtype}")
    triangles = triangles.astype(np.int64)
    out = np.flatnonzero(((triangles < 0) | (triangles >= len(points))).any(axis=1))
    if out.size:
        raise ValueError(
            f"surface triangle {out[0]} has a vertex index out of range [0, {len(points)}): "
            f"{triangles[out[0]].tolist()}"
        )
    return points, triangles


def directed_edges(triangles: np.ndarray) -> np.ndarray:
    """Directed edges ``(a, b)`` of every triangle in winding order, shape (3T, 2); row ``3t + k`` is edge k of t."""
    return triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)


def check_surface(points, triangles, *, closed: bool, name: str = "surface") -> np.ndarray:
    """Check that a triangle surface is an oriented 2-manifold (with boundary unless ``closed``).

    Args:
        points: Vertex positions, shape (V, 3).
        triangles: Vertex indices, shape (T, 3), wound consistently.
        closed: Require a watertight surface: every edge used by exactly two triangles, once in
            each direction.
        name: Label used in error messages.

    Returns:
        The boundary edges ``(a, b)`` in the winding of their triangle, shape (B, 2), int64 (empty
        when ``closed``).

    Raises:
        ValueError: naming the first offending triangle, edge or vertex: a repeated vertex in a
            triangle, a zero-area triangle, an edge shared by more than two triangles, two
            triangles traversing an edge in the same direction (inconsistent winding), an open edge
            of a surface that must be closed, or a boundary vertex where several boundary loops
            meet (a non-manifold "bow tie").
    """
    points = np.asarray(points, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.int64)
    repeated = np.flatnonzero(
        (triangles[:, 0] == triangles[:, 1])
        | (triangles[:, 1] == triangles[:, 2])
        | (triangles[:, 2] == triangles[:, 0])
    )
    if repeated.size:
        t = repeated[0]
        raise ValueError(f"{name}: triangle {t} repeats a vertex: {triangles[t].tolist()}")
    doubled_area = 2.0 * triangle_areas(triangle_corners(points, triangles))
    extent = float(np.ptp(points, axis=0).max()) or 1.0
    flat = np.flatnonzero(doubled_area <= 1e-14 * extent * extent)
    if flat.size:
        t = flat[0]
        raise ValueError(f"{name}: triangle {t} {triangles[t].tolist()} has zero area ({flat.size} such triangles)")

    directed = directed_edges(triangles)
    undirected = np.sort(directed, axis=1)
    keys, inverse, counts = np.unique(undirected, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    over = np.flatnonzero(counts > 2)
    if over.size:
        raise ValueError(
            f"{name}: edge {keys[over[0]].tolist()} is shared by {counts[over[0]]} triangles "
            f"(non-manifold; {over.size} such edges)"
        )
    _, directed_counts = np.unique(directed, axis=0, return_counts=True)
    if np.any(directed_counts > 1):
        dkeys, dcounts = np.unique(directed, axis=0, return_counts=True)
        edge = dkeys[np.flatnonzero(dcounts > 1)[0]]
        rows = np.flatnonzero((directed == edge).all(axis=1)) // 3
        raise ValueError(
            f"{name}: triangles {rows[:2].tolist()} both traverse edge {edge.tolist()} in the same direction "
            "(inconsistent winding: normals must all point out of the tissue)"
        )
    open_rows = np.flatnonzero(counts[inverse] == 1)
    if closed:
        if open_rows.size:
            edge = directed[open_rows[0]]
            raise ValueError(
                f"{name} is not watertight: edge {edge.tolist()} of triangle {open_rows[0] // 3} has no neighbour "
                f"({open_rows.size} open edges)"
            )
        return np.empty((0, 2), dtype=np.int64)
    boundary = directed[open_rows]
    outgoing = np.bincount(boundary[:, 0], minlength=len(points))
    bow_tie = np.flatnonzero(outgoing > 1)
    if bow_tie.size:
        v = bow_tie[0]
        raise ValueError(
            f"{name}: boundary vertex {v} at {points[v].tolist()} joins {outgoing[v]} boundary loops "
            "(non-manifold vertex); split it or remove a triangle"
        )
    return boundary


def boundary_loops(boundary_edges: np.ndarray) -> list[np.ndarray]:
    """Boundary edges grouped into closed loops (vertex indices in edge order), longest first.

    Labels each boundary vertex with the smallest vertex index on its loop by pointer doubling,
    then orders each loop's vertices along the edges.

    Args:
        boundary_edges: Directed boundary edges ``(a, b)``, shape (B, 2), each vertex the start of
            exactly one edge and the end of exactly one (as returned by :func:`check_surface`).
    """
    edges = np.asarray(boundary_edges, dtype=np.int64)
    if edges.size == 0:
        return []
    vertices, local = np.unique(edges, return_inverse=True)
    local = local.reshape(-1, 2)
    count = len(vertices)
    nxt = np.empty(count, dtype=np.int64)
    nxt[local[:, 0]] = local[:, 1]
    prev = np.empty(count, dtype=np.int64)
    prev[local[:, 1]] = local[:, 0]
    rounds = int(np.ceil(np.log2(max(count, 2)))) + 1
    # loop label: smallest local index on the loop (after k rounds label[v] is the minimum over the
    # 2^k vertices following v)
    label = np.arange(count)
    jump = nxt.copy()
    for _ in range(rounds):
        label = np.minimum(label, label[jump])
        jump = jump[jump]
    # rank along the loop from its label vertex (Wyllie's list ranking over the predecessor links)
    root = label == np.arange(count)
    rank = np.where(root, 0, 1)
    back = np.where(root, np.arange(count), prev)
    for _ in range(rounds):
        rank = rank + rank[back]
        back = back[back]
    loops = []
    for root in np.unique(label):
        members = np.flatnonzero(label == root)
        loops.append(vertices[members[np.argsort(rank[members])]])
    loops.sort(key=len, reverse=True)
    return loops


def find_self_intersections(points, triangles, *, max_pairs: int = 64, device=None) -> tuple[int, np.ndarray]:
    """Intersecting pairs of triangles that share no vertex (a Warp kernel over a BVH).

    Args:
        points: Vertex positions, shape (V, 3).
        triangles: Vertex indices, shape (T, 3).
        max_pairs: At most this many pairs are returned (all are counted).
        device: Warp device; ``None`` uses Warp's preferred device.

    Returns:
        ``(count, pairs)``: the number of intersecting pairs and up to ``max_pairs`` of them,
        shape (K, 2), int32, ``i < j``. Triangles sharing a vertex are not tested (they touch by
        construction); a fold between neighbours shows up as a flipped triangle instead.
    """
    device = as_device(device)
    points = np.asarray(points, dtype=np.float64)
    triangles = np.ascontiguousarray(triangles, dtype=np.int32)
    extent = float(np.ptp(points, axis=0).max()) or 1.0
    wp_points = wp.array(points, dtype=wp.vec3d, device=device)
    wp_tris = wp.array(triangles, dtype=wp.vec3i, device=device)
    # pad the float32 boxes so rounding never drops a touching pair from the broad phase
    bvh, lowers, uppers = padded_element_bvh(wp_points, triangles, 1e-6 * extent)
    count = wp.zeros(1, dtype=wp.int32, device=device)
    pairs = wp.zeros(max(int(max_pairs), 1), dtype=wp.vec2i, device=device)
    wp.launch(
        _self_intersections,
        dim=len(triangles),
        inputs=[bvh.id, wp_points, wp_tris, lowers, uppers],
        outputs=[count, pairs],
        device=device,
    )
    n = int(count.numpy()[0])
    found = pairs.numpy()[: min(n, int(max_pairs))]
    order = np.lexsort((found[:, 1], found[:, 0])) if len(found) else np.arange(0)
    return n, found[order]


# ---------------------------------------------------------------------------------------------- shell
