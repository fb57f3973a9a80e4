"""Live RGB-D cameras behind optional extras: Intel RealSense and Orbbec.

Both yield :class:`~warpface.tracking.sources.RGBDFrame` with depth registered (aligned) to the
colour image and the colour camera's intrinsics, so landmarks found in colour can be lifted with
that depth directly. The SDK wheels bundle their drivers:

* RealSense — ``pip install warpface[realsense]`` (``pyrealsense2``): ``rs.pipeline`` with z16
  depth and rgb8 colour streams, ``rs.align(rs.stream.color)``, depth scale from the device's
  first depth sensor, intrinsics ``ppx/ppy/fx/fy`` of the colour stream profile.
* Orbbec — ``pip install warpface[orbbec]`` (``pyorbbecsdk2``, imported as ``pyorbbecsdk``):
  ``Pipeline`` + ``Config`` with Y16 depth and RGB colour profiles, software ``AlignFilter`` to the
  colour stream, depth scale per frame (``DepthFrame.get_depth_scale()``, millimetres per unit),
  timestamps ``get_timestamp_us()``, intrinsics from ``Pipeline.get_camera_param().rgb_intrinsic``.

Errors: :class:`CameraUnavailable` when the extra is not installed or no device is attached;
:class:`CameraDisconnected` when frames stop arriving mid-capture (frames already yielded are the
consumer's to keep — everything downstream receives them before the error).
Timestamps are the device's frame timestamps converted to seconds; the default policy drops
repeated or backward timestamps (see :mod:`warpface.tracking.sources`).
"""

from __future__ import annotations

import importlib
from typing import Iterator

import numpy as np

from ..errors import CameraDisconnected, CameraError, CameraUnavailable
from .frames import RGBDFrame, SourceBase
from .intrinsics import CameraIntrinsics
from .streams import StreamGuard

__all__ = ["CameraError", "CameraUnavailable", "CameraDisconnected", "RealSenseCamera", "OrbbecCamera"]


def _import_sdk(module: str, extra: str, what: str):
    try:
        return importlib.import_module(module)
    except ImportError:
        raise CameraUnavailable(
            f"{what} support needs the optional extra: pip install 'warpface[{extra}]' (module {module!r} not found)"
        ) from None


class _LiveCamera(SourceBase):
    """What the live cameras share: the SDK import and frame-loop options, the frame checks, stopping."""

    def _open_sdk(self, name: str, module: str, extra: str, timeout_ms, max_frames, timestamp_policy):
        """Import the SDK ``module`` (extra ``extra``) of the ``name`` cameras and keep the frame loop's options;
        returns the module."""
        self._name = name
        sdk = _import_sdk(module, extra, name)
        self.timeout_ms = int(timeout_ms)
        self.max_frames = max_frames
        self.timestamp_policy = timestamp_policy
        StreamGuard(timestamp_policy, name)  # checks the policy before a device is touched
        self.dropped_frames = 0
        return sdk

    def _wants(self, index: int) -> bool:
        """Whether the frame loop goes on after ``index`` yielded frames."""
        return self._running and (self.max_frames is None or index < self.max_frames)

    def _accepts(self, guard: StreamGuard, timestamp: float, index: int, depth_image: np.ndarray) -> bool:
        """The guard's verdict on a frame; a dropped frame is counted in ``dropped_frames``."""
        if guard.accept(timestamp, index, depth_image.shape, "image size"):
            return True
        self.dropped_frames = guard.dropped
        return False

    def close(self) -> None:
        """Stop the pipeline. Safe to call twice."""
        if getattr(self, "_running", False):
            self._running = False
            self._pipeline.stop()


class RealSenseCamera(_LiveCamera):
    """An Intel RealSense camera (D400 series and similar) through ``pyrealsense2``.

    The pipeline starts on construction (intrinsics and depth scale are known from then on) and
    stops on :meth:`close`.

    Args:
        width, height, fps: stream size [px] and rate [1/s] for both colour and depth.
        serial: select a device by serial number; the first device when ``None``.
        timeout_ms: how long to wait for a frame before declaring the camera disconnected.
        max_frames: stop after this many frames (``None`` = until closed).
        timestamp_policy: ``"drop"`` (default) or ``"reject"``.

    Raises:
        CameraUnavailable: ``pyrealsense2`` missing, or no (matching) device attached.
    """

    def __init__(
        self,
        *,
        width: int = 640,
        height: int = 480,
        fps: int = 30,
        serial: str | None = None,
        timeout_ms: int = 5000,
        max_frames: int | None = None,
        timestamp_policy: str = "drop",
    ):
        rs = self._rs = self._open_sdk(
            "RealSense", "pyrealsense2", "realsense", timeout_ms, max_frames, timestamp_policy
        )
        devices = list(rs.context().query_devices())
        if not devices:
            raise CameraUnavailable("no RealSense device attached")
        if serial is not None:
            serials = [d.get_info(rs.camera_info.serial_number) for d in devices]
            if serial not in serials:
                raise CameraUnavailable(f"no RealSense device with serial {serial!r} (attached: {serials})")
        self._pipeline = rs.pipeline()
        config = rs.config()
        if serial is not None:
            config.enable_device(serial)
        config.enable_stream(rs.stream.depth, width, height, rs.format.z16, fps)
        config.enable_stream(rs.stream.color, width, height, rs.format.rgb8, fps)
        try:
            profile = self._pipeline.start(config)
        except RuntimeError as exc:
            raise CameraUnavailable(f"RealSense: could not start {width}×{height}@{fps} streams ({exc})") from None
        self._running = True
        self.depth_scale = float(profile.get_device().first_depth_sensor().get_depth_scale())
        """Metres per raw depth unit, from the device."""
        intr = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
        self.intrinsics = CameraIntrinsics(
            float(intr.fx), float(intr.fy), float(intr.ppx), float(intr.ppy), int(intr.width), int(intr.height)
        )
        self.fps = float(fps)
        self._align = rs.align(rs.stream.color)

    def frames(self) -> Iterator[RGBDFrame]:
        """Aligned colour + depth frames until ``max_frames`` or :meth:`close`.

        Raises:
            CameraDisconnected: no frame within ``timeout_ms`` (device unplugged or stalled).
        """
        guard = StreamGuard(self.timestamp_policy, self._name)
        index = 0
        while self._wants(index):
            try:
                frameset = self._pipeline.wait_for_frames(self.timeout_ms)
            except RuntimeError as exc:
                raise CameraDisconnected(f"RealSense: no frame after {index} frames ({exc})") from None
            aligned = self._align.process(frameset)
            depth = aligned.get_depth_frame()
            color = aligned.get_color_frame()
            if not depth or not color:
                continue
            timestamp = float(frameset.get_timestamp()) * 1e-3  # device clock, milliseconds
            depth_image = np.asanyarray(depth.get_data()).astype(np.uint16, copy=True)
            color_image = np.asanyarray(color.get_data()).astype(np.uint8, copy=True)
            if not self._accepts(guard, timestamp, index, depth_image):
                continue
            yield RGBDFrame(timestamp, color_image, depth_image, self.depth_scale, index)
            index += 1


class OrbbecCamera(_LiveCamera):
    """An Orbbec camera (Femto, Astra, Gemini series) through ``pyorbbecsdk`` (SDK v2 wheel).

    Args:
        width, height, fps: requested colour and depth profile; 0 lets the SDK choose.
        timeout_ms: per-frame wait; this many consecutive empty waits (``max_empty_waits``)
            mean the camera is gone.
        max_frames: stop after this many frames (``None`` = until closed).
        timestamp_policy: ``"drop"`` (default) or ``"reject"``.

    Raises:
        CameraUnavailable: ``pyorbbecsdk`` missing, or no device attached.
    """

    def __init__(
        self,
        *,
        width: int = 640,
        height: int = 480,
        fps: int = 30,
        timeout_ms: int = 1000,
        max_empty_waits: int = 5,
        max_frames: int | None = None,
        timestamp_policy: str = "drop",
    ):
        ob = self._ob = self._open_sdk("Orbbec", "pyorbbecsdk", "orbbec", timeout_ms, max_frames, timestamp_policy)
        self.max_empty_waits = int(max_empty_waits)
        if ob.Context().query_devices().get_count() < 1:
            raise CameraUnavailable("no Orbbec device attached")
        self._pipeline = ob.Pipeline()
        config = ob.Config()
        depth_profiles = self._pipeline.get_stream_profile_list(ob.OBSensorType.DEPTH_SENSOR)
        color_profiles = self._pipeline.get_stream_profile_list(ob.OBSensorType.COLOR_SENSOR)
        config.enable_stream(self._pick(depth_profiles, width, height, ob.OBFormat.Y16, fps))
        config.enable_stream(self._pick(color_profiles, width, height, ob.OBFormat.RGB, fps))
        try:
            self._pipeline.start(config)
        except Exception as exc:  # the SDK raises its own OBError
            raise CameraUnavailable(f"Orbbec: could not start streams ({exc})") from None
        self._running = True
        self._align = ob.AlignFilter(align_to_stream=ob.OBStreamType.COLOR_STREAM)
        intr = self._pipeline.get_camera_param().rgb_intrinsic
        self.intrinsics = CameraIntrinsics(
            float(intr.fx), float(intr.fy), float(intr.cx), float(intr.cy), int(intr.width), int(intr.height)
        )
        self.fps = float(fps) if fps else None

    def _pick(self, profiles, width, height, fmt, fps):
        try:
            return profiles.get_video_stream_profile(width, height, fmt, fps)
        except Exception:  # requested mode not offered: the device's default, if its format fits
            profile = profiles.get_default_video_stream_profile()
            if profile.get_format() != fmt:
                raise CameraUnavailable(
                    f"Orbbec: no {fmt} profile at {width}×{height}@{fps}, and the default is {profile.get_format()}"
                ) from None
            return profile

    def frames(self) -> Iterator[RGBDFrame]:
        """Aligned colour + depth frames until ``max_frames`` or :meth:`close`.

        Raises:
            CameraDisconnected: ``max_empty_waits`` consecutive waits without a frame set.
        """
        guard = StreamGuard(self.timestamp_policy, self._name)
        index = 0
        empty = 0
        while self._wants(index):
            frameset = self._pipeline.wait_for_frames(self.timeout_ms)
            if frameset is None:
                empty += 1
                if empty >= self.max_empty_waits:
                    raise CameraDisconnected(
                        f"Orbbec: no frames for {empty} × {self.timeout_ms} ms after {index} frames"
                    )
                continue
            empty = 0
            aligned = self._align.process(frameset)
            if aligned is None:
                continue
            aligned = aligned.as_frame_set()
            depth = aligned.get_depth_frame()
            color = aligned.get_color_frame()
            if depth is None or color is None:
                continue
            h, w = depth.get_height(), depth.get_width()
            depth_image = np.frombuffer(depth.get_data(), dtype=np.uint16).reshape(h, w).copy()
            ch, cw = color.get_height(), color.get_width()
            color_image = np.frombuffer(color.get_data(), dtype=np.uint8).reshape(ch, cw, 3).copy()
            depth_scale = float(depth.get_depth_scale()) * 1e-3  # SDK reports millimetres per unit
            timestamp = float(depth.get_timestamp_us()) * 1e-6  # device clock, microseconds
            if not self._accepts(guard, timestamp, index, depth_image):
                continue
            yield RGBDFrame(timestamp, color_image, depth_image, depth_scale, index)
            index += 1
