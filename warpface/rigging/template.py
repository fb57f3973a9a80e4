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

from ..assets import default_face, default_landmarks, face_frame
from .surface import vertex_normals

__all__ = ["Template", "template", "NODE_SPACING", "LANDMARK_POINTS"]

NODE_SPACING = 0.05
"""Target spacing of the deformation graph's nodes [inter-ocular units] (~3 mm on a 63 mm face)."""

# fmt: off
LANDMARK_POINTS = np.array(
    (
        (-1.0697, 0.2545, -0.6868), (-1.1189, -0.0794, -0.7708), (-1.0613, -0.3915, -0.7901),
        (-0.9679, -0.6860, -0.8058), (-0.8500, -1.0481, -0.7789), (-0.6490, -1.3660, -0.6869),
        (-0.4820, -1.5906, -0.5215), (-0.2334, -1.7249, -0.3375), (0.0000, -1.7922, -0.3333),
        (0.2334, -1.7249, -0.3375), (0.4820, -1.5906, -0.5215), (0.6490, -1.3660, -0.6869),
        (0.8500, -1.0481, -0.7789), (0.9679, -0.6860, -0.8058), (1.0613, -0.3915, -0.7901),
        (1.1189, -0.0794, -0.7708), (1.0697, 0.2545, -0.6868), (-0.8325, 0.2961, 0.0080),
        (-0.7095, 0.3390, 0.2151), (-0.5395, 0.3246, 0.3486), (-0.3428, 0.2678, 0.4457),
        (-0.1676, 0.2005, 0.4858), (0.1676, 0.2005, 0.4858), (0.3428, 0.2678, 0.4457),
        (0.5395, 0.3246, 0.3486), (0.7095, 0.3390, 0.2151), (0.8325, 0.2961, 0.0080),
        (0.0000, -0.1233, 0.3841), (0.0000, -0.3320, 0.3925), (0.0000, -0.5301, 0.4317),
        (0.0000, -0.7395, 0.4875), (-0.2229, -0.8675, 0.1348), (-0.0948, -0.8672, 0.1617),
        (0.0000, -0.8703, 0.1606), (0.0948, -0.8672, 0.1617), (0.2229, -0.8675, 0.1348),
        (-0.5895, 0.0655, -0.0314), (-0.5253, 0.0722, 0.1078), (-0.3845, 0.0317, 0.1656),
        (-0.2707, -0.0957, 0.1208), (-0.3937, -0.1407, 0.1177), (-0.5471, -0.1396, 0.0611),
        (0.2707, -0.0957, 0.1208), (0.3845, 0.0317, 0.1656), (0.5253, 0.0722, 0.1078),
        (0.5895, 0.0655, -0.0314), (0.5471, -0.1396, 0.0611), (0.3937, -0.1407, 0.1177),
        (-0.4270, -1.1722, -0.0904), (-0.2782, -1.0991, 0.0813), (-0.1157, -1.0716, 0.1472),
        (0.0000, -1.0804, 0.1363), (0.1157, -1.0716, 0.1472), (0.2782, -1.0991, 0.0813),
        (0.4270, -1.1722, -0.0904), (0.3050, -1.2785, -0.0234), (0.1687, -1.3272, 0.0176),
        (0.0000, -1.3406, 0.0318), (-0.1687, -1.3272, 0.0176), (-0.3050, -1.2785, -0.0234),
        (-0.3666, -1.1531, -0.1011), (-0.1567, -1.1519, 0.0047), (0.0000, -1.1593, 0.0248),
        (0.1567, -1.1519, 0.0047), (0.3666, -1.1531, -0.1011), (0.1695, -1.1639, -0.0054),
        (0.0000, -1.1686, 0.0161), (-0.1695, -1.1639, -0.0054),
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
