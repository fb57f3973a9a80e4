"""Alternating Gauss–Newton over the geometry parameters, the controls refitted for every trial (docs/RIG.md §13)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..assets.calibrated import EVERY_MUSCLE, Parameter, apply_parameters, parameter_layout
from ..rig import FaceRig
from .jacobian import jacobian, residual_layout, residuals
from .reach import moved_vertices, reach

__all__ = ["Trial", "Optimisation", "optimise", "active_muscles"]


@dataclass
class Trial:
    """One refitted evaluation: the data term (mean over examples of mean|x − T|²/before²), the prior term,
    the mean reach, λ and the seconds since the start."""

    data: float
    prior: float
    mean_reduction: float
    damping: float
    accepted: bool
    seconds: float


@dataclass
class Optimisation:
    """The result of :func:`optimise`: ``parameters`` and their ``theta``, the refitted reach of the training
    examples at the start and at the end, and every trial."""

    parameters: list[Parameter]
    theta: np.ndarray
    start: list
    end: list
    trials: list[Trial] = field(default_factory=list)

    @property
    def values(self) -> dict:
        return {p.key: float(v) for p, v in zip(self.parameters, self.theta) if v != 0.0}


def active_muscles(rig: FaceRig, rows, *, fraction: float = 0.01) -> list[str]:
    """Muscles that some example uses: |c| above ``fraction`` of the control's largest use over the examples,
    and that largest use itself above ``fraction`` of the largest over all muscles (after scaling each control
    by the skin motion it makes: lengths for linear muscles, the face's size for sphincters)."""
    names = rig.muscle_names
    controls = np.abs(np.array([row["controls"][: len(names)] for row in rows]))
    kinds = np.array([hasattr(m, "attachment") for m in rig.muscles])
    size = float(np.ptp(rig.mesh.points, axis=0).max())
    scaled = controls * np.where(kinds, 1.0, 0.1 * size)
    peak = scaled.max(axis=0)
    return [name for name, value in zip(names, peak) if value > fraction * max(peak.max(), 1e-30)]


def _terms(rows, theta, sigma, prior_weight) -> tuple[float, float]:
    data = float(np.mean([(row["after"] / row["before"]) ** 2 for row in rows]))
    return data, float(prior_weight * np.sum((theta / sigma) ** 2))


def optimise(
    rig: FaceRig,
    shapes,
    *,
    millimetre: float = 1e-3,
    iterations: int = 4,
    prior_weight: float = 1e-2,
    damping: float = 1e-2,
    difference: str = "grouped-central",
    max_rows: int = 1000,
    muscles=None,
    fields=None,
    device=None,
    log=None,
    **options,
) -> Optimisation:
    """Calibrate ``rig``'s muscle geometry on ``shapes`` (docs/RIG.md §13).

    Each iteration fits every example's controls (:func:`reach`, variable projection), takes the finite-difference
    Jacobian of the residual w.r.t. the parameters with those controls held, and tries damped Gauss–Newton steps
    (λ ×4 after a rejection, ×0.3 after an acceptance) until the refitted objective falls, at most three tries.

    Args:
        rig: the rig to calibrate (68 landmarks needed).
        shapes: :class:`~warpface.calibration.shapes.ExampleShape` s.
        millimetre: 1 mm in the rig's units.
        iterations: Gauss–Newton iterations (Jacobians).
        prior_weight: weight of the prior ``Σ(θ/σ)²``.
        damping: the initial Levenberg–Marquardt λ (relative to the diagonal).
        difference: the Jacobian's finite differences, one of :data:`~warpface.calibration.jacobian.DIFFERENCES`.
        max_rows: at most this many moved vertices per example in the residual.
        muscles: calibrate only these muscles (names or groups); default those the examples use and the
            shared group :data:`~warpface.assets.calibrated.EVERY_MUSCLE`.
        fields: calibrate only these fields (:data:`~warpface.assets.calibrated.PARAMETER_FIELDS`); default all.
        device: Warp device.
        log: a callable taking one line of progress, or None.
        **options: :class:`~warpface.solve.SolveOptions` fields for the fits.
    """
    say = log or (lambda line: None)
    started = time.perf_counter()
    rows = reach(rig, shapes, millimetre=millimetre, device=device, **options)
    if muscles is None:
        muscles = [EVERY_MUSCLE, *active_muscles(rig, rows)]
    parameters = parameter_layout(rig, muscles, fields)
    sigma = np.array([p.sigma for p in parameters])
    theta = np.zeros(len(parameters))
    start = rows
    data, prior = _terms(rows, theta, sigma, prior_weight)
    best = data + prior
    trials = [Trial(data, prior, _mean_reduction(rows), damping, True, time.perf_counter() - started)]
    say(f"start: mean reach {_mean_reduction(rows):.1%}, {len(parameters)} parameters of {len(muscles)} muscles")
    moved = [moved_vertices(rig.mesh.points, s.points, millimetre) for s in shapes]
    layout = residual_layout(rig, shapes, moved, [row["before"] for row in rows], max_rows=max_rows)
    for iteration in range(iterations):
        controls = np.array([row["controls"] for row in rows])
        current = apply_parameters(rig, {p.key: v for p, v in zip(parameters, theta)}, device=device)
        r0 = residuals(current, controls, layout, device=device)
        J = jacobian(rig, parameters, theta, controls, layout, difference=difference, device=device, r0=r0)
        J = J.astype(np.float64)
        normal = J.T @ J + prior_weight * np.diag(1.0 / sigma**2)
        gradient = J.T @ r0 + prior_weight * theta / sigma**2
        say(f"iteration {iteration + 1}: Jacobian {J.shape} in {time.perf_counter() - started:.0f} s")
        accepted = False
        for _ in range(3):
            step = -np.linalg.solve(normal + damping * np.diag(np.diag(normal)), gradient)
            trial_theta = np.clip(theta + step, -3.0 * sigma, 3.0 * sigma)
            trial_rig = apply_parameters(rig, {p.key: v for p, v in zip(parameters, trial_theta)}, device=device)
            trial_rows = reach(trial_rig, shapes, millimetre=millimetre, device=device, **options)
            data, prior = _terms(trial_rows, trial_theta, sigma, prior_weight)
            accepted = data + prior < best
            trials.append(
                Trial(data, prior, _mean_reduction(trial_rows), damping, accepted, time.perf_counter() - started)
            )
            say(
                f"  λ={damping:.3g}: mean reach {_mean_reduction(trial_rows):.1%}, objective {data + prior:.4f} "
                f"({'accepted' if accepted else 'rejected'}, best {best:.4f})"
            )
            if accepted:
                theta, rows, best = trial_theta, trial_rows, data + prior
                damping *= 0.3
                break
            damping *= 4.0
        if not accepted:
            break
    return Optimisation(parameters, theta, start, rows, trials)


def _mean_reduction(rows) -> float:
    return float(np.mean([row["reduction"] for row in rows]))
