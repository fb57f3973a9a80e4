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

__all__ = ["newmark_coefficients", "validate_newmark"]


def validate_newmark(dt: float, beta: float, gamma: float) -> tuple[float, float, float]:
    """Check and convert the step size [s] and Newmark parameters; returns them as floats.

    Raises:
        ValueError: ``dt <= 0`` or not finite, ``beta <= 0`` (explicit schemes are not supported:
            the step divides by β) or ``gamma <= 0``.
    """
    try:
        dt, beta, gamma = float(dt), float(beta), float(gamma)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"dt, beta and gamma must be numbers: {exc}") from None
    if not (math.isfinite(dt) and dt > 0.0):
        raise ValueError(f"time step dt must be a finite number > 0 [s], got {dt}")
    if not (math.isfinite(beta) and beta > 0.0):
        raise ValueError(f"Newmark beta must be > 0 (implicit schemes only), got {beta}")
    if not (math.isfinite(gamma) and gamma > 0.0):
        raise ValueError(f"Newmark gamma must be > 0, got {gamma}")
    return dt, beta, gamma


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
