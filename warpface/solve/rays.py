"""Solving controls and head pose from landmarks seen as viewing rays (a monocular camera), docs/CAPTURE.md §3.

The perspective reprojection term in its point-to-ray form, ``Σ ŵ_i |(I − D_i D_iᵀ)(P_i − o)|²``, minimised by
alternating the closest ray points ``y_i = o + D_i D_iᵀ (P_i − o)`` with :meth:`Solver.solve` toward them.
"""

from __future__ import annotations

import numpy as np

__all__ = ["closest_on_rays", "ray_distances", "RaySolve", "pnp_pose"]


def closest_on_rays(points, origin, directions) -> np.ndarray:
    """Closest point of each ray ``origin + s·D_i`` (s > 0) to ``points[i]``: (N, 3); NaN where the point is
    behind the camera (s ≤ 0) or the direction is NaN. ``directions`` are unit vectors (N, 3)."""
    points = np.asarray(points, dtype=np.float64)
    directions = np.asarray(directions, dtype=np.float64)
    along = np.einsum("nd,nd->n", points - origin, directions)
    with np.errstate(invalid="ignore"):
        ahead = along > 0.0
    return np.where(ahead[:, None], origin + along[:, None] * directions, np.nan)


def ray_distances(points, origin, directions) -> np.ndarray:
    """Distance of each point from its ray's line, (N,): ``|(I − D Dᵀ)(P − o)|``."""
    offset = np.asarray(points, dtype=np.float64) - origin
    along = np.einsum("nd,nd->n", offset, directions)
    return np.linalg.norm(offset - along[:, None] * directions, axis=1)


def pnp_pose(model_points, normalized, weights=None):
    """Rigid pose (R (3, 3), t (3,)) with ``camera = R·model + t`` from 3-D points and their normalised image
    coordinates ``(x/z, y/z)`` (N, 2) (EPnP, then Levenberg–Marquardt); ``None`` with fewer than 6 points."""
    import cv2

    model_points = np.asarray(model_points, dtype=np.float64)
    normalized = np.asarray(normalized, dtype=np.float64)
    keep = np.all(np.isfinite(normalized), axis=1) & np.all(np.isfinite(model_points), axis=1)
    if weights is not None:
        keep &= np.asarray(weights) > 0
    if keep.sum() < 6:
        return None
    obj = np.ascontiguousarray(model_points[keep]).reshape(-1, 1, 3)
    img = np.ascontiguousarray(normalized[keep]).reshape(-1, 1, 2)
    ok, rvec, tvec = cv2.solvePnP(obj, img, np.eye(3), None, flags=cv2.SOLVEPNP_EPNP)
    if not ok:
        return None
    ok, rvec, tvec = cv2.solvePnP(obj, img, np.eye(3), None, rvec, tvec, True, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok or not np.all(np.isfinite(tvec)) or tvec[2, 0] <= 0:
        return None
    return cv2.Rodrigues(rvec)[0], tvec[:, 0].copy()


class RaySolve:
    """Alternating solve of a :class:`~warpface.solve.Solver` toward viewing rays (docs/CAPTURE.md §3).

    Args:
        solver: a :class:`~warpface.solve.Solver` over the landmarks' vertices (usually with ``pose=True``).
        rounds: closest-point / solve rounds per frame.
    """

    def __init__(self, solver, *, rounds: int = 1):
        from .._validate import as_count

        self.solver = solver
        self.rounds = as_count(rounds, "rounds", minimum=1, maximum=100)

    def posed_landmarks(self) -> np.ndarray:
        """The model's landmarks at the solver's current controls and head pose, (N, 3), rig frame."""
        solver = self.solver
        local = solver.local.evaluate(solver.controls[None], jacobian=False)[0]
        points = np.asarray(solver.observation.apply_frames(local)[0], dtype=np.float64)
        return (points - solver.origin) @ solver.rotation.T + solver.origin + solver.translation

    def solve(self, origin, directions, weights, offsets=None, *, depths=None, depth_weight: float = 0.0):
        """Solve one frame: rays from ``origin`` (3,) along unit ``directions`` (N, 3) (NaN rows missing),
        ``weights`` (N,); ``offsets`` (N, 3), rig frame: where each detected landmark sits relative to its model
        point (turned with the head pose), so ray ``i`` is matched by ``P_i + R·offset_i``; ``depths`` (N,):
        measured distances along the rays, pulled toward with ``depth_weight`` λ ∈ [0, 1] (docs/CAPTURE.md §2).
        Returns ``(fit, targets (N, 3))``: the last :class:`~warpface.solve.Fit` and the targets it was solved
        toward (rig frame)."""
        origin = np.asarray(origin, dtype=np.float64)
        fit, targets = None, None
        for _ in range(self.rounds):
            shift = 0.0 if offsets is None else offsets @ self.solver.rotation.T
            predicted = self.posed_landmarks() + shift
            along = np.einsum("nd,nd->n", predicted - origin, directions)
            if depths is not None:  # the majorising step of the depth term: (1 − λ)·predicted + λ·measured
                along = (1.0 - depth_weight) * along + depth_weight * np.asarray(depths, dtype=np.float64)
            with np.errstate(invalid="ignore"):
                ahead = along > 0.0
            targets = np.where(ahead[:, None], origin + along[:, None] * directions, np.nan) - shift
            fit = self.solver.solve(targets, weights)
            if fit.skipped:
                break
        return fit, targets
