"""Rigid head pose for tracked targets: rotation about the observed points' rest centroid, plus translation."""

from __future__ import annotations

import numpy as np

__all__ = ["rotation_from_vector", "rigid_alignment", "skew"]


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices of vectors (..., 3) → (..., 3, 3): ``skew(a) @ b = a × b``."""
    zero = np.zeros(v.shape[:-1])
    return np.stack(
        [
            np.stack([zero, -v[..., 2], v[..., 1]], axis=-1),
            np.stack([v[..., 2], zero, -v[..., 0]], axis=-1),
            np.stack([-v[..., 1], v[..., 0], zero], axis=-1),
        ],
        axis=-2,
    )


def rotation_from_vector(omega: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation matrices (F, 3, 3) from rotation vectors (F, 3) [radians]."""
    angle = np.linalg.norm(omega, axis=-1)[..., None, None]
    k = skew(omega)
    small = angle < 1e-8
    safe = np.where(small, 1.0, angle)
    a = np.where(small, 1.0 - angle**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - angle**2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    return np.eye(3) + a * k + b * (k @ k)


def rigid_alignment(source: np.ndarray, target: np.ndarray, weight: np.ndarray, origin: np.ndarray):
    """Least-squares rotation R and translation t with ``R(source − origin) + origin + t ≈ target`` (Kabsch).

    Args:
        source, target: (N, 3); weight: (N,) ≥ 0 (0 for missing points); origin: (3,).

    Returns:
        ``(R (3, 3), t (3,))``; the identity when fewer than 3 points carry weight.
    """
    if np.count_nonzero(weight > 0.0) < 3:
        return np.eye(3), np.zeros(3)
    w = weight / weight.sum()
    a = source - origin
    b = np.where(weight[:, None] > 0.0, target, 0.0)
    ca, cb = w @ a, w @ b
    cov = (a - ca).T @ ((b - cb) * w[:, None])
    u, _, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rotation = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    translation = cb - rotation @ ca - origin
    return rotation, translation
