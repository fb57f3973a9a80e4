"""Named animation channels over time: the common form every driver format is read into.

Canonical channel names are ARKit's lowerCamel blendshape names (``browInnerUp``, ``mouthSmileLeft``;
``Left``/``Right`` are the subject's side) and FACS action units as ``AU01`` … ``AU46``. ARKit
weights live in [0, 1], action-unit intensities in [0, 5] (OpenFace's ``_r`` scale).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from .._validate import as_positive, expect_instance, expect_iterable

__all__ = [
    "ARKIT_CHANNELS",
    "AU_RANGE",
    "ARKIT_RANGE",
    "Curves",
    "canonical_channel",
    "channel_range",
]

ARKIT_CHANNELS: tuple[str, ...] = (
    "browDownLeft",
    "browDownRight",
    "browInnerUp",
    "browOuterUpLeft",
    "browOuterUpRight",
    "cheekPuff",
    "cheekSquintLeft",
    "cheekSquintRight",
    "eyeBlinkLeft",
    "eyeBlinkRight",
    "eyeLookDownLeft",
    "eyeLookDownRight",
    "eyeLookInLeft",
    "eyeLookInRight",
    "eyeLookOutLeft",
    "eyeLookOutRight",
    "eyeLookUpLeft",
    "eyeLookUpRight",
    "eyeSquintLeft",
    "eyeSquintRight",
    "eyeWideLeft",
    "eyeWideRight",
    "jawForward",
    "jawLeft",
    "jawOpen",
    "jawRight",
    "mouthClose",
    "mouthDimpleLeft",
    "mouthDimpleRight",
    "mouthFrownLeft",
    "mouthFrownRight",
    "mouthFunnel",
    "mouthLeft",
    "mouthLowerDownLeft",
    "mouthLowerDownRight",
    "mouthPressLeft",
    "mouthPressRight",
    "mouthPucker",
    "mouthRight",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthShrugLower",
    "mouthShrugUpper",
    "mouthSmileLeft",
    "mouthSmileRight",
    "mouthStretchLeft",
    "mouthStretchRight",
    "mouthUpperUpLeft",
    "mouthUpperUpRight",
    "noseSneerLeft",
    "noseSneerRight",
    "tongueOut",
)
"""ARKit's 52 blendshape channels (``ARFaceAnchor.BlendShapeLocation``), alphabetical as MediaPipe lists them."""

ARKIT_RANGE = (0.0, 1.0)
AU_RANGE = (0.0, 5.0)

_ARKIT_BY_LOWER = {name.lower(): name for name in ARKIT_CHANNELS}
_AU = re.compile(r"^\s*AU_?0*(\d{1,2})(?:_r)?\s*$", re.IGNORECASE)


def canonical_channel(name: str) -> str:
    """The canonical spelling of a channel name.

    ARKit names in any capitalisation (Live Link Face's ``BrowInnerUp``) become lowerCamel
    (``browInnerUp``); action units (``AU1``, ``AU01_r``, ``au_12``) become ``AU01``; other names are
    returned stripped and unchanged.
    """
    expect_instance(name, str, "channel name")
    stripped = name.strip()
    arkit = _ARKIT_BY_LOWER.get(stripped.lower())
    if arkit is not None:
        return arkit
    match = _AU.match(stripped)
    if match:
        return f"AU{int(match.group(1)):02d}"
    return stripped


def channel_range(name: str) -> tuple[float, float]:
    """The valid value range of a canonical channel: [0, 5] for action units, [0, 1] otherwise."""
    expect_instance(name, str, "channel name")
    return AU_RANGE if _AU.match(name) else ARKIT_RANGE


MAX_CHANNEL_VALUE = 1.0e6
"""Largest accepted |channel value| (weights are 0–1, action units 0–5; larger is a corrupt file)."""


@dataclass(frozen=True)
class Curves:
    """Channels sampled at timestamps.

    Attributes:
        times: timestamps [s], shape (F,), float64, finite and strictly increasing.
        names: canonical channel names, C of them, unique.
        values: channel values, shape (F, C), float64, finite.
        source: where the curves came from (a file name), for messages.
        fps: the recording's nominal frame rate [frames/s] when the format states one, else ``None``.
    """

    times: np.ndarray
    names: list[str]
    values: np.ndarray
    source: str = "curves"
    fps: float | None = None
    notes: list[str] = field(default_factory=list)
    """One line per thing the reader dropped or changed (unknown columns, untracked frames)."""

    def __post_init__(self) -> None:
        label = self.source
        try:
            times = np.asarray(self.times, dtype=np.float64)
            values = np.asarray(self.values, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{label}: times and values must be regular arrays of numbers") from None
        names = [str(n) for n in expect_iterable(self.names, f"{label}: names", item_types=str)]
        if times.ndim != 1 or len(times) == 0:
            raise ValueError(f"{label}: no frames")
        if values.shape != (len(times), len(names)):
            raise ValueError(f"{label}: values have shape {values.shape}, expected ({len(times)}, {len(names)})")
        if len(set(names)) != len(names):
            duplicate = next(n for n in names if names.count(n) > 1)
            raise ValueError(f"{label}: channel {duplicate!r} appears twice")
        bad_time = np.flatnonzero(~np.isfinite(times))
        if len(bad_time):
            raise ValueError(f"{label}: timestamp of frame {int(bad_time[0])} is not a number")
        steps = np.diff(times)
        if np.any(steps <= 0.0):
            frame = int(np.flatnonzero(steps <= 0.0)[0]) + 1
            kind = "repeats" if steps[frame - 1] == 0.0 else "goes backwards"
            raise ValueError(
                f"{label}: timestamp {times[frame]:g} s of frame {frame} {kind} (timestamps must increase)"
            )
        bad = np.argwhere(~np.isfinite(values))
        if len(bad):
            frame, column = (int(i) for i in bad[0])
            raise ValueError(
                f"{label}: channel {names[column]!r} is not a number at frame {frame} (t = {times[frame]:g} s)"
            )
        far = np.abs(values) > MAX_CHANNEL_VALUE
        if np.any(far):
            frame, column = (int(i) for i in np.argwhere(far)[0])
            raise ValueError(
                f"{label}: channel {names[column]!r} value {values[frame, column]:.6g} at frame {frame} is outside "
                f"±{MAX_CHANNEL_VALUE:g}"
            )
        if self.fps is not None:
            object.__setattr__(self, "fps", as_positive(self.fps, f"{label}: frame rate", maximum=1e6))
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "names", names)

    @property
    def frame_count(self) -> int:
        return len(self.times)

    def channel(self, name: str) -> np.ndarray:
        """The values of one channel, shape (F,)."""
        try:
            return self.values[:, self.names.index(name)]
        except ValueError:
            raise ValueError(f"{self.source}: no channel {name!r}") from None

    def as_dict(self) -> dict[str, np.ndarray]:
        """``{name: (F,) values}``."""
        return {name: self.values[:, k] for k, name in enumerate(self.names)}

    def replace(self, **changes) -> "Curves":
        """A copy with some fields changed (validated again)."""
        fields = dict(
            times=self.times,
            names=self.names,
            values=self.values,
            source=self.source,
            fps=self.fps,
            notes=list(self.notes),
        )
        fields.update(changes)
        return Curves(**fields)
