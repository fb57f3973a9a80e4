"""Temporal smoothing of landmark tracks: the one-euro filter (Casiez, Roussel & Vogel, CHI 2012).

Per coordinate, an exponential low-pass whose cut-off frequency rises with the speed of the signal:

    f_c = min_cutoff + beta · |ẋ̂|,   α(f) = 1 / (1 + 1 / (2π f Δt)),   x̂_k = α(f_c) x_k + (1 − α(f_c)) x̂_(k−1)

where ``ẋ̂`` is the derivative ``(x_k − x̂_(k−1)) / Δt`` low-passed at ``d_cutoff``. A still face is smoothed
strongly (jitter removed), a moving one lightly (little lag). Missing values (NaN) pass through as NaN and
leave the state as it was; a gap longer than ``reset_after`` seconds restarts the filter.
"""

from __future__ import annotations

import math

import numpy as np

from .._validate import as_positive

__all__ = ["OneEuroFilter"]


class OneEuroFilter:
    """One-euro filter over arrays of any fixed shape (see the module docstring).

    Args:
        min_cutoff: cut-off frequency of a still signal [Hz].
        beta: cut-off growth per unit speed [1/(units)] (pixels: per px/s).
        d_cutoff: cut-off of the speed estimate [Hz].
        reset_after: restart after a gap longer than this [s].
    """

    def __init__(self, *, min_cutoff: float = 1.5, beta: float = 0.05, d_cutoff: float = 1.0, reset_after=0.5):
        self.min_cutoff = as_positive(min_cutoff, "min_cutoff")
        self.beta = as_positive(beta, "beta", allow_zero=True)
        self.d_cutoff = as_positive(d_cutoff, "d_cutoff")
        self.reset_after = as_positive(reset_after, "reset_after")
        self.reset()

    def reset(self) -> None:
        """Forget the past."""
        self._value: np.ndarray | None = None
        self._speed: np.ndarray | None = None
        self._time: float | None = None

    @staticmethod
    def _alpha(cutoff, dt: float):
        return 1.0 / (1.0 + 1.0 / (2.0 * math.pi * cutoff * dt))

    def __call__(self, value, timestamp: float) -> np.ndarray:
        """The filtered ``value`` (float64 array) at ``timestamp`` [s]; NaN entries stay NaN."""
        x = np.array(value, dtype=np.float64)
        t = float(timestamp)
        if self._value is None or self._value.shape != x.shape or self._time is None:
            fresh = True
        else:
            dt = t - self._time
            fresh = not (0.0 < dt <= self.reset_after)
        if fresh:
            self._value, self._speed, self._time = x.copy(), np.zeros_like(x), t
            return x
        seen = np.isfinite(x)
        unset = seen & ~np.isfinite(self._value)
        self._value[unset], self._speed[unset] = x[unset], 0.0
        speed = (x - self._value) / dt
        a_d = self._alpha(self.d_cutoff, dt)
        speed = np.where(seen, a_d * speed + (1.0 - a_d) * self._speed, self._speed)
        a = self._alpha(self.min_cutoff + self.beta * np.abs(speed), dt)
        smoothed = np.where(seen, a * x + (1.0 - a) * self._value, self._value)
        self._value, self._speed, self._time = smoothed, speed, t
        return np.where(seen, smoothed, np.nan)
