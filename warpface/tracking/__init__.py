"""Tracking adapter: landmark streams (recorded, RGB-D, synthetic, live) → dense face motion.

Modules, each with one job:

* :mod:`~warpface.tracking.frames` — :class:`LandmarkFrame`, :class:`RGBDFrame` and the
  :class:`LandmarkSource` / :class:`RGBDSource` protocols.
* :mod:`~warpface.tracking.streams` — the timestamp policy, :func:`checked_frames`, :func:`fill_missing`.
* :mod:`~warpface.tracking.prefetch` — :func:`prefetch`, :class:`PrefetchedSource`: a stream read
  ahead in a background thread (the second CPU core).
* :mod:`~warpface.tracking.recorded` — :class:`RecordedLandmarks` (.npz);
  :mod:`~warpface.tracking.rgbd_folder` — :class:`RGBDFolder`;
  :mod:`~warpface.tracking.rgbd_landmarks` — :class:`RGBDLandmarks` (dots in colour, lifted with depth).
  (:mod:`~warpface.tracking.sources` gathers all of these.)
* :mod:`~warpface.tracking.cameras` — :class:`RealSenseCamera`, :class:`OrbbecCamera`.
* :mod:`~warpface.tracking.mediapipe` — :class:`MediaPipeLandmarks`.
* :mod:`~warpface.tracking.synthetic` — :class:`SyntheticRGBDCamera` (pyrender, ground truth).
* :mod:`~warpface.tracking.detect` — ArUco markers, dot blobs, :class:`DotTracker`.
* :mod:`~warpface.tracking.face_landmarks` — markerless: :class:`FaceLandmarks`, :func:`detect_face_landmarks`
  (:mod:`~warpface.tracking.face_detector` runs MediaPipe's face detection and face mesh,
  :mod:`~warpface.tracking.face_models` finds their files, :mod:`~warpface.tracking.face_mesh_ibug` maps
  the mesh to the 68 iBUG points, :mod:`~warpface.tracking.smoothing` smooths tracks);
  :mod:`~warpface.tracking.video` — :class:`VideoLandmarks` (a video file's 2-D landmarks).
* :mod:`~warpface.tracking.intrinsics` — :class:`CameraIntrinsics` (the pixel convention).
* :mod:`~warpface.tracking.depth` — robust :func:`backproject`.
* :mod:`~warpface.tracking.correspondence` — :class:`FaceNormalization`, :func:`compute_correspondence`
  (closest points through :mod:`warpface.geometry`).
* :mod:`~warpface.tracking.transfer` — :func:`blend_weights`, :class:`TrackingAdapter`.
* :mod:`~warpface.tracking.landmark_names` — landmarks named after dense vertices,
  :func:`adapter_for_face`.

Orchestration (recording to USD, the tissue FEM coupling, the ``track`` command) lives in
:mod:`warpface.pipelines`; this package imports no fem, usd, assets or metrics.

Importing this package needs only Warp and NumPy; OpenCV, pyrender and the camera SDKs are
imported when first used.
"""

from .cameras import CameraDisconnected, CameraError, CameraUnavailable, OrbbecCamera, RealSenseCamera
from .correspondence import Correspondence, FaceNormalization, compute_correspondence
from .depth import backproject
from .detect import ArucoMarkers, DotTracker
from .face_landmarks import FaceLandmarks, FaceRGBDLandmarks, detect_face_landmarks
from .intrinsics import KINECT_V1_INTRINSICS, CameraIntrinsics
from .landmark_names import adapter_for_face, landmark_vertices, vertex_landmark_names
from .mediapipe import MediaPipeLandmarks
from .prefetch import PrefetchedSource, prefetch
from .sources import (
    LandmarkFrame,
    LandmarkSource,
    RecordedLandmarks,
    RGBDFolder,
    RGBDFrame,
    RGBDLandmarks,
    RGBDSource,
)
from .synthetic import KinectNoise, SyntheticRGBDCamera, place_fiducials
from .transfer import TrackingAdapter
from .video import VideoLandmarks

__all__ = [
    # sources
    "LandmarkFrame",
    "LandmarkSource",
    "RGBDFrame",
    "RGBDSource",
    "prefetch",
    "PrefetchedSource",
    "RecordedLandmarks",
    "RGBDFolder",
    "RGBDLandmarks",
    "MediaPipeLandmarks",
    "RealSenseCamera",
    "OrbbecCamera",
    "CameraError",
    "CameraUnavailable",
    "CameraDisconnected",
    "SyntheticRGBDCamera",
    "KinectNoise",
    "place_fiducials",
    # detection and depth
    "ArucoMarkers",
    "DotTracker",
    "FaceLandmarks",
    "FaceRGBDLandmarks",
    "VideoLandmarks",
    "detect_face_landmarks",
    "CameraIntrinsics",
    "KINECT_V1_INTRINSICS",
    "backproject",
    # sparse → dense
    "FaceNormalization",
    "Correspondence",
    "compute_correspondence",
    "TrackingAdapter",
    # landmarks named after dense vertices
    "vertex_landmark_names",
    "landmark_vertices",
    "adapter_for_face",
]
