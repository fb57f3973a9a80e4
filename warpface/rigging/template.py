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
from scipy.spatial import cKDTree

from ..assets import default_face, default_landmarks
from ..assets.rig import face_frame
from ..geometry.triangles import triangle_edges
from .surface import vertex_normals

__all__ = ["Template", "template", "NODE_SPACING", "OUTLINE_BAND", "LANDMARK_POINTS"]

NODE_SPACING = 0.05
"""Target spacing of the deformation graph's nodes [inter-ocular units] (~3 mm on a 63 mm face)."""
OUTLINE_BAND = 0.15
"""Template vertices this close to its boundary [inter-ocular units] take no backward (skin → template)
match: skin beyond the template's outline (ears, neck, scalp of a whole head) would pull its edge out and
slide the jaw line back (0.15 d: worst warped-head error 10.6 → 7.7 mm; 0.3 d was worse)."""

# fmt: off
LANDMARK_POINTS = np.array(
    (
        (-1.0666, 0.4737, -0.6984), (-1.1082, 0.1074, -0.7837), (-1.0958, -0.2435, -0.7931),
        (-1.0050, -0.5740, -0.8026), (-0.8769, -0.9798, -0.7783), (-0.6735, -1.3436, -0.6851),
        (-0.4876, -1.5849, -0.5254), (-0.2321, -1.7339, -0.3438), (0.0000, -1.7966, -0.3413),
        (0.2321, -1.7339, -0.3438), (0.4876, -1.5849, -0.5254), (0.6735, -1.3436, -0.6851),
        (0.8769, -0.9798, -0.7783), (1.0050, -0.5740, -0.8026), (1.0958, -0.2435, -0.7931),
        (1.1082, 0.1074, -0.7837), (1.0666, 0.4737, -0.6984), (-0.8537, 0.3846, 0.0192),
        (-0.7102, 0.4160, 0.2138), (-0.5426, 0.3873, 0.3510), (-0.3457, 0.3165, 0.4479),
        (-0.1718, 0.2429, 0.4951), (0.1718, 0.2429, 0.4951), (0.3457, 0.3165, 0.4479),
        (0.5426, 0.3873, 0.3510), (0.7102, 0.4160, 0.2138), (0.8537, 0.3846, 0.0192),
        (0.0000, -0.1036, 0.3993), (0.0000, -0.3224, 0.3998), (0.0000, -0.5319, 0.4330),
        (0.0000, -0.7544, 0.4869), (-0.2134, -0.8583, 0.1199), (-0.0961, -0.8699, 0.1631),
        (0.0000, -0.8663, 0.1542), (0.0961, -0.8699, 0.1631), (0.2134, -0.8583, 0.1199),
        (-0.6103, 0.0919, -0.0151), (-0.5410, 0.0867, 0.1346), (-0.4024, 0.0470, 0.1895),
        (-0.2747, -0.0508, 0.1126), (-0.3978, -0.0965, 0.1104), (-0.5596, -0.0780, 0.0702),
        (0.2747, -0.0508, 0.1126), (0.4024, 0.0470, 0.1895), (0.5410, 0.0867, 0.1346),
        (0.6103, 0.0919, -0.0151), (0.5596, -0.0780, 0.0702), (0.3978, -0.0965, 0.1104),
        (-0.4070, -1.1347, -0.0997), (-0.2780, -1.1021, 0.0790), (-0.1186, -1.0795, 0.1454),
        (0.0000, -1.0912, 0.1379), (0.1186, -1.0795, 0.1454), (0.2780, -1.1021, 0.0790),
        (0.4070, -1.1347, -0.0997), (0.3082, -1.2675, -0.0178), (0.1674, -1.3294, 0.0114),
        (0.0000, -1.3496, 0.0254), (-0.1674, -1.3294, 0.0114), (-0.3082, -1.2675, -0.0178),
        (-0.3671, -1.1253, -0.0963), (-0.1581, -1.1528, 0.0052), (0.0000, -1.1607, 0.0170),
        (0.1581, -1.1528, 0.0052), (0.3671, -1.1253, -0.0963), (0.1712, -1.1644, -0.0023),
        (0.0000, -1.1700, 0.0083), (-0.1712, -1.1644, -0.0023),
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
    outline: np.ndarray
    """Boolean (V,): within :data:`OUTLINE_BAND` of the boundary (no backward matches there)."""
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
    tree = cKDTree(points)
    while True:
        far = int(np.argmax(distance))
        if distance[far] <= spacing:
            return np.asarray(chosen, dtype=np.int64)
        chosen.append(far)
        # only points nearer the new sample than the farthest distance so far can come nearer to the samples
        near = np.asarray(tree.query_ball_point(points[far], distance[far]), dtype=np.int64)
        distance[near] = np.minimum(distance[near], np.linalg.norm(points[near] - points[far], axis=1))


def _graph(points: np.ndarray, triangles: np.ndarray, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Geodesic Voronoi cells of ``nodes`` on the mesh, and the node pairs whose cells touch."""
    edges = triangle_edges(triangles)[0]
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
    nodes = _farthest_points(points, landmarks, NODE_SPACING)
    cell, edges = _graph(points, triangles, nodes)
    boundary = np.zeros(len(points), dtype=bool)
    boundary[mesh.boundary_vertices] = True
    outline = cKDTree(points[boundary]).query(points)[0] < OUTLINE_BAND
    for array in (points, nodes, cell, edges, boundary, outline):
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
        outline=outline,
        nodes=nodes,
        cell=cell,
        edges=edges,
        meters_per_unit=float(frame.scale),
        vertical=frame.axes @ np.array([0.0, 1.0, 0.0]),
        forward=frame.axes @ np.array([0.0, 0.0, 1.0]),
    )
