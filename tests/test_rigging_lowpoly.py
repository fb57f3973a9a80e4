"""Low-poly heads (docs/RIG.md §9, step 3, "Low-poly skins"): a skin of fewer than ``MIN_FIT_POINTS`` vertices gets
its edges' midpoints in the similarity fit. Checked on the sampling itself against a hand-made square, and on
MediaPipe's 468-vertex canonical face, which was refused without them."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.rigging_lowpoly import NAMED_ALIKE
from warpface.data import shared_data_path
from warpface.mesh import load_obj
from warpface.rigging import find_landmarks, surface
from warpface.rigging.surface import HeadSurface, midpoint_samples

MEDIAPIPE = shared_data_path("mediapipe", "canonical_face_model.obj")


def test_midpoint_samples_split_every_edge_once_level_by_level():
    square = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    triangles = np.array([[0, 1, 2], [0, 2, 3]])
    up = np.tile([0.0, 0.0, 1.0], (4, 1))
    points, normals = midpoint_samples(square, up, triangles, minimum=5)
    assert len(points) == 4 + 5  # four outline edges and the diagonal
    np.testing.assert_array_equal(points[:4], square)
    assert {tuple(p[:2]) for p in points[4:]} == {(0.5, 0.0), (1.0, 0.5), (0.5, 1.0), (0.0, 0.5), (0.5, 0.5)}
    np.testing.assert_allclose(normals, np.tile([0.0, 0.0, 1.0], (9, 1)))

    points = midpoint_samples(square, up, triangles, minimum=10)[0]
    grid = np.round(points[:, :2] * 4).astype(int)  # split twice: every point of a 5 × 5 grid, each once
    assert len(points) == 25 and len({tuple(g) for g in grid}) == 25 and grid.min() == 0 and grid.max() == 4

    tilted = np.array([[1.0, 0.0, 0.0]] * 2 + [[0.0, 0.0, 1.0]] * 2)
    points, normals = midpoint_samples(square, tilted, triangles, minimum=5)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0)
    bottom = np.flatnonzero(np.all(np.isclose(points, [0.5, 0.0, 0.0]), axis=1))[0]  # edge 0–1: both normals +x
    np.testing.assert_allclose(normals[bottom], [1.0, 0.0, 0.0])
    right = np.flatnonzero(np.all(np.isclose(points, [1.0, 0.5, 0.0]), axis=1))[0]  # edge 1–2: +x and +z
    np.testing.assert_allclose(normals[right], np.array([1.0, 0.0, 1.0]) / np.sqrt(2.0))


def test_a_dense_skin_is_fitted_on_its_own_vertices():
    rng = np.random.default_rng(3)
    grid = np.stack(np.meshgrid(np.arange(80.0), np.arange(80.0), indexing="ij"), axis=-1).reshape(-1, 2)
    points = np.column_stack([grid, rng.normal(0.0, 0.01, len(grid))])
    index = np.arange(80 * 80).reshape(80, 80)
    corners = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    triangles = np.concatenate([np.stack(corners[:3], 1), np.stack([corners[0], corners[2], corners[3]], 1)])
    head = HeadSurface(points, triangles)
    assert len(head.skin_vertices) >= surface.MIN_FIT_POINTS
    np.testing.assert_array_equal(head.skin_samples[0], points[head.skin_vertices])
    np.testing.assert_array_equal(head.skin_samples[1], head.skin_normals)


@pytest.mark.skipif(MEDIAPIPE is None, reason="MediaPipe's canonical face not in ../shared/data")
def test_a_low_poly_face_is_rigged_at_the_places_mediapipe_names(monkeypatch):
    points, triangles = load_obj(MEDIAPIPE)
    assert len(points) < surface.MIN_FIT_POINTS
    found = find_landmarks(points, triangles, label="canonical face")
    assert found.units == "cm"
    named = list(NAMED_ALIKE)
    error_mm = np.linalg.norm(points[found.indices[named]] - points[list(NAMED_ALIKE.values())], axis=1) * 10.0
    assert error_mm.mean() <= 2.0 and error_mm.max() <= 4.0, dict(zip(named, np.round(error_mm, 1)))

    monkeypatch.setattr(surface, "MIN_FIT_POINTS", 0)  # its own 468 vertices only: the fit reads no face
    with pytest.raises(ValueError, match="no face-like part"):
        find_landmarks(points, triangles, label="canonical face")
