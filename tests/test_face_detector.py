"""The markerless detector: anchors, the 468 → iBUG map (re-derived from the shared data), smoothing, and detection on
a rendered face (against its projected ground truth), a real photo when scikit-image is installed, and bad input."""

import numpy as np
import pytest

from warpface.data import shared_data_path
from warpface.tracking.face_detector import ssd_anchors
from warpface.tracking.face_mesh_ibug import IBUG_TRIANGLES, IBUG_WEIGHTS, derive_ibug_map, ibug_from_mesh
from warpface.tracking.face_models import model_path
from warpface.tracking.smoothing import OneEuroFilter


def _models_present() -> str | None:
    try:
        import ai_edge_litert  # noqa: F401
    except ImportError:
        return "ai-edge-litert is not installed (the markerless extra)"
    try:
        for role in ("detector", "detector_full", "mesh"):
            model_path(role)
    except FileNotFoundError as error:
        return str(error)
    return None


needs_models = pytest.mark.skipif(_models_present() is not None, reason=str(_models_present()))


def test_ssd_anchor_grids_match_the_networks_outputs():
    short, full = ssd_anchors(128), ssd_anchors(192)
    assert short.shape == (896, 2) and full.shape == (2304, 2)
    # stride 8: two anchors per cell, the first cell centred at (4, 4); stride 16 starts after 16·16·2 anchors
    assert np.allclose(short[0], [4, 4]) and np.allclose(short[1], [4, 4]) and np.allclose(short[2], [12, 4])
    assert np.allclose(short[512], [8, 8]) and np.allclose(short[512:518], [8, 8])
    assert np.allclose(full[48], [2, 6]) and np.allclose(full.max(axis=0), [190, 190])


def test_ibug_map_is_rederived_from_the_shared_data():
    obj = shared_data_path("mediapipe", "canonical_face_model.obj")
    marks = shared_data_path("ict_facekit", "landmarks_multipie68.txt")
    if obj is None or marks is None:
        pytest.skip("the shared face data (../shared/data) is absent")
    from warpface.mesh import load_obj

    points, triangles = load_obj(obj)
    triangles_, weights, distance = derive_ibug_map(points, triangles, np.loadtxt(marks)[:, 2:5])
    assert np.array_equal(triangles_, IBUG_TRIANGLES)
    assert np.allclose(weights, IBUG_WEIGHTS, atol=2e-4)
    assert distance.max() < 0.7  # cm: every ICT landmark lies on (near) the warped canonical face
    # the named points land on their own mesh point
    ibug = ibug_from_mesh(points)
    for number, vertex in ((36, 33), (39, 133), (42, 362), (45, 263), (30, 1), (48, 61), (54, 291)):
        assert np.linalg.norm(ibug[number] - points[vertex]) < 0.05, number
    # the subject's right (iBUG 36–41, mesh 33) is at −x in the canonical frame, as in warpface's
    assert ibug[36, 0] < 0 < ibug[45, 0]


def test_one_euro_filter_smooths_a_still_signal_and_follows_a_moving_one():
    rng = np.random.default_rng(0)
    still = OneEuroFilter()
    noisy = 100.0 + rng.normal(0, 1.0, (300, 2))
    out = np.array([still(x, i / 30) for i, x in enumerate(noisy)])
    assert out[50:].std() < 0.5 * noisy[50:].std()
    moving = OneEuroFilter(beta=0.5)
    ramp = np.stack([np.arange(60) * 10.0, np.zeros(60)], axis=1)
    lagged = np.array([moving(x, i / 30) for i, x in enumerate(ramp)])
    assert abs(lagged[-1, 0] - ramp[-1, 0]) < 15.0  # a fast linear motion lags by well under two frames
    gap = moving(np.array([np.nan, 0.0]), 2.0)
    assert np.isnan(gap[0]) and np.isfinite(gap[1])


def test_missing_model_file_is_one_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="face_landmark.tflite"):
        model_path("mesh", model_dir=tmp_path)
    with pytest.raises(FileNotFoundError, match="nothing.tflite"):
        model_path("mesh", path=tmp_path / "nothing.tflite")
    with pytest.raises(ValueError, match="role"):
        model_path("eyes")


@pytest.fixture(scope="module")
def rendered_face():
    pytest.importorskip("pyrender")
    from warpface.assets import default_rig
    from warpface.pipelines.markerless_loop import markerless_capture

    rig = default_rig()
    capture = markerless_capture(rig, seconds=0.2, noise=False)
    color, _ = capture.camera.render(0)
    projected = capture.camera.intrinsics.project(capture.camera.camera_points(0))
    yield color, projected[rig.landmarks], projected, rig
    capture.camera.close()


@needs_models
def test_rendered_face_landmarks_match_the_projected_ground_truth(rendered_face):
    from warpface.tracking import detect_face_landmarks

    color, truth, _, _ = rendered_face
    found = detect_face_landmarks(color)
    assert set(f"ibug{i:02d}" for i in range(68)) <= set(found)
    detected = np.array([found[f"ibug{i:02d}"] for i in range(68)])
    iod = np.linalg.norm(truth[36] - truth[45])
    error = np.linalg.norm(detected - truth, axis=1) / iod
    # eye and mouth corners (measured 0.9–4.0 % of the inter-ocular distance); the nose tip of the untextured,
    # frontally lit render has no cue but shading (measured 9.3 %)
    for number in (36, 39, 42, 45, 48, 54):
        assert error[number] < 0.06, (number, error[number])
    assert error[30] < 0.12
    assert detected[36, 0] < detected[45, 0]  # the subject's right eye at the image's left


@needs_models
def test_no_face_two_faces_and_bad_images(rendered_face):
    from warpface.tracking import detect_face_landmarks

    color, truth, _, _ = rendered_face
    assert detect_face_landmarks(np.zeros((480, 640, 3), np.uint8)) == {}
    assert detect_face_landmarks(np.random.default_rng(1).integers(0, 255, (240, 320, 3), dtype=np.uint8)) == {}
    # two faces side by side, the right one 0.8 times the size: the largest by default, the other with face=1
    import cv2

    left = color[140:360, 220:420]
    right = cv2.resize(left, None, fx=0.8, fy=0.8, interpolation=cv2.INTER_AREA)
    pair = np.zeros((220, 400, 3), np.uint8)
    pair[:, :200] = left
    pair[20 : 20 + right.shape[0], 210 : 210 + right.shape[1]] = right
    large = detect_face_landmarks(pair)
    other = detect_face_landmarks(pair, face=1)
    assert large and other
    assert abs(large["ibug30"][0] - (truth[30, 0] - 220)) < 8.0 and other["ibug30"][0] > 210
    assert detect_face_landmarks(pair, face=5) == {}
    with pytest.raises(TypeError, match="rgb"):
        detect_face_landmarks([[1, 2, 3]])
    with pytest.raises(ValueError, match="rgb"):
        detect_face_landmarks(np.zeros((480, 640), np.uint8))
    with pytest.raises(ValueError, match="rgb"):
        detect_face_landmarks(np.zeros((480, 640, 3), np.float32))


@needs_models
def test_real_photograph_astronaut():
    skimage_data = pytest.importorskip("skimage.data", reason="scikit-image is not installed")
    from warpface.tracking import detect_face_landmarks

    image = skimage_data.astronaut()
    found = detect_face_landmarks(image, mesh=True)
    ibug = np.array([found[f"ibug{i:02d}"] for i in range(68)])
    iod = np.linalg.norm(ibug[36] - ibug[45])
    assert 45 < iod < 80  # the face is ~95 px wide in the 512 px photo
    # the map puts the eye and mouth corners on the mesh's own corner points (within 3 % of the IOD)
    for number, vertex in ((36, 33), (39, 133), (42, 362), (45, 263), (48, 61), (54, 291)):
        assert np.linalg.norm(ibug[number] - np.array(found[f"mesh{vertex:03d}"])) < 0.03 * iod
    # anatomy: eyes above the nose tip above the mouth above the chin; the subject's right eye at the left
    assert ibug[36, 0] < ibug[39, 0] < ibug[42, 0] < ibug[45, 0]
    assert ibug[[36, 45], 1].max() < ibug[30, 1] < ibug[[48, 54], 1].min() < ibug[8, 1]


@needs_models
def test_dense_mesh_points_land_on_the_rigs_skin_where_the_network_sees_them(rendered_face):
    from warpface.tracking.face_detector import FaceMeshDetector
    from warpface.tracking.face_mesh_dense import dense_mesh_vertices

    color, truth, projected, rig = rendered_face
    mesh = FaceMeshDetector(track=False)(color)
    matched = dense_mesh_vertices(mesh.points, rig.mesh, rig.landmarks)
    points, vertices = np.array(list(matched)), np.array(list(matched.values()))
    assert 150 < len(matched) < 468 and len(set(vertices)) == len(vertices)
    assert not np.isin(vertices, rig.landmarks).any() and not np.isin(vertices, rig.mesh.boundary_vertices).any()
    # registered in 3-D from the network's own depth, the matched vertices project near the detected points
    iod = np.linalg.norm(truth[36] - truth[45])
    error = np.linalg.norm(projected[vertices] - mesh.points[points, :2], axis=1) / iod
    assert np.median(error) < 0.06 and np.percentile(error, 90) < 0.15, (np.median(error), np.percentile(error, 90))
    with pytest.raises(ValueError, match="468"):
        dense_mesh_vertices(mesh.points[:10], rig.mesh, rig.landmarks)


@needs_models
def test_any_array_gives_landmarks_nothing_or_one_clear_error():
    from hypothesis import given, settings
    from hypothesis import strategies as st
    from hypothesis.extra.numpy import arrays

    from warpface.tracking import detect_face_landmarks

    shapes = st.tuples(st.integers(0, 40), st.integers(0, 40)).flatmap(
        lambda hw: st.sampled_from([hw, (*hw, 3), (*hw, 4), (*hw, 3, 1)])
    )

    @settings(max_examples=40, deadline=None)
    @given(arrays(st.sampled_from([np.uint8, np.float32, np.int64, bool]), shapes))
    def check(image):
        try:
            found = detect_face_landmarks(image)
        except (TypeError, ValueError) as error:
            assert "rgb" in str(error) and "\n" not in str(error)
            return
        assert found == {} or all(np.isfinite(v).all() for v in found.values())

    check()
