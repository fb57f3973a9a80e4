"""Markerless closed loop: a rig with painted features performs an expression in front of the synthetic camera;
the markerless paths (RGB-D: landmarks lifted with depth; video: rays and the point-to-ray solve) recover its
controls, scored against the ground truth.

* :func:`markerless_capture` — the painted face (:func:`~warpface.tracking.synthetic_face.paint_face_features`)
  filmed by a 640×480 Kinect-like RGB-D camera (depth noise and holes), nose ``distance`` away.
* :func:`write_video` — the camera's colour frames as a video file (``cv2.VideoWriter``, MPEG-4 part 2).
* :func:`solve_markerless` — one path over the frames: controls, skin and timings per frame.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .capture import SyntheticCapture

__all__ = ["markerless_capture", "write_video", "solve_markerless", "MarkerlessRun"]


def markerless_capture(rig=None, expression: str = "smile", *, distance=0.45, noise=True, device=None, **timeline):
    """The built-in face (or ``rig``: upright, frontal, metres, with 68 landmarks) performing ``expression``, with
    brows, lips and nostrils painted on and no dots, filmed from the front (ground truth in the capture): the nose
    ``distance`` [m] away, Kinect-like depth noise and 2 % holes with ``noise``. ``timeline``: ``seconds``
    (default 1) and ``fps`` (default 30) of :func:`warpface.assets.expression_timeline`."""
    from ..assets import default_rig, expression_timeline
    from ..tracking import KinectNoise, SyntheticRGBDCamera
    from ..tracking.synthetic import default_model_to_camera
    from ..tracking.synthetic_face import paint_face_features
    from .track_mono import rig_landmark_names

    rig = default_rig() if rig is None else rig
    rig_landmark_names(rig, "rig")
    fps = float(timeline.pop("fps", 30.0))
    muscles = expression_timeline(expression, rig, seconds=float(timeline.pop("seconds", 1.0)), fps=fps, **timeline)
    controls = np.pad(muscles, ((0, 0), (0, len(rig.control_names) - len(rig.muscles))))
    truth = rig.model(device=device).evaluate(controls).astype(np.float64)
    rest = truth[0]
    camera = SyntheticRGBDCamera(
        truth,
        rig.mesh.triangles,
        [int(rig.landmarks[30])],  # one invisible fiducial: the camera needs one; the features do the work
        dot_radius=1e-6,
        fps=fps,
        model_to_camera=default_model_to_camera(rest, distance),
        depth_noise=KinectNoise(dropout=0.02) if noise else None,
    )
    paint_face_features(camera, rest[rig.landmarks])
    return SyntheticCapture(
        camera=camera,
        source=None,
        truth=truth,
        triangles=rig.mesh.triangles,
        fiducial_vertices=np.asarray(rig.landmarks),
        controls=controls,
    )


def write_video(camera, path, *, frames: int | None = None) -> int:
    """Write the camera's colour frames to ``path`` (``.mp4`` or ``.avi``, MPEG-4 part 2) at its frame rate;
    returns the number of frames written."""
    import cv2

    count = len(camera) if frames is None else min(int(frames), len(camera))
    size = (camera.intrinsics.width, camera.intrinsics.height)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), float(camera.fps), size)
    if not writer.isOpened():
        raise ValueError(f"video {path}: OpenCV cannot write it")
    try:
        for index in range(count):
            color, _ = camera.render(index)
            writer.write(cv2.cvtColor(color, cv2.COLOR_RGB2BGR))
    finally:
        writer.release()
    return count


@dataclass
class MarkerlessRun:
    """One markerless path over a capture."""

    controls: np.ndarray
    """Solved controls per frame, (F, C)."""
    skins: np.ndarray
    """Solved skin per frame [m], (F, V, 3), rig frame."""
    skipped: np.ndarray
    """Frames whose controls were held (no face, too few landmarks), (F,) bool."""
    detect_seconds: float
    """Time in face detection and landmark lifting (or ray making) [s]."""
    solve_seconds: float
    """Time in the solve and the skin [s]."""

    def control_mm(self, truth_controls: np.ndarray, reach: np.ndarray) -> float:
        """Mean over frames of the RMS over controls of ``|c − c_true| · reach`` [mm]."""
        truth = np.pad(truth_controls, ((0, 0), (0, self.controls.shape[1] - truth_controls.shape[1])))
        wrong = (self.controls - truth[: len(self.controls)]) * reach * 1e3
        return float(np.sqrt(np.mean(wrong**2, axis=1)).mean())

    def surface_mm(self, truth: np.ndarray) -> float:
        """Mean distance of the solved skin from the true one [mm]."""
        return float(np.linalg.norm(self.skins - truth[: len(self.skins)], axis=2).mean() * 1e3)


def _dense_names(capture, rig, video) -> dict:
    """The dense landmark names of the capture's first frame (the video's, or the rendered one)."""
    from ..tracking.face_detector import FaceMeshDetector
    from ..tracking.face_mesh_dense import dense_mesh_vertices
    from ..tracking.landmark_names import vertex_landmark_names
    from .track_mono import dense_landmark_names

    if video is not None:
        return dense_landmark_names(video, rig)
    mesh = FaceMeshDetector(track=False)(capture.camera.render(0)[0])
    matched = dense_mesh_vertices(mesh.points, rig.mesh, rig.landmarks)
    return dict(zip(vertex_landmark_names(list(matched.values())), (f"mesh{p:03d}" for p in matched)))


class _RenderedFrames:
    """The camera's RGB-D frames rendered up front (rendering is not part of a capture's cost)."""

    def __init__(self, camera):
        self.intrinsics, self.fps = camera.intrinsics, camera.fps
        self._frames = list(camera.frames())

    def frames(self):
        return iter(self._frames)

    def close(self) -> None:
        self._frames = []


def solve_markerless(
    capture: SyntheticCapture,
    rig=None,
    *,
    mode: str = "rgbd",
    video=None,
    prefetch: int = 0,
    dense: bool = False,
    device=None,
    **options,
):
    """Run one markerless path over ``capture`` and return a :class:`MarkerlessRun`.

    Args:
        capture: from :func:`markerless_capture` (filmed by ``rig``, default the built-in face).
        mode: ``"rgbd"`` (face mesh in colour, lifted with the noisy depth, camera → rig known, solved as 3-D
            points: SPEC §6.1's term), ``"rgbd-rays"`` (the same landmarks solved as rays with a depth term,
            λ = 0.05 unless ``depth_weight`` says otherwise, docs/CAPTURE.md §2) or ``"video"``
            (the video file ``video``, written by :func:`write_video`; rays, intrinsics given, camera → rig from
            the first frame's perspective-n-point fit).
        dense: also the face mesh's points the rig's skin has, matched on the first frame
            (:func:`~warpface.pipelines.track_mono.dense_landmark_names`).
        prefetch: > 0: detect that many frames ahead in a background thread (the second core) while the solve runs;
            :attr:`MarkerlessRun.detect_seconds` is then the time the solve waited for a frame.
        **options: for the tracker (``smoothness``, ``rounds`` …).
    """
    from ..assets import default_rig
    from ..tracking import PrefetchedSource
    from ..tracking.face_landmarks import FaceLandmarks, FaceRGBDLandmarks
    from ..tracking.smoothing import OneEuroFilter
    from .track_mono import MonocularTracker, rig_landmark_names
    from .track_solve import SolvingTracker

    rig = default_rig() if rig is None else rig
    names = rig_landmark_names(rig, "rig")
    if dense:
        names.update(_dense_names(capture, rig, video if mode == "video" else None))
    if mode == "video":
        from ..tracking.video import VideoLandmarks

        source = VideoLandmarks(video, intrinsics=capture.camera.intrinsics, names=names)
        tracker = MonocularTracker(rig, source.landmark_names, device=device, **{"neutral_offsets": True, **options})
    elif mode in ("rgbd", "rgbd-rays"):
        detector = FaceLandmarks(names, smoothing=OneEuroFilter(), fps=capture.camera.fps)  # as `warpface track`
        source = FaceRGBDLandmarks(_RenderedFrames(capture.camera), detector, device=device)
        options = {"neutral_offsets": True, "camera_to_model": capture.camera_to_rig, **options}
        if mode == "rgbd-rays":
            tracker = MonocularTracker(rig, source.landmark_names, device=device, **{"depth_weight": 0.05, **options})
        else:
            tracker = SolvingTracker(rig, source.landmark_names, device=device, **options)
    else:
        raise ValueError(f"mode must be 'rgbd', 'rgbd-rays' or 'video', got {mode!r}")
    controls, skins, skipped = [], [], []
    detect = solve = 0.0
    try:
        frames = iter((PrefetchedSource(source, depth=prefetch) if prefetch else source).frames())
        while True:
            started = time.perf_counter()
            frame = next(frames, None)
            if frame is None:
                break
            between = time.perf_counter()
            solved = tracker.track_frame(frame)
            detect += between - started
            solve += time.perf_counter() - between
            controls.append(solved.controls)
            skins.append(solved.skin)
            skipped.append(solved.skipped)
    finally:
        if mode == "video":
            source.close()
    return MarkerlessRun(np.array(controls), np.array(skins), np.array(skipped), detect, solve)
