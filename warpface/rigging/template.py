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
        (-1.0498, 0.3169, -0.6561), (-1.1217, -0.0529, -0.7404), (-1.0571, -0.3835, -0.7640),
        (-0.9610, -0.7061, -0.7850), (-0.8325, -1.0852, -0.7693), (-0.6139, -1.4082, -0.6897),
        (-0.4571, -1.6201, -0.5299), (-0.2197, -1.7450, -0.3523), (0.0000, -1.7999, -0.3441),
        (0.2197, -1.7450, -0.3523), (0.4571, -1.6201, -0.5299), (0.6139, -1.4082, -0.6897),
        (0.8325, -1.0852, -0.7693), (0.9610, -0.7061, -0.7850), (1.0571, -0.3835, -0.7640),
        (1.1217, -0.0529, -0.7404), (1.0498, 0.3169, -0.6561), (-0.8340, 0.3369, 0.0485),
        (-0.6884, 0.3933, 0.2371), (-0.5220, 0.3830, 0.3645), (-0.3329, 0.3288, 0.4537),
        (-0.1640, 0.2578, 0.4997), (0.1640, 0.2578, 0.4997), (0.3329, 0.3288, 0.4537),
        (0.5220, 0.3830, 0.3645), (0.6884, 0.3933, 0.2371), (0.8340, 0.3369, 0.0485),
        (0.0000, -0.0931, 0.3966), (0.0000, -0.3035, 0.4021), (0.0000, -0.5075, 0.4289),
        (0.0000, -0.7273, 0.4868), (-0.2120, -0.8647, 0.1282), (-0.0914, -0.8622, 0.1540),
        (0.0000, -0.8690, 0.1599), (0.0914, -0.8622, 0.1540), (0.2120, -0.8647, 0.1282),
        (-0.5853, 0.0504, 0.0026), (-0.5183, 0.0664, 0.1490), (-0.3861, 0.0375, 0.2017),
        (-0.2641, -0.0666, 0.1304), (-0.3853, -0.0973, 0.1419), (-0.5382, -0.0829, 0.1041),
        (0.2641, -0.0666, 0.1304), (0.3861, 0.0375, 0.2017), (0.5183, 0.0664, 0.1490),
        (0.5853, 0.0504, 0.0026), (0.5382, -0.0829, 0.1041), (0.3853, -0.0973, 0.1419),
        (-0.4011, -1.1765, -0.0920), (-0.2701, -1.1090, 0.0797), (-0.1122, -1.0740, 0.1389),
        (0.0000, -1.0857, 0.1432), (0.1122, -1.0740, 0.1389), (0.2701, -1.1090, 0.0797),
        (0.4011, -1.1765, -0.0920), (0.2857, -1.2820, -0.0360), (0.1629, -1.3352, 0.0067),
        (0.0000, -1.3456, 0.0116), (-0.1629, -1.3352, 0.0067), (-0.2857, -1.2820, -0.0360),
        (-0.3527, -1.1680, -0.0994), (-0.1524, -1.1611, 0.0036), (0.0000, -1.1644, 0.0195),
        (0.1524, -1.1611, 0.0036), (0.3527, -1.1680, -0.0994), (0.1745, -1.1832, 0.0262),
        (0.0000, -1.2001, 0.0443), (-0.1745, -1.1832, 0.0262),
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
