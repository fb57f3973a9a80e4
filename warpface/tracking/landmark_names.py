"""Landmarks named after the dense vertex they sit on, and the tracking adapter they define.

Landmarks that drive a warpface face are named ``v01234`` (:func:`vertex_landmark_names`): a
recording, an RGB-D folder or a live camera's fiducial layout made for a face then maps onto it
with no other bookkeeping. The sparse tracking mesh is the Delaunay triangulation of those
vertices at rest (:func:`adapter_for_face`).
"""

from __future__ import annotations

import re
from typing import Sequence

import numpy as np

from .._validate import as_count, as_points, expect_iterable
from .correspondence import triangulate_landmarks
from .transfer import TrackingAdapter

__all__ = ["vertex_landmark_names", "landmark_vertices", "adapter_for_face"]

_NAME = re.compile(r"^v(\d+)$")


def vertex_landmark_names(vertices) -> list[str]:
    """Landmark names for dense vertex indices: ``[12, 345] → ["v00012", "v00345"]``."""
    try:
        indices = np.asarray(vertices)
    except (TypeError, ValueError):
        raise ValueError("vertices: expected a flat array of integer vertex indices") from None
    if indices.size and (not np.issubdtype(indices.dtype, np.integer) or indices.min() < 0):
        raise ValueError(
            f"vertices: expected non-negative integer vertex indices, got {indices.dtype} "
            f"{indices.ravel()[:5].tolist()}"
        )
    return [f"v{int(v):05d}" for v in indices.ravel()]


def landmark_vertices(names: Sequence[str], vertex_count: int) -> np.ndarray:
    """Dense vertex indices from names made by :func:`vertex_landmark_names`.

    Raises:
        ValueError: a name that is not ``v<index>``, or an index outside the face.
    """
    vertex_count = as_count(vertex_count, "vertex_count")
    indices = []
    for name in expect_iterable(names, "landmark names", item_types=str):
        match = _NAME.match(str(name))
        if match is None:
            raise ValueError(
                f"landmark {name!r}: expected a dense-vertex name like 'v01234' (see vertex_landmark_names)"
            )
        index = int(match.group(1))
        if index >= vertex_count:
            raise ValueError(f"landmark {name!r}: vertex {index} is outside the face ({vertex_count} vertices)")
        indices.append(index)
    return np.asarray(indices, dtype=np.int64)


def adapter_for_face(
    rest_points: np.ndarray, landmark_names: Sequence[str], *, camera_to_model=None, stabilize=False, device=None
) -> TrackingAdapter:
    """A :class:`TrackingAdapter` whose sparse mesh is the face's own landmark vertices, triangulated."""
    rest_points = as_points(rest_points, "rest_points", min_count=3)
    vertices = landmark_vertices(landmark_names, len(rest_points))
    sparse = rest_points[vertices]
    return TrackingAdapter(
        sparse,
        triangulate_landmarks(sparse),
        rest_points,
        landmark_names=list(landmark_names),
        camera_to_model=camera_to_model,
        stabilize=stabilize,
        device=device,
    )
