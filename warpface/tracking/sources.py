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
"""

from __future__ import annotations

import json
import math
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator, Protocol, Sequence, runtime_checkable

import numpy as np

from ._io import atomic_path, write_json_atomic
from .depth import CameraIntrinsics, backproject

__all__ = [
    "LandmarkFrame",
    "LandmarkSource",
    "RGBDFrame",
    "RGBDSource",
    "TIMESTAMP_POLICIES",
    "checked_frames",
    "fill_missing",
    "RecordedLandmarks",
    "RGBDFolder",
    "RGBDLandmarks",
]

TIMESTAMP_POLICIES = ("reject", "drop")
"""Accepted values of ``timestamp_policy``; see the module docstring."""


# --------------------------------------------------------------------------------------------
# Frames
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class LandmarkFrame:
    """One frame of landmarks.

    Construction copies and validates: ``points`` becomes float64 (N, 3), ``confidence`` float32
    (N,); a landmark whose point is not finite gets confidence 0 and a NaN row.
    """

    timestamp: float
    """Capture time [s]."""
    points: np.ndarray
    """Landmark positions [m], shape (N, 3), float64, camera frame; NaN rows are missing."""
    confidence: np.ndarray
    """Per-landmark confidence in [0, 1], shape (N,), float32; 0 = missing (or filled in)."""
    index: int
    """Frame number in the source (0-based)."""

    def __post_init__(self):
        pts = np.array(self.points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"frame {self.index}: points must have shape (N, 3), got {pts.shape}")
        conf = np.array(self.confidence, dtype=np.float32).reshape(-1)
        if conf.shape[0] != pts.shape[0]:
            raise ValueError(
                f"frame {self.index}: {conf.shape[0]} confidences for {pts.shape[0]} landmarks"
            )
        if not math.isfinite(float(self.timestamp)):
            raise ValueError(f"frame {self.index}: timestamp {self.timestamp} is not finite")
        missing = ~np.all(np.isfinite(pts), axis=1) | ~np.isfinite(conf)
        pts[missing] = np.nan
        conf = np.where(missing, 0.0, np.clip(conf, 0.0, 1.0)).astype(np.float32)
        object.__setattr__(self, "timestamp", float(self.timestamp))
        object.__setattr__(self, "index", int(self.index))
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
        color = np.asarray(self.color)
        depth = np.asarray(self.depth)
        if color.ndim != 3 or color.shape[2] != 3 or color.dtype != np.uint8:
            raise ValueError(f"frame {self.index}: color must be (H, W, 3) uint8, got {color.shape} {color.dtype}")
        if depth.ndim != 2 or depth.dtype != np.uint16:
            raise ValueError(f"frame {self.index}: depth must be (H, W) uint16, got {depth.shape} {depth.dtype}")
        if depth.shape != color.shape[:2]:
            raise ValueError(f"frame {self.index}: depth {depth.shape} and color {color.shape[:2]} sizes differ")
        if not (math.isfinite(self.depth_scale) and self.depth_scale > 0):
            raise ValueError(f"frame {self.index}: depth_scale must be > 0, got {self.depth_scale}")
        if not math.isfinite(float(self.timestamp)):
            raise ValueError(f"frame {self.index}: timestamp {self.timestamp} is not finite")

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


# --------------------------------------------------------------------------------------------
# Stream checks
# --------------------------------------------------------------------------------------------


class _StreamGuard:
    """Applies the timestamp policy and the fixed landmark/image size to a stream of frames."""

    def __init__(self, policy: str, where: str):
        if policy not in TIMESTAMP_POLICIES:
            raise ValueError(f"timestamp_policy must be one of {TIMESTAMP_POLICIES}, got {policy!r}")
        self.policy = policy
        self.where = where
        self.last_time: float | None = None
        self.last_index: int | None = None
        self.shape: tuple | None = None
        self.dropped = 0

    def accept(self, timestamp: float, index: int, shape: tuple, what: str) -> bool:
        """True to pass the frame on, False to drop it; raises ValueError per the policy."""
        if self.shape is None:
            self.shape = shape
        elif shape != self.shape:
            raise ValueError(
                f"{self.where}: frame {index} has {what} {shape}, but the stream started with {self.shape}"
            )
        if self.last_time is not None and not timestamp > self.last_time:
            if self.policy == "reject":
                kind = "duplicate" if timestamp == self.last_time else "decreasing"
                raise ValueError(
                    f"{self.where}: {kind} timestamp at frame {index}: {timestamp!r} s after "
                    f"{self.last_time!r} s at frame {self.last_index} (timestamps must increase strictly)"
                )
            self.dropped += 1
            return False
        self.last_time = timestamp
        self.last_index = index
        return True


def checked_frames(
    frames: Iterable[LandmarkFrame], *, landmark_count: int | None = None, timestamp_policy: str = "reject",
    where: str = "landmark stream",
) -> Iterator[LandmarkFrame]:
    """Pass frames through the timestamp policy and the fixed landmark count (see module docstring).

    Args:
        frames: any iterable of :class:`LandmarkFrame`.
        landmark_count: expected N; taken from the first frame when ``None``.
        timestamp_policy: ``"reject"`` or ``"drop"``.
        where: name used in error messages.
    """
    guard = _StreamGuard(timestamp_policy, where)
    if landmark_count is not None:
        guard.shape = (int(landmark_count),)
    for frame in frames:
        if guard.accept(frame.timestamp, frame.index, (frame.landmark_count,), "landmark count"):
            yield frame


def fill_missing(
    frames: Iterable[LandmarkFrame], *, mode: str = "hold", max_lookahead: int = 300
) -> Iterator[LandmarkFrame]:
    """Replace missing landmarks so no NaN goes downstream; filled landmarks keep confidence 0.

    ``"hold"`` repeats a landmark's last measured position (causal, suits live capture).
    ``"interpolate"`` interpolates linearly in time between the measurements either side of a gap
    (it waits for the gap to close, up to ``max_lookahead`` frames, then holds). In both modes a
    landmark not yet measured at the start takes its first measured position, so frames are held
    back until every landmark has been seen once.

    Raises:
        ValueError: ``mode`` unknown, or a landmark still unmeasured after ``max_lookahead`` frames
            (or at the end of the stream), naming it.
    """
    if mode not in ("hold", "interpolate"):
        raise ValueError(f"mode must be 'hold' or 'interpolate', got {mode!r}")
    buffer: deque[LandmarkFrame] = deque()
    last_point: np.ndarray | None = None  # (N, 3) last measured (or filled) positions
    last_time: np.ndarray | None = None  # (N,) time of each landmark's last measurement
    have: np.ndarray | None = None

    def release(frame: LandmarkFrame, future: Sequence[LandmarkFrame]) -> LandmarkFrame:
        nonlocal last_point, last_time
        pts = frame.points.copy()
        miss = frame.missing
        if mode == "interpolate" and miss.any():
            for j in np.flatnonzero(miss):
                nxt = next((f for f in future if not f.missing[j]), None)
                if nxt is not None and np.isfinite(last_time[j]):
                    s = (frame.timestamp - last_time[j]) / (nxt.timestamp - last_time[j])
                    pts[j] = (1.0 - s) * last_point[j] + s * nxt.points[j]
                elif nxt is not None:
                    pts[j] = nxt.points[j]
        still = miss & ~np.all(np.isfinite(pts), axis=1)
        pts[still] = last_point[still]
        measured = ~miss
        last_point = np.where(measured[:, None], frame.points, last_point)
        last_time = np.where(measured, frame.timestamp, last_time)
        return LandmarkFrame(frame.timestamp, pts, frame.confidence, frame.index)

    for frame in frames:
        if have is None:
            have = np.zeros(frame.landmark_count, dtype=bool)
            last_point = np.full((frame.landmark_count, 3), np.nan)
            last_time = np.full(frame.landmark_count, np.nan)
        have |= ~frame.missing
        buffer.append(frame)
        if not have.all():
            if len(buffer) > max_lookahead:
                raise ValueError(f"landmark {int(np.flatnonzero(~have)[0])} not measured in the first "
                                 f"{len(buffer)} frames")
            continue
        if last_point is not None and np.isnan(last_point).any():
            # First release: seed every landmark with its first measurement.
            for j in range(frame.landmark_count):
                first = next(f for f in buffer if not f.missing[j])
                if np.isnan(last_point[j]).any():
                    last_point[j] = first.points[j]
        # Keep frames while an interpolation gap is still open (bounded lookahead).
        while buffer:
            head = buffer[0]
            if mode == "interpolate" and head.missing.any() and len(buffer) <= max_lookahead:
                open_gap = any(all(f.missing[j] for f in list(buffer)[1:]) for j in np.flatnonzero(head.missing))
                if open_gap:
                    break
            buffer.popleft()
            yield release(head, list(buffer))
    if buffer:
        if have is None or not have.all():
            missing = int(np.flatnonzero(~have)[0]) if have is not None else 0
            raise ValueError(f"landmark {missing} was never measured in the stream")
        while buffer:
            head = buffer.popleft()
            yield release(head, list(buffer))


# --------------------------------------------------------------------------------------------
# Recorded landmarks (.npz)
# --------------------------------------------------------------------------------------------


def _estimate_fps(timestamps: np.ndarray) -> float | None:
    if timestamps.shape[0] < 2:
        return None
    step = float(np.median(np.diff(timestamps)))
    return 1.0 / step if step > 0 else None


def _validate_names(names, count: int, where: str) -> tuple[str, ...]:
    names = tuple(str(n) for n in names)
    if len(names) != count:
        raise ValueError(f"{where}: {len(names)} landmark names for {count} landmarks")
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise ValueError(f"{where}: landmark name {dup!r} appears more than once")
    return names


class RecordedLandmarks(SourceBase):
    """Landmarks recorded in an ``.npz`` file.

    Arrays: ``timestamps`` (F,) float64 [s], ``points`` (F, N, 3) float64 [m] camera frame (NaN =
    missing), ``confidence`` (F, N) float32, ``names`` (N,) unicode, optional ``fps`` () float64.
    Written by :meth:`write`; read back bit for bit.

    Args:
        path: the ``.npz`` file.
        timestamp_policy: ``"reject"`` (default) or ``"drop"``; checked when frames are read.

    Raises:
        ValueError: missing file or array, inconsistent shapes, or bad names.
    """

    def __init__(self, path: str | Path, *, timestamp_policy: str = "reject"):
        self.path = Path(path)
        if not self.path.is_file():
            raise ValueError(f"{self.path}: no such landmark file")
        try:
            with np.load(self.path, allow_pickle=False) as data:
                arrays = {k: data[k] for k in data.files}
        except (OSError, ValueError) as exc:
            raise ValueError(f"{self.path}: not a readable .npz file ({exc})") from None
        for key in ("timestamps", "points", "confidence", "names"):
            if key not in arrays:
                raise ValueError(f"{self.path}: missing array {key!r}")
        self.timestamps = np.asarray(arrays["timestamps"], dtype=np.float64)
        """Frame times [s], shape (F,), float64."""
        self.points = np.asarray(arrays["points"], dtype=np.float64)
        """Landmark positions [m], shape (F, N, 3), float64 (NaN = missing)."""
        self.confidence = np.asarray(arrays["confidence"], dtype=np.float32)
        """Confidences, shape (F, N), float32."""
        f = self.timestamps.shape[0]
        if self.timestamps.ndim != 1 or self.points.ndim != 3 or self.points.shape[0] != f or self.points.shape[2] != 3:
            raise ValueError(
                f"{self.path}: expected timestamps (F,) and points (F, N, 3), got "
                f"{self.timestamps.shape} and {self.points.shape}"
            )
        if self.confidence.shape != self.points.shape[:2]:
            raise ValueError(f"{self.path}: confidence {self.confidence.shape} ≠ points {self.points.shape[:2]}")
        self.landmark_names = _validate_names(arrays["names"].tolist(), self.points.shape[1], str(self.path))
        fps = float(arrays["fps"]) if "fps" in arrays else float("nan")
        self.fps = fps if math.isfinite(fps) and fps > 0 else _estimate_fps(self.timestamps)
        self.timestamp_policy = timestamp_policy
        _StreamGuard(timestamp_policy, str(self.path))  # validate the policy name now

    def __len__(self) -> int:
        return int(self.timestamps.shape[0])

    def frames(self) -> Iterator[LandmarkFrame]:
        """Frames in file order, through the timestamp policy."""
        raw = (
            LandmarkFrame(self.timestamps[i], self.points[i], self.confidence[i], i) for i in range(len(self))
        )
        yield from checked_frames(raw, timestamp_policy=self.timestamp_policy, where=str(self.path))

    @staticmethod
    def write(
        path: str | Path, frames: Iterable[LandmarkFrame], landmark_names: Sequence[str], *, fps: float | None = None
    ) -> Path:
        """Record ``frames`` to ``path`` (temporary file + rename); returns ``path``.

        Frames are checked with the ``"reject"`` timestamp policy and a fixed landmark count. If the
        iterable fails part-way (a camera unplugged), the frames received so far are still written
        and the exception is re-raised.
        """
        path = Path(path)
        names = list(_validate_names(landmark_names, len(landmark_names), str(path)))
        times, points, confidence = [], [], []
        failure: BaseException | None = None
        try:
            for frame in checked_frames(frames, landmark_count=len(names), where=str(path)):
                times.append(frame.timestamp)
                points.append(frame.points)
                confidence.append(frame.confidence)
        except BaseException as exc:  # keep what arrived, then re-raise
            failure = exc
        n = len(names)
        arrays = {
            "timestamps": np.asarray(times, dtype=np.float64).reshape(-1),
            "points": np.asarray(points, dtype=np.float64).reshape(-1, n, 3),
            "confidence": np.asarray(confidence, dtype=np.float32).reshape(-1, n),
            "names": np.asarray(names, dtype=np.str_),
            "fps": np.float64(fps if fps is not None else np.nan),
        }
        with atomic_path(path, ".npz") as tmp:
            with tmp.open("wb") as handle:
                np.savez(handle, **arrays)
        if failure is not None:
            raise failure
        return path


# --------------------------------------------------------------------------------------------
# RGB-D folder
# --------------------------------------------------------------------------------------------


def _encode_png(image: np.ndarray) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise ValueError("could not encode PNG")
    return buf.tobytes()


def _decode_png(path: Path, flags) -> np.ndarray:
    import cv2

    data = np.fromfile(path, dtype=np.uint8) if path.is_file() else None
    image = cv2.imdecode(data, flags) if data is not None and data.size else None
    if image is None:
        raise ValueError(f"{path}: missing or unreadable PNG")
    return image


class RGBDFolder(SourceBase):
    """An RGB-D recording on disk.

    Layout::

        meta.json          {"intrinsics": {fx, fy, cx, cy, width, height},   # OpenCV convention
                            "depth_scale": metres per depth unit, "timestamps": [s, ...],
                            "fps": optional, "fiducials": optional {...}}
        color/000000.png   8-bit RGB (stored as PNG)
        depth/000000.png   16-bit depth registered to colour, 0 = no measurement

    Args:
        path: the folder.
        timestamp_policy: ``"reject"`` (default) or ``"drop"``.

    Raises:
        ValueError: no ``meta.json``, intrinsics missing or invalid, bad depth scale or timestamps.
            Missing or mis-sized images are reported when the frame is read.
    """

    def __init__(self, path: str | Path, *, timestamp_policy: str = "reject"):
        self.path = Path(path)
        meta_path = self.path / "meta.json"
        if not meta_path.is_file():
            raise ValueError(f"{self.path}: not an RGB-D folder (no meta.json)")
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise ValueError(f"{meta_path}: invalid JSON ({exc})") from None
        if "intrinsics" not in meta:
            raise ValueError(f"{meta_path}: intrinsics missing (need fx, fy, cx, cy, width, height)")
        self.intrinsics = CameraIntrinsics.from_dict(meta["intrinsics"], where=f"{meta_path}: intrinsics")
        scale = meta.get("depth_scale")
        if not isinstance(scale, (int, float)) or not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"{meta_path}: depth_scale must be a positive number [m per unit], got {scale!r}")
        self.depth_scale = float(scale)
        """Metres per raw depth unit."""
        stamps = meta.get("timestamps")
        if not isinstance(stamps, list):
            raise ValueError(f"{meta_path}: timestamps must be a list of seconds")
        self.timestamps = np.asarray(stamps, dtype=np.float64)
        """Frame times [s], shape (F,)."""
        fps = meta.get("fps")
        self.fps = float(fps) if isinstance(fps, (int, float)) and fps > 0 else _estimate_fps(self.timestamps)
        self.fiducials = meta.get("fiducials")
        """Optional fiducial layout stored with the recording (e.g. initial dot pixels), or None."""
        self.timestamp_policy = timestamp_policy
        _StreamGuard(timestamp_policy, str(self.path))

    def __len__(self) -> int:
        return int(self.timestamps.shape[0])

    def read(self, index: int) -> RGBDFrame:
        """Frame ``index`` (no timestamp policy applied)."""
        import cv2

        if not 0 <= index < len(self):
            raise IndexError(f"{self.path}: frame {index} out of range [0, {len(self)})")
        bgr = _decode_png(self.path / "color" / f"{index:06d}.png", cv2.IMREAD_COLOR)
        depth = _decode_png(self.path / "depth" / f"{index:06d}.png", cv2.IMREAD_UNCHANGED)
        expected = (self.intrinsics.height, self.intrinsics.width)
        if bgr.shape[:2] != expected or depth.shape != expected or depth.dtype != np.uint16:
            raise ValueError(
                f"{self.path}: frame {index} images are color {bgr.shape[:2]}, depth {depth.shape} {depth.dtype}; "
                f"expected {expected} and uint16 depth"
            )
        return RGBDFrame(self.timestamps[index], np.ascontiguousarray(bgr[:, :, ::-1]), depth, self.depth_scale, index)

    def frames(self) -> Iterator[RGBDFrame]:
        """Frames in order, through the timestamp policy."""
        guard = _StreamGuard(self.timestamp_policy, str(self.path))
        for i in range(len(self)):
            frame = self.read(i)
            if guard.accept(frame.timestamp, i, frame.depth.shape, "image size"):
                yield frame

    @staticmethod
    def write(
        path: str | Path,
        frames: Iterable[RGBDFrame],
        intrinsics: CameraIntrinsics,
        *,
        fps: float | None = None,
        fiducials: dict | None = None,
    ) -> Path:
        """Record RGB-D frames to a folder; returns ``path``.

        Images are written as they arrive (each through a temporary file + rename) and
        ``meta.json`` last — also when the iterable fails part-way, so a recording cut short keeps
        every frame written; the exception is then re-raised. Frames must share one depth scale and
        the intrinsics' image size, with strictly increasing timestamps.
        """
        path = Path(path)
        (path / "color").mkdir(parents=True, exist_ok=True)
        (path / "depth").mkdir(parents=True, exist_ok=True)
        guard = _StreamGuard("reject", str(path))
        stamps: list[float] = []
        scale: float | None = None
        failure: BaseException | None = None
        try:
            for frame in frames:
                guard.accept(frame.timestamp, frame.index, frame.depth.shape, "image size")
                if frame.depth.shape != (intrinsics.height, intrinsics.width):
                    raise ValueError(f"{path}: frame {frame.index} is {frame.depth.shape[::-1]} px, intrinsics "
                                     f"say {intrinsics.width}×{intrinsics.height}")
                if scale is None:
                    scale = frame.depth_scale
                elif frame.depth_scale != scale:
                    raise ValueError(f"{path}: frame {frame.index} depth_scale {frame.depth_scale} ≠ {scale}")
                k = len(stamps)
                with atomic_path(path / "color" / f"{k:06d}.png", ".png") as tmp:
                    tmp.write_bytes(_encode_png(np.ascontiguousarray(frame.color[:, :, ::-1])))
                with atomic_path(path / "depth" / f"{k:06d}.png", ".png") as tmp:
                    tmp.write_bytes(_encode_png(frame.depth))
                stamps.append(frame.timestamp)
        except BaseException as exc:
            failure = exc
        meta = {
            "intrinsics": intrinsics.to_dict(),
            "depth_scale": scale if scale is not None else 1e-3,
            "timestamps": stamps,
            "pixel_convention": "opencv (pixel centres at integer coordinates)",
        }
        if fps is not None:
            meta["fps"] = float(fps)
        if fiducials is not None:
            meta["fiducials"] = fiducials
        write_json_atomic(path / "meta.json", meta)
        if failure is not None:
            raise failure
        return path


# --------------------------------------------------------------------------------------------
# RGB-D → landmarks
# --------------------------------------------------------------------------------------------


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

    def __init__(self, rgbd, detector, *, window: int = 9, min_valid: int = 12,
                 timestamp_policy: str = "reject", device=None):
        self.rgbd = rgbd
        self.detector = detector
        self.landmark_names = tuple(detector.landmark_names)
        self.fps = getattr(rgbd, "fps", None)
        self.window = window
        self.min_valid = min_valid
        self.device = device
        self.timestamp_policy = timestamp_policy
        _StreamGuard(timestamp_policy, "rgbd")

    def landmarks(self, frame: RGBDFrame) -> LandmarkFrame:
        """Detect and back-project the landmarks of one RGB-D frame."""
        pixels, confidence = self.detector.detect(frame.color)
        points, inliers = backproject(
            pixels, frame.depth_m, self.rgbd.intrinsics, window=self.window, min_valid=self.min_valid,
            device=self.device,
        )
        confidence = np.where(inliers > 0, confidence, 0.0)
        return LandmarkFrame(frame.timestamp, points, confidence, frame.index)

    def frames(self) -> Iterator[LandmarkFrame]:
        """One landmark frame per RGB-D frame."""
        guard = _StreamGuard(self.timestamp_policy, "rgbd stream")
        for frame in self.rgbd.frames():
            if guard.accept(frame.timestamp, frame.index, frame.depth.shape, "image size"):
                yield self.landmarks(frame)

    def close(self) -> None:
        """Close the underlying RGB-D source."""
        self.rgbd.close()
