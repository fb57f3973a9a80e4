"""Cleaning curves before they drive a rig: neutral calibration, gain/offset, clamping, filtering, resampling.

:func:`clean` applies, in this order:

1. **Neutral calibration**: the performer's rest values ``n`` (the mean over a neutral segment, one
   frame, or given values) are removed and the range above them stretched back to full:
   ``s' = max(s − n, 0) · hi / (hi − n)`` (``hi`` = the channel's top, 1 or 5), so a channel that
   idles at 0.2 reads 0 at rest and still reaches 1.
2. **Gain and offset** per channel: ``s' = gain · s + offset``.
3. **Clamping** to the channel's range ([0, 1] for ARKit, [0, 5] for action units); every clamped
   channel is reported once in ``Curves.notes`` with its count and extreme value.
4. **1€ filter** (Casiez, Roussel & Vogel, CHI 2012), optional: a low-pass filter whose cut-off rises
   with speed, ``f_c = f_min + β·|ṡ|``, so slow drift (jitter) is smoothed while fast motion keeps
   little lag. Each step is exponential smoothing ``ŝ_i = α s_i + (1 − α) ŝ_{i−1}`` with
   ``α = 1 / (1 + τ/Δt)``, ``τ = 1/(2π f_c)``, and the speed ``ṡ`` is itself smoothed at
   ``f_d`` (1 Hz). Being a convex combination, it keeps values inside the clamped range.
5. **Resampling** to a uniform rate (linear interpolation), times ``t0 + k/fps``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._validate import as_finite_array, as_positive, expect_instance
from .channels import Curves, channel_range

__all__ = [
    "OneEuroFilter",
    "neutral_values",
    "calibrate_neutral",
    "apply_gain_offset",
    "clamp_to_range",
    "resample",
    "clean",
]


@dataclass(frozen=True)
class OneEuroFilter:
    """Parameters of the 1€ filter.

    Attributes:
        min_cutoff: ``f_min`` [Hz], the cut-off at rest (lower = smoother, more lag when slow).
        beta: speed coefficient [1/(channel unit)] (higher = less lag when fast).
        derivative_cutoff: ``f_d`` [Hz], the cut-off of the speed estimate.
    """

    min_cutoff: float = 1.5
    beta: float = 0.5
    derivative_cutoff: float = 1.0

    def __post_init__(self) -> None:
        for name in ("min_cutoff", "beta", "derivative_cutoff"):
            value = getattr(self, name)
            if (
                not isinstance(value, (int, float))
                or not math.isfinite(value)
                or value < 0
                or (value == 0 and name != "beta")
            ):
                raise ValueError(
                    f"1€ filter: {name} must be a {'non-negative' if name == 'beta' else 'positive'} number, got "
                    f"{value!r}"
                )

    def __call__(self, times: np.ndarray, values: np.ndarray) -> np.ndarray:
        """Filter ``values`` (F, C) sampled at ``times`` (F,) [s]; returns a new (F, C) array."""
        values = np.asarray(values, dtype=np.float64)
        out = np.empty_like(values)
        if len(values) == 0:
            return out
        out[0] = values[0]
        speed = np.zeros(values.shape[1])
        steps = np.diff(times)

        def alpha(cutoff, dt):
            return 1.0 / (1.0 + 1.0 / (2.0 * math.pi * cutoff * dt))

        for i in range(1, len(values)):  # recursive: each frame needs the previous estimate
            dt = steps[i - 1]
            raw_speed = (values[i] - out[i - 1]) / dt
            a_d = alpha(self.derivative_cutoff, dt)
            speed = a_d * raw_speed + (1.0 - a_d) * speed
            a = alpha(self.min_cutoff + self.beta * np.abs(speed), dt)
            out[i] = a * values[i] + (1.0 - a) * out[i - 1]
        return out


MAX_RESAMPLED_FRAMES = 10_000_000
"""Most frames :func:`resample` makes (over 3 days at 30 fps)."""


def neutral_values(curves: Curves, neutral) -> np.ndarray:
    """Per-channel rest values (C,) from ``neutral``: a frame index (int), a segment ``(t0, t1)`` [s]
    whose frames are averaged, or ``{channel: value}`` (others 0).

    Raises:
        ValueError: frame out of range, a segment with no frame, unknown channel names, non-finite values.
    """
    if isinstance(neutral, dict):
        unknown = [k for k in neutral if k not in curves.names]
        if unknown:
            raise ValueError(f"neutral: unknown channel {unknown[0]!r} (channels: {', '.join(curves.names[:6])}, …)")
        rest = np.zeros(len(curves.names))
        for name, value in neutral.items():
            number = float(as_finite_array(value, f"neutral[{name!r}]", shape=()))
            if not math.isfinite(number):
                raise ValueError(f"neutral: value of {name!r} is not a finite number")
            rest[curves.names.index(name)] = number
        return rest
    if isinstance(neutral, (int, np.integer)) and not isinstance(neutral, bool):
        if not -curves.frame_count <= int(neutral) < curves.frame_count:
            raise ValueError(
                f"neutral frame {int(neutral)} is outside the {curves.frame_count} frames of {curves.source}"
            )
        return curves.values[int(neutral)].copy()
    try:
        start, end = (float(t) for t in neutral)
    except (TypeError, ValueError) as exc:
        raise type(exc)(
            "neutral: expected a frame index, a (start, end) segment in seconds or {channel: value}, "
            f"got {type(neutral).__name__}"
        ) from None
    inside = (curves.times >= start) & (curves.times <= end)
    if not inside.any():
        raise ValueError(
            f"neutral segment [{start:g}, {end:g}] s contains no frame of {curves.source} "
            f"({curves.times[0]:g}–{curves.times[-1]:g} s)"
        )
    return curves.values[inside].mean(axis=0)


def calibrate_neutral(curves: Curves, neutral) -> Curves:
    """Remove the rest values of :func:`neutral_values` and stretch the rest of the range back to full."""
    expect_instance(curves, Curves, "curves")
    rest = neutral_values(curves, neutral)
    tops = np.array([channel_range(n)[1] for n in curves.names])
    headroom = np.maximum(tops - rest, 1e-6 * tops)
    values = np.maximum(curves.values - rest, 0.0) * (tops / headroom)
    return curves.replace(values=values)


def apply_gain_offset(
    curves: Curves, gain: dict[str, float] | None = None, offset: dict[str, float] | None = None
) -> Curves:
    """``s' = gain · s + offset`` per named channel (others unchanged).

    Raises:
        ValueError: a name not among the channels, a non-finite number.
    """
    values = curves.values.copy()
    for label, table, apply in (("gain", gain, np.multiply), ("offset", offset, np.add)):
        if table is not None and not isinstance(table, dict):
            raise TypeError(f"{label}: expected {{channel: number}}, got {type(table).__name__}")
        for name, number in (table or {}).items():
            if name not in curves.names:
                raise ValueError(f"{label}: {curves.source} has no channel {name!r}")
            number = float(as_finite_array(number, f"{label}[{name!r}]", shape=()))
            if not math.isfinite(number):
                raise ValueError(f"{label} of {name!r}: not a finite number")
            column = curves.names.index(name)
            values[:, column] = apply(values[:, column], number)
    return curves.replace(values=values)


def clamp_to_range(curves: Curves) -> Curves:
    """Values clamped to each channel's range; one note per clamped channel (count, extreme value)."""
    expect_instance(curves, Curves, "curves")
    ranges = np.array([channel_range(n) for n in curves.names]).reshape(-1, 2)
    low, high = ranges[:, 0], ranges[:, 1]
    below, above = curves.values < low, curves.values > high
    notes = list(curves.notes)
    for column in np.flatnonzero(below.any(axis=0) | above.any(axis=0)):
        bad = below[:, column] | above[:, column]
        worst = curves.values[bad, column][
            np.argmax(np.abs(curves.values[bad, column] - 0.5 * (low[column] + high[column])))
        ]
        notes.append(
            f"{curves.source}: {curves.names[column]}: {int(bad.sum())} values outside "
            f"[{low[column]:g}, {high[column]:g}] clamped (extreme {worst:.4g})"
        )
    return curves.replace(values=np.clip(curves.values, low, high), notes=notes)


def resample(curves: Curves, fps: float) -> Curves:
    """Curves at ``t0 + k/fps`` for every k up to the last timestamp (linear interpolation); ``fps`` set."""
    expect_instance(curves, Curves, "curves")
    fps = as_positive(fps, "fps", maximum=1e4)
    start, end = curves.times[0], curves.times[-1]
    count = int(math.floor((end - start) * fps + 1e-9)) + 1
    if count > MAX_RESAMPLED_FRAMES:
        raise ValueError(
            f"fps: resampling {end - start:g} s at {fps:g} fps gives {count} frames, more than {MAX_RESAMPLED_FRAMES}"
        )
    times = start + np.arange(count) / fps
    values = np.empty((count, len(curves.names)))
    for column in range(len(curves.names)):
        values[:, column] = np.interp(times, curves.times, curves.values[:, column])
    return curves.replace(times=times, values=values, fps=fps)


def clean(
    curves: Curves,
    *,
    neutral=None,
    gain=None,
    offset=None,
    clamp: bool = True,
    filter: OneEuroFilter | None = None,
    fps: float | None = None,
) -> Curves:
    """The clean-up steps of the module notes, in order; each is skipped when its argument is None/False."""
    expect_instance(curves, Curves, "curves")
    if neutral is not None:
        curves = calibrate_neutral(curves, neutral)
    if gain or offset:
        curves = apply_gain_offset(curves, gain, offset)
    if clamp:
        curves = clamp_to_range(curves)
    if filter is not None:
        expect_instance(filter, OneEuroFilter, "filter")
        curves = curves.replace(values=filter(curves.times, curves.values))
    if fps is not None:
        curves = resample(curves, fps)
    return curves
