"""Markerless capture onto a rig: the face mesh's landmarks named after the rig's vertices, from RGB-D or from a
plain video (monocular: :class:`MonocularTracker` solves against viewing rays, docs/CAPTURE.md §3).

* :func:`rig_landmark_names` — ``{vertex name: ibugNN}``: each of the rig's 68 iBUG vertices takes the
  detector's landmark of the same number, so the stream drives the rig like a dot layout made for it.
* :func:`markerless_source` — a landmark source for ``realsense``, ``orbbec``, an RGB-D folder or a video.
* :class:`MonocularTracker` — :class:`~warpface.pipelines.track_solve.SolvingTracker` for ray frames: the
  camera → rig transform from a perspective-n-point fit on the first frame with a face, then per frame the
  alternating point-to-ray solve (:class:`warpface.solve.rays.RaySolve`); the frames it yields carry the
  lifted landmarks (closest ray points, camera frame), which the stage records.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..tracking import LandmarkFrame
from .track_solve import SolvedFrame, SolvingTracker

__all__ = ["rig_landmark_names", "markerless_source", "MonocularTracker", "is_video", "parse_intrinsics"]


def is_video(spec: str) -> bool:
    """Whether a ``track`` source names a video file (by its suffix)."""
    from ..tracking.video import VIDEO_SUFFIXES

    return Path(str(spec)).suffix.lower() in VIDEO_SUFFIXES


def parse_intrinsics(text):
    """``--intrinsics``: ``None``, a JSON file with fx, fy, cx, cy, width, height, or those six numbers comma-separated
    (``"600,600,319.5,239.5,640,480"``) → a :class:`~warpface.tracking.CameraIntrinsics` or ``None``."""
    import json

    from ..tracking import CameraIntrinsics

    if text is None:
        return None
    text = str(text)
    if Path(text).suffix.lower() == ".json":
        from .._files import read_text

        try:
            data = json.loads(read_text(Path(text)))
        except json.JSONDecodeError as error:
            raise ValueError(f"--intrinsics {text}: not JSON ({error.msg} at line {error.lineno})") from None
        return CameraIntrinsics.from_dict(data, where=f"--intrinsics {text}")
    parts = text.split(",")
    try:
        values = [float(part) for part in parts]
    except ValueError:
        values = []
    if len(values) != 6:
        raise ValueError(
            f"--intrinsics: expected a .json file or six numbers fx,fy,cx,cy,width,height, got {text[:60]!r}"
        )
    return CameraIntrinsics.from_dict(
        dict(zip(("fx", "fy", "cx", "cy", "width", "height"), values)), where="--intrinsics"
    )


def rig_landmark_names(rig, where: str = "--rig") -> dict:
    """``{"v01234": "ibug36", …}``: the detector's iBUG landmark for each of the rig's 68 landmark vertices (a vertex
    holding two iBUG points keeps the first).

    Raises:
        ValueError: the rig has no 68 iBUG landmarks.
    """
    from ..landmarks import IBUG_COUNT
    from ..tracking.landmark_names import vertex_landmark_names

    if rig.landmarks is None or len(rig.landmarks) != IBUG_COUNT:
        raise ValueError(
            f"{where}: the rig has no 68 iBUG landmarks, which markerless tracking maps the face mesh onto "
            "(a rig made by `warpface rig` has them)"
        )
    names: dict = {}
    for number, name in enumerate(vertex_landmark_names(rig.landmarks)):
        names.setdefault(name, f"ibug{number:02d}")
    return names


def markerless_source(spec: str, rig, *, intrinsics=None, face: int = 0, landmark_model=None, device=None):
    """The markerless landmark source of a ``track`` spec: ``realsense`` / ``orbbec`` / an RGB-D folder (3-D
    landmarks lifted with depth) or a video file (rays); landmarks named after ``rig``'s vertices."""
    from ..tracking.face_landmarks import FaceLandmarks, FaceRGBDLandmarks
    from ..tracking.smoothing import OneEuroFilter

    names = rig_landmark_names(rig)
    options = dict(face=face, mesh_model=landmark_model)
    if is_video(spec):
        from ..tracking.video import VideoLandmarks

        return VideoLandmarks(spec, intrinsics=intrinsics, names=names, **options)
    if spec in ("realsense", "orbbec"):
        from ..tracking import OrbbecCamera, RealSenseCamera

        detector = FaceLandmarks(names, smoothing=OneEuroFilter(), **options)
        camera = RealSenseCamera() if spec == "realsense" else OrbbecCamera()
        return FaceRGBDLandmarks(camera, detector, timestamp_policy="drop", device=device)
    from ..tracking import RGBDFolder

    folder = RGBDFolder(spec)
    detector = FaceLandmarks(names, smoothing=OneEuroFilter(), fps=folder.fps or 30.0, **options)
    return FaceRGBDLandmarks(folder, detector, device=device)


class MonocularTracker(SolvingTracker):
    """Ray frames (:class:`~warpface.tracking.video.VideoLandmarks`) → solved controls, head pose and skin.

    Args:
        rig, landmark_names: as :class:`SolvingTracker` (the rig in metres: its size sets the depth).
        rounds: closest-point / solve rounds per frame (docs/CAPTURE.md §3).
        **options: the other :class:`SolvingTracker` options (``smoothness``, ``device`` …).
    """

    def __init__(self, rig, landmark_names, *, rounds: int = 3, **options):
        from ..solve.rays import RaySolve

        options.pop("camera_to_model", None)
        options.pop("residual_transfer", None)
        super().__init__(rig, landmark_names, **options)
        self.rays = RaySolve(self.solver, rounds=rounds)
        self.lifted: LandmarkFrame | None = None

    def track(self, source):
        """Yield ``(frame of lifted landmarks (camera frame), skin)`` per frame of ray frames."""
        for _, skin in super().track(source):
            yield self.lifted, skin

    def track_frame(self, frame: LandmarkFrame, order: np.ndarray | None = None) -> SolvedFrame:
        """Solve one frame of rays (points at depth 1, camera frame)."""
        from ..solve.rays import closest_on_rays, pnp_pose
        from .track_solve import neutral_offsets

        rays = np.asarray(frame.points, dtype=np.float64)
        confidence = np.asarray(frame.confidence, dtype=np.float64)
        if order is not None:
            rays, confidence = rays[order], confidence[order]
        valid = np.all(np.isfinite(rays), axis=1) & (confidence > self.min_confidence)
        weights = np.where(valid, np.clip(confidence, 0.0, 1.0), 0.0)
        if self.camera_to_model is None:
            pose = pnp_pose(self.rest[self.vertices], rays[:, :2] / rays[:, 2:3], weights)
            if pose is not None:  # the rig at rest under the first face frame's pose: camera → rig is its inverse
                rotation, translation = pose
                self.camera_to_model = np.eye(4)
                self.camera_to_model[:3, :3] = rotation.T
                self.camera_to_model[:3, 3] = -rotation.T @ translation
        if self.camera_to_model is None:
            targets = np.full_like(rays, np.nan)
            fit = self.solver.solve(targets, weights if valid.any() else None)
        else:
            turn, origin = self.camera_to_model[:3, :3], self.camera_to_model[:3, 3]
            directions = rays @ turn.T
            directions /= np.linalg.norm(directions, axis=1, keepdims=True)
            directions[~valid] = np.nan
            if self.neutral_offsets and self.offsets is None and valid.sum() >= 6:
                rest = self.rest[self.vertices]
                seen = closest_on_rays(rest, origin, directions)
                self.offsets = neutral_offsets(rest, seen, weights, self.solver.origin)
            fit, targets = self.rays.solve(origin, directions, weights, self.offsets)
        solved = self._finish(frame, fit, targets)
        camera = self._camera_points(targets)
        self.lifted = LandmarkFrame(
            frame.timestamp, camera, np.where(np.isfinite(camera[:, 0]), weights, 0.0), frame.index
        )
        return solved

    def _camera_points(self, targets: np.ndarray) -> np.ndarray:
        if self.camera_to_model is None:
            return targets
        inverse = np.linalg.inv(self.camera_to_model)
        return targets @ inverse[:3, :3].T + inverse[:3, 3]
