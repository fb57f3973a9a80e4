"""Landmarks recorded in an ``.npz`` file: read frame by frame, and written from any landmark stream."""

from __future__ import annotations

import math
import zipfile
from pathlib import Path
from typing import Iterable, Iterator, Sequence

import numpy as np

from .._validate import as_path, as_positive, expect_iterable
from ._io import atomic_path
from .frames import LandmarkFrame, SourceBase
from .streams import StreamGuard, checked_frames, estimate_fps, validate_landmark_names

__all__ = ["RecordedLandmarks"]


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
        self.path = as_path(path, "path")
        if not self.path.is_file():
            raise ValueError(f"{self.path}: no such landmark file")
        try:
            loaded = np.load(self.path, allow_pickle=False)
            if not hasattr(loaded, "files"):
                raise ValueError("a single array, not an .npz archive")
            with loaded as data:
                arrays = {k: data[k] for k in data.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise ValueError(
                f"{self.path}: not a readable .npz file ({str(exc).splitlines()[0][:120] or type(exc).__name__})"
            ) from None
        for key in ("timestamps", "points", "confidence", "names"):
            if key not in arrays:
                raise ValueError(f"{self.path}: missing array {key!r}")
        for key, ndim in (("timestamps", 1), ("points", 3), ("confidence", 2), ("names", 1)):
            if arrays[key].ndim != ndim:
                raise ValueError(
                    f"{self.path}: array {key!r} must have {ndim} dimension(s), got shape {arrays[key].shape}"
                )
        for key in ("timestamps", "points", "confidence"):
            if not (np.issubdtype(arrays[key].dtype, np.floating) or np.issubdtype(arrays[key].dtype, np.integer)):
                raise ValueError(f"{self.path}: array {key!r} must be numeric, got dtype {arrays[key].dtype}")
        self.timestamps = arrays["timestamps"].astype(np.float64)
        """Frame times [s], shape (F,), float64."""
        with np.errstate(over="ignore"):
            self.points = arrays["points"].astype(np.float64)
            """Landmark positions [m], shape (F, N, 3), float64 (NaN = missing)."""
            self.confidence = arrays["confidence"].astype(np.float32)
            """Confidences, shape (F, N), float32."""
        f = self.timestamps.shape[0]
        if self.points.shape[0] != f or self.points.shape[2] != 3:
            raise ValueError(
                f"{self.path}: expected timestamps (F,) and points (F, N, 3), got "
                f"{self.timestamps.shape} and {self.points.shape}"
            )
        if self.confidence.shape != self.points.shape[:2]:
            raise ValueError(f"{self.path}: confidence {self.confidence.shape} ≠ points {self.points.shape[:2]}")
        if not np.all(np.isfinite(self.timestamps)):
            raise ValueError(
                f"{self.path}: timestamp of frame {int(np.argmax(~np.isfinite(self.timestamps)))} is not finite"
            )
        self.landmark_names = validate_landmark_names(arrays["names"].tolist(), self.points.shape[1], str(self.path))
        fps = arrays["fps"] if "fps" in arrays else np.float64(np.nan)
        if fps.shape != () or not (np.issubdtype(fps.dtype, np.floating) or np.issubdtype(fps.dtype, np.integer)):
            raise ValueError(f"{self.path}: array 'fps' must be a number, got shape {fps.shape} dtype {fps.dtype}")
        fps = float(fps)
        self.fps = fps if math.isfinite(fps) and fps > 0 else estimate_fps(self.timestamps)
        self.timestamp_policy = timestamp_policy
        StreamGuard(timestamp_policy, str(self.path))  # validate the policy name now

    def __len__(self) -> int:
        return int(self.timestamps.shape[0])

    def frames(self) -> Iterator[LandmarkFrame]:
        """Frames in file order, through the timestamp policy."""
        raw = (LandmarkFrame(self.timestamps[i], self.points[i], self.confidence[i], i) for i in range(len(self)))
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
        path = as_path(path, "path")
        landmark_names = expect_iterable(landmark_names, "landmark_names", sized=True)
        frames = expect_iterable(frames, "frames")
        fps = None if fps is None else as_positive(fps, "fps", maximum=1e6)
        if len(landmark_names) == 0:
            raise ValueError(f"{path}: landmark_names: a recording needs at least one landmark")
        names = list(validate_landmark_names(landmark_names, len(landmark_names), str(path)))
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
