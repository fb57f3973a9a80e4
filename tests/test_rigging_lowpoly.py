"""Low-poly heads (docs/RIG.md §9, step 3, "Low-poly skins"): a skin of fewer than ``MIN_FIT_POINTS`` vertices gets
its edges' midpoints in the similarity fit. Checked on the sampling itself against a hand-made square, and on
MediaPipe's 468-vertex canonical face, whose similarity score they make what the same surface split finely scores."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.rigging_lowpoly import NAMED_ALIKE
from warpface.data import shared_data_path
from warpface.mesh import load_obj
from warpface.rigging import find_landmarks, surface
from warpface.rigging.align import fit_similarity
from warpface.rigging.surface import HeadSurface, midpoint_samples
from warpface.rigging.template import template

MEDIAPIPE = shared_data_path("mediapipe", "canonical_face_model.obj")


def test_midpoint_samples_split_every_edge_once_level_by_level():
    square = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    triangles = np.array([[0, 1, 2], [0, 2, 3]])
    up, outline = np.tile([0.0, 0.0, 1.0], (4, 1)), np.ones(4, bool)
    points, normals, boundary = midpoint_samples(square, up, outline, triangles, minimum=5)
    assert len(points) == 4 + 5  # four outline edges and the diagonal
    np.testing.assert_array_equal(points[:4], square)
    midpoints = {(0.5, 0.0), (1.0, 0.5), (0.5, 1.0), (0.0, 0.5), (0.5, 0.5)}
    assert {tuple(p[:2]) for p in points[4:]} == midpoints
    assert {tuple(p[:2]) for p in points[boundary]} == {tuple(p[:2]) for p in square} | midpoints - {(0.5, 0.5)}
    np.testing.assert_allclose(normals, np.tile([0.0, 0.0, 1.0], (9, 1)))

    points, _, boundary = midpoint_samples(square, up, outline, triangles, minimum=10)
    grid = np.round(points[:, :2] * 4).astype(int)  # split twice: every point of a 5 × 5 grid, each once
    assert len(points) == 25 and len({tuple(g) for g in grid}) == 25 and grid.min() == 0 and grid.max() == 4
    np.testing.assert_array_equal(boundary, (grid == 0).any(axis=1) | (grid == 4).any(axis=1))

    tilted = np.array([[1.0, 0.0, 0.0]] * 2 + [[0.0, 0.0, 1.0]] * 2)
    points, normals, _ = midpoint_samples(square, tilted, outline, triangles, minimum=5)
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
    np.testing.assert_array_equal(head.skin_samples[2], head.skin_boundary)


@pytest.mark.skipif(MEDIAPIPE is None, reason="MediaPipe's canonical face not in ../shared/data")
def test_a_low_poly_face_is_rigged_at_the_places_mediapipe_names():
    points, triangles = load_obj(MEDIAPIPE)
    assert len(points) < surface.MIN_FIT_POINTS
    found = find_landmarks(points, triangles, label="canonical face")
    assert found.units == "cm"
    named = list(NAMED_ALIKE)
    error_mm = np.linalg.norm(points[found.indices[named]] - points[list(NAMED_ALIKE.values())], axis=1) * 10.0
    assert error_mm.mean() <= 2.0 and error_mm.max() <= 4.0, dict(zip(named, np.round(error_mm, 1)))


def _split(points: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every triangle split in four at its edge midpoints (the same surface, four times the faces)."""
    edges = {tuple(sorted(e)) for t in triangles.tolist() for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
    middle = {edge: len(points) + k for k, edge in enumerate(sorted(edges))}
    points = np.vstack([points, [0.5 * (points[a] + points[b]) for a, b in sorted(edges)]])
    faces = []
    for a, b, c in triangles.tolist():
        ab, bc, ca = (middle[tuple(sorted(e))] for e in ((a, b), (b, c), (c, a)))
        faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
    return points, np.array(faces)


@pytest.mark.skipif(MEDIAPIPE is None, reason="MediaPipe's canonical face not in ../shared/data")
def test_the_similarity_score_of_a_low_poly_face_does_not_depend_on_its_tessellation(monkeypatch):
    points, triangles = load_obj(MEDIAPIPE)
    fine = _split(*_split(points, np.asarray(triangles)))  # 7.3k vertices: fitted on its own vertices

    def score(points, triangles):
        head = HeadSurface(points, triangles)
        return fit_similarity(template(), *head.skin_samples)[0].residual

    dense = score(*fine)
    assert len(fine[0]) >= surface.MIN_FIT_POINTS
    assert abs(score(points, triangles) - dense) < 0.01
    monkeypatch.setattr(surface, "MIN_FIT_POINTS", 0)  # its own 468 vertices: each up to half an edge off the surface
    assert score(points, triangles) - dense > 0.02
