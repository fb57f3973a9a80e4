"""Closed loop with ground truth: synthetic RGB-D camera → fiducials → 3-D landmarks → dense face."""

import os

import numpy as np
import pytest

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
pytest.importorskip("pyrender")

from warpface.data import ict_face_region  # noqa: E402
from warpface.mesh import load_obj  # noqa: E402
from warpface.tracking import (
    KinectNoise,
    RGBDFolder,
    RGBDLandmarks,
    SyntheticRGBDCamera,
    TrackingAdapter,
    backproject,
    place_fiducials,
)
from warpface.tracking.correspondence import triangulate_landmarks
from warpface.tracking.detect import detect_blobs
from warpface.tracking.synthetic import default_model_to_camera, procedural_face, procedural_jaw_open


def face_sequence(frames: int, amount: float):
    """(points per frame [m], triangles, source): ICT neutral → jawOpen when the data is there,
    else the procedural face opening its jaw by up to 2 cm."""
    neutral, jaw = ict_face_region("neutral"), ict_face_region("jawOpen")
    weights = np.linspace(0.0, amount, frames)
    if neutral is not None and jaw is not None:
        p0, tri = load_obj(neutral)
        p1, _ = load_obj(jaw)
        p0, p1 = p0 * 0.01, p1 * 0.01  # centimetres → metres
        return p0[None] + weights[:, None, None] * (p1 - p0)[None], tri, "ICT-FaceKit"
    p0, tri = procedural_face(96)
    return np.stack([procedural_jaw_open(p0, 0.02 * w) for w in weights]), tri, "procedural"


def test_kinect_noise_statistics():
    rng = np.random.default_rng(0)
    noise = KinectNoise()
    depth = np.full((400, 400), 0.6)
    out = noise.apply(depth, rng)
    sigma = noise.sigma0 + noise.sigma2 * (0.6 - noise.z_ref) ** 2
    step = 0.6**2 * noise.disparity_step / noise.baseline_focal
    assert abs(out.mean() - 0.6) < 2e-5
    assert out.std() == pytest.approx(np.sqrt(sigma**2 + step**2 / 12), rel=0.03)
    levels = np.unique(np.round(out, 9))
    assert np.median(np.diff(levels)) == pytest.approx(step, rel=0.02)  # disparity quantisation
    holes = KinectNoise(dropout=0.25).apply(depth, rng)
    assert (holes == 0).mean() == pytest.approx(0.25, abs=0.01)


def test_pixel_convention_and_rendered_depth_are_exact():
    points, tri = procedural_face(80)
    fid = place_fiducials(points, tri, 25, spacing=0.02)
    for lighting in ("lit", "flat"):
        cam = SyntheticRGBDCamera(points, tri, fid, lighting=lighting)
        color, depth = cam.render(0)
        truth = cam.landmark_pixels(0)
        blobs = detect_blobs(color)
        d = np.linalg.norm(truth[:, None] - blobs.centers[None], axis=2)
        nearest = blobs.centers[d.argmin(axis=1)]
        assert d.min(axis=1).max() < 0.25
        # pyrender's half-pixel offset handled: no systematic shift (it would be 0.5 px).
        assert np.abs((nearest - truth).mean(axis=0)).max() < 0.03
        lifted, _ = backproject(truth, depth, cam.intrinsics, device="cpu")
        # Linear depth in the same camera: exact up to the local fit's residual bias on the nose tip.
        assert np.abs(lifted - cam.landmark_positions(0)).max() < 2e-4
        cam.close()


def test_closed_loop_dots_with_kinect_noise():
    frames, tri, name = face_sequence(8, 0.6)
    eye = np.linalg.inv(default_model_to_camera(frames[0]))[:3, 3]
    fid = place_fiducials(frames[0], tri, 40, spacing=0.018, camera_position=eye)
    camera = SyntheticRGBDCamera(frames, tri, fid, depth_noise=KinectNoise(dropout=0.05), seed=3)
    assert camera.intrinsics.width == 640 and camera.intrinsics.height == 480
    assert camera.landmark_positions(0)[:, 2].min() > 0.59  # the face is ~0.6 m away
    source = RGBDLandmarks(camera, camera.dot_tracker(), device="cpu")
    errors, found = [], []
    for frame in source.frames():
        truth = camera.landmark_positions(frame.index)
        err = np.linalg.norm(frame.points - truth, axis=1)
        errors.append(err[~frame.missing])
        found.append((~frame.missing).mean())
    errors = np.concatenate(errors)
    print(
        f"\n{name}: {len(fid)} dots, {np.mean(found):.0%} found, 3-D landmark error "
        f"mean {errors.mean() * 1e3:.2f} mm, max {errors.max() * 1e3:.2f} mm"
    )
    assert errors.mean() <= 1e-3
    assert np.mean(found) >= 0.85
    camera.close()


def test_dense_transfer_follows_the_tracked_face():
    frames, tri, name = face_sequence(5, 0.5)
    rest = frames[0]
    eye = np.linalg.inv(default_model_to_camera(rest))[:3, 3]
    fid = place_fiducials(rest, tri, 50, spacing=0.016, camera_position=eye)
    camera = SyntheticRGBDCamera(frames, tri, fid, depth_noise=KinectNoise(), seed=1)
    sparse = rest[fid]
    adapter = TrackingAdapter(
        sparse,
        triangulate_landmarks(sparse),
        rest,
        landmark_names=camera.landmark_names,
        camera_to_model=np.linalg.inv(camera.model_to_camera),
        device="cpu",
    )
    source = RGBDLandmarks(camera, camera.dot_tracker(), device="cpu")
    driven = adapter.weights > 0.999
    for _frame, dense in adapter.track(source):
        assert dense.shape == rest.shape and np.all(np.isfinite(dense))
    truth = frames[-1]
    err = np.linalg.norm(dense - truth, axis=1)[driven]
    still = np.linalg.norm(rest - truth, axis=1)[driven]
    print(
        f"\n{name}: dense surface error in the driven region {err.mean() * 1e3:.2f} mm "
        f"(not tracking: {still.mean() * 1e3:.2f} mm), {driven.sum()} of {len(rest)} vertices driven"
    )
    assert err.mean() < 0.6 * still.mean()
    camera.close()


def test_aruco_markers_on_the_synthetic_face(tmp_path):
    points, tri = procedural_face(96)
    fid = place_fiducials(points, tri, 4, spacing=0.045, min_facing=0.85, boundary_margin=0.025)
    cam = SyntheticRGBDCamera(
        points, tri, fid, style="aruco", aruco_ids=[5, 9, 13, 17][: len(fid)], aruco_size=0.024, depth_noise=None
    )
    detector = cam.aruco_detector()
    color, depth = cam.render(0)
    pixels, conf = detector.detect(color)
    assert conf.all()
    # Markers 24 mm wide on a curved dome: the image's diagonal crossing is within a pixel of the
    # projected texture centre.
    np.testing.assert_allclose(pixels, cam.landmark_pixels(0), atol=0.8)
    lifted, _ = backproject(pixels, depth, cam.intrinsics, device="cpu")
    assert np.linalg.norm(lifted - cam.landmark_positions(0), axis=1).max() < 1e-3
    cam.close()


def test_recorded_synthetic_capture_gives_the_same_landmarks(tmp_path):
    points, tri = procedural_face(64)
    frames = np.stack([procedural_jaw_open(points, a) for a in (0.0, 0.003, 0.006)])
    fid = place_fiducials(points, tri, 20, spacing=0.02)
    cam = SyntheticRGBDCamera(frames, tri, fid, depth_noise=KinectNoise(), seed=2)
    folder = RGBDFolder.write(
        tmp_path / "capture", cam.frames(), cam.intrinsics, fps=cam.fps, fiducials=cam.fiducial_layout()
    )
    live = list(RGBDLandmarks(cam, cam.dot_tracker(), device="cpu").frames())
    recorded = RGBDFolder(folder)
    from warpface.tracking import DotTracker

    layout = recorded.fiducials
    tracker = DotTracker(np.array(layout["initial_pixels"]), names=layout["names"])
    replay = list(RGBDLandmarks(recorded, tracker, device="cpu").frames())
    assert len(replay) == len(live) == 3
    for a, b in zip(live, replay):
        assert a.timestamp == b.timestamp
        np.testing.assert_array_equal(a.points, b.points)
    cam.close()


def test_synthetic_camera_bad_input():
    points, tri = procedural_face(8)
    with pytest.raises(ValueError, match="vertex index out of range"):
        SyntheticRGBDCamera(points, tri, [len(points)])
    with pytest.raises(ValueError, match="style"):
        SyntheticRGBDCamera(points, tri, [3], style="star")
    with pytest.raises(ValueError, match="barycentric"):
        SyntheticRGBDCamera(points, tri, (np.array([0]), np.array([[0.5, 0.6, 0.1]])))
    with pytest.raises(ValueError, match="points"):
        SyntheticRGBDCamera(points[None, :, :2], tri, [3])
