"""The registration's correspondence and proportion stages (docs/RIG.md §9, steps 5b and 5c): matches nearest in
position and normal together, checked against a brute-force reference on a folded surface; and a closed loop on
the whole ICT head stretched or flattened (ground truth carried along), which the re-read proportions must meet
within bounds the single re-read of before did not (max 6.5 and 7.2 mm)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from warpface.data import ict_landmark_indices, shared_data_path
from warpface.mesh import read_obj_polygons
from warpface.rigging import find_landmarks, nonrigid, polygons_to_triangles
from warpface.rigging.nonrigid import SkinTarget


def _roof(spacing: float = 0.02):
    """A surface folded by 45° along x = 0: the flat half z = 0 (normal +z) for x ≤ 0, the half z = −x
    (normal (1, 0, 1)/√2) for x > 0; points on a grid, (points, normals)."""
    along = np.arange(-0.2, 0.2 + 1e-9, spacing)
    flat = np.array([(x, y, 0.0) for x in np.arange(-0.3, 1e-9, spacing) for y in along])
    sloped = np.array([(s, y, -s) for s in np.arange(spacing, 0.3, spacing / np.sqrt(2.0)) for y in along])
    normals = np.vstack(
        [np.tile([0.0, 0.0, 1.0], (len(flat), 1)), np.tile(np.array([1.0, 0.0, 1.0]) / np.sqrt(2.0), (len(sloped), 1))]
    )
    return np.vstack([flat, sloped]), normals


def test_matches_are_nearest_in_position_and_normal_together():
    points, normals = _roof()
    skin = SkinTarget(points, normals, np.zeros(len(points), dtype=bool), cKDTree(points))
    rng = np.random.default_rng(5)
    # template vertices just past the fold that face like the flat half: the nearest skin point is on the slope
    query = np.column_stack([rng.uniform(0.02, 0.04, 50), rng.uniform(-0.1, 0.1, 50), rng.uniform(-0.012, -0.008, 50)])
    query_normals = np.tile([0.0, 0.0, 1.0], (50, 1))
    distance, index = skin.match(query, query_normals)
    weight = nonrigid.NORMAL_WEIGHT
    cost = np.sum((query[:, None] - points[None]) ** 2, axis=2)
    cost += weight**2 * np.sum((query_normals[:, None] - normals[None]) ** 2, axis=2)
    np.testing.assert_array_equal(index, np.argmin(cost, axis=1))  # the brute-force float64 reference
    np.testing.assert_allclose(distance, np.linalg.norm(query - points[index], axis=1))
    assert np.all(points[index, 0] < 1e-9)  # the flat half, facing the vertex's way
    assert np.all(points[skin.tree.query(query)[1], 0] > 0.0)  # while plain nearest points lie on the slope


def test_without_the_normal_weight_matches_are_plain_nearest_points(monkeypatch):
    points, normals = _roof()
    skin = SkinTarget(points, normals, np.zeros(len(points), dtype=bool), cKDTree(points))
    monkeypatch.setattr(nonrigid, "NORMAL_WEIGHT", 0.0)
    query = np.random.default_rng(6).uniform(-0.2, 0.2, (40, 3))
    distance, index = skin.match(query, np.tile([0.0, 0.0, 1.0], (40, 1)))
    expected_distance, expected_index = skin.tree.query(query)
    np.testing.assert_array_equal(index, expected_index)
    np.testing.assert_allclose(distance, expected_distance)


HEAD = shared_data_path("ict_facekit", "original", "generic_neutral_mesh.obj")


@pytest.mark.skipif(HEAD is None, reason="ICT-FaceKit data not in ../shared/data (set WARPFACE_SHARED_DATA)")
@pytest.mark.parametrize(("label", "factor"), [("wider", (1.08, 1.0, 1.0)), ("flatter", (1.0, 1.0, 0.9))])
def test_stretched_whole_head_takes_its_proportions_from_the_features(label, factor):
    polygons = read_obj_polygons(HEAD)
    points = polygons.points * factor
    found = find_landmarks(points, polygons_to_triangles(polygons.counts, polygons.indices), label=label)
    error_mm = 10.0 * np.linalg.norm(points[found.indices] - points[ict_landmark_indices()], axis=1)
    # one re-read of the proportions (before): 1.50 / 6.5 mm wider, 1.37 / 7.2 mm flatter (benchmarks/rigging.py)
    assert error_mm.mean() <= 1.0 and error_mm.max() <= 4.5


def test_an_off_skin_eye_point_snaps_across_its_normal_and_a_near_one_to_the_nearest_vertex():
    """A lid's thin margin (a row of vertices at y = 0, z = 0.05, facing front) above a cheek (y ≤ −0.035, z = 0):
    a carried point 0.045 behind the margin is nearer the cheek's top row in space, but across its normal it is
    the margin's vertex (docs/RIG.md §9, step 6). Within ``OFF_SKIN`` of the skin, the nearest vertex wins."""
    from warpface.rigging.detect import OFF_SKIN, snap_to_skin

    xs = np.linspace(-0.1, 0.1, 21)
    margin = np.stack([xs, np.zeros_like(xs), np.full_like(xs, 0.05)], axis=1)
    cheek = np.array([(x, y, 0.0) for y in (-0.035, -0.045, -0.055) for x in xs])
    points = np.vstack([margin, cheek])
    normals = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    skin = SkinTarget(points, normals, np.zeros(len(points), dtype=bool), cKDTree(points))
    behind = np.array([[0.0, 0.0, 0.005]])
    front = np.array([[0.0, 0.0, 1.0]])
    assert np.linalg.norm(points[21 + 10] - behind[0]) < np.linalg.norm(points[10] - behind[0])  # cheek nearer
    index, distance = snap_to_skin(behind, front, skin, across=np.array([True]))
    assert index[0] == 10 and distance[0] == pytest.approx(0.045)
    assert snap_to_skin(behind, front, skin)[0][0] == 21 + 10  # not an eye landmark: the nearest vertex
    near = np.array([[0.004, -0.034, 0.0]])  # on the cheek, within OFF_SKIN of it
    assert np.linalg.norm(points[21 + 10] - near[0]) < OFF_SKIN
    assert snap_to_skin(near, front, skin, across=np.array([True]))[0][0] == 21 + 10
