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
        (-1.0531, 0.3252, -0.6652), (-1.1186, -0.0457, -0.7468), (-1.0611, -0.3791, -0.7731),
        (-0.9643, -0.7002, -0.7961), (-0.8360, -1.0807, -0.7734), (-0.6163, -1.4101, -0.6917),
        (-0.4597, -1.6198, -0.5309), (-0.2214, -1.7440, -0.3523), (0.0000, -1.8007, -0.3440),
        (0.2214, -1.7440, -0.3523), (0.4597, -1.6198, -0.5309), (0.6163, -1.4101, -0.6917),
        (0.8360, -1.0807, -0.7734), (0.9643, -0.7002, -0.7961), (1.0611, -0.3791, -0.7731),
        (1.1186, -0.0457, -0.7468), (1.0531, 0.3252, -0.6652), (-0.8369, 0.3436, 0.0421),
        (-0.6912, 0.4043, 0.2333), (-0.5248, 0.3907, 0.3635), (-0.3354, 0.3332, 0.4535),
        (-0.1662, 0.2638, 0.4963), (0.1662, 0.2638, 0.4963), (0.3354, 0.3332, 0.4535),
        (0.5248, 0.3907, 0.3635), (0.6912, 0.4043, 0.2333), (0.8369, 0.3436, 0.0421),
        (0.0000, -0.0938, 0.3971), (0.0000, -0.3068, 0.4029), (0.0000, -0.5093, 0.4292),
        (0.0000, -0.7295, 0.4878), (-0.2107, -0.8600, 0.1207), (-0.0925, -0.8637, 0.1569),
        (0.0000, -0.8690, 0.1607), (0.0925, -0.8637, 0.1569), (0.2107, -0.8600, 0.1207),
        (-0.5934, 0.0744, -0.0033), (-0.5216, 0.0869, 0.1365), (-0.3908, 0.0439, 0.1942),
        (-0.2643, -0.0773, 0.1226), (-0.3826, -0.1259, 0.1158), (-0.5342, -0.1196, 0.0542),
        (0.2643, -0.0773, 0.1226), (0.3908, 0.0439, 0.1942), (0.5216, 0.0869, 0.1365),
        (0.5934, 0.0744, -0.0033), (0.5342, -0.1196, 0.0542), (0.3826, -0.1259, 0.1158),
        (-0.4307, -1.2076, -0.0901), (-0.2707, -1.1055, 0.0861), (-0.1120, -1.0700, 0.1399),
        (0.0000, -1.0801, 0.1417), (0.1120, -1.0700, 0.1399), (0.2707, -1.1055, 0.0861),
        (0.4307, -1.2076, -0.0901), (0.3011, -1.2976, -0.0308), (0.1647, -1.3375, 0.0041),
        (0.0000, -1.3496, 0.0070), (-0.1647, -1.3375, 0.0041), (-0.3011, -1.2976, -0.0308),
        (-0.3817, -1.1988, -0.0978), (-0.1486, -1.1563, 0.0052), (0.0000, -1.1582, 0.0176),
        (0.1486, -1.1563, 0.0052), (0.3817, -1.1988, -0.0978), (0.1789, -1.1913, 0.0274),
        (0.0000, -1.2045, 0.0455), (-0.1789, -1.1913, 0.0274),
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
