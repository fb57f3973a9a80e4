"""Newmark-β constants and the effective matrix of SPEC §2.

With ``β = 1/4, γ = 1/2`` (average acceleration) the step is exactly SPEC §2:
``A = K + 4/dt² M + 2/dt C`` and ``q_n = (4/dt² M + 2/dt C) d_n + (4/dt M + C) v_n + M a_n``.
For general ``β, γ`` the same structure holds with

    A   = K + c0 M + c3 C
    q_n = M (c0 d + c1 v + c2 a) + C (c3 d + c4 v + c5 a)
    a_{n+1} = c0 (d_{n+1} - d_n) - c1 v_n - c2 a_n
    v_{n+1} = v_n + c6 a_n + c7 a_{n+1}

(constants in :func:`newmark_coefficients`).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["BETA_RANGE", "DT_RANGE", "GAMMA_RANGE", "newmark_coefficients", "validate_newmark"]

DT_RANGE = (1.0e-8, 10.0)
"""Accepted time steps [s]. Below 1e-8 s the mass term ``c0 M = M / (β dt²)`` swamps the stiffness
by more than float64 can resolve (at 1e-160 s it overflows); above 10 s a tissue step is no longer
dynamics (use a static solve)."""

BETA_RANGE = (0.01, 1.0)
"""Accepted Newmark β. β = 0 (explicit) is not supported: the step divides by β; β = 1/4 is the
average-acceleration rule, β = 1/6 linear acceleration."""

GAMMA_RANGE = (0.5, 1.0)
"""Accepted Newmark γ. γ < 1/2 amplifies every mode step by step (negative numerical damping);
γ > 1/2 adds numerical damping, γ = 1 the most that is still first-order accurate."""


def validate_newmark(dt: float, beta: float, gamma: float) -> tuple[float, float, float]:
    """Check and convert the time step [s] and Newmark parameters; returns them as floats.

    Raises:
        ValueError: a value is not a finite number or lies outside :data:`DT_RANGE`,
            :data:`BETA_RANGE` or :data:`GAMMA_RANGE` (naming the parameter and its interval).
    """
    values = []
    for name, value, (low, high), unit in (("time step dt", dt, DT_RANGE, " [s]"),
                                           ("Newmark beta", beta, BETA_RANGE, ""),
                                           ("Newmark gamma", gamma, GAMMA_RANGE, "")):
        if isinstance(value, (bool, np.bool_)):
            raise TypeError(f"{name} must be a number, got {value!r}")
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise TypeError(f"{name} must be a number, got {type(value).__name__}") from None
        if not (math.isfinite(number) and low <= number <= high):
            raise ValueError(f"{name} must be in [{low:g}, {high:g}]{unit}, got {number!r}")
        values.append(number)
    return values[0], values[1], values[2]


def newmark_coefficients(dt: float, beta: float = 0.25, gamma: float = 0.5) -> np.ndarray:
    """Newmark constants ``[c0, c1, c2, c3, c4, c5, c6, c7, dt, dt²/2]``, shape (10,), float64.

    ``c0 = 1/(β dt²)``, ``c1 = 1/(β dt)``, ``c2 = 1/(2β) − 1``, ``c3 = γ/(β dt)``, ``c4 = γ/β − 1``,
    ``c5 = dt (γ/(2β) − 1)``, ``c6 = dt (1 − γ)``, ``c7 = dt γ``; the last two give the warm start
    ``d + dt v + dt²/2 a`` of iterative solvers.
    """
    dt, beta, gamma = validate_newmark(dt, beta, gamma)
    return np.array(
        [
            1.0 / (beta * dt * dt),
            1.0 / (beta * dt),
            1.0 / (2.0 * beta) - 1.0,
            gamma / (beta * dt),
            gamma / beta - 1.0,
            dt * (gamma / (2.0 * beta) - 1.0),
            dt * (1.0 - gamma),
            dt * gamma,
            dt,
            0.5 * dt * dt,
        ],
        dtype=np.float64,
    )
