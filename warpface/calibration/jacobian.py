"""Residuals of the examples and their derivative w.r.t. the geometry parameters (docs/RIG.md §13).

No kernel gives ∂x/∂θ for a muscle's ends or zone, so the Jacobian is taken by finite differences over the
evaluator: each column rebuilds the rig with one parameter moved (:func:`~warpface.assets.calibrated.apply_parameters`)
and evaluates every example's controls in one batch (:meth:`warpface.ExpressionModel.evaluate`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..assets.calibrated import WHOLE_RIG_KINDS, Parameter, apply_parameters
from ..rig import FaceRig

__all__ = ["DIFFERENCES", "ResidualLayout", "residual_layout", "residuals", "jacobian"]

DIFFERENCES = ("forward", "central", "grouped", "grouped-central")


@dataclass(frozen=True)
class ResidualLayout:
    """Which vertices of which example enter the residual, and their weights.

    ``rows[s]`` are the vertex indices of example ``s`` (its moved vertices, thinned to at most a given count);
    ``weight[s] = 1 / (before_s · sqrt(|rows_s| · S))`` so that ``|r|²`` is the mean over examples of
    ``mean |x − T|² / before²``; ``targets[s]`` the example's points at ``rows[s]``.
    """

    rows: tuple[np.ndarray, ...]
    weight: np.ndarray
    targets: tuple[np.ndarray, ...]


def residual_layout(rig: FaceRig, shapes, moved, before, *, max_rows: int = 1000) -> ResidualLayout:
    """The residual's rows: each example's moved vertices (boolean (V,) each) thinned evenly to ``max_rows``."""
    rows, weights, targets = [], [], []
    count = len(shapes)
    for shape, mask, error in zip(shapes, moved, before):
        index = np.flatnonzero(mask)
        if len(index) > max_rows:
            index = index[np.linspace(0, len(index) - 1, max_rows).round().astype(np.int64)]
        rows.append(index)
        weights.append(1.0 / (max(error, 1e-12) * np.sqrt(len(index) * count)))
        targets.append(np.asarray(shape.points, dtype=np.float64)[index])
    return ResidualLayout(tuple(rows), np.asarray(weights), tuple(targets))


def residuals(rig: FaceRig, controls: np.ndarray, layout: ResidualLayout, *, device=None) -> np.ndarray:
    """The stacked weighted residual ``w_s·(x(c_s) − T_s)`` at the layout's rows, flat (Σ 3·|rows_s|,)."""
    frames = np.asarray(rig.model(device=device).evaluate(np.asarray(controls, dtype=np.float64)), dtype=np.float64)
    frames = frames.reshape(len(layout.rows), -1, 3)
    parts = [
        (frame[rows] - target).ravel() * weight
        for frame, rows, target, weight in zip(frames, layout.rows, layout.targets, layout.weight)
    ]
    return np.concatenate(parts)


def _values(layout: list[Parameter], theta: np.ndarray) -> dict:
    return {p.key: float(v) for p, v in zip(layout, theta)}


def jacobian(
    base: FaceRig,
    parameters: list[Parameter],
    theta: np.ndarray,
    controls: np.ndarray,
    layout: ResidualLayout,
    *,
    step: float = 0.05,
    difference: str = "forward",
    device=None,
    r0: np.ndarray | None = None,
) -> np.ndarray:
    """``∂r/∂θ`` (rows, P) float32 at ``theta`` with the controls held: finite differences, each parameter moved
    by ``step·σ`` (its prior's standard deviation); ``difference`` is ``"forward"`` (one rebuild per column,
    ``r0`` reused) or ``"central"`` (two)."""
    if difference not in DIFFERENCES:
        raise ValueError(f"difference: expected one of {', '.join(DIFFERENCES)}, got {difference!r}")
    theta = np.asarray(theta, dtype=np.float64)
    if difference.startswith("grouped"):
        central = difference == "grouped-central"
        return _grouped_jacobian(
            base, parameters, theta, controls, layout, step=step, device=device, r0=r0, central=central
        )
    if r0 is None and difference == "forward":
        r0 = residuals(
            apply_parameters(base, _values(parameters, theta), device=device), controls, layout, device=device
        )
    columns = None
    for k, parameter in enumerate(parameters):
        h = step * parameter.sigma
        ahead = theta.copy()
        ahead[k] += h
        r_plus = residuals(
            apply_parameters(base, _values(parameters, ahead), device=device), controls, layout, device=device
        )
        if difference == "central":
            behind = theta.copy()
            behind[k] -= h
            r_minus = residuals(
                apply_parameters(base, _values(parameters, behind), device=device), controls, layout, device=device
            )
            column = (r_plus - r_minus) / (2.0 * h)
        else:
            column = (r_plus - r0) / h
        if columns is None:
            columns = np.empty((len(column), len(parameters)), dtype=np.float32)
        columns[:, k] = column
    return columns


def _stacked_frames(rig: FaceRig, controls: np.ndarray, pairs, masks, device) -> np.ndarray:
    """Frames (len(pairs), V, 3) of ``rig`` for each (group g, example s): example s's controls with only group g's
    muscles (and the jaw) kept."""
    batch = np.array([controls[s] * masks[g] for g, s in pairs])
    return np.asarray(rig.model(device=device).evaluate(batch), dtype=np.float64).reshape(len(pairs), -1, 3)


def _grouped_jacobian(base, parameters, theta, controls, layout, *, step, device, r0, central=False) -> np.ndarray:
    """The Jacobian with one rebuilt rig per *field*: every muscle group's parameter of that field moves at once,
    and each group's effect is read from frames that keep only its own muscles' controls (and the jaw's).

    Exact for the muscle displacements (each is linear in its own field); the coupling of one muscle's change with
    another's pull through the nonlinear stages (stretch, bulge, wrinkles) is dropped. The parameters of the
    shared group (:data:`~warpface.assets.calibrated.EVERY_MUSCLE`) move every muscle, the eyelids' every lid
    hinge (:data:`~warpface.assets.calibrated.WHOLE_RIG_KINDS`): they get columns of their own (forward
    differences). The optimiser accepts a step only on the refitted objective, so the approximation costs at most
    some steps. ``central``: each field's rig is also rebuilt with the parameters moved back, and
    the columns are central differences."""
    from ..assets.calibrated import muscle_group

    names = base.muscle_names
    groups = sorted({p.group for p in parameters if p.kind not in WHOLE_RIG_KINDS})
    masks = {}
    for group in groups:
        mask = np.array([muscle_group(n)[0] == group for n in names] + [True] * (len(base.control_names) - len(names)))
        masks[group] = mask.astype(np.float64)
    muscle_only = {g: m * (np.arange(len(m)) < len(names)) for g, m in masks.items()}
    pairs = [(g, s) for g in groups for s in range(len(controls)) if np.any(controls[s] * muscle_only[g])]
    columns = np.zeros((sum(3 * len(r) for r in layout.rows), len(parameters)), dtype=np.float32)
    offsets = np.concatenate([[0], np.cumsum([3 * len(r) for r in layout.rows])])
    shared = [k for k, p in enumerate(parameters) if p.kind in WHOLE_RIG_KINDS]
    if shared:
        columns[:, shared] = _shared_columns(base, parameters, theta, controls, layout, shared, step, device, r0)
    if not pairs:
        return columns
    if not central:
        current = apply_parameters(base, _values(parameters, theta), device=device)
        rest = _stacked_frames(current, controls, pairs, masks, device)
    for field in sorted({p.field for p in parameters if p.kind not in WHOLE_RIG_KINDS}):
        ks = [k for k, p in enumerate(parameters) if p.field == field and p.kind not in WHOLE_RIG_KINDS]
        h = {parameters[k].group: step * parameters[k].sigma for k in ks}
        ahead, behind = theta.copy(), theta.copy()
        for k in ks:
            ahead[k] += h[parameters[k].group]
            behind[k] -= h[parameters[k].group]
        moved = _stacked_frames(
            apply_parameters(base, _values(parameters, ahead), device=device), controls, pairs, masks, device
        )
        if central:
            rest = _stacked_frames(
                apply_parameters(base, _values(parameters, behind), device=device), controls, pairs, masks, device
            )
        column_of = {parameters[k].group: k for k in ks}
        for index, (group, s) in enumerate(pairs):
            k = column_of.get(group)
            if k is None:
                continue
            rows = layout.rows[s]
            span = (2.0 if central else 1.0) * h[group]
            change = (moved[index][rows] - rest[index][rows]).ravel() * layout.weight[s] / span
            columns[offsets[s] : offsets[s + 1], k] = change
    return columns


def _shared_columns(base, parameters, theta, controls, layout, shared, step, device, r0) -> np.ndarray:
    """Forward-difference columns of the shared parameters (indices ``shared``) at the full ``theta``."""
    if r0 is None:
        r0 = residuals(
            apply_parameters(base, _values(parameters, theta), device=device), controls, layout, device=device
        )
    out = np.empty((len(r0), len(shared)), dtype=np.float32)
    for column, k in enumerate(shared):
        ahead = theta.copy()
        ahead[k] += step * parameters[k].sigma
        moved = residuals(
            apply_parameters(base, _values(parameters, ahead), device=device), controls, layout, device=device
        )
        out[:, column] = (moved - r0) / (step * parameters[k].sigma)
    return out
