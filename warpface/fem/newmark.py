"""Newmark-β constants and the effective matrix of SPEC §2.

With ``β = 1/4, γ = 1/2`` (average acceleration) the step is exactly SPEC §2:
``A = K + 4/dt² M + 2/dt C`` and ``q_n = (4/dt² M + 2/dt C) d_n + (4/dt M + C) v_n + M a_n``.
For general ``β, γ`` the same structure holds with

    A   = K + c0 M + c3 C
    q_n = M (c0 d + c1 v + c2 a) + C (c3 d + c4 v + c5 a)
    a_{n+1} = c0 (d_{n+1} - d_n) - c1 v_n - c2 a_n
    v_{n+1} = v_n + c6 a_n + c7 a_{n+1}

(constants, by name, in :class:`NewmarkCoefficients`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "BETA_RANGE",
    "DT_RANGE",
    "GAMMA_RANGE",
    "NewmarkCoefficients",
    "check_step_dt",
    "step_key",
    "newmark_coefficients",
    "validate_newmark",
]

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
    for name, value, (low, high), unit in (
        ("time step dt", dt, DT_RANGE, " [s]"),
        ("Newmark beta", beta, BETA_RANGE, ""),
        ("Newmark gamma", gamma, GAMMA_RANGE, ""),
    ):
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


@dataclass(frozen=True)
class NewmarkCoefficients:
    """The constants of one Newmark-β step for time step ``dt`` (SPEC §2, module docstring), float64.

    The effective matrix is ``A = K + mass_displacement M + damping_displacement C``; the right-hand
    side ``q = M (mass_displacement d + mass_velocity v + mass_acceleration a) + C (damping_displacement d
    + damping_velocity v + damping_acceleration a)``; the update
    ``a' = mass_displacement (d' − d) − mass_velocity v − mass_acceleration a`` and
    ``v' = v + velocity_old_acceleration a + velocity_new_acceleration a'``; iterative solvers start
    from the predictor ``d + dt v + half_dt_squared a``.
    """

    mass_displacement: float
    """c0 = 1 / (β dt²) [1/s²]."""
    mass_velocity: float
    """c1 = 1 / (β dt) [1/s]."""
    mass_acceleration: float
    """c2 = 1 / (2β) − 1."""
    damping_displacement: float
    """c3 = γ / (β dt) [1/s]."""
    damping_velocity: float
    """c4 = γ / β − 1."""
    damping_acceleration: float
    """c5 = dt (γ / (2β) − 1) [s]."""
    velocity_old_acceleration: float
    """c6 = dt (1 − γ) [s]."""
    velocity_new_acceleration: float
    """c7 = dt γ [s]."""
    dt: float
    """Time step [s]."""
    half_dt_squared: float
    """dt² / 2 [s²]."""


def newmark_coefficients(dt: float, beta: float = 0.25, gamma: float = 0.5) -> NewmarkCoefficients:
    """The :class:`NewmarkCoefficients` of time step ``dt`` [s] and parameters ``beta``, ``gamma``.

    Raises:
        ValueError, TypeError: see :func:`validate_newmark`.
    """
    dt, beta, gamma = validate_newmark(dt, beta, gamma)
    return NewmarkCoefficients(
        mass_displacement=1.0 / (beta * dt * dt),
        mass_velocity=1.0 / (beta * dt),
        mass_acceleration=1.0 / (2.0 * beta) - 1.0,
        damping_displacement=gamma / (beta * dt),
        damping_velocity=gamma / beta - 1.0,
        damping_acceleration=dt * (gamma / (2.0 * beta) - 1.0),
        velocity_old_acceleration=dt * (1.0 - gamma),
        velocity_new_acceleration=dt * gamma,
        dt=dt,
        half_dt_squared=0.5 * dt * dt,
    )


def step_key(state_in, state_out, control) -> tuple:
    """The array addresses of a solver step's ``(state_in, state_out, control)``, which key its cached binding;
    TypeError unless they are a TissueState, a TissueState and a TissueControl."""
    try:
        return state_in.d.ptr, state_out.d.ptr, control.driven.ptr
    except AttributeError:
        raise TypeError(
            "step(state_in, state_out, control): expected TissueState, TissueState, TissueControl, got "
            f"{type(state_in).__name__}, {type(state_out).__name__}, {type(control).__name__}"
        ) from None


def check_step_dt(dt, coefficients: NewmarkCoefficients) -> None:
    """Raise ValueError unless ``dt`` (a solver step's argument) is None or the time step the solver was built for:
    its factorisation or operators hold ``dt``, so another one needs a new solver."""
    if dt is not None and dt != coefficients.dt:
        raise ValueError(
            f"dt must be the solver's time step {coefficients.dt:g} s (its operators are built for it), got {dt!r}; "
            "build a new solver for another dt"
        )
