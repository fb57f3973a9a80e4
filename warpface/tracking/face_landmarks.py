"""Markerless facial landmarks: the face mesh's 68 iBUG points (and optionally all 468 mesh points) with the
fiducial detectors' interface, and :func:`detect_face_landmarks` for one image.

:class:`FaceLandmarks` has ``landmark_names`` and ``detect(color) -> (pixels (N, 2), confidence (N,))``, as
:class:`~warpface.tracking.detect.DotTracker` and :class:`~warpface.tracking.detect.ArucoMarkers`, so
:class:`~warpface.tracking.rgbd_landmarks.RGBDLandmarks` lifts it with depth and the monocular video source
uses it directly. Frame to frame it follows one face (:class:`~warpface.tracking.face_detector.FaceMeshDetector`),
smooths the points (:class:`~warpface.tracking.smoothing.OneEuroFilter`) and, when the face is lost,
reports every landmark missing (NaN, confidence 0) for that frame and counts it in ``lost_frames``.
"""

from __future__ import annotations

import threading

import numpy as np

from .face_mesh_ibug import IBUG_NAMES, ibug_from_mesh
from .frames import LandmarkFrame, RGBDFrame
from .rgbd_landmarks import RGBDLandmarks
from .smoothing import OneEuroFilter

__all__ = [
    "FaceLandmarks",
    "FaceRGBDLandmarks",
    "detect_face_landmarks",
    "MAX_DEPTH_JUMP",
    "JAW_CONTOUR_CONFIDENCE",
    "MESH_NAMES",
]

MESH_NAMES = tuple(f"mesh{i:03d}" for i in range(468))
"""Names of the 468 face-mesh points."""
JAW_CONTOUR_CONFIDENCE = 0.3
"""Confidence of the jaw-line points iBUG 0–16 (8, the chin, excepted): they lie on the face's outline,
which slides over the skin as the head turns, so they pull less than points fixed on the skin."""
_CACHE: dict = {}
_CACHE_LOCK = threading.Lock()


class FaceLandmarks:
    """The face mesh's landmarks in colour images (see the module docstring).

    Args:
        names: the landmark names to report, in order: ``ibugNN`` and/or ``meshNNN`` (default the 68 iBUG
            points); or a mapping ``{output name: ibug/mesh name}`` to rename them (e.g. after rig vertices).
        smoothing: a :class:`OneEuroFilter` for the pixels, or ``None`` (images: default, no smoothing).
        fps: frame rate of the frames given to :meth:`detect` [1/s] (the filter's time step).
        **detector: :class:`~warpface.tracking.face_detector.FaceMeshDetector` options (``model_dir``,
            ``mesh_model``, ``face``, ``track``, ``threads``, ``min_score``, ``min_presence``).
    """

    def __init__(self, names=None, *, smoothing: OneEuroFilter | None = None, fps: float = 30.0, **detector):
        from .face_detector import FaceMeshDetector

        if names is None:
            names = IBUG_NAMES
        pairs = list(names.items()) if isinstance(names, dict) else [(n, n) for n in names]
        self.landmark_names = tuple(str(out) for out, _ in pairs)
        self._sources = np.array([_source_index(str(src)) for _, src in pairs], dtype=np.int64)
        if len(set(self.landmark_names)) != len(self.landmark_names):
            raise ValueError("names: a landmark name appears more than once")
        self.detector = FaceMeshDetector(**detector)
        self.smoothing = smoothing
        self._step = 1.0 / float(fps)
        self._frame = 0
        self.lost_frames = 0
        """Frames in which no face was found."""
        self.found = False
        """Whether the last frame had a face."""
        confidence = np.ones(68 + 468, dtype=np.float32)
        contour = [i for i in range(17) if i != 8]
        confidence[contour] = JAW_CONTOUR_CONFIDENCE
        self._confidence = confidence[self._sources]

    def detect(self, color: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Landmark pixels (N, 2) [OpenCV convention] and confidence (N,) in ``color`` (H, W, 3) uint8 RGB;
        NaN rows and confidence 0 when no face is found."""
        timestamp = self._frame * self._step
        self._frame += 1
        mesh = self.detector(color)
        count = len(self.landmark_names)
        if mesh is None:
            self.found = False
            self.lost_frames += 1
            if self.smoothing is not None:
                self.smoothing.reset()
            return np.full((count, 2), np.nan), np.zeros(count, dtype=np.float32)
        self.found = True
        xy = mesh.points[:, :2]
        every = np.concatenate([ibug_from_mesh(xy), xy])
        pixels = every[self._sources]
        if self.smoothing is not None:
            pixels = self.smoothing(pixels, timestamp)
        return pixels, self._confidence * np.float32(mesh.presence)

    def reset(self) -> None:
        """Forget the followed face and the filter's state (a cut in the video)."""
        self.detector.reset()
        if self.smoothing is not None:
            self.smoothing.reset()


def _source_index(name: str) -> int:
    if name.startswith("ibug") and name[4:].isdigit() and int(name[4:]) < 68 and len(name) == 6:
        return int(name[4:])
    if name.startswith("mesh") and name[4:].isdigit() and int(name[4:]) < 468 and len(name) == 7:
        return 68 + int(name[4:])
    raise ValueError(f"landmark {name!r}: expected 'ibug00' … 'ibug67' or 'mesh000' … 'mesh467'")


def detect_face_landmarks(rgb, *, face: int = 0, mesh: bool = False, model_dir=None) -> dict:
    """Facial landmarks in one image.

    Args:
        rgb: the image, (H, W, 3) uint8, RGB order.
        face: which face when there are several: 0 the largest, 1 the next, ...
        mesh: also return the 468 face-mesh points (``mesh000`` … ``mesh467``).
        model_dir: folder with the model files (see :mod:`warpface.tracking.face_models`).

    Returns:
        ``{name: (x, y)}`` pixel positions (OpenCV convention: pixel centres at integer coordinates) with at
        least ``ibug00`` … ``ibug67`` (iBUG numbering is the subject's: ``ibug36`` is the subject's right eye's
        outer corner); ``{}`` when there is no face.

    Raises:
        TypeError / ValueError: ``rgb`` is not an (H, W, 3) uint8 array.
        FileNotFoundError: a model file is missing; ImportError: ``ai-edge-litert`` is not installed.
    """
    key = (None if model_dir is None else str(model_dir), int(face))
    with _CACHE_LOCK:  # one interpreter per (folder, face), shared by the threads that call this
        if key not in _CACHE:
            _CACHE[key] = FaceLandmarks(IBUG_NAMES + MESH_NAMES, model_dir=model_dir, face=face, track=False)
        detector = _CACHE[key]
        pixels, _ = detector.detect(rgb)
        found = detector.found
    if not found:
        return {}
    count = len(IBUG_NAMES) + (len(MESH_NAMES) if mesh else 0)
    return {name: (float(x), float(y)) for name, (x, y) in zip(detector.landmark_names[:count], pixels[:count])}


MAX_DEPTH_JUMP = 0.12
"""Largest distance [m] of a lifted landmark's depth from the median of the frame's landmarks (docs/CAPTURE.md
§2): a face is ~0.1 m deep, so a landmark farther off landed on the background or an occluder."""


class FaceRGBDLandmarks(RGBDLandmarks):
    """:class:`~warpface.tracking.rgbd_landmarks.RGBDLandmarks` for face-mesh landmarks, with a depth-jump gate:
    a landmark whose depth is more than ``max_depth_jump`` [m] from the frame's median landmark depth is
    reported missing (an outline point lifted off the background)."""

    def __init__(self, rgbd, detector, *, max_depth_jump: float = MAX_DEPTH_JUMP, **options):
        from .._validate import as_positive

        super().__init__(rgbd, detector, **options)
        self.max_depth_jump = as_positive(max_depth_jump, "max_depth_jump")

    def landmarks(self, frame: RGBDFrame) -> LandmarkFrame:
        lifted = super().landmarks(frame)
        depth = lifted.points[:, 2]
        found = np.isfinite(depth)
        if not found.any():
            return lifted
        jump = np.abs(depth - np.median(depth[found])) > self.max_depth_jump
        points = np.where(jump[:, None], np.nan, lifted.points)
        return LandmarkFrame(lifted.timestamp, points, np.where(jump, 0.0, lifted.confidence), lifted.index)
