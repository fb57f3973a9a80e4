"""The registration template: the built-in face in its own landmark frame, with a coarse deformation graph.

The built-in face (:func:`warpface.assets.default_face`) and its 68 landmarks are expressed in their
:class:`~warpface.assets.FaceFrame` (origin between the eyes, x to the subject's left, y up, z out of
the face, unit = inter-ocular distance), so every length of the registration is in inter-ocular units.

The landmarks carried over are :data:`LANDMARK_POINTS`, calibrated to the ICT-FaceKit annotation.

The non-rigid fit moves a graph of ~2,700 *nodes* (farthest-point samples of the surface, the 68
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

from ..assets import default_face, default_landmarks
from ..assets.rig import face_frame
from .surface import vertex_normals

__all__ = ["Template", "template", "NODE_SPACING", "LANDMARK_POINTS"]

NODE_SPACING = 0.05
"""Target spacing of the deformation graph's nodes [inter-ocular units] (~3 mm on a 63 mm face)."""

# fmt: off
LANDMARK_POINTS = np.array(
    (
        (-1.0634, 0.2685, -0.6898), (-1.1213, -0.0695, -0.7670), (-1.0589, -0.3770, -0.7852),
        (-0.9751, -0.6761, -0.8015), (-0.8544, -1.0415, -0.7717), (-0.6534, -1.3671, -0.6806),
        (-0.4835, -1.5869, -0.5165), (-0.2333, -1.7233, -0.3337), (0.0000, -1.7891, -0.3248),
        (0.2333, -1.7233, -0.3337), (0.4835, -1.5869, -0.5165), (0.6534, -1.3671, -0.6806),
        (0.8544, -1.0415, -0.7717), (0.9751, -0.6761, -0.8015), (1.0589, -0.3770, -0.7852),
        (1.1213, -0.0695, -0.7670), (1.0634, 0.2685, -0.6898), (-0.8339, 0.3068, 0.0087),
        (-0.7087, 0.3544, 0.2155), (-0.5396, 0.3338, 0.3499), (-0.3423, 0.2776, 0.4471),
        (-0.1683, 0.2109, 0.4878), (0.1683, 0.2109, 0.4878), (0.3423, 0.2776, 0.4471),
        (0.5396, 0.3338, 0.3499), (0.7087, 0.3544, 0.2155), (0.8339, 0.3068, 0.0087),
        (0.0000, -0.1182, 0.3854), (0.0000, -0.3249, 0.3967), (0.0000, -0.5260, 0.4292),
        (0.0000, -0.7355, 0.4892), (-0.2232, -0.8644, 0.1347), (-0.0963, -0.8679, 0.1639),
        (0.0000, -0.8683, 0.1607), (0.0963, -0.8679, 0.1639), (0.2232, -0.8644, 0.1347),
        (-0.5928, 0.0676, -0.0306), (-0.5264, 0.0741, 0.1089), (-0.3854, 0.0374, 0.1655),
        (-0.2682, -0.0890, 0.1168), (-0.3934, -0.1387, 0.1158), (-0.5469, -0.1371, 0.0601),
        (0.2682, -0.0890, 0.1168), (0.3854, 0.0374, 0.1655), (0.5264, 0.0741, 0.1089),
        (0.5928, 0.0676, -0.0306), (0.5469, -0.1371, 0.0601), (0.3934, -0.1387, 0.1158),
        (-0.4197, -1.1501, -0.0823), (-0.2778, -1.0968, 0.0838), (-0.1183, -1.0663, 0.1499),
        (0.0000, -1.0784, 0.1360), (0.1183, -1.0663, 0.1499), (0.2778, -1.0968, 0.0838),
        (0.4197, -1.1501, -0.0823), (0.3034, -1.2676, -0.0172), (0.1697, -1.3242, 0.0225),
        (0.0000, -1.3393, 0.0342), (-0.1697, -1.3242, 0.0225), (-0.3034, -1.2676, -0.0172),
        (-0.3705, -1.1421, -0.0900), (-0.1570, -1.1493, 0.0090), (0.0000, -1.1587, 0.0257),
        (0.1570, -1.1493, 0.0090), (0.3705, -1.1421, -0.0900), (0.1701, -1.1610, 0.0012),
        (0.0000, -1.1681, 0.0170), (-0.1701, -1.1610, 0.0012),
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
    landmark_vertices: np.ndarray
    """Template vertex nearest each landmark point (68,): its normal is the landmark's."""
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
        landmark_vertices=nearest,
        landmark_nodes=cell[nearest],
        boundary=boundary,
        nodes=nodes,
        cell=cell,
        edges=edges,
        meters_per_unit=float(frame.scale),
        vertical=frame.axes @ np.array([0.0, 1.0, 0.0]),
        forward=frame.axes @ np.array([0.0, 0.0, 1.0]),
    )
