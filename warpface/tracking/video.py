"""A plain video's facial landmarks as viewing rays: the monocular landmark source.

:class:`VideoLandmarks` reads a video file with ``cv2.VideoCapture``, finds the face mesh's landmarks in each
frame (:class:`~warpface.tracking.face_landmarks.FaceLandmarks`) and yields :class:`LandmarkFrame` whose
points are **rays**, not positions: each landmark's point at depth 1 in the camera frame,
``((u − c_x)/f_x, (v − c_y)/f_y, 1)`` (:meth:`CameraIntrinsics.unproject` at Z = 1). The monocular tracker
(:class:`~warpface.pipelines.track_mono.MonocularTracker`) solves the rig against them (docs/CAPTURE.md §3).

Intrinsics: given, or estimated from the frame size (:func:`estimated_intrinsics`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from .frames import LandmarkFrame, SourceBase
from .intrinsics import CameraIntrinsics

__all__ = ["VideoFrames", "VideoLandmarks", "estimated_intrinsics", "VIDEO_SUFFIXES"]

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".wmv")
"""File suffixes ``warpface track`` treats as videos."""


def estimated_intrinsics(width: int, height: int) -> CameraIntrinsics:
    """A pinhole camera for an unknown lens: ``f_x = f_y = max(W, H)`` (≈ 53° across the longer side, between a
    webcam's and a phone's), principal point at the image centre."""
    focal = float(max(width, height))
    return CameraIntrinsics(focal, focal, 0.5 * (width - 1), 0.5 * (height - 1), int(width), int(height))


class VideoFrames(SourceBase):
    """RGB frames of a video file: ``frames()`` yields ``(index, timestamp [s], rgb (H, W, 3) uint8)``.

    Raises:
        ValueError: the file is missing or OpenCV cannot decode a first frame from it (one line naming it).
    """

    def __init__(self, path):
        import os

        # FFmpeg's own log lines (e.g. "moov atom not found") would add a second line to the one-line error
        # below; OpenCV reads this when its FFmpeg back end starts (a user's own setting wins).
        os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
        import cv2

        self.path = Path(path)
        if not self.path.is_file():
            raise ValueError(f"video {self.path}: file not found")
        self._capture = cv2.VideoCapture(str(self.path))
        ok, first = self._capture.read() if self._capture.isOpened() else (False, None)
        if not ok or first is None or first.ndim != 3:
            self._capture.release()
            raise ValueError(f"video {self.path}: cannot be read (not a video OpenCV can decode)")
        self._first = first
        fps = float(self._capture.get(cv2.CAP_PROP_FPS) or 0.0)
        self.fps = fps if np.isfinite(fps) and 0.0 < fps < 1000.0 else None
        """Frame rate [1/s] from the container, or ``None``."""
        self.height, self.width = first.shape[:2]

    def frames(self) -> Iterator[tuple[int, float, np.ndarray]]:
        import cv2

        if self._first is None:
            raise ValueError(f"video {self.path}: frames() can only be read once")
        step = 1.0 / (self.fps or 30.0)
        frame, index = self._first, 0
        self._first = None
        while frame is not None:
            if frame.shape[:2] != (self.height, self.width):
                raise ValueError(
                    f"video {self.path}: frame {index} is {frame.shape[1]}×{frame.shape[0]}, "
                    f"the video started at {self.width}×{self.height}"
                )
            yield index, index * step, cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
            ok, frame = self._capture.read()
            frame = frame if ok else None
            index += 1

    def close(self) -> None:
        self._capture.release()


class VideoLandmarks(SourceBase):
    """Landmark rays of a video file (see the module docstring).

    Args:
        path: the video.
        detector: a :class:`~warpface.tracking.face_landmarks.FaceLandmarks` (default: the 68 iBUG points,
            smoothed by a one-euro filter, following the largest face).
        intrinsics: the camera; estimated from the frame size when ``None``.
        names: the landmark names to report (forwarded to the default detector).
        **detector_options: more options of the default detector (``face``, ``model_dir``, ``mesh_model``).
    """

    def __init__(self, path, detector=None, *, intrinsics: CameraIntrinsics | None = None, names=None, **options):
        from .face_landmarks import FaceLandmarks
        from .smoothing import OneEuroFilter

        self.video = VideoFrames(path)
        self.fps = self.video.fps
        try:
            if intrinsics is None:
                intrinsics = estimated_intrinsics(self.video.width, self.video.height)
            if (intrinsics.width, intrinsics.height) != (self.video.width, self.video.height):
                raise ValueError(
                    f"intrinsics: made for {intrinsics.width}×{intrinsics.height}, the video {self.video.path.name} "
                    f"is {self.video.width}×{self.video.height}"
                )
            self.intrinsics = intrinsics
            if detector is None:
                detector = FaceLandmarks(names, smoothing=OneEuroFilter(), fps=self.fps or 30.0, **options)
        except BaseException:
            self.video.close()
            raise
        self.detector = detector
        self.landmark_names = tuple(detector.landmark_names)

    def rays(self, pixels: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) → their rays' points at depth 1, (N, 3) (NaN rows stay NaN)."""
        k = self.intrinsics
        return np.column_stack([(pixels[:, 0] - k.cx) / k.fx, (pixels[:, 1] - k.cy) / k.fy, np.ones(len(pixels))])

    def frames(self) -> Iterator[LandmarkFrame]:
        """One frame of rays per video frame; a frame without a face has every landmark missing."""
        for index, timestamp, rgb in self.video.frames():
            pixels, confidence = self.detector.detect(rgb)
            yield LandmarkFrame(timestamp, self.rays(pixels), confidence, index)

    def close(self) -> None:
        """Release the video."""
        self.video.close()
