"""Landmarks from an RGB-D stream: fiducials found in colour, lifted to 3-D with depth."""

from __future__ import annotations

from typing import Iterator

import numpy as np

from .depth import backproject
from .frames import LandmarkFrame, RGBDFrame, SourceBase
from .streams import StreamGuard

__all__ = ["RGBDLandmarks"]


class RGBDLandmarks(SourceBase):
    """Landmarks from an RGB-D stream: fiducials found in colour, lifted to 3-D with depth.

    Args:
        rgbd: any :class:`RGBDSource`.
        detector: a fiducial detector with ``landmark_names`` and ``detect(color) -> (pixels (N, 2),
            confidence (N,))`` (:class:`~warpface.tracking.detect.DotTracker`,
            :class:`~warpface.tracking.detect.ArucoMarkers`).
        window, min_valid: passed to :func:`~warpface.tracking.depth.backproject`.
        timestamp_policy: applied to the RGB-D frames.
        device: Warp device for back-projection.
    """

    def __init__(
        self, rgbd, detector, *, window: int = 9, min_valid: int = 12, timestamp_policy: str = "reject", device=None
    ):
        self.rgbd = rgbd
        self.detector = detector
        self.landmark_names = tuple(detector.landmark_names)
        self.fps = getattr(rgbd, "fps", None)
        self.window = window
        self.min_valid = min_valid
        self.device = device
        self.timestamp_policy = timestamp_policy
        StreamGuard(timestamp_policy, "rgbd")

    def landmarks(self, frame: RGBDFrame) -> LandmarkFrame:
        """Detect and back-project the landmarks of one RGB-D frame."""
        pixels, confidence = self.detector.detect(frame.color)
        points, inliers = backproject(
            pixels,
            frame.depth_m,
            self.rgbd.intrinsics,
            window=self.window,
            min_valid=self.min_valid,
            device=self.device,
        )
        confidence = np.where(inliers > 0, confidence, 0.0)
        return LandmarkFrame(frame.timestamp, points, confidence, frame.index)

    def frames(self) -> Iterator[LandmarkFrame]:
        """One landmark frame per RGB-D frame."""
        guard = StreamGuard(self.timestamp_policy, "rgbd stream")
        for frame in self.rgbd.frames():
            if guard.accept(frame.timestamp, frame.index, frame.depth.shape, "image size"):
                yield self.landmarks(frame)

    def close(self) -> None:
        """Close the underlying RGB-D source."""
        self.rgbd.close()
