"""Controls back to channels: a rig's performance as ARKit weights for other rigs.

For each frame, the weights ``s`` solve the bounded least-squares projection onto the mapping

    min_s  |D (M s + c₀ − c)|² + λ |s|²    subject to  lo ≤ s ≤ hi   (ARKit: 0 ≤ s ≤ 1)

where ``D`` divides each control by the largest weight any channel gives it (so a contraction in
metres and a dimensionless sphincter count alike) and the small ridge ``λ`` picks one answer when
channels share a control (``mouthPucker`` and ``mouthFunnel`` both pull ``orbicularis_oris``).
All frames are solved together by FISTA (Beck & Teboulle 2009): projected gradient steps of size
``1/L``, ``L`` = the largest eigenvalue of ``2(AᵀA + λI)``, with Nesterov momentum restarted when it
points uphill (O'Donoghue & Candès 2015), until no weight moves by more than ``tolerance``. Controls the
mapping does not use are ignored.
"""

from __future__ import annotations

import numpy as np

from .._validate import as_count, as_finite_array, as_positive, expect_instance
from .channels import Curves, channel_range
from .mapping import Mapping

__all__ = ["project_controls", "controls_to_curves"]


def project_controls(
    mapping: Mapping,
    controls: dict[str, np.ndarray] | np.ndarray,
    *,
    ridge: float = 1e-4,
    tolerance: float = 1e-7,
    max_iterations: int = 5000,
) -> np.ndarray:
    """Channel weights (F, C) in the mapping's channel order whose mapped controls best match ``controls``.

    Args:
        mapping: the rig's mapping (channels → controls).
        controls: ``{control name: (F,) values}`` (controls missing here are taken at their offset) or an
            (F, K) array in ``mapping.controls`` order.
        ridge: ``λ``, relative to the scaled problem (weights are O(1)).
        tolerance: stop when the largest weight change of an iteration is below this.
        max_iterations: iteration cap.

    Raises:
        ValueError: wrong shapes, non-finite values, an empty mapping.
    """
    expect_instance(mapping, Mapping, "mapping")
    if not mapping.channels or not mapping.controls:
        raise ValueError(f"mapping {mapping.name!r} has no channels or controls to project onto")
    ridge = as_positive(ridge, "ridge", allow_zero=True, maximum=1e6)
    tolerance = as_positive(tolerance, "tolerance", maximum=1.0)
    max_iterations = as_count(max_iterations, "max_iterations", minimum=1, maximum=10_000_000)
    if isinstance(controls, dict):
        unknown = [k for k in controls if k not in mapping.controls]
        controls = {
            name: as_finite_array(series, f"controls[{name!r}]", max_abs=1e12).reshape(-1)
            for name, series in controls.items()
        }
        frames = {len(v) for v in controls.values()}
        if len(frames) != 1:
            raise ValueError("controls: every control needs the same number of frames")
        count = frames.pop()
        table = np.tile(mapping.offsets, (count, 1))
        for name, series in controls.items():
            if name in unknown:
                continue
            table[:, mapping.controls.index(name)] = np.asarray(series, dtype=np.float64).reshape(count)
    else:
        table = as_finite_array(controls, "controls", max_abs=1e12)
        if table.ndim != 2 or table.shape[1] != len(mapping.controls):
            raise ValueError(f"controls: expected shape (F, {len(mapping.controls)}), got {table.shape}")
    if not np.isfinite(table).all():
        raise ValueError("controls: non-finite value")
    used = np.flatnonzero(np.abs(mapping.matrix).max(axis=1) > 0)
    if len(used) == 0:
        raise ValueError(f"mapping {mapping.name!r} has no non-zero weight to project onto")
    scale = np.abs(mapping.matrix[used]).max(axis=1)
    A = mapping.matrix[used] / scale[:, None]  # (K', C)
    target = (table[:, used] - mapping.offsets[used]) / scale  # (F, K')
    bounds = np.array([channel_range(n) for n in mapping.channels])
    low, high = bounds[:, 0], bounds[:, 1]
    gram = A.T @ A + ridge * np.eye(A.shape[1])
    lipschitz = 2.0 * float(np.linalg.eigvalsh(gram)[-1])
    linear = target @ A  # (F, C)
    weights = np.clip(np.linalg.lstsq(gram, linear.T, rcond=None)[0].T, low, high)
    momentum_point, momentum = weights.copy(), 1.0
    for _ in range(int(max_iterations)):
        gradient = 2.0 * (momentum_point @ gram - linear)
        updated = np.clip(momentum_point - gradient / lipschitz, low, high)
        change = float(np.abs(updated - weights).max())
        if float(np.sum((momentum_point - updated) * (updated - weights))) > 0.0:
            momentum = 1.0  # adaptive restart (O'Donoghue & Candès 2015): momentum points uphill
        next_momentum = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * momentum * momentum))
        momentum_point = updated + ((momentum - 1.0) / next_momentum) * (updated - weights)
        weights, momentum = updated, next_momentum
        if change < tolerance:
            break
    return weights


def controls_to_curves(
    mapping: Mapping, times, controls, *, source: str = "export", fps: float | None = None, **options
) -> Curves:
    """:func:`project_controls` as :class:`Curves` (times [s], the mapping's channels) ready to write."""
    expect_instance(mapping, Mapping, "mapping")
    weights = project_controls(mapping, controls, **options)
    return Curves(
        times=as_finite_array(times, "times"), names=list(mapping.channels), values=weights, source=source, fps=fps
    )
