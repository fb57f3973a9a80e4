"""An RGB-D recording on disk (colour and depth PNGs plus ``meta.json``): read and written."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from .._validate import as_path
from ._io import atomic_path, write_json_atomic
from .frames import RGBDFrame, SourceBase
from .intrinsics import CameraIntrinsics
from .streams import StreamGuard, estimate_fps

__all__ = ["RGBDFolder"]


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
        self.path = as_path(path, "path")
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
        self.fps = float(fps) if isinstance(fps, (int, float)) and fps > 0 else estimate_fps(self.timestamps)
        self.fiducials = meta.get("fiducials")
        """Optional fiducial layout stored with the recording (e.g. initial dot pixels), or None."""
        self.timestamp_policy = timestamp_policy
        StreamGuard(timestamp_policy, str(self.path))

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
        guard = StreamGuard(self.timestamp_policy, str(self.path))
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
        path = as_path(path, "path")
        (path / "color").mkdir(parents=True, exist_ok=True)
        (path / "depth").mkdir(parents=True, exist_ok=True)
        guard = StreamGuard("reject", str(path))
        stamps: list[float] = []
        scale: float | None = None
        failure: BaseException | None = None
        try:
            for frame in frames:
                guard.accept(frame.timestamp, frame.index, frame.depth.shape, "image size")
                if frame.depth.shape != (intrinsics.height, intrinsics.width):
                    raise ValueError(
                        f"{path}: frame {frame.index} is {frame.depth.shape[::-1]} px, intrinsics "
                        f"say {intrinsics.width}×{intrinsics.height}"
                    )
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
