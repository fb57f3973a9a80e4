"""Sparse ↔ dense correspondence (SPEC §3 steps 1–2): face normalisation and closest points.

* :class:`FaceNormalization` — Kato eq. 5.1–5.4: both models are scaled by their face width; the
  dense model's height is scaled separately above and below the eye line so that its proportions
  match the sparse model's.
* :func:`compute_correspondence` — the per-dense-vertex correspondence used by the transfer: the
  closest point of the sparse surface through :class:`warpface.geometry.TriangleMeshIndex` (a BVH, then
  the exact :func:`warpface.geometry.closest_point_on_triangle`).

Models are given in a *model frame*: x across the face (to the subject's left or right, either
way), +y up, +z toward the viewer; units metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_count, as_finite_array, as_indices, as_points, as_positive, as_triangles
from ..geometry import TriangleMeshIndex, triangle_corners, triangle_normals
from ..geometry.triangles import triangle_crosses

__all__ = [
    "FaceNormalization",
    "Correspondence",
    "compute_correspondence",
    "triangulate_landmarks",
]


# --------------------------------------------------------------------------------------------
# Normalisation (eq. 5.1–5.4)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FaceNormalization:
    """Measurements of one face model that define its normalised coordinates.

    Normalised coordinates put the origin on the eye line, at the horizontal centre of the face and
    at its front-most depth, and divide by the face width ``w``:
    ``x̂ = (x − o_x) / w``, ``ẑ = (z − o_z) / w``, ``ŷ = (y − o_y) / w`` (eq. 5.1–5.2). For the model
    that must be *matched* to another (the dense model in Kato), ``ŷ`` is instead scaled per half so
    that the heights above and below the eye line become the other model's (eq. 5.3–5.4):
    ``ŷ = (y − o_y) · (h_u' / w') / h_u`` above the eye line, ``(y − o_y) · (h_d' / w') / h_d`` below.
    """

    origin: np.ndarray
    """Normalisation origin [m], shape (3,): (face-width centre, eye-line height, front-most z)."""
    width: float
    """Face width ``w`` [m]: the x extent of the model."""
    upper: float
    """Height above the eye line ``h_u`` [m]."""
    lower: float
    """Height below the eye line ``h_d`` [m]."""

    def __post_init__(self):
        object.__setattr__(
            self, "origin", as_finite_array(self.origin, "FaceNormalization.origin", shape=(3,), max_abs=1e6)
        )
        for name in ("width", "upper", "lower"):
            object.__setattr__(self, name, as_positive(getattr(self, name), f"FaceNormalization.{name}"))

    @classmethod
    def measure(cls, points, eye_y: float, *, front_z: float | None = None) -> "FaceNormalization":
        """Measure a model: width from its x extent, heights from ``eye_y`` to its top and bottom.

        Args:
            points: model points [m], shape (P, 3), model frame (+y up, +z toward the viewer).
            eye_y: height of the eye line [m] (e.g. the mean y of the eye-corner landmarks).
            front_z: depth of the origin [m]; the model's maximum z (its front, the nose tip)
                when omitted.

        Raises:
            ValueError: points not (P, 3) finite, or the eye line not strictly inside the y range.
        """
        pts = as_points(points, "points", min_count=1)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        eye_y = float(as_finite_array(eye_y, "eye_y", shape=()))
        if not (lo[1] < eye_y < hi[1]):
            raise ValueError(f"eye_y={eye_y} must lie strictly inside the model's y range [{lo[1]}, {hi[1]}]")
        width = float(hi[0] - lo[0])
        if width <= 0.0:
            raise ValueError("points: the model has zero width along x")
        z0 = float(hi[2]) if front_z is None else float(as_finite_array(front_z, "front_z", shape=(), max_abs=1e6))
        origin = np.array([0.5 * (lo[0] + hi[0]), eye_y, z0])
        return cls(origin=origin, width=width, upper=float(hi[1] - eye_y), lower=float(eye_y - lo[1]))

    def normalize(self, points, *, match: "FaceNormalization | None" = None) -> np.ndarray:
        """Normalised coordinates of ``points`` (shape (P, 3), float64).

        With ``match``, heights above/below the eye line are rescaled to ``match``'s proportions.
        """
        pts = as_points(points, "points")
        out = (pts - self.origin) / self.width
        if match is not None:
            dy = pts[:, 1] - self.origin[1]
            out[:, 1] = np.where(
                dy >= 0.0, dy * (match.upper / match.width) / self.upper, dy * (match.lower / match.width) / self.lower
            )
        return out

    def denormalize(self, normalized, *, match: "FaceNormalization | None" = None) -> np.ndarray:
        """Inverse of :meth:`normalize` (same ``match``), shape (P, 3), float64."""
        nrm = as_points(normalized, "normalized")
        out = nrm * self.width + self.origin
        if match is not None:
            y = nrm[:, 1]
            out[:, 1] = self.origin[1] + np.where(
                y >= 0.0, y * self.upper / (match.upper / match.width), y * self.lower / (match.lower / match.width)
            )
        return out


# --------------------------------------------------------------------------------------------
# Correspondence (eq. 4.1–4.14)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Correspondence:
    """Where each dense vertex attaches to the sparse mesh (computed once, at rest)."""

    triangle: np.ndarray
    """Sparse triangle per dense vertex, shape (V,), int32."""
    barycentric: np.ndarray
    """Barycentric coordinates ``a_j`` in that triangle, shape (V, 3), float32, rows sum to 1."""
    distance: np.ndarray
    """Distance from the dense vertex to its closest sparse point [dense m], shape (V,), float64."""
    overhang: np.ndarray
    """In-plane part of that offset [dense m], shape (V,), float64: 0 where the vertex projects inside
    a sparse triangle, growing with the distance beyond the sparse mesh's contour."""

    def __post_init__(self):
        checked = self.checked()
        for name in ("triangle", "barycentric", "distance", "overhang"):
            object.__setattr__(self, name, getattr(checked, name))

    def checked(self, triangle_count: int | None = None, vertex_count: int | None = None) -> "Correspondence":
        """The arrays converted and checked, optionally against the sparse triangle count and the
        dense vertex count; returns a correspondence with contiguous arrays of the documented dtypes.

        Raises:
            TypeError: triangle indices that are not numbers (or are booleans).
            ValueError: mismatched lengths, a triangle index that is not a whole number in
                [0, ``triangle_count``), or non-finite or negative coordinates/distances (naming the item).
        """
        triangle = as_indices(self.triangle, 2**31, "correspondence.triangle")  # int32 on the device
        count = triangle.shape[0]
        if triangle_count is not None:
            triangle_count = as_count(triangle_count, "triangle_count")
        if vertex_count is not None:
            vertex_count = as_count(vertex_count, "vertex_count")
        if vertex_count is not None and count != vertex_count:
            raise ValueError(f"correspondence is for {count} dense vertices, not {vertex_count}")
        if triangle_count is not None and count and int(triangle.max()) >= triangle_count:
            v = int(np.argmax(triangle))
            raise ValueError(
                f"correspondence.triangle: vertex {v} refers to sparse triangle {int(triangle[v])}, "
                f"but there are {triangle_count}"
            )
        barycentric = as_finite_array(self.barycentric, "correspondence.barycentric", shape=(count, 3), max_abs=1e6)
        distance = as_finite_array(self.distance, "correspondence.distance", shape=(count,), max_abs=1e6)
        overhang = as_finite_array(self.overhang, "correspondence.overhang", shape=(count,), max_abs=1e6)
        for name, values in (("distance", distance), ("overhang", overhang)):
            if count and values.min() < 0:
                raise ValueError(f"correspondence.{name}: negative value at vertex {int(np.argmin(values))}")
        result = object.__new__(Correspondence)
        for name, value in (
            ("triangle", triangle.astype(np.int32)),
            ("barycentric", barycentric.astype(np.float32)),
            ("distance", distance),
            ("overhang", overhang),
        ):
            object.__setattr__(result, name, np.ascontiguousarray(value))
        return result


def compute_correspondence(
    dense_points,
    sparse_points,
    sparse_triangles,
    *,
    sparse_normalization: FaceNormalization | None = None,
    dense_normalization: FaceNormalization | None = None,
    device=None,
) -> Correspondence:
    """For every dense vertex, the closest sparse triangle and barycentric coordinates (eq. 4.1–4.14).

    With both normalisations given, the search runs in normalised coordinates (the dense model
    matched to the sparse model's proportions, eq. 5.1–5.4); distances are reported back in dense
    metres (normalised distance × dense face width). Without them, both models must already share
    a frame and scale.

    Args:
        dense_points: dense rest points [m], shape (V, 3).
        sparse_points: sparse rest points [m], shape (N, 3).
        sparse_triangles: sparse triangles, shape (T, 3), integer.
        sparse_normalization, dense_normalization: both or neither.
        device: Warp device for the query.
    """
    if (sparse_normalization is None) != (dense_normalization is None):
        raise ValueError("give both sparse_normalization and dense_normalization, or neither")
    for name, value in (("sparse_normalization", sparse_normalization), ("dense_normalization", dense_normalization)):
        if value is not None and not isinstance(value, FaceNormalization):
            raise TypeError(f"{name}: expected a FaceNormalization, got {type(value).__name__}")
    dense = as_points(dense_points, "dense_points")
    sparse = as_points(sparse_points, "sparse_points")
    tri = as_triangles(sparse_triangles, sparse.shape[0], "sparse_triangles")
    to_dense = 1.0
    if sparse_normalization is not None:
        sparse = sparse_normalization.normalize(sparse)
        dense = dense_normalization.normalize(dense, match=sparse_normalization)
        to_dense = dense_normalization.width
    triangle, bary, dist = TriangleMeshIndex(sparse, tri, device=device).query(dense)

    corners = triangle_corners(sparse, tri[triangle])  # (V, 3, 3)
    closest = np.einsum("vj,vjk->vk", bary.astype(np.float64), corners)
    normal = triangle_normals(crosses=triangle_crosses(corners))
    offset = dense - closest
    tangential = offset - np.sum(offset * normal, axis=1, keepdims=True) * normal
    return Correspondence(
        triangle=triangle.astype(np.int32),
        barycentric=bary.astype(np.float32),
        distance=dist.astype(np.float64) * to_dense,
        overhang=np.linalg.norm(tangential, axis=1) * to_dense,
    )


def triangulate_landmarks(points, *, max_edge: float | None = None) -> np.ndarray:
    """A sparse tracking mesh over landmarks: Delaunay triangulation of their front (x, y) projection.

    Args:
        points: landmark positions [m], shape (N, 3), model frame (+z toward the viewer).
        max_edge: drop triangles with an edge longer than this [m] (the long slivers Delaunay
            puts along a concave hull); default 2.5 × the median edge length.

    Returns:
        Triangles, shape (T, 3), int32, oriented toward +z.

    Raises:
        ValueError: fewer than 3 points, points whose (x, y) projections are collinear or
            coincide, a ``max_edge`` that is not positive, or no triangle left.
    """
    from scipy.spatial import Delaunay, QhullError

    pts = as_points(points, "points")
    if pts.shape[0] < 3:
        raise ValueError(f"points: need ≥ 3 landmarks to triangulate, got {pts.shape[0]}")
    if max_edge is not None:
        max_edge = as_positive(max_edge, "max_edge")
    front = pts[:, :2] - pts[:, :2].mean(axis=0)
    extent = float(np.abs(front).max())
    singular = np.linalg.svd(front / extent, compute_uv=False) if extent > 0 else np.zeros(2)
    if singular[-1] <= 1e-9 * max(singular[0], 1e-300) or len(np.unique(pts[:, :2], axis=0)) < 3:
        raise ValueError("points: the landmarks' (x, y) projections are collinear or coincide; nothing to triangulate")
    try:
        tri = Delaunay(pts[:, :2]).simplices.astype(np.int64)
    except QhullError as exc:
        raise ValueError(
            f"points: cannot triangulate the landmarks' (x, y) projections ({str(exc).strip().splitlines()[0]})"
        ) from None
    # Orient toward +z: counter-clockwise in (x, y).
    e1 = pts[tri[:, 1], :2] - pts[tri[:, 0], :2]
    e2 = pts[tri[:, 2], :2] - pts[tri[:, 0], :2]
    flip = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    tri[flip] = tri[flip][:, [0, 2, 1]]
    edges = np.stack([np.linalg.norm(pts[tri[:, a]] - pts[tri[:, b]], axis=1) for a, b in ((0, 1), (1, 2), (2, 0))], 1)
    limit = 2.5 * float(np.median(edges)) if max_edge is None else float(max_edge)
    tri = tri[edges.max(axis=1) <= limit]
    if tri.shape[0] == 0:
        raise ValueError("triangulate_landmarks: no triangle shorter than max_edge")
    return tri.astype(np.int32)
