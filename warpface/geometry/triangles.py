"""NumPy triangle helpers: corners, cross products, areas, unit normals, area-weighted vertex normals, edges, shells.

Small array functions in the style of trimesh's ``triangles`` module: each takes either the triangle
corners or a quantity already computed from them (``crosses``), so a caller that needs areas and
normals forms the cross products once. All results are float64.
"""

from __future__ import annotations

import numpy as np

from .._validate import as_finite_array, as_triangles

_MAX_ABS = 1e60  # |coordinate| bound: squared cross-product norms (≈ coordinate⁴) stay finite in float64

__all__ = [
    "triangle_corners",
    "triangle_crosses",
    "triangle_areas",
    "triangle_normals",
    "area_weighted_vertex_normals",
    "triangle_edges",
    "vertex_triangles",
    "vertex_shells",
    "weld_seams",
    "SEAM_TOLERANCE",
    "SEAM_NORMAL_COS",
    "SEAM_MIN_SHARE",
    "SOUP_SHARE",
]

SEAM_TOLERANCE = 1e-6
"""Vertices closer than this (relative to the mesh's bounding-box diagonal) are copies of one point."""
SEAM_NORMAL_COS = 0.25
"""Copies are welded only where their own faces' normals agree this well (within ~75°: a seam, even along a crease
of the gums); lips or lids modelled touching face each other (~180°) and stay apart."""
SEAM_MIN_SHARE = 0.1
"""A seam is welded only where one of its two pieces holds at least this share of the mesh's area (a part of the
skin): a lip or ear split off by a hard edge or a UV island joins the face, while small pieces that meet only each
other — lashes and eye films rooted at a lid (each well under 1 %), gums and a tongue — stay shells of their own,
which the rig moves whole (rigidly, with the jaw or riding the skin), as it did before."""
SOUP_SHARE = 0.5
"""When more than this share of the used vertices has a copy, the mesh is a triangle soup and is left as it is."""


def triangle_corners(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Corner positions per triangle, shape (T, 3, 3): ``corners[t, k]`` is vertex ``triangles[t, k]``."""
    points = as_finite_array(points, "points", shape=(None, 3), max_abs=_MAX_ABS)
    return points[as_triangles(triangles, len(points), "triangles", allow_empty=True)]


def triangle_crosses(corners: np.ndarray) -> np.ndarray:
    """``(p1 − p0) × (p2 − p0)`` per triangle, shape (T, 3): twice the area times the unit normal.

    Args:
        corners: triangle corners, shape (T, 3, 3) (see :func:`triangle_corners`).
    """
    corners = as_finite_array(corners, "corners", shape=(None, 3, 3), max_abs=_MAX_ABS)
    return np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])


def _crosses(corners, crosses) -> np.ndarray:
    if crosses is not None:
        return as_finite_array(crosses, "crosses", shape=(None, 3), max_abs=_MAX_ABS**2)
    if corners is None:
        raise ValueError("give corners or crosses")
    return triangle_crosses(corners)


def triangle_areas(corners: np.ndarray | None = None, *, crosses: np.ndarray | None = None) -> np.ndarray:
    """Triangle areas [units²], shape (T,), from ``corners`` (T, 3, 3) or precomputed ``crosses`` (T, 3)."""
    return 0.5 * np.linalg.norm(_crosses(corners, crosses), axis=1)


def triangle_normals(corners: np.ndarray | None = None, *, crosses: np.ndarray | None = None) -> np.ndarray:
    """Unit triangle normals (right-handed in corner order), shape (T, 3); zero rows for zero-area triangles.

    Takes ``corners`` (T, 3, 3) or precomputed ``crosses`` (T, 3).
    """
    crosses = _crosses(corners, crosses)
    length = np.linalg.norm(crosses, axis=1, keepdims=True)
    return np.divide(crosses, length, out=np.zeros_like(crosses), where=length > 0.0)


def area_weighted_vertex_normals(
    points: np.ndarray, triangles: np.ndarray, *, crosses: np.ndarray | None = None
) -> np.ndarray:
    """Area-weighted unit vertex normals in float64, shape (V, 3); zero rows for isolated vertices.

    The float64 NumPy twin of :meth:`warpface.FaceMesh.vertex_normals` (a float32 kernel), for
    one-off work that needs double precision (e.g. offsetting a surface by a thickness).

    Args:
        points: vertex positions, shape (V, 3).
        triangles: vertex indices, shape (T, 3).
        crosses: precomputed :func:`triangle_crosses` of these triangles, shape (T, 3).
    """
    points = as_finite_array(points, "points", shape=(None, 3), max_abs=_MAX_ABS)
    triangles = as_triangles(triangles, len(points), "triangles", allow_empty=True)
    if crosses is None:
        crosses = triangle_crosses(triangle_corners(points, triangles))
    else:
        crosses = as_finite_array(crosses, "crosses", shape=(len(triangles), 3), max_abs=_MAX_ABS**2)
    vertex = triangles.reshape(-1)
    summed = np.stack(
        [np.bincount(vertex, weights=np.repeat(crosses[:, k], 3), minlength=len(points)) for k in range(3)], axis=1
    ).astype(np.float64)  # bincount of no weights is int
    length = np.linalg.norm(summed, axis=1, keepdims=True)
    return np.divide(summed, length, out=np.zeros_like(summed), where=length > 0.0)


def triangle_edges(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The undirected edges of triangles (T, 3) as ``(edges (E, 2) int64 with edges[:, 0] < edges[:, 1], sorted
    lexicographically; triangles per edge (E,))``: an edge of one triangle is on an open boundary.

    The same rows as ``np.unique(np.sort(pairs, axis=1), axis=0, return_counts=True)``, found by sorting one int64
    key per edge instead of rows (3–4× faster on a 27k-vertex head, whose guards and jaw ask for it repeatedly)."""
    triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    pairs = np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    span = int(pairs.max()) + 1 if len(pairs) else 1
    keys, counts = np.unique(pairs[:, 0] * span + pairs[:, 1], return_counts=True)
    return np.stack([keys // span, keys % span], axis=1), counts


def vertex_triangles(triangles: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertex → incident triangles as CSR: ``(offsets (count + 1,), triangle ids (3T,))``, both int64; the triangles of
    vertex ``v`` are ``ids[offsets[v]:offsets[v + 1]]``, in increasing order."""
    corners = np.asarray(triangles, dtype=np.int64).reshape(-1)
    offsets = np.zeros(count + 1, dtype=np.int64)
    np.cumsum(np.bincount(corners, minlength=count), out=offsets[1:])
    return offsets, np.argsort(corners, kind="stable") // 3


def vertex_shells(triangles: np.ndarray, count: int) -> np.ndarray:
    """The shell (connected part over the triangles' edges) of each of ``count`` vertices, shape (count,) int32:
    equal labels for vertices joined by a path of edges; a vertex on no triangle is a shell of its own."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    rows, columns = triangles.ravel(), triangles[:, [1, 2, 0]].ravel()
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, columns)), shape=(count, count))
    return connected_components(graph, directed=False)[1]


def weld_seams(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The triangles (T', 3) with the copies of a vertex split along a seam joined again; vertices are untouched.

    Game and glTF exports split vertices along UV and material seams: a head comes as pieces whose borders
    coincide, and its face is no longer one connected surface. Here copies closer than :data:`SEAM_TOLERANCE`
    of the bounding-box diagonal, each on the open border of its own faces, one of them in a piece with at least
    :data:`SEAM_MIN_SHARE` of the mesh's area, and with normals (from their own faces) within
    :data:`SEAM_NORMAL_COS`, are replaced by the lowest index among them. Copies whose faces turn
    against each other stay apart: lips or lids modelled touching, whose slit must still open. A triangle that
    joining leaves with a repeated vertex is dropped. Indices out of range or non-finite points are returned as
    given, for the caller's checks to name. A triangle soup (more than :data:`SOUP_SHARE` of the used
    vertices have a copy) is returned as given, for the caller to refuse.

    Args:
        points: vertex positions (V, 3).
        triangles: vertex indices (T, 3).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    points = np.asarray(points, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    used = np.unique(triangles)
    if len(used) < 2 or used[0] < 0 or used[-1] >= len(points) or not np.isfinite(points[used]).all():
        return triangles  # nothing to join, or a fault the caller's checks name
    diagonal = float(np.linalg.norm(np.ptp(points[used], axis=0)))
    pairs = cKDTree(points[used]).query_pairs(SEAM_TOLERANCE * diagonal, output_type="ndarray")
    if len(pairs) == 0 or len(np.unique(pairs)) > SOUP_SHARE * len(used):
        return triangles
    first, second = used[pairs[:, 0]], used[pairs[:, 1]]
    edges, counts = triangle_edges(triangles)
    border = np.zeros(len(points), dtype=bool)
    border[edges[counts == 1].ravel()] = True
    shell = vertex_shells(triangles, len(points))
    corners = triangle_corners(points, triangles)
    crosses = triangle_crosses(corners)
    area = np.bincount(shell[triangles[:, 0]], weights=triangle_areas(crosses=crosses), minlength=shell.max() + 1)
    large = area[shell] >= SEAM_MIN_SHARE * area.sum()
    normals = area_weighted_vertex_normals(points, triangles, crosses=crosses)
    seam = border[first] & border[second] & (large[first] | large[second])
    seam &= np.sum(normals[first] * normals[second], axis=1) > SEAM_NORMAL_COS
    if not np.any(seam):
        return triangles
    graph = coo_matrix((np.ones(int(seam.sum())), (first[seam], second[seam])), shape=(len(points), len(points)))
    label = connected_components(graph, directed=False)[1]
    lowest = np.full(label.max() + 1, len(points), dtype=np.int64)
    np.minimum.at(lowest, label, np.arange(len(points)))
    joined = lowest[label][triangles]
    distinct = (joined[:, 0] != joined[:, 1]) & (joined[:, 1] != joined[:, 2]) & (joined[:, 0] != joined[:, 2])
    return weld_seams(points, joined[distinct])  # a small piece that met only a now-joined one joins next
