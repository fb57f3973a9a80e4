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

__all__ = [
    "rig_landmark_names",
    "dense_landmark_names",
    "markerless_source",
    "MonocularTracker",
    "is_video",
    "parse_intrinsics",
]


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


def markerless_source(
    spec: str, rig, *, intrinsics=None, face: int = 0, landmark_model=None, dense: bool = False, device=None
):
    """The markerless landmark source of a ``track`` spec: ``realsense`` / ``orbbec`` / an RGB-D folder (3-D
    landmarks lifted with depth) or a video file (rays); landmarks named after ``rig``'s vertices. ``dense``: also
    the face mesh's points the rig's skin has (:func:`dense_landmark_names`; a video or an RGB-D folder)."""
    from ..tracking.face_landmarks import FaceLandmarks, FaceRGBDLandmarks
    from ..tracking.smoothing import OneEuroFilter

    names = rig_landmark_names(rig)
    options = dict(face=face, mesh_model=landmark_model)
    if dense:
        if spec in ("realsense", "orbbec"):
            raise ValueError("--dense needs a recording (a video or an RGB-D folder), not a live camera")
        names.update(dense_landmark_names(spec, rig, **options))
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


def dense_landmark_names(spec, rig, *, face: int = 0, mesh_model=None, max_frames: int = 150) -> dict:
    """``{"v01234": "mesh123", …}``: the face mesh's points on ``rig``'s skin, matched on the first frame of the video
    or RGB-D folder ``spec`` with a face (:func:`warpface.tracking.face_mesh_dense.dense_mesh_vertices`; it should
    be neutral). ValueError when none of the first ``max_frames`` frames has a face."""
    from ..tracking.face_detector import FaceMeshDetector
    from ..tracking.face_mesh_dense import dense_mesh_vertices
    from ..tracking.landmark_names import vertex_landmark_names

    detector = FaceMeshDetector(face=face, mesh_model=mesh_model, track=False)
    if is_video(spec):
        from ..tracking.video import VideoFrames

        reader = VideoFrames(spec)
        images = (rgb for _, _, rgb in reader.frames())
    else:
        from ..tracking import RGBDFolder

        reader = RGBDFolder(spec)
        images = (frame.color for frame in reader.frames())
    try:
        for count, rgb in enumerate(images):
            mesh = detector(rgb)
            if mesh is not None:
                matched = dense_mesh_vertices(mesh.points, rig.mesh, rig.landmarks)
                return dict(zip(vertex_landmark_names(list(matched.values())), (f"mesh{p:03d}" for p in matched)))
            if count + 1 >= max_frames:
                break
    finally:
        reader.close()
    raise ValueError(f"{spec}: no face in the first {max_frames} frames to match the face mesh onto the rig")


class MonocularTracker(SolvingTracker):
    """Landmarks as viewing rays → solved controls, head pose and skin (docs/CAPTURE.md §3).

    Ray frames (:class:`~warpface.tracking.video.VideoLandmarks`: points at depth 1) are solved with the
    point-to-ray term alone; with ``depth_weight`` λ the frames are 3-D camera-frame points (an RGB-D source) and
    each landmark's depth along its ray is also pulled toward the measured one with weight λ (docs/CAPTURE.md
    §2: the depth image's noise is several times its pixels', so λ < 1 trusts the pixels more).

    Args:
        rig, landmark_names: as :class:`SolvingTracker` (the rig in metres: its size sets the depth).
        rounds: closest-point / solve rounds per frame.
        depth_weight: λ in [0, 1] for 3-D frames, ``None`` for ray frames.
        camera_to_model: for 3-D frames, as :class:`SolvingTracker` (ray frames: from a PnP fit on the first frame).
        **options: the other :class:`SolvingTracker` options (``smoothness``, ``neutral_offsets``, ``device`` …).
    """

    def __init__(self, rig, landmark_names, *, rounds: int = 1, depth_weight=None, camera_to_model=None, **options):
        from .._validate import as_bounded
        from ..solve.rays import RaySolve

        options.pop("residual_transfer", None)
        self.depth_weight = None if depth_weight is None else as_bounded(depth_weight, "depth_weight", 0.0, 1.0)
        super().__init__(
            rig, landmark_names, camera_to_model=None if depth_weight is None else camera_to_model, **options
        )
        self.rays = RaySolve(self.solver, rounds=rounds)
        self.lifted: LandmarkFrame | None = None

    def track(self, source):
        """Yield ``(frame of lifted landmarks (camera frame), skin)`` per frame of ``source``."""
        for _, skin in super().track(source):
            yield self.lifted, skin

    def track_frame(self, frame: LandmarkFrame, order: np.ndarray | None = None) -> SolvedFrame:
        """Solve one frame (rays at depth 1, or 3-D points with ``depth_weight``; camera frame)."""
        from ..solve.rays import closest_on_rays
        from .track_solve import neutral_offsets

        points = np.asarray(frame.points, dtype=np.float64)
        confidence = np.asarray(frame.confidence, dtype=np.float64)
        if order is not None:
            points, confidence = points[order], confidence[order]
        valid = np.all(np.isfinite(points), axis=1) & (confidence > self.min_confidence)
        weights = np.where(valid, np.clip(confidence, 0.0, 1.0), 0.0)
        if self.camera_to_model is None:
            self.camera_to_model = self._first_camera_to_model(points, weights)
        if self.camera_to_model is None:
            targets = np.full_like(points, np.nan)
            fit = self.solver.solve(targets, weights if valid.any() else None)
        else:
            origin = self.camera_to_model[:3, 3]
            along = points @ self.camera_to_model[:3, :3].T  # from the camera centre, model frame
            depths = np.linalg.norm(along, axis=1)
            directions = np.where(valid[:, None], along / depths[:, None], np.nan)
            if self.neutral_offsets and self.offsets is None and valid.sum() >= 6:
                rest = self.rest[self.vertices]
                seen = closest_on_rays(rest, origin, directions) if self.depth_weight is None else origin + along
                self.offsets = neutral_offsets(rest, seen, weights, self.solver.origin)
            if self.depth_weight is None:
                fit, targets = self.rays.solve(origin, directions, weights, self.offsets)
            else:
                fit, targets = self.rays.solve(
                    origin, directions, weights, self.offsets, depths=depths, depth_weight=self.depth_weight
                )
        solved = self._finish(frame, fit, targets)
        camera = self._camera_points(targets)
        self.lifted = LandmarkFrame(
            frame.timestamp, camera, np.where(np.isfinite(camera[:, 0]), weights, 0.0), frame.index
        )
        return solved

    def _first_camera_to_model(self, points, weights):
        """Camera → rig from the first usable frame: the inverse PnP pose of the rest landmarks (rays), or the
        similarity taking the measured points onto them (3-D points); ``None`` while there are too few."""
        from ..solve.rays import pnp_pose
        from ..tracking.alignment import similarity_fit

        rest = self.rest[self.vertices]
        transform = np.eye(4)
        if self.depth_weight is None:
            pose = pnp_pose(rest, points[:, :2] / points[:, 2:3], weights)
            if pose is None:
                return None
            rotation, translation = pose  # the rig at rest under the first face frame's pose
            transform[:3, :3], transform[:3, 3] = rotation.T, -rotation.T @ translation
            return transform
        usable = weights > 0
        if usable.sum() < 4:
            return None
        scale, rotation, translation, _ = similarity_fit(points[usable], rest[usable])
        transform[:3, :3], transform[:3, 3] = scale * rotation, translation
        return transform

    def _camera_points(self, targets: np.ndarray) -> np.ndarray:
        if self.camera_to_model is None:
            return targets
        inverse = np.linalg.inv(self.camera_to_model)
        return targets @ inverse[:3, :3].T + inverse[:3, 3]
