"""The eyes placed on an open eye's socket (warpface.rigging.eye_opening, docs/RIG.md §9 step 6c)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from warpface.data import ict_landmark_indices, shared_data_path
from warpface.mesh import load_obj
from warpface.rigging import eye_opening
from warpface.rigging.detect import SNAPPED_ACROSS, register, snap_to_skin
from warpface.rigging.eye_opening import CELL, CORNER_OFFSETS, eye_openings, front_depth, socket_outline
from warpface.rigging.nonrigid import SkinTarget

CENTRE = np.array([-0.45, 0.0])
SEMI_AXES = np.array([0.17, 0.06])


def _sheet(hole: bool, spacing: float = 0.01) -> tuple[SkinTarget, np.ndarray]:
    """A flat skin at z = 0 facing +z over [−1.2, 0.3] × [−0.5, 0.5], vertices ``spacing`` apart, with an elliptical
    opening about :data:`CENTRE` when ``hole`` (template frame, inter-ocular units)."""
    xs, ys = np.linspace(-1.2, 0.3, round(1.5 / spacing) + 1), np.linspace(-0.5, 0.5, round(1.0 / spacing) + 1)
    x, y = np.meshgrid(xs, ys, indexing="ij")
    points = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    index = np.arange(x.size).reshape(x.shape)
    a, b, c, d = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    triangles = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    if hole:
        centroid = points[triangles].mean(axis=1)[:, :2]
        triangles = triangles[np.sum(((centroid - CENTRE) / SEMI_AXES) ** 2, axis=1) > 1.0]
    normals = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    return SkinTarget(points, normals, np.zeros(len(points), bool), cKDTree(points)), triangles


def _carried(offset=(0.03, 0.04)) -> np.ndarray:
    """68 landmark points, the right eye's ring (iBUG 36–41) an ellipse-like hexagon about CENTRE + offset."""
    marks = np.zeros((68, 3))
    angles = np.radians([180.0, 120.0, 60.0, 0.0, -60.0, -120.0])  # outer corner, upper lid, inner corner, lower
    ring = CENTRE + np.asarray(offset) + SEMI_AXES * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    marks[36:42, :2] = ring
    marks[42:48, :2] = ring * [-1.0, 1.0]
    return marks


def test_the_depth_buffer_matches_a_brute_force_reference():
    rng = np.random.default_rng(3)
    points = rng.uniform([-0.3, -0.3, -0.5], [0.3, 0.3, 0.5], (30, 3))
    triangles = rng.integers(0, 30, (25, 3))
    low, shape = np.array([-0.2, -0.15]), (40, 30)
    depth = front_depth(points, triangles, low, shape, -10.0)
    reference = np.full(shape, -np.inf)
    for i in range(shape[0]):
        for j in range(shape[1]):
            p = low + (np.array([i, j]) + 0.5) * CELL
            for a, b, c in points[triangles].astype(np.float64):
                if np.cross(b - a, c - a)[2] <= 0.0:
                    continue
                weights = np.linalg.solve(np.array([[b[0] - a[0], c[0] - a[0]], [b[1] - a[1], c[1] - a[1]]]), p - a[:2])
                if weights.min() >= 0.0 and weights.sum() <= 1.0:
                    reference[i, j] = max(reference[i, j], a[2] + weights @ [b[2] - a[2], c[2] - a[2]])
    assert np.isfinite(reference).sum() > 100
    np.testing.assert_allclose(depth, reference, atol=1e-9)


def test_a_ring_carried_off_an_opening_moves_onto_its_outline():
    skin, triangles = _sheet(hole=True)
    marks = _carried()
    moved = eye_openings(skin, triangles, marks)
    ring = moved[36:42, :2]
    outer, inner = CENTRE - [SEMI_AXES[0], 0.0], CENTRE + [SEMI_AXES[0], 0.0]
    width = inner[0] - outer[0]
    for point, (along, up) in zip(ring[[0, 3]], CORNER_OFFSETS):
        np.testing.assert_allclose(point, outer + width * np.array([along, up]), atol=3 * CELL)
    lids = ring[[1, 2, 4, 5]]
    on_ellipse = np.sum(((lids - CENTRE) / SEMI_AXES) ** 2, axis=1)
    assert np.all(np.abs(np.sqrt(on_ellipse) - 1.0) < 2 * CELL / SEMI_AXES[1])
    assert np.all(np.sign(lids[:, 1] - CENTRE[1]) == [1, 1, -1, -1])  # upper lid points stay on the upper lid
    np.testing.assert_allclose(
        moved[17:22, :2] - marks[17:22, :2], np.tile(np.mean(ring - marks[36:42, :2], 0), (5, 1))
    )
    np.testing.assert_array_equal(
        np.delete(moved, np.r_[17:22, 36:48], axis=0), np.delete(marks, np.r_[17:22, 36:48], 0)
    )
    np.testing.assert_array_equal(moved[:, 2], marks[:, 2])


def test_skin_over_the_eye_a_coarse_skin_or_an_eye_carried_too_far_leaves_the_ring_as_it_was(monkeypatch):
    closed, triangles = _sheet(hole=False)
    assert socket_outline(closed, triangles, _carried()[36:42], right_eye=True) is None
    coarse, triangles = _sheet(hole=True, spacing=0.075)  # edges 0.075–0.106 d: median over MAX_EDGE
    assert socket_outline(coarse, triangles, _carried()[36:42], right_eye=True) is None
    monkeypatch.setattr(eye_opening, "MAX_EDGE", 0.2)
    assert socket_outline(coarse, triangles, _carried()[36:42], right_eye=True) is not None
    monkeypatch.undo()
    np.testing.assert_array_equal(eye_openings(closed, triangles, _carried()), _carried())
    skin, triangles = _sheet(hole=True)
    assert socket_outline(skin, triangles, _carried()[36:42], right_eye=True) is not None
    monkeypatch.setattr(eye_opening, "MAX_MOVE", 0.04)  # the ring above moves ~0.05 d
    np.testing.assert_array_equal(eye_openings(skin, triangles, _carried()), _carried())


def test_the_socket_places_the_eyes_of_a_warped_ict_head_the_registration_left_off():
    """Development head 618 (a bumpy warp): its right eye is carried ~9 mm high; on the socket both eyes
    come within a few millimetres of the annotation and the brows follow them part of the way, while the ICT head
    itself stays where it was."""
    from benchmarks.rigging import bumpy_warp

    path = shared_data_path("ict_facekit", "original", "generic_neutral_mesh.obj")
    if path is None:
        pytest.skip("../shared/data/ict_facekit is not present")
    rest, triangles = load_obj(path)
    truth = ict_landmark_indices()
    moved = np.r_[17:27, 36:48]  # brows, eyes
    for points, eyes_before_at_least, eyes_after_at_most, brows_gain_at_least in (
        (bumpy_warp(rest, 618), 5.0, 3.5, 2.0),
        (rest, 0.0, 0.2, 0.0),
    ):
        registration = register(points, triangles)
        surface, skin = registration.surface, registration.skin
        marks, normals = registration.landmark_points()
        eyes, brows = [], []
        for carried in (marks, eye_openings(skin, surface.skin_faces, marks)):
            index, _ = snap_to_skin(carried[moved], normals[moved], skin, across=np.isin(moved, SNAPPED_ACROSS))
            error = np.linalg.norm(points[surface.skin_vertices[index]] - points[truth[moved]], axis=1) * 10.0  # mm
            brows.append(error[:10].mean())
            eyes.append(error[10:].mean())
        assert eyes[0] >= eyes_before_at_least and eyes[1] <= eyes_after_at_most, eyes
        assert brows[0] - brows[1] >= brows_gain_at_least and brows[1] <= brows[0] + 0.2, brows
