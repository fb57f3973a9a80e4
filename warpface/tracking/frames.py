"""Frames and stream protocols: what a tracker reads.

**Camera frame**: OpenCV's — x right, y down, z forward (away from the camera), metres.
**Missing landmarks** are NaN rows with confidence 0 in a :class:`LandmarkFrame`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator, Protocol, runtime_checkable

import numpy as np

from .._validate import MAX_COORDINATE
from .intrinsics import CameraIntrinsics

__all__ = ["LandmarkFrame", "RGBDFrame", "LandmarkSource", "RGBDSource", "SourceBase"]


@dataclass(frozen=True, eq=False)
class LandmarkFrame:
    """One frame of landmarks.

    Construction copies and validates: ``points`` becomes float64 (N, 3), ``confidence`` float32
    (N,); a landmark whose point is not finite gets confidence 0 and a NaN row.
    """

    timestamp: float
    """Capture time [s]."""
    points: np.ndarray
    """Landmark positions [m], shape (N, 3), float64, camera frame; NaN rows are missing (so are
    points beyond ±``MAX_COORDINATE``, 1e6 m: no camera measures those)."""
    confidence: np.ndarray
    """Per-landmark confidence in [0, 1], shape (N,), float32; 0 = missing (or filled in)."""
    index: int
    """Frame number in the source (0-based)."""

    def __post_init__(self):
        index = _frame_index(self.index)
        try:
            pts = np.array(self.points, dtype=np.float64)
            with np.errstate(over="ignore"):
                conf = np.array(self.confidence, dtype=np.float32).reshape(-1)
            timestamp = float(self.timestamp)
        except (TypeError, ValueError):
            raise ValueError(
                f"frame {index}: points, confidence and timestamp must be numbers and arrays of numbers"
            ) from None
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"frame {index}: points must have shape (N, 3), got {pts.shape}")
        if conf.shape[0] != pts.shape[0]:
            raise ValueError(f"frame {index}: {conf.shape[0]} confidences for {pts.shape[0]} landmarks")
        if not math.isfinite(timestamp):
            raise ValueError(f"frame {index}: timestamp {self.timestamp} is not finite")
        with np.errstate(invalid="ignore"):
            far = np.any(np.abs(pts) > MAX_COORDINATE, axis=1)
        missing = ~np.all(np.isfinite(pts), axis=1) | far | ~np.isfinite(conf)
        pts[missing] = np.nan
        conf = np.where(missing, 0.0, np.clip(conf, 0.0, 1.0)).astype(np.float32)
        object.__setattr__(self, "timestamp", timestamp)
        object.__setattr__(self, "index", index)
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "confidence", conf)

    @property
    def landmark_count(self) -> int:
        """Number of landmarks N."""
        return self.points.shape[0]

    @property
    def missing(self) -> np.ndarray:
        """Landmarks with no measurement (NaN point), shape (N,), bool."""
        return ~np.all(np.isfinite(self.points), axis=1)


@dataclass(frozen=True, eq=False)
class RGBDFrame:
    """One colour + registered depth frame."""

    timestamp: float
    """Capture time [s]."""
    color: np.ndarray
    """Colour image, shape (H, W, 3), uint8, RGB order."""
    depth: np.ndarray
    """Raw depth registered to the colour image, shape (H, W), uint16; 0 = no measurement."""
    depth_scale: float
    """Metres per raw depth unit (1e-3 for millimetres)."""
    index: int
    """Frame number in the source (0-based)."""

    def __post_init__(self):
        object.__setattr__(self, "index", _frame_index(self.index))
        color = np.asarray(self.color)
        depth = np.asarray(self.depth)
        if color.ndim != 3 or color.shape[2] != 3 or color.dtype != np.uint8:
            raise ValueError(f"frame {self.index}: color must be (H, W, 3) uint8, got {color.shape} {color.dtype}")
        if depth.ndim != 2 or depth.dtype != np.uint16:
            raise ValueError(f"frame {self.index}: depth must be (H, W) uint16, got {depth.shape} {depth.dtype}")
        if depth.shape != color.shape[:2]:
            raise ValueError(f"frame {self.index}: depth {depth.shape} and color {color.shape[:2]} sizes differ")
        try:
            depth_scale, timestamp = float(self.depth_scale), float(self.timestamp)
        except (TypeError, ValueError):
            raise ValueError(f"frame {self.index}: depth_scale and timestamp must be numbers") from None
        if not (math.isfinite(depth_scale) and 0 < depth_scale <= 1.0):
            raise ValueError(f"frame {self.index}: depth_scale must be in (0, 1] m per unit, got {self.depth_scale}")
        if not math.isfinite(timestamp):
            raise ValueError(f"frame {self.index}: timestamp {self.timestamp} is not finite")
        object.__setattr__(self, "depth_scale", depth_scale)
        object.__setattr__(self, "timestamp", timestamp)

    @property
    def depth_m(self) -> np.ndarray:
        """Depth [m], shape (H, W), float32; 0 = no measurement."""
        return self.depth.astype(np.float32) * np.float32(self.depth_scale)


# --------------------------------------------------------------------------------------------
# Protocols
# --------------------------------------------------------------------------------------------


@runtime_checkable
class LandmarkSource(Protocol):
    """A stream of :class:`LandmarkFrame` with a fixed, named set of landmarks."""

    landmark_names: tuple[str, ...]
    """One name per landmark, length N."""
    fps: float | None
    """Native frame rate [1/s] (USD ``timeCodesPerSecond``), or ``None`` if unknown."""

    def frames(self) -> Iterator[LandmarkFrame]:
        """Frames in time order, timestamps strictly increasing."""
        ...

    def close(self) -> None:
        """Release files/devices. Safe to call twice."""
        ...

    def __enter__(self): ...

    def __exit__(self, *exc) -> None: ...


@runtime_checkable
class RGBDSource(Protocol):
    """A stream of :class:`RGBDFrame` with fixed intrinsics."""

    intrinsics: CameraIntrinsics
    """Intrinsics of the colour image (depth is registered to it)."""
    fps: float | None
    """Native frame rate [1/s], or ``None`` if unknown."""

    def frames(self) -> Iterator[RGBDFrame]:
        """Frames in time order, timestamps strictly increasing."""
        ...

    def close(self) -> None: ...

    def __enter__(self): ...

    def __exit__(self, *exc) -> None: ...


class SourceBase:
    """Context-manager plumbing shared by the sources: ``with source: ...`` closes it."""

    def close(self) -> None:
        """Release resources (nothing to release here). Safe to call twice."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _frame_index(value) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"frame index: expected an integer, got {type(value).__name__}")
    return int(value)
