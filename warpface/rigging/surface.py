"""A head mesh as found in a file, made ready for landmark detection: triangles, shells, the skin.

Character heads come with extra shells (eyeballs, teeth, gums, tongue) and in quads or n-gons. The
detector works on triangles of the *skin*: the shell with the largest surface area. Vertex indices
stay those of the input, so whatever is found points into the user's own vertex order.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .._validate import as_finite_array
from ..geometry.triangles import triangle_edges, vertex_shells, weld_seams
from ..mesh import fan_triangles

__all__ = [
    "HeadSurface",
    "midpoint_samples",
    "polygons_to_triangles",
    "vertex_normals",
    "TWIN_AREA",
    "MIN_SKIN_VERTICES",
    "MIN_FIT_POINTS",
]

MIN_SKIN_VERTICES = 100
"""Fewer vertices in the largest shell cannot hold a face."""
TWIN_AREA = 0.5
"""A second shell with more than this fraction of the skin's area, away from it, is a second head."""
MIN_FIT_POINTS = 5000
"""A skin with fewer vertices is sampled more densely for the similarity fit (:attr:`HeadSurface.skin_samples`): its
score is the template's distance to the nearest skin point, and on a low-poly face the nearest vertex lies up to half
an edge off the surface (MediaPipe's 468-vertex canonical face: 0.089 eye distances on its vertices, 0.064 with the
midpoints, as on the same surface split finely; a face is refused above 0.12)."""


def polygons_to_triangles(counts, indices) -> np.ndarray:
    """Polygons given as per-face corner counts and flat corner indices → fan triangles (T, 3) int64."""
    return fan_triangles(counts, indices)


def vertex_normals(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (V, 3); a vertex on no triangle gets (0, 0, 0)."""
    corners = points[triangles]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals = np.zeros_like(points)
    for k in range(3):
        np.add.at(normals, triangles[:, k], cross)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)


def midpoint_samples(
    points: np.ndarray, normals: np.ndarray, boundary: np.ndarray, triangles: np.ndarray, minimum: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``points`` (N, 3) with unit ``normals`` and ``boundary`` flags (N,), then their triangles' (local indices)
    edge midpoints, the triangles split at them level by level until there are at least ``minimum`` points; a
    midpoint's normal is its edge's normalised mean, and it is on the boundary when its edge is (an edge of one
    triangle). Returns (points, normals, boundary)."""
    while len(points) < minimum:
        edges, uses = triangle_edges(triangles)  # sorted by a * span + b for any span above the largest index
        middle = len(points) + np.arange(len(edges))
        span = len(points)
        pairs = np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        mid = middle[np.searchsorted(edges[:, 0] * span + edges[:, 1], pairs[:, 0] * span + pairs[:, 1])]
        mid = mid.reshape(-1, 3)  # the midpoints of edges 01, 12, 20
        mean = normals[edges[:, 0]] + normals[edges[:, 1]]
        points = np.concatenate([points, 0.5 * (points[edges[:, 0]] + points[edges[:, 1]])])
        normals = np.concatenate([normals, mean / np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-300)])
        boundary = np.concatenate([boundary, uses == 1])
        a, b, c = triangles.T
        triangles = np.concatenate(
            [
                np.stack([a, mid[:, 0], mid[:, 2]], axis=1),
                np.stack([b, mid[:, 1], mid[:, 0]], axis=1),
                np.stack([c, mid[:, 2], mid[:, 1]], axis=1),
                mid,
            ]
        )
    return points, normals, boundary


@dataclass(eq=False)
class HeadSurface:
    """Points and triangles of a head mesh, with its shells split and the skin picked.

    Args:
        points: vertex positions (V, 3) in the file's units.
        triangles: (T, 3) vertex indices (fan-triangulate polygons first with :func:`polygons_to_triangles`);
            vertices split along seams are joined (:func:`~warpface.geometry.triangles.weld_seams`).
        label: names the mesh in error messages.

    Raises:
        ValueError: no vertices, no faces (a point cloud), indices out of range, non-finite points,
            or a skin with no area.
    """

    points: np.ndarray
    triangles: np.ndarray
    label: str = "mesh"

    def __post_init__(self) -> None:
        for name, value in (("points", self.points), ("triangles", self.triangles)):
            if value is None or isinstance(value, (str, bytes)):
                raise TypeError(f"{self.label}: {name}: expected an array, got {type(value).__name__}")
        points = np.asarray(self.points)
        if points.size == 0:
            raise ValueError(f"{self.label}: has no vertices; export the head mesh with its geometry")
        self.points = as_finite_array(points, f"{self.label}: points", shape=(None, 3))
        triangles = np.asarray(self.triangles)
        if triangles.size == 0:
            raise ValueError(
                f"{self.label}: {len(self.points)} vertices but no faces (a point cloud?); "
                "landmarks need a surface mesh: export it with its faces or mesh the scan first"
            )
        if triangles.ndim != 2 or triangles.shape[1] != 3 or not np.issubdtype(triangles.dtype, np.integer):
            raise ValueError(f"{self.label}: triangles must be an integer (T, 3) array, got shape {triangles.shape}")
        if triangles.min() < 0 or triangles.max() >= len(self.points):
            raise ValueError(f"{self.label}: face vertex indices outside [0, {len(self.points)})")
        keep = (
            (triangles[:, 0] != triangles[:, 1])
            & (triangles[:, 1] != triangles[:, 2])
            & (triangles[:, 0] != triangles[:, 2])
        )
        self.triangles = weld_seams(self.points, triangles[keep])  # a head split along UV seams is one surface
        if len(self.triangles) == 0:
            raise ValueError(f"{self.label}: every face repeats a vertex; no surface to find a face on")

    @cached_property
    def shell_of_vertex(self) -> np.ndarray:
        """Connected-component label of every vertex (V,); vertices on no face get their own labels."""
        return vertex_shells(self.triangles, len(self.points))

    @cached_property
    def triangle_areas(self) -> np.ndarray:
        corners = self.points[self.triangles]
        return 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)

    @cached_property
    def shell_areas(self) -> np.ndarray:
        """Surface area of every shell label (indexed by label)."""
        labels = self.shell_of_vertex[self.triangles[:, 0]]
        return np.bincount(labels, weights=self.triangle_areas, minlength=int(self.shell_of_vertex.max()) + 1)

    @property
    def shell_count(self) -> int:
        """Shells that carry faces."""
        return int(np.count_nonzero(self.shell_areas > 0))

    @cached_property
    def skin_label(self) -> int:
        """The shell of largest area; ValueError when a second shell as large lies apart from it (two heads)."""
        order = np.argsort(self.shell_areas)[::-1]
        size = int(np.count_nonzero(self.shell_of_vertex == order[0]))
        if size < MIN_SKIN_VERTICES:
            raise ValueError(
                f"{self.label}: the largest connected part has only {size} vertices (a triangle soup? weld its "
                "vertices); a face needs a few thousand"
            )
        if len(order) > 1 and self.shell_areas[order[1]] > TWIN_AREA * self.shell_areas[order[0]]:
            first, second = (self.points[self.shell_of_vertex == label] for label in order[:2])
            diagonal = float(np.linalg.norm(np.ptp(first, axis=0)))
            if np.linalg.norm(first.mean(axis=0) - second.mean(axis=0)) > 0.5 * diagonal:
                raise ValueError(
                    f"{self.label}: two head-sized parts apart from each other ({len(first)} and {len(second)} "
                    "vertices); export one head per file"
                )
        return int(order[0])

    @cached_property
    def skin_triangles(self) -> np.ndarray:
        """Triangles of the skin shell (T_s, 3), indices into :attr:`points`."""
        triangles = self.triangles[self.shell_of_vertex[self.triangles[:, 0]] == self.skin_label]
        areas = self.triangle_areas[self.shell_of_vertex[self.triangles[:, 0]] == self.skin_label]
        if areas.sum() <= 0.0:
            raise ValueError(f"{self.label}: the largest shell has no area; no surface to find a face on")
        return triangles

    @cached_property
    def skin_vertices(self) -> np.ndarray:
        """Vertex indices of the skin shell (sorted)."""
        return np.unique(self.skin_triangles)

    @cached_property
    def skin_faces(self) -> np.ndarray:
        """:attr:`skin_triangles` as indices into :attr:`skin_vertices` (T_s, 3)."""
        return np.searchsorted(self.skin_vertices, self.skin_triangles)

    @cached_property
    def skin_normals(self) -> np.ndarray:
        """Unit normals of :attr:`skin_vertices` (in their order), from the skin's triangles, turned outward:
        a mesh wound inside out gets its normals flipped (most of them must point away from the skin's centre)."""
        normals = vertex_normals(self.points, self.skin_triangles)[self.skin_vertices]
        return -normals if self.inside_out else normals

    @cached_property
    def inside_out(self) -> bool:
        """True when the skin is wound inside out: most of its normals point toward its centre."""
        normals = vertex_normals(self.points, self.skin_triangles)[self.skin_vertices]
        points = self.points[self.skin_vertices]
        outward = np.sum((points - points.mean(axis=0)) * normals, axis=1)
        return bool(np.count_nonzero(outward > 0) < np.count_nonzero(outward < 0))

    @cached_property
    def skin_boundary(self) -> np.ndarray:
        """Boolean per :attr:`skin_vertices`: the vertex lies on a boundary edge (an edge of one triangle)."""
        unique, counts = triangle_edges(self.skin_triangles)
        on_boundary = np.zeros(len(self.points), dtype=bool)
        on_boundary[unique[counts == 1].ravel()] = True
        return on_boundary[self.skin_vertices]

    @cached_property
    def skin_samples(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points on the skin for the similarity fit, their outward unit normals (N, 3 each) and open-boundary flags
        (N,): the skin's vertices (in :attr:`skin_vertices` order), then, while there are fewer than
        :data:`MIN_FIT_POINTS`, its edges' midpoints level by level (a low-poly head; every later stage and the
        landmarks use the vertices)."""
        vertices = self.points[self.skin_vertices]
        return midpoint_samples(vertices, self.skin_normals, self.skin_boundary, self.skin_faces, MIN_FIT_POINTS)
