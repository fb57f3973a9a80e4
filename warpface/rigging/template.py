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

LANDMARK_POINTS = np.array(
    (
        (-1.0625, 0.2183, -0.6840),
        (-1.1168, -0.1110, -0.7546),
        (-1.0526, -0.4143, -0.7770),
        (-0.9595, -0.7051, -0.7968),
        (-0.8413, -1.0613, -0.7724),
        (-0.6426, -1.3727, -0.6721),
        (-0.4814, -1.5911, -0.5182),
        (-0.2350, -1.7227, -0.3370),
        (0.0000, -1.7873, -0.3328),
        (0.2350, -1.7227, -0.3370),
        (0.4814, -1.5911, -0.5182),
        (0.6426, -1.3727, -0.6721),
        (0.8413, -1.0613, -0.7724),
        (0.9595, -0.7051, -0.7968),
        (1.0526, -0.4143, -0.7770),
        (1.1168, -0.1110, -0.7546),
        (1.0625, 0.2183, -0.6840),
        (-0.8175, 0.2385, -0.0082),
        (-0.7127, 0.2867, 0.2123),
        (-0.5434, 0.2789, 0.3412),
        (-0.3422, 0.2300, 0.4393),
        (-0.1652, 0.1627, 0.4733),
        (0.1652, 0.1627, 0.4733),
        (0.3422, 0.2300, 0.4393),
        (0.5434, 0.2789, 0.3412),
        (0.7127, 0.2867, 0.2123),
        (0.8175, 0.2385, -0.0082),
        (0.0000, -0.1579, 0.3845),
        (0.0000, -0.3591, 0.3935),
        (0.0000, -0.5539, 0.4355),
        (0.0000, -0.7574, 0.4859),
        (-0.2112, -0.8670, 0.1198),
        (-0.0908, -0.8628, 0.1329),
        (0.0000, -0.8774, 0.1596),
        (0.0908, -0.8628, 0.1329),
        (0.2112, -0.8670, 0.1198),
        (-0.5846, -0.0305, -0.0214),
        (-0.4946, 0.0183, 0.0665),
        (-0.3632, -0.0024, 0.1219),
        (-0.2732, -0.1234, 0.1295),
        (-0.3906, -0.1507, 0.1268),
        (-0.5384, -0.1349, 0.0810),
        (0.2732, -0.1234, 0.1295),
        (0.3632, -0.0024, 0.1219),
        (0.4946, 0.0183, 0.0665),
        (0.5846, -0.0305, -0.0214),
        (0.5384, -0.1349, 0.0810),
        (0.3906, -0.1507, 0.1268),
        (-0.4187, -1.1560, -0.0741),
        (-0.2778, -1.1050, 0.0842),
        (-0.1198, -1.0745, 0.1475),
        (0.0000, -1.0819, 0.1403),
        (0.1198, -1.0745, 0.1475),
        (0.2778, -1.1050, 0.0842),
        (0.4187, -1.1560, -0.0741),
        (0.3201, -1.2715, 0.0061),
        (0.1658, -1.3194, 0.0108),
        (0.0000, -1.3380, 0.0236),
        (-0.1658, -1.3194, 0.0108),
        (-0.3201, -1.2715, 0.0061),
        (-0.3690, -1.1480, -0.0823),
        (-0.1567, -1.1542, 0.0111),
        (0.0000, -1.1566, 0.0253),
        (0.1567, -1.1542, 0.0111),
        (0.3690, -1.1480, -0.0823),
        (0.1760, -1.1765, 0.0142),
        (0.0000, -1.1658, 0.0164),
        (-0.1760, -1.1765, 0.0142),
    )
)
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
