"""Stream rules shared by every source: the timestamp policy, a fixed landmark count or image size,
and filling in missing landmarks.

**Timestamp policy** (``timestamp_policy``): timestamps are seconds and must increase strictly.
``"reject"`` raises ValueError at the first frame whose timestamp is not greater than the previous
one (naming both); ``"drop"`` skips such frames (a duplicate delivered twice, a clock step back)
and counts them in ``dropped_frames``. Files default to ``"reject"`` (a file that goes back in time
is damaged); live cameras default to ``"drop"``.

**Landmark count**: fixed for a stream; a frame with a different count raises ValueError naming the
frame and both counts.
"""

from __future__ import annotations

from collections import deque
from typing import Iterable, Iterator, Sequence

import numpy as np

from .._validate import as_count, expect_iterable
from .frames import LandmarkFrame

__all__ = [
    "TIMESTAMP_POLICIES",
    "StreamGuard",
    "checked_frames",
    "fill_missing",
    "estimate_fps",
    "validate_landmark_names",
]

TIMESTAMP_POLICIES = ("reject", "drop")
"""Accepted values of ``timestamp_policy``; see the module docstring."""


class StreamGuard:
    """Applies the timestamp policy and the fixed landmark/image size to a stream of frames."""

    def __init__(self, policy: str, where: str):
        if not isinstance(policy, str):
            raise TypeError(f"timestamp_policy: expected one of {TIMESTAMP_POLICIES}, got {type(policy).__name__}")
        if policy not in TIMESTAMP_POLICIES:
            raise ValueError(f"timestamp_policy: expected one of {TIMESTAMP_POLICIES}, got {policy[:40]!r}")
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
    frames: Iterable[LandmarkFrame],
    *,
    landmark_count: int | None = None,
    timestamp_policy: str = "reject",
    where: str = "landmark stream",
) -> Iterator[LandmarkFrame]:
    """Pass frames through the timestamp policy and the fixed landmark count (see module docstring).

    Args:
        frames: any iterable of :class:`LandmarkFrame`.
        landmark_count: expected N; taken from the first frame when ``None``.
        timestamp_policy: ``"reject"`` or ``"drop"``.
        where: name used in error messages.
    """
    guard = StreamGuard(timestamp_policy, where)
    if landmark_count is not None:
        guard.shape = (as_count(landmark_count, "landmark_count"),)
    for frame in expect_iterable(frames, where, item_types=LandmarkFrame):
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
    max_lookahead = as_count(max_lookahead, "max_lookahead", minimum=1)
    frames = expect_iterable(frames, "frames", item_types=LandmarkFrame)
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
                raise ValueError(
                    f"landmark {int(np.flatnonzero(~have)[0])} not measured in the first {len(buffer)} frames"
                )
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


def estimate_fps(timestamps: np.ndarray) -> float | None:
    if timestamps.shape[0] < 2:
        return None
    step = float(np.median(np.diff(timestamps)))
    return 1.0 / step if step > 0 else None


def validate_landmark_names(names, count: int, where: str) -> tuple[str, ...]:
    """``names`` as a tuple of ``count`` unique strings; ValueError naming ``where`` otherwise."""
    if isinstance(names, (str, bytes)) or not hasattr(names, "__iter__"):
        raise TypeError(f"{where}: expected a sequence of landmark names, got {type(names).__name__}")
    names = tuple(str(n) for n in names)
    if len(names) != count:
        raise ValueError(f"{where}: {len(names)} landmark names for {count} landmarks")
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise ValueError(f"{where}: landmark name {dup!r} appears more than once")
    return names
