"""The registration template: the built-in face in its own landmark frame, with a coarse deformation graph.

The built-in face (:func:`warpface.assets.default_face`) and its 68 landmarks are expressed in their
:class:`~warpface.assets.FaceFrame` (origin between the eyes, x to the subject's left, y up, z out of
the face, unit = inter-ocular distance), so every length of the registration is in inter-ocular units.

The landmarks carried over are :data:`LANDMARK_POINTS`, calibrated to the ICT-FaceKit annotation.

The non-rigid fit moves a graph of ~1,500 *nodes* (farthest-point samples of the surface, the 68
landmark vertices among them), not the 11k vertices: every vertex follows the affine map of its
node, the node whose geodesic Voronoi cell holds it; nodes are neighbours when their cells share a
mesh edge, so the graph does not bridge the eyes or the mouth.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from ..assets import default_face, default_landmarks, face_frame
from .surface import vertex_normals

__all__ = ["Template", "template", "NODE_SPACING", "LANDMARK_POINTS"]

NODE_SPACING = 0.075
"""Target spacing of the deformation graph's nodes [inter-ocular units] (~4.7 mm on a 63 mm face)."""

# fmt: off
LANDMARK_POINTS = np.array(
    (
        (-1.0640, 0.2576, -0.6940), (-1.1234, -0.0833, -0.7759), (-1.0593, -0.3977, -0.7999),
        (-0.9692, -0.7001, -0.8161), (-0.8437, -1.0613, -0.7871), (-0.6363, -1.3818, -0.6915),
        (-0.4735, -1.6004, -0.5271), (-0.2306, -1.7319, -0.3431), (0.0000, -1.7949, -0.3370),
        (0.2306, -1.7319, -0.3431), (0.4735, -1.6004, -0.5271), (0.6363, -1.3818, -0.6915),
        (0.8437, -1.0613, -0.7871), (0.9692, -0.7001, -0.8161), (1.0593, -0.3977, -0.7999),
        (1.1234, -0.0833, -0.7759), (1.0640, 0.2576, -0.6940), (-0.8279, 0.2797, 0.0124),
        (-0.6996, 0.3343, 0.2168), (-0.5329, 0.3205, 0.3513), (-0.3372, 0.2672, 0.4479),
        (-0.1644, 0.1999, 0.4863), (0.1644, 0.1999, 0.4863), (0.3372, 0.2672, 0.4479),
        (0.5329, 0.3205, 0.3513), (0.6996, 0.3343, 0.2168), (0.8279, 0.2797, 0.0124),
        (0.0000, -0.1292, 0.3792), (0.0000, -0.3372, 0.3975), (0.0000, -0.5342, 0.4376),
        (0.0000, -0.7436, 0.4865), (-0.2009, -0.8511, 0.1149), (-0.0917, -0.8676, 0.1627),
        (0.0000, -0.8774, 0.1668), (0.0917, -0.8676, 0.1627), (0.2009, -0.8511, 0.1149),
        (-0.6154, -0.0222, 0.0070), (-0.5200, 0.0249, 0.1114), (-0.3872, -0.0021, 0.1735),
        (-0.2648, -0.1002, 0.1152), (-0.3911, -0.1325, 0.1346), (-0.5474, -0.1187, 0.0979),
        (0.2648, -0.1002, 0.1152), (0.3872, -0.0021, 0.1735), (0.5200, 0.0249, 0.1114),
        (0.6154, -0.0222, 0.0070), (0.5474, -0.1187, 0.0979), (0.3911, -0.1325, 0.1346),
        (-0.3979, -1.1580, -0.0993), (-0.2725, -1.1012, 0.0809), (-0.1165, -1.0708, 0.1493),
        (0.0000, -1.0823, 0.1450), (0.1165, -1.0708, 0.1493), (0.2725, -1.1012, 0.0809),
        (0.3979, -1.1580, -0.0993), (0.2988, -1.2728, -0.0191), (0.1697, -1.3281, 0.0196),
        (0.0000, -1.3442, 0.0297), (-0.1697, -1.3281, 0.0196), (-0.2988, -1.2728, -0.0191),
        (-0.3562, -1.1482, -0.0995), (-0.1534, -1.1523, 0.0089), (0.0000, -1.1630, 0.0313),
        (0.1534, -1.1523, 0.0089), (0.3562, -1.1482, -0.0995), (0.1701, -1.1687, 0.0074),
        (0.0000, -1.1724, 0.0225), (-0.1701, -1.1687, 0.0074),
    )
)
# fmt: on
"""Where the 68 landmarks are carried from, in the template's frame [inter-ocular units]: the built-in
face's own landmark vertices moved to the ICT-FaceKit annotation's convention (how far down the jaw
line, how high on the brows, how deep in the alar crease). Calibrated by ``benchmarks/rigging.py
--calibrate``: the ICT neutral's ground-truth landmarks mapped back through the registration onto the
undeformed template, then made mirror-symmetric (docs/RIG.md, "Automatic landmarks")."""


@dataclass(frozen=True)
class Template:
    """The built-in face in inter-ocular units of its landmark frame, and its deformation graph."""

    points: np.ndarray
    """Vertices (V, 3), local frame."""
    triangles: np.ndarray
    normals: np.ndarray
    """Unit vertex normals (V, 3), out of the face."""
    landmarks: np.ndarray
    """The built-in face's 68 iBUG vertex indices."""
    landmark_points: np.ndarray
    """:data:`LANDMARK_POINTS`: the points carried over as landmarks (68, 3)."""
    landmark_nodes: np.ndarray
    """Graph node carrying each landmark point (68,)."""
    boundary: np.ndarray
    """Boolean (V,): on the outline, an eye or the mouth."""
    nodes: np.ndarray
    """Vertex index of every graph node (K,)."""
    cell: np.ndarray
    """Node (0 … K−1) owning every vertex (V,)."""
    edges: np.ndarray
    """Neighbouring node pairs (E, 2)."""
    meters_per_unit: float
    """Size of one inter-ocular unit of the built-in face [m]."""
    vertical: np.ndarray
    """The head's up direction (the built-in face's +y) in the template frame, which tilts with the face."""
    forward: np.ndarray
    """The head's looking direction (the built-in face's +z) in the template frame."""


def _farthest_points(points: np.ndarray, seeds: np.ndarray, spacing: float) -> np.ndarray:
    """Indices of farthest-point samples of ``points``, starting from ``seeds``, until none is farther
    than ``spacing`` from the chosen ones."""
    chosen = list(np.unique(seeds))
    distance = np.min(np.linalg.norm(points[:, None, :] - points[chosen][None, :, :], axis=2), axis=1)
    while True:
        far = int(np.argmax(distance))
        if distance[far] <= spacing:
            return np.asarray(chosen, dtype=np.int64)
        chosen.append(far)
        distance = np.minimum(distance, np.linalg.norm(points - points[far], axis=1))


def _graph(points: np.ndarray, triangles: np.ndarray, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Geodesic Voronoi cells of ``nodes`` on the mesh, and the node pairs whose cells touch."""
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    edges = np.unique(np.sort(edges, axis=1), axis=0)
    lengths = np.linalg.norm(points[edges[:, 0]] - points[edges[:, 1]], axis=1)
    v = len(points)
    graph = coo_matrix((lengths, (edges[:, 0], edges[:, 1])), shape=(v, v)).tocsr()
    _, _, sources = dijkstra(graph, directed=False, indices=nodes, min_only=True, return_predecessors=True)
    node_of_vertex = np.full(v, -1, dtype=np.int64)
    node_of_vertex[nodes] = np.arange(len(nodes))
    cell = node_of_vertex[sources]
    pairs = np.sort(cell[edges], axis=1)
    pairs = np.unique(pairs[pairs[:, 0] != pairs[:, 1]], axis=0)
    return cell, pairs


@functools.lru_cache(maxsize=1)
def template() -> Template:
    """The cached registration template (built once, ~0.5 s)."""
    mesh = default_face()
    landmarks = default_landmarks()
    frame = face_frame(mesh, landmarks)
    points = frame.to_local(mesh.points)
    triangles = np.asarray(mesh.triangles, dtype=np.int64)
    nearest = np.argmin(np.linalg.norm(points[None, :, :] - LANDMARK_POINTS[:, None, :], axis=2), axis=1)
    nodes = _farthest_points(points, nearest, NODE_SPACING)
    cell, edges = _graph(points, triangles, nodes)
    boundary = np.zeros(len(points), dtype=bool)
    boundary[mesh.boundary_vertices] = True
    for array in (points, nodes, cell, edges, boundary):
        array.setflags(write=False)
    return Template(
        points=points,
        triangles=triangles,
        normals=vertex_normals(points, triangles),
        landmarks=landmarks,
        landmark_points=LANDMARK_POINTS,
        landmark_nodes=cell[nearest],
        boundary=boundary,
        nodes=nodes,
        cell=cell,
        edges=edges,
        meters_per_unit=float(frame.scale),
        vertical=frame.axes @ np.array([0.0, 1.0, 0.0]),
        forward=frame.axes @ np.array([0.0, 0.0, 1.0]),
    )
