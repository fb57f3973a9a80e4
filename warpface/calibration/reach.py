"""Reach: how much of each example's motion a rig's fitted controls reproduce (docs/RIG.md §7, §13)."""

from __future__ import annotations

import numpy as np

from ..rig import FaceRig
from ..solve import fit

__all__ = ["MOVED_MM", "ShapeReach", "reach", "moved_vertices"]

MOVED_MM = 0.2
"""A vertex counts as moved when the example moves it more than this [mm]."""


def moved_vertices(rest: np.ndarray, target: np.ndarray, millimetre: float) -> np.ndarray:
    """Boolean (V,): the vertices the target moves more than :data:`MOVED_MM` (``millimetre``: 1 mm in mesh units);
    every vertex when none moves that far."""
    moved = np.linalg.norm(target - rest, axis=1) > MOVED_MM * millimetre
    return moved if moved.any() else np.ones(len(rest), dtype=bool)


def _mean_error(points, target, moved) -> float:
    return float(np.linalg.norm(np.asarray(points, dtype=np.float64)[moved] - target[moved], axis=1).mean())


class ShapeReach(dict):
    """One example's reach: ``name``, ``moved`` (count), ``before`` and ``after`` (mean error over moved vertices
    [mesh units]), ``max_before``, ``max_after``, ``reduction`` (1 − after/before), ``converged``, ``controls``
    (M,) in rig order. A dict, so it goes to JSON as it is (``controls`` as a list)."""


def reach(rig: FaceRig, shapes, *, millimetre: float = 1e-3, landmarks: bool = False, device=None, **options):
    """Fit ``rig`` to every example with :func:`warpface.solve.fit` and measure the error over its moved vertices.

    Args:
        rig: the rig.
        shapes: :class:`~warpface.calibration.shapes.ExampleShape` s (points in the rig's units).
        millimetre: 1 mm in the rig's units (1e-3 for metres).
        landmarks: fit from the rig's landmark vertices only (the dense error is still what is measured).
        device: Warp device of the fits.
        **options: :class:`~warpface.solve.SolveOptions` fields.

    Returns:
        A list of :class:`ShapeReach`, one per example, in order.
    """
    rows = rig.landmarks if landmarks else None
    if landmarks and rows is None:
        raise ValueError(f"rig {rig.name!r}: a landmark fit needs the rig's landmarks")
    rest = rig.mesh.points
    out = []
    for shape in shapes:
        target = shape.points
        moved = moved_vertices(rest, target, millimetre)
        solved = fit(rig, target if rows is None else target[rows], vertices=rows, device=device, **options)
        points = np.asarray(solved.points, dtype=np.float64)
        before, after = _mean_error(rest, target, moved), _mean_error(points, target, moved)
        distance = np.linalg.norm(points[moved] - target[moved], axis=1)
        out.append(
            ShapeReach(
                name=shape.name,
                moved=int(moved.sum()),
                before=before,
                after=after,
                max_before=float(np.linalg.norm(rest[moved] - target[moved], axis=1).max()),
                max_after=float(distance.max()),
                reduction=1.0 - after / before if before > 0 else 0.0,
                converged=bool(solved.converged),
                controls=np.asarray(solved.vector, dtype=np.float64),
            )
        )
    return out
