"""``FaceMesh``: the rest surface of a face — points, triangles, adjacency, areas, normals.

Everything here depends only on rest geometry and is computed once; per-frame quantities live in
:mod:`warpface.expression`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import warp as wp

from ._validate import as_device, as_path, as_points, as_triangles
from .geometry import triangle_areas, triangle_corners
from .geometry.triangles import triangle_crosses, triangle_edges, vertex_shells, vertex_triangles
from .kernels_surface import frame_sizes, stretch_reference_lengths, triangle_area_vectors, vertex_normals_kernel

__all__ = [
    "FaceMesh",
    "VertexTriangleAdjacency",
    "load_obj",
    "read_obj_polygons",
    "ObjPolygons",
    "fan_triangles",
    "DEGENERATE_AREA_RTOL",
    "MIN_TRIANGLE_AREA",
]

DEGENERATE_AREA_RTOL = 1e-12
"""A rest triangle is degenerate when its area ≤ this × (bounding-box diagonal)²."""

MIN_TRIANGLE_AREA = 1e-15
"""A rest triangle is degenerate when its area ≤ this [mesh units²], whatever the mesh's size: the
float32 kernels square area vectors (≈ area²), which would underflow to 0 and divide the stretch
ratio by zero. It is also degenerate when rounding its corners to float32 loses half its area
(a tiny triangle far from the origin), for the same reason."""


@dataclass(frozen=True)
class VertexTriangleAdjacency:
    """Vertex → incident triangles in CSR form.

    Triangles of vertex ``v`` are ``triangles[offsets[v]:offsets[v + 1]]``.
    """

    offsets: np.ndarray
    """Row offsets, shape (V + 1,), int32."""
    triangles: np.ndarray
    """Incident triangle indices, shape (3·T,), int32, sorted by vertex then triangle."""

    @property
    def counts(self) -> np.ndarray:
        """Number of incident triangles per vertex, shape (V,), int32."""
        return np.diff(self.offsets).astype(np.int32)


@dataclass(eq=False)
class FaceMesh:
    """A validated triangle surface at rest.

    Args:
        points: rest positions, shape (V, 3), any float dtype; stored as float64.
        triangles: vertex indices, shape (T, 3), any integer dtype; stored as int32.
        name: label used in error messages and on stages.
        degenerate: policy for zero-area rest triangles: ``"error"`` (default) raises ValueError
            naming them; ``"ignore"`` keeps them for topology but gives them no weight in the
            stretch ratio and normals (their stretch is undefined).

    Points must lie within ±:data:`~warpface._validate.MAX_COORDINATE` (1e6) mesh units: the
    per-frame kernels run in float32.

    Raises:
        ValueError: non-finite or out-of-range points, indices out of range, repeated indices in a
            triangle, or degenerate triangles under the ``"error"`` policy.
    """

    points: np.ndarray
    triangles: np.ndarray
    name: str = "face"
    degenerate: str = "error"
    _cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str):
            raise TypeError(f"name: expected a mesh name (str), got {type(self.name).__name__}")
        if not self.name:
            raise ValueError("name: expected a non-empty mesh name")
        self.points = as_points(self.points, f"{self.name}: points", min_count=1)
        triangles = as_triangles(self.triangles, len(self.points), f"{self.name}: triangles", integral_floats=True)
        repeated = np.flatnonzero(
            (triangles[:, 0] == triangles[:, 1])
            | (triangles[:, 1] == triangles[:, 2])
            | (triangles[:, 0] == triangles[:, 2])
        )
        if len(repeated):
            t = int(repeated[0])
            raise ValueError(f"{self.name}: triangle {t} repeats a vertex: {triangles[t].tolist()}")
        self.triangles = triangles
        if not isinstance(self.degenerate, str):
            raise TypeError(
                f"{self.name}: degenerate: expected 'error' or 'ignore', got {type(self.degenerate).__name__}"
            )
        if self.degenerate not in ("error", "ignore"):
            raise ValueError(f"{self.name}: degenerate policy must be 'error' or 'ignore', got {self.degenerate!r}")
        bad = np.flatnonzero(self.degenerate_triangles)
        if len(bad) and self.degenerate == "error":
            raise ValueError(
                f"{self.name}: {len(bad)} zero-area rest triangle(s), first {int(bad[0])} "
                f"{self.triangles[bad[0]].tolist()}; pass degenerate='ignore' to keep them without weight"
            )

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_obj(cls, path: str | Path, **kwargs) -> "FaceMesh":
        """Load an OBJ file (``v`` and ``f`` records; polygons fan-triangulated)."""
        points, triangles = load_obj(path)
        kwargs.setdefault("name", Path(path).stem)
        return cls(points, triangles, **kwargs)

    # ------------------------------------------------------------------ sizes
    @property
    def vertex_count(self) -> int:
        return int(len(self.points))

    @property
    def triangle_count(self) -> int:
        return int(len(self.triangles))

    @cached_property
    def bounding_box(self) -> tuple[np.ndarray, np.ndarray]:
        """(min, max) corners of the rest points, each shape (3,)."""
        return self.points.min(axis=0), self.points.max(axis=0)

    @cached_property
    def size(self) -> float:
        """Bounding-box diagonal of the rest points [mesh units]."""
        lo, hi = self.bounding_box
        return float(np.linalg.norm(hi - lo))

    # ------------------------------------------------------------------ rest geometry
    @cached_property
    def rest_areas(self) -> np.ndarray:
        """Rest triangle areas [units²], shape (T,), float64."""
        return triangle_areas(triangle_corners(self.points, self.triangles))

    @cached_property
    def degenerate_triangles(self) -> np.ndarray:
        """Mask of zero-area rest triangles, shape (T,), bool (see :data:`MIN_TRIANGLE_AREA`)."""
        tiny = self.rest_areas <= max(DEGENERATE_AREA_RTOL * self.size**2, MIN_TRIANGLE_AREA)
        area32 = triangle_areas(
            crosses=triangle_crosses(triangle_corners(self.points.astype(np.float32), self.triangles))
        )
        return tiny | (area32 <= 0.5 * self.rest_areas)

    @cached_property
    def adjacency(self) -> VertexTriangleAdjacency:
        """Vertex → incident-triangle CSR adjacency."""
        offsets, triangles = vertex_triangles(self.triangles, self.vertex_count)
        return VertexTriangleAdjacency(offsets=offsets.astype(np.int32), triangles=triangles.astype(np.int32))

    @cached_property
    def edges(self) -> np.ndarray:
        """The undirected edges, shape (E, 2) int64, smaller index first, sorted (:func:`triangle_edges`)."""
        return self._edges_and_counts[0]

    @cached_property
    def open_edges(self) -> np.ndarray:
        """The edges of one triangle (an open boundary: a mouth opening, a neck), shape (B, 2) int64, sorted."""
        edges, counts = self._edges_and_counts
        return edges[counts == 1]

    @cached_property
    def _edges_and_counts(self) -> tuple[np.ndarray, np.ndarray]:
        return triangle_edges(self.triangles)

    @cached_property
    def shells(self) -> np.ndarray:
        """The shell (connected part) of every vertex, shape (V,) int32
        (:func:`~warpface.geometry.triangles.vertex_shells`): a whole head's skin, eyes, teeth and mouth socket get
        different labels."""
        return vertex_shells(self.triangles, self.vertex_count)

    @cached_property
    def boundary_vertices(self) -> np.ndarray:
        """Indices of vertices on an open boundary (an edge used by one triangle), shape (B,), int64."""
        return np.unique(self.open_edges)

    def vertex_normals(self, points: np.ndarray | None = None, *, device=None) -> np.ndarray:
        """Area-weighted unit vertex normals, shape (V, 3), float32, computed by a Warp kernel.

        Args:
            points: positions to take normals of, shape (V, 3), within ±1e6; the rest points when omitted.
            device: Warp device (default: Warp's preferred device).
        """
        device = as_device(device)
        positions = self.points if points is None else as_points(points, f"{self.name}: points")
        if positions.shape != self.points.shape:
            raise ValueError(f"{self.name}: points must have shape {self.points.shape}, got {positions.shape}")
        buffers = self.device_buffers(device=device)
        x = wp.array(positions.astype(np.float32), dtype=wp.vec3, device=device)
        area_vectors = _area_vectors(x, buffers.triangles, buffers.triangle_weight)
        normals = wp.empty(self.vertex_count, dtype=wp.vec3, device=device)
        wp.launch(
            vertex_normals_kernel,
            dim=self.vertex_count,
            inputs=[
                area_vectors,
                buffers.adjacency_offsets,
                buffers.adjacency_triangles,
                frame_sizes(self.vertex_count, self.triangle_count),
            ],
            outputs=[normals],
            device=device,
        )
        return normals.numpy()

    def device_buffers(self, *, device=None) -> "MeshBuffers":
        """Rest geometry uploaded to ``device`` (cached per device)."""
        device = as_device(device)
        key = ("buffers", str(device))
        if key not in self._cache:
            self._cache[key] = MeshBuffers.upload(self, device=device)
        return self._cache[key]


@dataclass(frozen=True)
class MeshBuffers:
    """Rest geometry of a :class:`FaceMesh` as Warp arrays on one device."""

    rest_points: wp.array
    """Rest positions, shape (V,), vec3 (float32)."""
    triangles: wp.array
    """Triangle vertex indices, shape (T,), vec3i."""
    rest_area_lengths: wp.array
    """Rest ``|(p1 − p0) × (p2 − p0)|`` per counted triangle (1 for ignored ones), shape (T,), float32,
    computed by the same kernel as every frame so that an undeformed frame has a stretch ratio of exactly 1."""
    triangle_weight: wp.array
    """1 for triangles that count in stretch and normals, 0 for ignored degenerate ones, shape (T,), float32."""
    adjacency_offsets: wp.array
    """Vertex → triangle CSR offsets, shape (V + 1,), int32."""
    adjacency_triangles: wp.array
    """Vertex → triangle CSR entries, shape (3·T,), int32."""

    @classmethod
    def upload(cls, mesh: FaceMesh, *, device) -> "MeshBuffers":
        weight = wp.array((~mesh.degenerate_triangles).astype(np.float32), dtype=wp.float32, device=device)
        rest_points = wp.array(mesh.points.astype(np.float32), dtype=wp.vec3, device=device)
        triangles = wp.array(mesh.triangles.astype(np.int32), dtype=wp.vec3i, device=device)
        area_vectors = _area_vectors(rest_points, triangles, weight)
        lengths = wp.empty(mesh.triangle_count, dtype=wp.float32, device=device)
        wp.launch(
            stretch_reference_lengths,
            dim=mesh.triangle_count,
            inputs=[area_vectors, weight],
            outputs=[lengths],
            device=device,
        )
        return cls(
            rest_points=rest_points,
            triangles=triangles,
            rest_area_lengths=lengths,
            triangle_weight=weight,
            adjacency_offsets=wp.array(mesh.adjacency.offsets, dtype=wp.int32, device=device),
            adjacency_triangles=wp.array(mesh.adjacency.triangles, dtype=wp.int32, device=device),
        )


def _area_vectors(points: wp.array, triangles: wp.array, weight: wp.array) -> wp.array:
    """``weight · (p1 − p0) × (p2 − p0)`` per triangle of one frame of ``points`` (vec3, on their device)."""
    area_vectors = wp.empty(triangles.shape[0], dtype=wp.vec3, device=points.device)
    wp.launch(
        triangle_area_vectors,
        dim=triangles.shape[0],
        inputs=[points, triangles, weight, frame_sizes(points.shape[0], triangles.shape[0])],
        outputs=[area_vectors],
        device=points.device,
    )
    return area_vectors


@dataclass(frozen=True)
class ObjPolygons:
    """An OBJ mesh as written: polygons (quads and n-gons kept), UVs, normals, groups and materials.

    ``counts``/``indices`` are USD's ``faceVertexCounts``/``faceVertexIndices``; ``uv_indices`` and
    ``normal_indices`` give each face corner its ``vt``/``vn`` (``None`` when any corner lacks one).
    ``groups``/``materials`` name the ``g`` groups and ``usemtl`` materials; ``face_groups`` and
    ``face_materials`` give each face's index into them (-1: none).
    """

    points: np.ndarray
    counts: np.ndarray
    indices: np.ndarray
    uvs: np.ndarray | None = None
    uv_indices: np.ndarray | None = None
    normals: np.ndarray | None = None
    normal_indices: np.ndarray | None = None
    groups: tuple[str, ...] = ()
    face_groups: np.ndarray | None = None
    materials: tuple[str, ...] = ()
    face_materials: np.ndarray | None = None

    def triangles(self) -> np.ndarray:
        """Fan triangles (T, 3) int64 of the polygons, from each polygon's first corner."""
        return fan_triangles(self.counts, self.indices)


def fan_triangles(counts, indices) -> np.ndarray:
    """Polygons as per-face corner counts and flat corner indices → fan triangles (T, 3) int64."""
    counts = np.asarray(counts, dtype=np.int64).reshape(-1)
    indices = np.asarray(indices, dtype=np.int64).reshape(-1)
    if len(counts) and counts.min() < 3:
        raise ValueError(f"faces: face {int(np.argmin(counts))} has {int(counts.min())} corners (needs ≥ 3)")
    if int(counts.sum()) != len(indices):
        raise ValueError(f"faces: corner counts sum to {int(counts.sum())} but there are {len(indices)} corner indices")
    if len(counts) and np.all(counts == 3):
        return indices.reshape(-1, 3)
    per_face = counts - 2
    face = np.repeat(np.arange(len(counts)), per_face)
    corner = np.arange(int(per_face.sum())) - np.repeat(np.cumsum(per_face) - per_face, per_face) + 1
    start = (np.cumsum(counts) - counts)[face]
    return np.stack([indices[start], indices[start + corner], indices[start + corner + 1]], axis=1)


def _obj_index(token: str, count: int, where: str) -> int:
    try:
        index = int(token)
    except ValueError:
        raise ValueError(f"{where}: face index {token!r} is not an integer") from None
    if index == 0:
        raise ValueError(f"{where}: face index 0 (OBJ indices start at 1)")
    return index - 1 if index > 0 else count + index


def read_obj_polygons(path: str | Path) -> ObjPolygons:
    """Read a Wavefront OBJ file keeping its polygons, ``vt``, ``vn``, ``g`` groups and ``usemtl`` materials.

    Negative (relative) indices are resolved. Raises ValueError naming the file and line of a bad record.
    """
    path = as_path(path, "path")
    if not path.is_file():
        raise ValueError(f"OBJ file not found: {path}")
    records: dict[str, list] = {"v": [], "vt": [], "vn": []}
    counts, corners, uv_corners, normal_corners = [], [], [], []
    groups, face_groups, materials, face_materials = {}, [], {}, []
    group, material = -1, -1
    with path.open("r", encoding="utf-8", errors="replace") as handle:
        for line_number, line in enumerate(handle, start=1):
            fields = line.split()
            if not fields:
                continue
            key, where = fields[0], f"{path}:{line_number}"
            if key in ("v", "vt", "vn"):
                size = 2 if key == "vt" else 3
                if len(fields) < size + 1:
                    raise ValueError(f"{where}: {'vertex' if key == 'v' else key} needs {size} coordinates")
                try:
                    records[key].append([float(v) for v in fields[1 : size + 1]])
                except ValueError:
                    raise ValueError(f"{where}: vertex coordinates are not numbers: {line.strip()!r}") from None
            elif key == "f":
                if len(fields) < 4:
                    raise ValueError(f"{where}: face needs at least 3 vertices")
                for token in fields[1:]:
                    parts = token.split("/")
                    corners.append(_obj_index(parts[0], len(records["v"]), where))
                    has_uv, has_normal = len(parts) > 1 and parts[1], len(parts) > 2 and parts[2]
                    uv_corners.append(_obj_index(parts[1], len(records["vt"]), where) if has_uv else -1)
                    normal_corners.append(_obj_index(parts[2], len(records["vn"]), where) if has_normal else -1)
                counts.append(len(fields) - 1)
                face_groups.append(group)
                face_materials.append(material)
            elif key in ("g", "o") and len(fields) > 1:
                group = groups.setdefault(" ".join(fields[1:]), len(groups))
            elif key == "usemtl" and len(fields) > 1:
                material = materials.setdefault(" ".join(fields[1:]), len(materials))
    if not records["v"] or not counts:
        raise ValueError(f"{path}: no vertices or faces found")
    points = np.asarray(records["v"], dtype=np.float64)
    indices = np.asarray(corners, dtype=np.int64)
    if indices.min() < 0 or indices.max() >= len(points):
        raise ValueError(f"{path}: face vertex indices outside [1, {len(points)}]")

    def corner_table(values, table):
        table = np.asarray(table, dtype=np.int64)
        if not values or table.min() < 0 or table.max() >= len(values):
            return None, None  # some corner has none (or one out of range): not kept
        return np.asarray(values, dtype=np.float64), table

    uvs, uv_indices = corner_table(records["vt"], uv_corners)
    normals, normal_indices = corner_table(records["vn"], normal_corners)
    return ObjPolygons(
        points,
        np.asarray(counts, dtype=np.int64),
        indices,
        uvs,
        uv_indices,
        normals,
        normal_indices,
        tuple(groups),
        np.asarray(face_groups, dtype=np.int64),
        tuple(materials),
        np.asarray(face_materials, dtype=np.int64),
    )


def load_obj(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read vertex positions and faces from a Wavefront OBJ file (:func:`read_obj_polygons`).

    Polygons are fan-triangulated. Returns ``(points (V, 3) float64, triangles (T, 3) int64)``.
    """
    polygons = read_obj_polygons(path)
    return polygons.points, polygons.triangles()
