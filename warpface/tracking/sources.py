"""Landmark and RGB-D sources: what a tracker reads, frame by frame.

Two kinds of stream:

* **Landmark streams** (:class:`LandmarkSource`) yield :class:`LandmarkFrame` — 3-D landmark
  positions in the camera frame. :class:`RecordedLandmarks` (``.npz``), :class:`RGBDLandmarks`
  (fiducials found in an RGB-D stream) and :class:`~warpface.tracking.mediapipe.MediaPipeLandmarks`
  are landmark streams.
* **RGB-D streams** (:class:`RGBDSource`) yield :class:`RGBDFrame` — a colour image, a registered
  depth image and intrinsics. :class:`RGBDFolder`, the live cameras in
  :mod:`warpface.tracking.cameras` and :class:`~warpface.tracking.synthetic.SyntheticRGBDCamera`
  are RGB-D streams.

**Camera frame**: OpenCV's — x right, y down, z forward (away from the camera), metres.

**Timestamp policy** (``timestamp_policy``): timestamps are seconds and must increase strictly.
``"reject"`` raises ValueError at the first frame whose timestamp is not greater than the previous
one (naming both); ``"drop"`` skips such frames (a duplicate delivered twice, a clock step back)
and counts them in ``dropped_frames``. Files default to ``"reject"`` (a file that goes back in time
is damaged); live cameras default to ``"drop"``.

**Landmark count**: fixed for a stream; a frame with a different count raises ValueError naming the
frame and both counts.

**Missing landmarks** are NaN rows with confidence 0 in a :class:`LandmarkFrame`.
:func:`fill_missing` replaces them (hold the last value, or interpolate in time) so nothing NaN
reaches the dense mesh; :class:`~warpface.tracking.transfer.TrackingAdapter` also holds them itself.

This module gathers them; each lives in a small module of its own: :mod:`~warpface.tracking.frames`
(frames, protocols), :mod:`~warpface.tracking.streams` (timestamp policy, :func:`fill_missing`),
:mod:`~warpface.tracking.recorded`, :mod:`~warpface.tracking.rgbd_folder`,
:mod:`~warpface.tracking.rgbd_landmarks`.
"""

from __future__ import annotations

from .frames import LandmarkFrame, LandmarkSource, RGBDFrame, RGBDSource, SourceBase
from .recorded import RecordedLandmarks
from .rgbd_folder import RGBDFolder
from .rgbd_landmarks import RGBDLandmarks
from .streams import TIMESTAMP_POLICIES, StreamGuard, checked_frames, fill_missing

__all__ = [
    "LandmarkFrame",
    "LandmarkSource",
    "RGBDFrame",
    "RGBDSource",
    "SourceBase",
    "StreamGuard",
    "TIMESTAMP_POLICIES",
    "checked_frames",
    "fill_missing",
    "RecordedLandmarks",
    "RGBDFolder",
    "RGBDLandmarks",
]
