"""Tracking drives the tissue FEM: tracked skin stays exactly tracked, the FEM moves the rest smoothly."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import patch

from warpface.fem import TissueMaterial
from warpface.fem.volume import tissue_from_surface
from warpface.pipelines.tissue_drive import TissueDrive, bone_side_nodes
from warpface.tracking import adapter_for_face, vertex_landmark_names
from warpface.tracking.sources import LandmarkFrame


@pytest.fixture(scope="module")
def skin_and_tissue():
    points, triangles = patch(17, size=0.08, hole=False)
    tetmesh = tissue_from_surface((points, triangles), 0.006, target_nodes=700, device="cpu")
    return points, triangles, tetmesh


def test_tissue_drive_keeps_tracked_skin_and_moves_the_rest(skin_and_tissue):
    points, triangles, tetmesh = skin_and_tissue
    centre = np.flatnonzero(np.linalg.norm(points[:, :2], axis=1) < 0.022)  # dots on the middle only
    names = vertex_landmark_names(centre)
    adapter = adapter_for_face(points, names, camera_to_model=np.eye(4), device="cpu")
    material = TissueMaterial(E=192.4e3, nu=0.495, eta=476.8, rho=1100.0)
    drive = TissueDrive(adapter, tetmesh, material, fps=30.0, dt=1.0 / 90.0, thickness=0.006, device="cpu")
    assert drive.substeps == 3 and len(drive.fixed_nodes) > 0
    assert np.intersect1d(drive.fixed_nodes, drive.driven_nodes).size == 0
    lift = np.array([0.0, 0.0, 0.002])
    adapter.bind(names)
    for i in range(6):
        frame = LandmarkFrame(
            timestamp=i / 30.0, points=points[centre] + lift * min(i, 3) / 3, confidence=np.ones(len(centre)), index=i
        )
        direct = adapter.track_frame(frame)
        blended = drive(frame, direct)
    assert np.all(np.isfinite(blended))
    tracked = adapter.weights >= 1.0
    np.testing.assert_allclose(blended[tracked], direct[tracked], atol=1e-7)  # tracked skin is untouched
    outside = adapter.weights == 0.0
    assert outside.any()
    moved = np.linalg.norm(blended - points, axis=1)
    lifted = moved[tracked].mean()
    assert lifted == pytest.approx(0.002, rel=0.05)
    near = outside & (np.linalg.norm(points[:, :2], axis=1) < 0.045)
    assert moved[near].max() > 0.05 * lifted  # the tissue pulls untracked skin along
    assert moved[outside].max() < lifted  # but less than the tracked motion


def test_bone_side_is_the_deep_boundary(skin_and_tissue):
    points, _, tetmesh = skin_and_tissue
    deep = bone_side_nodes(tetmesh, points, 0.006)
    assert len(deep) > 0
    assert np.all(tetmesh.points[deep, 2] < -0.003)  # the patch faces +z; the bone side is 6 mm below
