"""The solver's Levenberg–Marquardt iteration in NumPy: the reference of :mod:`.step_kernels`.

Same contract as :class:`.device_steps.DeviceSteps` (``run`` takes and returns the same arrays), so the
solver picks either (``device_steps=False``: this loop). Each iteration asks the data term for its
normal equations at every still-active frame, adds the regularisation of SPEC §6.1, holds the controls
pushed against a bound, solves the damped system on the free variables and tries the projected step,
growing the damping until E does not rise (at most 8 tries, then the frame counts as stationary).

The L1 term ``l1·Σ|u|`` has a kink at 0, which matters for the jaw's signed controls (a muscle's
contraction is ≥ 0, where ``|u| = u``). Each iteration works in one orthant (as OWL-QN does): a control
keeps the sign it has, and one at 0 takes the side its smooth gradient's descent points to — or stays
at 0 when ``|∂/∂u (E − l1·Σ|u|)| ≤ l1``. In that orthant the term is linear and 0 acts as a bound of
the iteration, so a control crosses 0 only by landing on it first; unused jaw slides stay exactly 0.
"""

from __future__ import annotations

import numpy as np

from .objective import DeviceObjective
from .pose import rotation_from_vector

__all__ = ["Iteration", "HostSteps", "MAX_TRIES", "BOUND_SLACK", "orthant", "damped_update"]

MAX_TRIES = 8
"""Rejected trials per iteration before a frame counts as stationary."""
BOUND_SLACK = 1e-12
"""A scaled control this close to a bound counts as at it."""


class Iteration:
    """What both iterations share: the data term and the solver's constants in scaled controls.

    Args:
        objective: the data term (targets bound per chunk by the caller).
        scale: (C,) control scale (``u = c·scale``); low, high: (C,) scaled bounds.
        pairs: (P, 2) mirrored control pairs; unit: the face unit ℓ [mesh units].
    """

    def __init__(
        self,
        objective: DeviceObjective,
        *,
        scale: np.ndarray,
        low: np.ndarray,
        high: np.ndarray,
        pairs: np.ndarray,
        unit: float,
    ):
        self.objective = objective
        self.scale = np.asarray(scale, dtype=np.float64)
        self.low, self.high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
        self.pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        self.unit = float(unit)
        self.column = np.full(objective.variable_count, 1.0 / self.unit)
        """Per variable: the data term's columns are mesh units per variable, ``× column`` makes them
        ``∂e/∂u`` (``e`` in face units)."""
        self.column[: len(self.scale)] = 1.0 / (self.scale * self.unit)

    @staticmethod
    def result(u, rotation, translation, misfit, converged, active, iterations) -> dict:
        """What :meth:`run` returns: host arrays by name (``converged``, ``active`` as bool)."""
        names = ("u", "rotation", "translation", "misfit", "converged", "active", "iterations")
        values = (u, rotation, translation, misfit, converged.astype(bool), active.astype(bool), iterations)
        return dict(zip(names, values))


class HostSteps(Iteration):
    """Runs the projected Levenberg–Marquardt loop of a :class:`DeviceObjective` with NumPy on the host
    (arguments: :class:`Iteration`)."""

    def run(self, u, rotation, translation, previous, active, damping, *, options, smooth: float) -> dict:
        """Iterate the bound chunk from ``u`` (F, C) scaled controls, ``rotation`` (F, 3, 3), ``translation``
        (F, 3) [face units], ``previous`` (F, C) temporal anchor, ``active`` (F,) bool, ``damping`` (F,).

        Returns ``u``, ``rotation``, ``translation``, ``misfit``, ``converged``, ``active``, ``iterations``.
        """
        u, rotation, translation = u.copy(), rotation.copy(), translation.copy()
        active, damping = active.copy(), np.asarray(damping, dtype=np.float64).copy()
        frames = len(u)
        low, high, n = self.low, self.high, len(self.scale)
        iterations = np.zeros(frames, dtype=np.int64)
        converged = np.zeros(frames, dtype=bool)
        current = np.full(frames, np.inf)
        misfit = np.zeros(frames)
        for _ in range(options.max_iterations):
            todo = np.flatnonzero(active)
            if len(todo) == 0:
                break
            iterations[todo] += 1
            hessian, gradient, data = self.system(u, rotation, translation, active, previous, options, smooth)
            hessian, gradient, misfit[todo] = hessian[todo], gradient[todo], data[todo]
            current[todo] = misfit[todo] + self.regularisation(u[todo], previous[todo], options, smooth)
            slope, lower, upper = orthant(u[todo], gradient[:, :n], low, high, options.l1)
            gradient[:, :n] += 0.5 * options.l1 * slope
            at_low = (u[todo] <= lower + BOUND_SLACK) & (gradient[:, :n] > 0.0)
            at_high = (u[todo] >= upper - BOUND_SLACK) & (gradient[:, :n] < 0.0)
            held = np.concatenate([at_low | at_high, np.zeros((len(todo), hessian.shape[1] - n), bool)], axis=1)
            projected = np.where(held, 0.0, gradient)
            small = np.abs(projected).max(axis=1) < 1e-14
            converged[todo[small]] = True
            active[todo[small]] = False
            pending = np.flatnonzero(~small)
            for _try in range(MAX_TRIES):
                if len(pending) == 0:
                    break
                frame = todo[pending]
                step = damped_update(hessian[pending], projected[pending], held[pending], damping[frame])
                if _try == 0:
                    # The quadratic model's predicted decrease; negligible → converged without a trial.
                    curvature = np.einsum("fi,fij,fj->f", step, hessian[pending], step)
                    predicted = -(np.einsum("fi,fi->f", projected[pending], step) + 0.5 * curvature)
                    negligible = predicted <= options.tolerance * current[frame] + options.energy_tolerance
                    converged[frame[negligible]] = True
                    active[frame[negligible]] = False
                    pending, step, frame = pending[~negligible], step[~negligible], frame[~negligible]
                    if len(pending) == 0:
                        break
                trial_u, trial_r, trial_t = u.copy(), rotation.copy(), translation.copy()
                trial_u[frame] = np.clip(u[frame] + step[:, :n], lower[pending], upper[pending])
                if step.shape[1] > n:
                    trial_r[frame] = rotation_from_vector(step[:, n : n + 3]) @ rotation[frame]
                    trial_t[frame] = translation[frame] + step[:, n + 3 :]
                on = np.zeros(frames, dtype=bool)
                on[frame] = True
                trial_misfit = self.objective.evaluate(trial_u / self.scale, trial_r, trial_t, on, jacobian=False)[0][
                    frame
                ]
                value = trial_misfit + self.regularisation(trial_u[frame], previous[frame], options, smooth)
                better = np.isfinite(value) & (value <= current[frame])
                accepted = frame[better]
                decrease = current[accepted] - value[better]
                moved = np.abs(trial_u[accepted] - u[accepted]).max(axis=1, initial=0.0)
                u[accepted], rotation[accepted], translation[accepted] = (
                    trial_u[accepted],
                    trial_r[accepted],
                    trial_t[accepted],
                )
                done = (decrease <= options.tolerance * current[accepted] + options.energy_tolerance) | (
                    moved < options.step_tolerance
                )
                converged[accepted[done]] = True
                active[accepted[done]] = False
                current[accepted], misfit[accepted] = value[better], trial_misfit[better]
                damping[accepted] = np.maximum(damping[accepted] / 10.0, 1e-9)
                damping[frame[~better]] *= 4.0
                pending = pending[~better]
            # No decrease even with heavy damping: at a (numerically) stationary point.
            stalled = todo[pending]
            converged[stalled] = True
            active[stalled] = False
        return self.result(u, rotation, translation, misfit, converged, active, iterations)

    def regularisation(self, u, previous, options, smooth):
        """``l2·|u|² + l1·Σ|u| + smooth·|u − u_prev|² + symmetry·Σ (u_l − u_r)²`` per frame, (F,)."""
        value = options.l2 * np.sum(u * u, axis=1) + options.l1 * np.sum(np.abs(u), axis=1)
        if smooth:
            value = value + smooth * np.sum((u - previous) ** 2, axis=1)
        if options.symmetry and len(self.pairs):
            diff = u[:, self.pairs[:, 0]] - u[:, self.pairs[:, 1]]
            value = value + options.symmetry * np.sum(diff * diff, axis=1)
        return value

    def system(self, u, rotation, translation, on, previous, options, smooth):
        """Gauss–Newton ``(H, g)`` of ½E without its L1 term (see :func:`orthant`) for every frame (zeros
        where ``on`` is False) and the data term: H (F, K, K), g (F, K), misfit (F,), K = C (+ 6 with pose)."""
        scale = self.scale
        misfit, hessian, gradient = self.objective.evaluate(u / scale, rotation, translation, on, jacobian=True)
        column = self.column
        hessian *= column[None, :, None] * column[None, None, :]
        gradient *= column[None]
        n = len(scale)
        diag = np.arange(n)
        hessian[:, diag, diag] += options.l2 + smooth
        gradient[:, :n] += options.l2 * u + smooth * (u - previous)
        if options.symmetry and len(self.pairs):
            left, right = self.pairs[:, 0], self.pairs[:, 1]
            diff = u[:, left] - u[:, right]
            gradient[:, left] += options.symmetry * diff
            gradient[:, right] -= options.symmetry * diff
            hessian[:, left, left] += options.symmetry
            hessian[:, right, right] += options.symmetry
            hessian[:, left, right] -= options.symmetry
            hessian[:, right, left] -= options.symmetry
        return hessian, gradient, misfit


def orthant(u, gradient, low, high, l1):
    """The orthant of this iteration (module docstring): ``(slope, lower, upper)``, each (F, C).

    ``slope`` is ∂|u|/∂u there (±1) and ``[lower, upper]`` the bounds narrowed to it; ``gradient`` is the
    smooth part's (½E without the L1 term). Without an L1 term (``l1 = 0``) the bounds stay as given.
    """
    descend_negative = gradient - 0.5 * l1 > 0.0
    slope = np.where(u > 0.0, 1.0, np.where(u < 0.0, -1.0, np.where(descend_negative, -1.0, 1.0)))
    if l1 <= 0.0:
        return slope, np.broadcast_to(low, u.shape), np.broadcast_to(high, u.shape)
    return slope, np.where(slope > 0.0, np.maximum(low, 0.0), low), np.where(slope < 0.0, np.minimum(high, 0.0), high)


def damped_update(hessian, gradient, held, damping):
    """Levenberg–Marquardt step ``(H + λ·diag(H)) s = −g`` on the free variables (held ones stay): (F, K)."""
    size = hessian.shape[1]
    free = ~held
    system = np.where(free[:, :, None] & free[:, None, :], hessian, 0.0)
    diagonal = np.einsum("fii->fi", hessian)
    scaled = damping[:, None] * np.maximum(diagonal, 1e-12 * np.maximum(diagonal.max(axis=1, keepdims=True), 1e-300))
    system[:, np.arange(size), np.arange(size)] = np.where(free, diagonal + scaled, 1.0)
    rhs = np.where(free, -gradient, 0.0)
    try:
        step = np.linalg.solve(system, rhs[..., None])[..., 0]
    except np.linalg.LinAlgError:
        step = rhs / np.where(free, diagonal + scaled, 1.0)
    return np.where(np.isfinite(step), step, 0.0)
