"""Automatic landmarks (warpface.rigging): invariance to unit, pose, vertex order and extra shells; accuracy
against real ground truth (ICT-FaceKit, menpo james, when ../shared/data is present); units and bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from warpface.assets import default_face
from warpface.data import shared_data_path
from warpface.mesh import load_obj
from warpface.rigging import (
    HeadSurface,
    find_landmarks,
    infer_units,
    landmarks_from_values,
    polygons_to_triangles,
    read_landmark_file,
)
from warpface.rigging.align import symmetry_plane, umeyama
from warpface.rigging.detect import PASSES
from warpface.rigging.units import parse_axis

MENPO_TO_IBUG = np.r_[0:17, 29:34, 43:48, 34:43, 17:23, 23:29, 48:68]
"""james.ljson lists chin, eyes (subject's right first), brows, nose, then the mouth: this reorders it to iBUG."""


@pytest.fixture(scope="module")
def face_fit():
    face = default_face()
    return face, find_landmarks(face.points, face.triangles, label="built-in")


def _sphere(count=600, seed=0):
    """A closed convex surface: points on a unit sphere and their hull's triangles."""
    from scipy.spatial import ConvexHull

    points = np.random.default_rng(seed).normal(size=(count, 3))
    points /= np.linalg.norm(points, axis=1, keepdims=True)
    return points, ConvexHull(points).simplices


def _tube(count=80, radius=10.0, height=30.0):
    """An open cylinder about y (cm): a grid wrapped once around, (points, triangles)."""
    around, along = np.meshgrid(np.linspace(-np.pi, np.pi, count), np.linspace(-0.5, 0.5, count), indexing="ij")
    points = np.column_stack([radius * np.cos(around.ravel()), height * along.ravel(), radius * np.sin(around.ravel())])
    index = np.arange(count * count).reshape(count, count)
    a, b, c, d = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    return points, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def test_a_tube_the_template_fits_is_refused_by_its_landmarks_layout():
    """The template lies on a cylinder almost as on a face (similarity score 0.073 d, under the 0.12 d limit); the
    landmarks it leaves are not laid out as a face's, and that is what refuses it."""
    points, triangles = _tube()
    with pytest.raises(ValueError, match="no face-like part found .*not laid out as a face's"):
        find_landmarks(points, triangles, label="tube")


def test_built_in_face_is_found_upright_in_metres(face_fit):
    face, found = face_fit
    assert found.units == "m" and found.meters_per_unit == 1.0
    assert found.up @ [0, 1, 0] > 0.99 and found.front @ [0, 0, 1] > 0.99 and found.left @ [1, 0, 0] > 0.99
    assert found.indices.shape == (68,) and found.confidence.shape == (68,)
    assert np.all((found.confidence >= 0) & (found.confidence <= 1)) and found.confidence.mean() > 0.5
    marks = face.points[found.indices]
    assert np.all(marks[36:42, 0] < 0) and np.all(marks[42:48, 0] > 0)  # the subject's right eye at −x
    assert marks[30, 2] == pytest.approx(face.points[:, 2].max(), abs=0.004)  # the nose tip sticks out most


def test_turned_z_up_millimetre_shuffled_head_with_an_extra_shell_gives_the_same_landmarks(face_fit):
    face, found = face_fit
    rotation = Rotation.from_euler("xyz", [-90.0 + 14.0, 0.0, 130.0], degrees=True)  # Y-up → Z-up, tilted, turned
    points = rotation.apply(np.array(face.points)) * 1000.0 + [250.0, -40.0, 900.0]
    order = np.random.default_rng(3).permutation(face.vertex_count)  # new index → old index
    moved, old_to_new = points[order], np.argsort(order)
    triangles = old_to_new[face.triangles]
    eye, eye_triangles = _sphere()
    eye = rotation.apply(eye * 0.012 + np.array(face.points[found.indices[36:42]]).mean(axis=0) - [0, 0, 0.013])
    moved = np.vstack([moved, eye * 1000.0 + [250.0, -40.0, 900.0]])
    triangles = np.vstack([triangles, eye_triangles + face.vertex_count])
    again = find_landmarks(moved, triangles, label="turned")
    assert again.units == "mm" and again.shells == 2
    assert again.up @ rotation.apply([0, 1, 0]) > 0.99 and again.front @ rotation.apply([0, 0, 1]) > 0.99
    assert np.all(again.indices < face.vertex_count)  # on the skin, not the eyeball
    gap_mm = np.linalg.norm(moved[again.indices] - points[found.indices], axis=1)
    assert gap_mm.mean() < 1.0 and gap_mm.max() < 4.0


def test_hints_pick_the_orientation_and_contradictions_are_refused(face_fit):
    face, found = face_fit
    stages = []
    hinted = find_landmarks(face.points * 100.0, face.triangles, up="y", front="+z", units="cm", progress=stages.append)
    assert hinted.units == "cm" and hinted.up @ [0, 1, 0] > 0.99
    fits = [f"non-rigid fit {k} of {PASSES + 1}" for k in range(1, PASSES + 2)]
    assert stages == ["orientation", "proportions", *fits, "landmarks"]
    np.testing.assert_array_equal(hinted.indices, found.indices)
    with pytest.raises(ValueError, match="not perpendicular"):
        find_landmarks(face.points, face.triangles, up="y", front="-y")
    with pytest.raises(ValueError, match="units"):
        find_landmarks(face.points, face.triangles, units="km")
    with pytest.raises(ValueError, match="up"):
        find_landmarks(face.points, face.triangles, up="w")


def test_symmetry_plane_of_a_mirror_symmetric_cloud_and_umeyama_recover_known_transforms():
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(1)
    half = rng.normal(size=(400, 3)) * [1.0, 2.0, 0.7] + [1.5, 0.0, 0.0]
    cloud = np.vstack([half, half * [-1, 1, 1]])
    turn = Rotation.from_euler("zyx", [30, -20, 10], degrees=True)
    moved = turn.apply(cloud) + [0.3, -0.2, 0.5]
    normal, offset, residual = symmetry_plane(moved, cKDTree(moved))
    assert abs(normal @ turn.apply([1, 0, 0])) > 0.999 and residual < 1e-6
    assert offset == pytest.approx(turn.apply([1, 0, 0]) @ [0.3, -0.2, 0.5] * np.sign(normal @ turn.apply([1, 0, 0])))
    scale, rotation, translation = umeyama(cloud, 2.5 * moved, np.ones(len(cloud)))
    assert scale == pytest.approx(2.5) and np.allclose(rotation, turn.as_matrix())
    assert np.allclose(translation, 2.5 * np.array([0.3, -0.2, 0.5]))


def test_the_batched_similarity_fits_equal_each_fit_alone_and_recover_known_transforms():
    """umeyama_many recovers several known similarities from weighted, noisy matches in one call, and the ICP run from
    several starts at once (a start whose matches all fall away stops) ends where each start run alone ends."""
    from scipy.spatial import cKDTree

    from warpface.rigging import align
    from warpface.rigging.align import Similarity, umeyama_many

    rng = np.random.default_rng(4)
    source = rng.normal(size=(300, 3)) * [1.0, 1.4, 0.6]
    turns = Rotation.random(5, random_state=4).as_matrix()
    scales, shifts = rng.uniform(0.5, 2.0, 5), rng.normal(size=(5, 3))
    targets = scales[:, None, None] * source @ np.swapaxes(turns, 1, 2) + shifts[:, None]
    weights = rng.uniform(0.1, 1.0, (5, 300))
    scale, rotation, translation = umeyama_many(source, targets, weights)
    np.testing.assert_allclose(scale, scales, rtol=1e-12)
    np.testing.assert_allclose(rotation, turns, atol=1e-12)
    np.testing.assert_allclose(translation, shifts, atol=1e-12)
    one = umeyama(source, targets[2] + rng.normal(0.0, 0.05, (300, 3)), weights[2])
    assert one[0] == pytest.approx(scales[2], rel=0.05) and np.allclose(one[1], turns[2], atol=0.05)

    skin = rng.normal(size=(2000, 3)) * [1.0, 1.3, 0.5]  # an ellipsoid's shell, its normals pointing out
    skin /= np.linalg.norm(skin / [1.0, 1.3, 0.5], axis=1, keepdims=True)
    normals = skin / np.array([1.0, 1.3, 0.5]) ** 2
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    template, template_normals = skin[::10] * 0.9, normals[::10]
    starts = [
        Similarity(1.0, np.eye(3), np.zeros(3)),
        Similarity(1.2, Rotation.from_euler("z", 20, degrees=True).as_matrix(), np.array([0.1, 0.0, 0.0])),
        Similarity(1.0, np.eye(3), np.array([50.0, 0.0, 0.0])),  # far from the skin: its weights vanish at once
    ]
    tree = cKDTree(skin)
    together = align._icp(template, template_normals, skin, normals, tree, starts, 12)
    for start, fit in zip(starts, together):
        alone = align._icp(template, template_normals, skin, normals, tree, [start], 12)[0]
        assert fit.scale == pytest.approx(alone.scale, rel=1e-12) and fit.residual == pytest.approx(alone.residual)
        np.testing.assert_allclose(fit.rotation, alone.rotation, atol=1e-12)
        np.testing.assert_allclose(fit.translation, alone.translation, atol=1e-12)
    assert together[2].scale == 1.0 and np.allclose(together[2].translation, [50.0, 0.0, 0.0])
    assert together[0].residual < 0.05 and together[0].scale == pytest.approx(1.0 / 0.9, rel=0.05)


def test_the_non_rigid_fit_s_node_order_keeps_each_node_together_and_solves_exactly():
    """The fit's fill-reducing order comes from the node graph alone: a permutation of the 4K unknowns that keeps each
    node's four together; systems with the graph's pattern in 4 × 4 blocks (smoothness plus block-diagonal data, as
    the fit builds them) solve in it to a dense float64 solve's answer."""
    import scipy.sparse as sp

    from warpface.rigging import nonrigid

    rng = np.random.default_rng(2)
    k = 120
    path = sp.diags([np.full(k - 1, -1.0), np.full(k, 2.0), np.full(k - 1, -1.0)], [-1, 0, 1])
    links = sp.random(k, k, density=0.02, random_state=rng)
    laplacian = sp.csgraph.laplacian(((path != 0) + (links @ links.T != 0)).astype(float))
    smooth = sp.kron(laplacian, sp.identity(4), format="csc")
    order = nonrigid._node_order(smooth)
    assert sorted(order.tolist()) == list(range(4 * k))
    np.testing.assert_array_equal(order.reshape(k, 4) % 4, np.tile(np.arange(4), (k, 1)))
    np.testing.assert_array_equal(order.reshape(k, 4) // 4, np.repeat(order[::4] // 4, 4).reshape(k, 4))
    for alpha in (50.0, 0.5):
        data = [rng.normal(size=(6, 4)) for _ in range(k)]
        blocks = sp.block_diag([d.T @ d + 1e-3 * np.eye(4) for d in data])
        system = (alpha * smooth + blocks).tocsr()
        right = rng.normal(size=(4 * k, 3))
        solution = nonrigid._solve(system, right, order)
        np.testing.assert_allclose(solution, np.linalg.solve(system.toarray(), right), rtol=1e-9, atol=1e-9)


def test_polygons_become_fans_over_the_original_vertices():
    counts, indices = [4, 3, 5], [0, 1, 2, 3, 3, 2, 4, 4, 2, 5, 6, 7]
    triangles = polygons_to_triangles(counts, indices)
    assert triangles.tolist() == [[0, 1, 2], [0, 2, 3], [3, 2, 4], [4, 2, 5], [4, 5, 6], [4, 6, 7]]
    with pytest.raises(ValueError, match="corners"):
        polygons_to_triangles([2], [0, 1])


def test_units_from_the_eye_distance():
    assert infer_units(0.064) == ("m", 1.0)
    assert infer_units(6.1) == ("cm", 0.01)
    assert infer_units(70.0) == ("mm", 0.001)
    with pytest.raises(ValueError, match="not a human head in m, cm or mm"):
        infer_units(6.3e-5, "head.obj")  # kilometres
    assert parse_axis("-z", "front").tolist() == [0, 0, -1]


def test_bad_surfaces_say_what_was_found():
    with pytest.raises(TypeError, match="points"):
        HeadSurface(None, [[0, 1, 2]])
    with pytest.raises(TypeError, match="landmarks"):
        landmarks_from_values("68 points", np.zeros((10, 3)))
    with pytest.raises(ValueError, match="no vertices"):
        HeadSurface(np.zeros((0, 3)), np.zeros((0, 3), dtype=int))
    with pytest.raises(ValueError, match="point cloud"):
        HeadSurface(np.random.default_rng(0).normal(size=(50, 3)), np.zeros((0, 3), dtype=int))
    points, triangles = _sphere(2000)
    with pytest.raises(ValueError, match="no face-like part"):
        find_landmarks(points * 0.1, triangles)
    two = HeadSurface(np.vstack([points, points + [5.0, 0.0, 0.0]]), np.vstack([triangles, triangles + len(points)]))
    with pytest.raises(ValueError, match="two head-sized parts"):
        _ = two.skin_vertices
    eye_and_head = HeadSurface(np.vstack([points, 0.2 * points]), np.vstack([triangles, triangles + len(points)]))
    assert eye_and_head.shell_count == 2 and eye_and_head.skin_vertices.max() < len(points)
    soup = np.arange(3 * len(triangles)).reshape(-1, 3)
    with pytest.raises(ValueError, match="triangle soup"):
        find_landmarks(points[triangles].reshape(-1, 3), soup)


def test_landmark_values_and_files(tmp_path):
    face = default_face()
    indices = np.arange(0, 68 * 50, 50)
    assert landmarks_from_values(indices.tolist(), face.points).tolist() == indices.tolist()
    assert landmarks_from_values(face.points[indices] + 1e-5, face.points).tolist() == indices.tolist()
    (tmp_path / "marks.json").write_text(json.dumps({"landmarks": face.points[indices].tolist()}))
    assert read_landmark_file(tmp_path / "marks.json", face.points).tolist() == indices.tolist()
    rows = "".join(f'<point x="{x}" y="{y}" z="{z}" name="{i}"/>' for i, (x, y, z) in enumerate(face.points[indices]))
    (tmp_path / "marks.pp").write_text(f"<!DOCTYPE PickedPoints><PickedPoints>{rows}</PickedPoints>")
    assert read_landmark_file(tmp_path / "marks.pp", face.points).tolist() == indices.tolist()
    with pytest.raises(ValueError, match="expected 68"):
        landmarks_from_values(indices[:60], face.points)
    with pytest.raises(ValueError, match="off the mesh"):
        landmarks_from_values(face.points[indices] * 100.0, face.points)
    (tmp_path / "empty.json").write_text("")
    with pytest.raises(ValueError, match="empty"):
        read_landmark_file(tmp_path / "empty.json", face.points)


ICT = shared_data_path("ict_facekit")
JAMES = shared_data_path("menpo3d_james")


@pytest.mark.skipif(ICT is None, reason="ICT-FaceKit data not in ../shared/data (set WARPFACE_SHARED_DATA)")
def test_ict_face_region_landmarks_within_3_mm():
    from warpface.data import ict_face_region, ict_landmark_indices

    points, triangles = load_obj(ict_face_region())
    found = find_landmarks(points, triangles, label="ict")
    error_mm = 10.0 * np.linalg.norm(points[found.indices] - points[ict_landmark_indices()], axis=1)
    assert found.units == "cm" and error_mm.mean() <= 3.0 and error_mm.max() <= 10.0


@pytest.mark.skipif(JAMES is None, reason="menpo3d james not in ../shared/data (set WARPFACE_SHARED_DATA)")
def test_james_scan_landmarks_against_its_reordered_ground_truth():
    points, triangles = load_obj(JAMES / "james.obj")
    truth = np.asarray(json.loads((JAMES / "james.ljson").read_text())["groups"]["LJSON"]["landmarks"]["points"])
    truth = truth[MENPO_TO_IBUG]
    found = find_landmarks(points, triangles, label="james")
    error_mm = np.linalg.norm(points[found.indices] - truth, axis=1)
    assert found.units == "mm"
    assert error_mm[27:].mean() <= 5.0  # nose, eyes, mouth: geometric features the registration matches
    assert error_mm.mean() <= 9.0  # jaw line and brows follow ICT's annotation, not menpo's (docs/RIG.md)


def test_profile_peaks_are_the_most_forward_points_spaced_along_up():
    from warpface.rigging.align import TIP_STARTS, profile_peaks

    heights = np.linspace(-1.0, 1.0, 401)
    forward = np.exp(-((heights - 0.3) ** 2) / 0.005) + 1.2 * np.exp(-((heights + 0.5) ** 2) / 0.02)  # nose, chin
    profile = np.stack([np.zeros_like(heights), heights, forward], axis=1)
    peaks = profile_peaks(profile, np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]), spacing=0.3)
    assert TIP_STARTS == 2 and len(peaks) == 2
    np.testing.assert_allclose([peaks[0][1], peaks[1][1]], [-0.5, 0.3], atol=0.006)  # the chin first, then the nose
    assert len(profile_peaks(profile, np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]), spacing=3.0)) == 1
