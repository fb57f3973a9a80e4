"""``calibrate(rig, shapes)``: learn a rig's muscle geometry from example shapes (docs/RIG.md §13)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..assets.calibrated import apply_parameters
from ..errors import RigError
from ..rig import FaceRig
from .optimize import optimise
from .reach import reach
from .shapes import check_shapes

__all__ = ["Calibration", "calibrate"]


@dataclass
class Calibration:
    """What :func:`calibrate` found.

    Attributes:
        rig: the calibrated rig, or the input rig when the calibration did not improve the training fit.
        improved: the training examples' mean reach rose.
        message: one line saying what happened.
        values: ``{(group, field): value}`` of the calibrated rig ({} when the input rig is kept).
        reach: ``{"train": {"before": rows, "after": rows}, "held_out": {...}}`` with
            :class:`~warpface.calibration.reach.ShapeReach` rows (dense fits; ``"landmarks"`` too when asked).
        trials: the optimiser's :class:`~warpface.calibration.optimize.Trial` s.
        seconds: wall time.
    """

    rig: FaceRig
    improved: bool
    message: str
    values: dict
    reach: dict = field(default_factory=dict)
    trials: list = field(default_factory=list)
    seconds: float = 0.0


def _mean(rows) -> float:
    return float(np.mean([row["reduction"] for row in rows])) if rows else float("nan")


def calibrate(
    rig: FaceRig,
    shapes,
    *,
    holdout=(),
    millimetre: float = 1e-3,
    iterations: int = 4,
    prior_weight: float = 1e-2,
    difference: str = "grouped-central",
    landmarks: bool = False,
    muscles=None,
    fields=None,
    device=None,
    log=None,
    **options,
) -> Calibration:
    """Calibrate ``rig``'s muscle geometry on example shapes, jointly with each example's controls.

    Args:
        rig: a :class:`~warpface.FaceRig` with its 68 iBUG landmarks.
        shapes: :class:`~warpface.calibration.shapes.ExampleShape` s or ``{name: (V, 3) points}`` in the rig's
            units (:func:`~warpface.calibration.shapes.read_shapes` reads files).
        holdout: names of examples measured but not trained on.
        millimetre: 1 mm in the rig's units (1e-3 for metres, 0.1 for centimetres).
        iterations: Gauss–Newton iterations.
        prior_weight: weight of the prior ``Σ(θ/σ)²`` that keeps the anatomy near the input's.
        difference: the Jacobian's finite differences, one of :data:`~warpface.calibration.jacobian.DIFFERENCES`.
        landmarks: also report the reach of fits from the 68 landmarks only.
        muscles, fields: calibrate only these muscles (names or groups) and fields; default: the muscles the
            examples use, every field.
        device: Warp device.
        log: a callable taking one progress line, or None.
        **options: :class:`~warpface.solve.SolveOptions` fields for the fits.

    Raises:
        TypeError: ``rig`` not a FaceRig.
        ValueError: no examples; an example of another vertex count or with NaN; a held-out name that is no
            example; every example held out; the rig without landmarks (RigError).
    """
    started = time.perf_counter()
    shapes = check_shapes(shapes, rig)
    holdout = [holdout] if isinstance(holdout, str) else list(holdout)
    names = {s.name for s in shapes}
    unknown = [name for name in holdout if name not in names]
    if unknown:
        raise ValueError(f"holdout: {unknown[0]!r} is not one of the examples")
    train = [s for s in shapes if s.name not in holdout]
    held = [s for s in shapes if s.name in holdout]
    if not train:
        raise ValueError("holdout: every example is held out; nothing is left to calibrate on")
    if not isinstance(millimetre, (int, float)) or not millimetre > 0:
        raise ValueError(f"millimetre: expected a positive length, got {millimetre!r}")
    if rig.landmarks is None or len(rig.landmarks) != 68:
        raise RigError(f"rig {rig.name!r}: calibration needs the 68 iBUG landmarks (the rig has none)")
    result = optimise(
        rig,
        train,
        millimetre=millimetre,
        iterations=iterations,
        prior_weight=prior_weight,
        difference=difference,
        muscles=muscles,
        fields=fields,
        device=device,
        log=log,
        **options,
    )
    before, after = _mean(result.start), _mean(result.end)
    improved = after > before and bool(result.values)
    calibrated = apply_parameters(rig, result.values, device=device) if improved else rig
    message = (
        f"calibrated {len(result.values)} parameters: training reach {before:.1%} -> {after:.1%}"
        if improved
        else f"calibration did not improve the training reach ({before:.1%}); the input rig is kept"
    )
    report = {"train": {"before": result.start, "after": result.end if improved else result.start}}
    if held:
        report["held_out"] = {
            "before": reach(rig, held, millimetre=millimetre, device=device, **options),
            "after": reach(calibrated, held, millimetre=millimetre, device=device, **options),
        }
    if landmarks:
        for split, examples in (("train_landmarks", train), ("held_out_landmarks", held)):
            if examples:
                report[split] = {
                    "before": reach(rig, examples, millimetre=millimetre, landmarks=True, device=device, **options),
                    "after": reach(
                        calibrated, examples, millimetre=millimetre, landmarks=True, device=device, **options
                    ),
                }
    if log:
        log(message)
    return Calibration(
        calibrated,
        improved,
        message,
        result.values if improved else {},
        report,
        result.trials,
        time.perf_counter() - started,
    )
