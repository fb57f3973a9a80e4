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
        (-1.0619, 0.2444, -0.6885), (-1.1234, -0.0915, -0.7672), (-1.0595, -0.4009, -0.7885),
        (-0.9689, -0.6988, -0.8025), (-0.8465, -1.0539, -0.7770), (-0.6439, -1.3795, -0.6849),
        (-0.4772, -1.5938, -0.5200), (-0.2323, -1.7257, -0.3353), (0.0000, -1.7930, -0.3327),
        (0.2323, -1.7257, -0.3353), (0.4772, -1.5938, -0.5200), (0.6439, -1.3795, -0.6849),
        (0.8465, -1.0539, -0.7770), (0.9689, -0.6988, -0.8025), (1.0595, -0.4009, -0.7885),
        (1.1234, -0.0915, -0.7672), (1.0619, 0.2444, -0.6885), (-0.8266, 0.2814, 0.0093),
        (-0.7065, 0.3335, 0.2184), (-0.5364, 0.3216, 0.3491), (-0.3416, 0.2652, 0.4469),
        (-0.1685, 0.1961, 0.4851), (0.1685, 0.1961, 0.4851), (0.3416, 0.2652, 0.4469),
        (0.5364, 0.3216, 0.3491), (0.7065, 0.3335, 0.2184), (0.8266, 0.2814, 0.0093),
        (0.0000, -0.1274, 0.3830), (0.0000, -0.3342, 0.3969), (0.0000, -0.5300, 0.4314),
        (0.0000, -0.7372, 0.4879), (-0.2059, -0.8613, 0.1167), (-0.0958, -0.8671, 0.1581),
        (0.0000, -0.8699, 0.1621), (0.0958, -0.8671, 0.1581), (0.2059, -0.8613, 0.1167),
        (-0.5840, 0.0533, -0.0325), (-0.5257, 0.0703, 0.1068), (-0.3865, 0.0240, 0.1721),
        (-0.2694, -0.0996, 0.1198), (-0.3962, -0.1431, 0.1245), (-0.5519, -0.1418, 0.0653),
        (0.2694, -0.0996, 0.1198), (0.3865, 0.0240, 0.1721), (0.5257, 0.0703, 0.1068),
        (0.5840, 0.0533, -0.0325), (0.5519, -0.1418, 0.0653), (0.3962, -0.1431, 0.1245),
        (-0.4192, -1.1563, -0.0872), (-0.2769, -1.1004, 0.0787), (-0.1180, -1.0730, 0.1458),
        (0.0000, -1.0836, 0.1380), (0.1180, -1.0730, 0.1458), (0.2769, -1.1004, 0.0787),
        (0.4192, -1.1563, -0.0872), (0.3019, -1.2756, -0.0228), (0.1698, -1.3280, 0.0173),
        (0.0000, -1.3420, 0.0341), (-0.1698, -1.3280, 0.0173), (-0.3019, -1.2756, -0.0228),
        (-0.3701, -1.1483, -0.0950), (-0.1579, -1.1513, 0.0092), (0.0000, -1.1563, 0.0255),
        (0.1579, -1.1513, 0.0092), (0.3701, -1.1483, -0.0950), (0.1720, -1.1652, 0.0026),
        (0.0000, -1.1656, 0.0168), (-0.1720, -1.1652, 0.0026),
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
