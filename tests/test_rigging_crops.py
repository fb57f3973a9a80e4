"""Cropped faces (docs/RIG.md §9, step 3, "Cropped faces"): template points hanging past the skin's open boundary are
charged at most ``BEYOND`` in the similarity score, so a face cut at the brows is fitted upright. A closed loop on
the ICT face region with its forehead removed (ground truth by vertex index), against the full ``MISS`` charge."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from warpface.data import ict_landmark_indices, shared_data_path
from warpface.mesh import load_obj
from warpface.rigging import align, find_landmarks
from warpface.rigging.surface import HeadSurface

FACE = shared_data_path("ict_facekit", "face_region_tri", "neutral.obj")


@pytest.mark.skipif(FACE is None, reason="ICT-FaceKit data not in ../shared/data (set WARPFACE_SHARED_DATA)")
def test_a_face_cut_at_the_brows_is_fitted_upright(monkeypatch):
    points, triangles = load_obj(FACE)
    truth = points[ict_landmark_indices()]
    below_brows = points[:, 1] < truth[17:27, 1].mean()
    kept = triangles[below_brows[triangles].all(axis=1)]

    error_mm = np.linalg.norm(points[find_landmarks(points, kept).indices] - truth, axis=1) * 10.0
    assert error_mm.mean() < 1.5 and error_mm[27:].max() < 3.0  # the brows lie on the cut

    monkeypatch.setattr(align, "BEYOND", align.MISS)  # points past the cut charged as misses: chin up
    upside_down = np.linalg.norm(points[find_landmarks(points, kept).indices] - truth, axis=1) * 10.0
    assert upside_down.mean() > 50.0


@pytest.mark.skipif(FACE is None, reason="ICT-FaceKit data not in ../shared/data (set WARPFACE_SHARED_DATA)")
def test_the_similarity_score_charges_points_past_the_boundary_at_most_beyond():
    """The score of a fit against a float64 brute-force reference: the mean over the template points of the distance
    to the nearest skin point in eye distances, capped at MISS and charged MISS where the normals disagree, and at
    most BEYOND where that skin point is on the open boundary."""
    points, triangles = load_obj(FACE)
    skin, normals, boundary = HeadSurface(points, triangles).skin_samples
    rng = np.random.default_rng(5)
    chosen = rng.choice(len(skin), 400, replace=False)
    nodes = skin[chosen] + rng.normal(0.0, 1.5, (400, 3))  # cm, around the skin: some past its outline
    node_normals = normals[rng.permutation(chosen)]  # some facing away
    fit = align.Similarity(6.0, np.eye(3), np.zeros(3))  # 1 template unit = 6 cm
    scored = align._icp(nodes / 6.0, node_normals, skin, normals, cKDTree(skin), [fit], 0, boundary=boundary)[0]

    costs, past = [], 0
    for point, normal in zip(nodes.astype(np.float64), node_normals):
        distances = np.linalg.norm(skin - point, axis=1)
        nearest = int(np.argmin(distances))
        cost = min(distances[nearest] / 6.0, align.MISS) if normal @ normals[nearest] > align.FACING else align.MISS
        past += bool(boundary[nearest])
        costs.append(min(cost, align.BEYOND) if boundary[nearest] else cost)
    assert past > 10 and max(costs) == align.MISS  # both rules are exercised
    assert scored.residual == pytest.approx(np.mean(costs), rel=1e-9)
