"""Markerless capture: the point-to-ray geometry, PnP, and ``warpface track VIDEO`` end to end and on bad input."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from warpface.solve.rays import closest_on_rays, pnp_pose, ray_distances

REPO = Path(__file__).resolve().parents[1]


def test_closest_ray_points_are_perpendicular_feet():
    rng = np.random.default_rng(0)
    origin = rng.normal(size=3)
    directions = rng.normal(size=(20, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    points = origin + directions * rng.uniform(0.5, 2.0, (20, 1)) + rng.normal(0, 0.1, (20, 3))
    feet = closest_on_rays(points, origin, directions)
    # the foot lies on the ray and the offset to the point is perpendicular to it; its length is the distance
    assert np.allclose(np.cross(feet - origin, directions), 0.0, atol=1e-12)
    assert np.allclose(np.einsum("nd,nd->n", points - feet, directions), 0.0, atol=1e-12)
    assert np.allclose(np.linalg.norm(points - feet, axis=1), ray_distances(points, origin, directions))
    behind = closest_on_rays(origin - directions[:1], origin, directions[:1])
    assert np.isnan(behind).all()


def test_pnp_recovers_a_known_pose():
    rng = np.random.default_rng(1)
    model = rng.normal(0, 0.05, (30, 3))
    angle = 0.3
    rotation = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    translation = np.array([0.02, -0.01, 0.6])
    camera = model @ rotation.T + translation
    pose = pnp_pose(model, camera[:, :2] / camera[:, 2:3])
    assert pose is not None
    assert np.allclose(pose[0], rotation, atol=1e-6) and np.allclose(pose[1], translation, atol=1e-6)
    assert pnp_pose(model[:5], camera[:5, :2] / camera[:5, 2:3]) is None


def _need_models():
    try:
        from warpface.tracking.face_models import model_path

        model_path("mesh")
        import ai_edge_litert  # noqa: F401
    except (FileNotFoundError, ImportError) as error:
        pytest.skip(f"face models or runtime absent: {error}")


def _cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "warpface.cli", "--device", "cpu", "--quiet", "track", *args],
        capture_output=True,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
        timeout=600,
    )


def test_unreadable_video_and_bad_options_are_one_line_and_write_nothing(tmp_path):
    bad = tmp_path / "broken.mp4"
    bad.write_text("not a video")
    stage = tmp_path / "out" / "capture.usda"
    for args, message in (
        ([str(bad)], "cannot be read"),
        ([str(tmp_path / "missing.mp4")], "file not found"),
        ([str(bad), "--intrinsics", "1,2,3"], "six numbers"),
        (["synthetic", "--markerless"], "--markerless needs images"),
        (["synthetic", "--dense"], "--dense needs"),
        ([str(bad), "--face", "-1"], "--face"),
    ):
        result = _cli(*args, "--stage", str(stage))
        assert result.returncode == 2, result.stderr[-500:]
        assert message in result.stderr and len(result.stderr.strip().splitlines()) == 1, result.stderr[-500:]
        assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_video_of_a_performance_is_solved_onto_the_stage(tmp_path):
    pytest.importorskip("pyrender")
    _need_models()
    from warpface.pipelines.markerless_loop import markerless_capture, write_video
    from warpface.pipelines.track_solve import read_solved_capture

    capture = markerless_capture(expression="smile", seconds=0.5, noise=False)
    video = tmp_path / "smile.mp4"
    frames = write_video(capture.camera, video)
    capture.camera.close()
    k = capture.camera.intrinsics
    stage = tmp_path / "out" / "smile.usda"
    intrinsics = f"{k.fx},{k.fy},{k.cx},{k.cy},{k.width},{k.height}"
    result = _cli(str(video), "--stage", str(stage), "--intrinsics", intrinsics, "--dense")
    assert result.returncode == 0, result.stderr[-800:]
    solved = read_solved_capture(stage)
    assert solved["controls"].shape[0] == frames and np.all(np.isfinite(solved["controls"]))
    assert not solved["skipped"].any()
    assert abs(solved["fps"] - capture.camera.fps) < 1e-6
    # the skin follows the performance: the solved mouth corners move apart while the truth's are apart. The face
    # mesh model sees about half of the painted face's corner motion (6.9–7.5 of 13.7–13.9 px at its widest, with
    # the hand-placed, stale and recalibrated anatomies alike), and the exact rays of the same frames are solved to
    # 92–95 % of it (test_monocular_solve_reprojects_exact_rays_and_recovers_the_head_turn checks that solve), so
    # what this pipeline reaches is bounded by the detector: measured 0.28–0.33 of the true widening on every rig.
    # A solve that missed the smile would give ≤ 0 here.
    from warpface.assets import default_rig

    corners = default_rig().landmarks[[48, 54]]
    true_width = np.linalg.norm(np.diff(capture.truth[:, corners], axis=1)[:, 0], axis=1)
    solved_width = np.linalg.norm(np.diff(solved["skin"][:, corners], axis=1)[:, 0], axis=1)
    true_rise = true_width.max() - true_width[0]
    assert (solved_width.max() - solved_width[0]) > 0.2 * true_rise
    # widest while the truth is wide (the detector's One-Euro filter may lag two frames), narrower again at the end
    wide = np.flatnonzero(true_width > true_width[0] + 0.5 * true_rise)
    assert wide[0] <= np.argmax(solved_width) <= wide[-1] + 2
    assert solved_width[-1] < solved_width.max() - 0.25 * (solved_width.max() - solved_width[0])


@pytest.mark.slow
def test_rgbd_folder_markerless_solve_holds_the_controls_on_a_frame_without_a_face(tmp_path):
    pytest.importorskip("pyrender")
    _need_models()
    from warpface.pipelines.markerless_loop import markerless_capture
    from warpface.pipelines.track_solve import read_solved_capture
    from warpface.tracking import RGBDFolder, RGBDFrame

    capture = markerless_capture(expression="smile", seconds=0.4)
    frames = list(capture.camera.frames())
    capture.camera.close()
    blank = frames[6]  # a frame without a face: the camera looked away
    frames[6] = RGBDFrame(blank.timestamp, np.zeros_like(blank.color), blank.depth, blank.depth_scale, blank.index)
    folder = RGBDFolder.write(tmp_path / "take", frames, capture.camera.intrinsics, fps=capture.camera.fps)
    stage = tmp_path / "out" / "take.usda"
    result = _cli(str(folder), "--markerless", "--solve", "--stage", str(stage))
    assert result.returncode == 0, result.stderr[-800:]
    solved = read_solved_capture(stage)
    assert len(solved["times"]) == len(frames)
    assert solved["skipped"][6] and not solved["skipped"][[0, 5, 7]].any()
    assert np.array_equal(solved["controls"][6], solved["controls"][5])  # held
    assert np.all(np.isfinite(solved["skin"])) and np.all(np.isfinite(solved["controls"]))
    # the landmarks the stage records for the faceless frame are missing, not invented
    assert (solved["confidence"][6] == 0).all()


@pytest.fixture(scope="module")
def performance():
    from warpface.assets import default_rig, expression_timeline
    from warpface.pipelines.track_mono import rig_landmark_names
    from warpface.tracking.landmark_names import landmark_vertices
    from warpface.tracking.synthetic import default_model_to_camera

    rig = default_rig()
    muscles = expression_timeline("smile", rig, seconds=0.4, fps=30.0)
    controls = np.pad(muscles, ((0, 0), (0, len(rig.control_names) - len(rig.muscles))))
    truth = rig.model(device="cpu").evaluate(controls).astype(np.float64)
    names = list(rig_landmark_names(rig))
    vertices = landmark_vertices(names, rig.mesh.vertex_count)
    model_to_camera = default_model_to_camera(truth[0], 0.5)
    # the head turns 8° about the vertical while smiling: the pose must be solved too
    angles = np.linspace(0.0, np.radians(8.0), len(truth))
    camera = []
    for points, angle in zip(truth, angles):
        turn = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
        centre = truth[0][vertices].mean(axis=0)
        posed = (points[vertices] - centre) @ turn.T + centre
        camera.append(posed @ model_to_camera[:3, :3].T + model_to_camera[:3, 3])
    return rig, names, controls, truth, np.array(camera), angles


def _control_error_mm(tracker, solved, controls):
    return float(np.sqrt(np.mean(((np.array(solved) - controls) * tracker.solver.reach * 1e3) ** 2, axis=1)).max())


def test_monocular_solve_reprojects_exact_rays_and_recovers_the_head_turn(performance):
    from warpface.pipelines.track_mono import MonocularTracker
    from warpface.tracking import LandmarkFrame
    from warpface.tracking.landmark_names import landmark_vertices

    rig, names, controls, truth, camera, angles = performance
    vertices = landmark_vertices(names, rig.mesh.vertex_count)
    tracker = MonocularTracker(rig, names, rounds=3, device="cpu")
    skins, reprojection = [], []
    for index, points in enumerate(camera):
        rays = points / points[:, 2:3]  # pixels only (normalised): the depth is gone
        result = tracker.track_frame(LandmarkFrame(index / 30.0, rays, np.ones(len(rays)), index))
        skins.append(result.skin)
        # the solved head turn matches the true one (about the vertical axis)
        turned = np.degrees(np.arctan2(result.rotation[0, 2], result.rotation[0, 0]))
        assert abs(turned - np.degrees(angles[index])) < 0.5, (index, turned)
        posed = (result.skin.astype(np.float64)[vertices] - result.origin) @ result.rotation.T
        posed += result.origin + result.translation
        back = np.linalg.inv(tracker.camera_to_model)
        seen = posed @ back[:3, :3].T + back[:3, 3]
        reprojection.append(np.linalg.norm(seen[:, :2] / seen[:, 2:3] - rays[:, :2], axis=1).mean() * 525.0)
    # what a camera sees is matched (measured ≤ 0.14 px at f = 525 px); what it cannot see, the depth along the
    # rays, is left to the rig's shape and the priors: the skin error is mostly depth (measured 0.39 mm mean
    # against 1.9 mm for a face that did not move; with the 3-D landmarks 0.01 mm)
    assert max(reprojection) < 0.3, reprojection
    skin_error = np.linalg.norm(np.array(skins) - truth, axis=2).mean(axis=1) * 1e3
    still_error = np.linalg.norm(truth - truth[0], axis=2).mean(axis=1) * 1e3
    assert skin_error.mean() < 0.35 * still_error.max(), (skin_error, still_error)
    assert not tracker.summary["skipped"]


@pytest.mark.slow  # end to end, over 20 s on the 2-core CI machine
def test_rays_with_a_depth_term_match_the_point_solve_on_exact_depth(performance):
    from warpface.pipelines.track_mono import MonocularTracker
    from warpface.pipelines.track_solve import SolvingTracker
    from warpface.tracking import LandmarkFrame

    rig, names, controls, truth, camera, _ = performance
    results = {}
    for label, make in (
        ("points", lambda: SolvingTracker(rig, names, device="cpu")),
        ("λ=1", lambda: MonocularTracker(rig, names, depth_weight=1.0, device="cpu")),
        ("λ=0.2", lambda: MonocularTracker(rig, names, rounds=3, depth_weight=0.2, device="cpu")),
        ("λ=0", lambda: MonocularTracker(rig, names, rounds=3, depth_weight=0.0, device="cpu")),
    ):
        tracker = make()
        solved = [
            tracker.track_frame(LandmarkFrame(i / 30.0, p, np.ones(len(p)), i)).controls for i, p in enumerate(camera)
        ]
        results[label] = _control_error_mm(tracker, solved, controls)
    # λ = 1 targets the measured points themselves: the point solve; the exact depth helps the rays
    assert results["points"] < 0.3 and abs(results["λ=1"] - results["points"]) < 0.02, results
    assert results["λ=0.2"] < results["λ=0"], results
    with pytest.raises(ValueError, match="depth_weight"):
        MonocularTracker(rig, names, depth_weight=2.0)


@pytest.mark.slow  # end to end, over 20 s on the 2-core CI machine
def test_video_without_a_face_and_a_bad_landmark_model(tmp_path):
    _need_models()
    import cv2

    from warpface.pipelines.track_solve import read_solved_capture

    video = tmp_path / "wall.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (160, 120))
    for _ in range(5):
        writer.write(np.full((120, 160, 3), 128, np.uint8))
    writer.release()
    stage = tmp_path / "out" / "wall.usda"
    for model, message in ((tmp_path / "missing.tflite", "file not found"), (video, "not a TFLite model")):
        result = _cli(str(video), "--stage", str(stage), "--landmark-model", str(model))
        assert result.returncode == 2 and message in result.stderr, result.stderr[-500:]
        assert len(result.stderr.strip().splitlines()) == 1 and not (tmp_path / "out").exists()
    result = _cli(str(video), "--stage", str(stage))
    assert result.returncode == 0, result.stderr[-500:]
    solved = read_solved_capture(stage)
    assert solved["skipped"].all() and len(solved["skipped"]) == 5
    assert np.all(solved["controls"] == 0.0) and abs(solved["fps"] - 25.0) < 1e-6
