"""How right a rigged face looks: lid gaps, lip order and folded triangles (issue 25's checks).

All measures take deformed points in the mesh's units and report millimetres given ``mm_per_unit``.
The face's up axis is its landmark frame's y axis (:class:`~warpface.assets.frame.FaceFrame`).

- **Lid gap** at the lid midpoints (iBUG 37/41, 38/40 on the subject's right eye, 43/47, 44/46 on the
  left): the distance between the paired points, and the signed height of the upper point above the
  lower one along up (negative: the upper lid passed the lower one).
- **Lip order** at the inner-lip midpoints (iBUG 61/67, 62/66, 63/65): the signed height of the upper
  point above the lower one along up (negative: the lips crossed).
- **Flipped triangles**: triangles whose deformed normal points against the rest normal
  (rest · deformed < 0), degenerate rest triangles ignored.
"""

from __future__ import annotations

import numpy as np

from .._validate import as_points
from ..mesh import FaceMesh
from .frame import FaceFrame, check_landmarks

__all__ = ["LID_PAIRS", "LIP_PAIRS", "face_up", "pair_heights", "pair_distances", "flipped_triangles"]

LID_PAIRS: tuple[tuple[int, int], ...] = ((37, 41), (38, 40), (43, 47), (44, 46))
"""(upper, lower) iBUG landmarks at the lid midpoints."""
LIP_PAIRS: tuple[tuple[int, int], ...] = ((61, 67), (62, 66), (63, 65))
"""(upper, lower) iBUG landmarks at the inner lips' midpoints."""


def face_up(mesh: FaceMesh, landmarks) -> np.ndarray:
    """The face's unit up axis (its landmark frame's y), shape (3,)."""
    landmarks = check_landmarks(mesh, landmarks)
    return FaceFrame.from_landmarks(mesh.points[landmarks]).axes[1]


def _pairs(points, landmarks, pairs) -> tuple[np.ndarray, np.ndarray]:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim < 2 or points.shape[-1] != 3:
        raise ValueError(f"points: expected shape (..., V, 3), got {points.shape}")
    upper = np.asarray(landmarks)[[a for a, _ in pairs]]
    lower = np.asarray(landmarks)[[b for _, b in pairs]]
    return points[..., upper, :], points[..., lower, :]


def pair_heights(points, landmarks, pairs, up, mm_per_unit: float = 1.0) -> np.ndarray:
    """Signed height [mm] of each pair's upper point above its lower one along ``up``, shape (..., P)."""
    upper, lower = _pairs(points, landmarks, pairs)
    return ((upper - lower) @ np.asarray(up, dtype=np.float64)) * mm_per_unit


def pair_distances(points, landmarks, pairs, mm_per_unit: float = 1.0) -> np.ndarray:
    """Distance [mm] between each pair's points, shape (..., P)."""
    upper, lower = _pairs(points, landmarks, pairs)
    return np.linalg.norm(upper - lower, axis=-1) * mm_per_unit


def _normals(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    p = points[..., triangles, :]
    return np.cross(p[..., 1, :] - p[..., 0, :], p[..., 2, :] - p[..., 0, :])


def flipped_triangles(mesh: FaceMesh, points) -> np.ndarray:
    """Per frame, the number of triangles whose deformed normal opposes the rest one: shape (...,) of ints."""
    points = np.asarray(points, dtype=np.float64)
    as_points(points.reshape(-1, 3), "points")
    if points.shape[-2:] != mesh.points.shape:
        raise ValueError(f"points: expected (..., {mesh.vertex_count}, 3), got {points.shape}")
    keep = ~mesh.degenerate_triangles
    triangles = mesh.triangles[keep]
    rest = _normals(mesh.points.astype(np.float64), triangles)
    deformed = _normals(points, triangles)
    return (np.einsum("...ti,ti->...t", deformed, rest) < 0.0).sum(axis=-1)
