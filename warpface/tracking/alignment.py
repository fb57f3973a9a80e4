"""Point-set alignment in NumPy (float64): similarity (Umeyama) and rigid (Kabsch) least squares.

Used at set-up and once per frame on a few hundred landmarks — small dense problems where a 3×3
SVD is the right tool.
"""

from __future__ import annotations

import numpy as np

from .._validate import as_finite_array, as_points

__all__ = ["similarity_fit", "rigid_fit"]


def _weighted(source, target, weights):
    src = as_points(source, "source")
    dst = as_points(target, "target")
    if src.shape != dst.shape or src.shape[0] < 3:
        raise ValueError(f"source, target: need matching (N, 3) point sets with N ≥ 3, got {src.shape} and {dst.shape}")
    w = np.ones(src.shape[0]) if weights is None else as_finite_array(weights, "weights", max_abs=1e300).reshape(-1)
    if w.shape[0] != src.shape[0] or (w < 0).any() or w.sum() <= 0:
        raise ValueError("weights: need one non-negative weight per point, not all zero")
    w = w / w.sum()
    mu_s, mu_d = w @ src, w @ dst
    a, b = src - mu_s, dst - mu_d
    u, sig, vt = np.linalg.svd((b * w[:, None]).T @ a)
    d = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        d[2] = -1.0
    rot = u @ np.diag(d) @ vt
    return src, dst, w, mu_s, mu_d, a, sig, d, rot


def similarity_fit(source, target, weights=None):
    """Least-squares similarity ``target ≈ s R source + t`` (Umeyama 1991).

    Args:
        source, target: corresponding points, shape (N, 3), N ≥ 3.
        weights: optional non-negative weight per point (N,).

    Returns:
        ``(s, R (3, 3), t (3,), rms)`` — scale, proper rotation, translation, and the weighted
        root-mean-square residual.
    """
    src, dst, w, mu_s, mu_d, a, sig, d, rot = _weighted(source, target, weights)
    var_s = float(w @ np.sum(a * a, axis=1))
    scale = float((sig * d).sum() / var_s) if var_s > 0 else 1.0
    t = mu_d - scale * rot @ mu_s
    resid = dst - (scale * src @ rot.T + t)
    return scale, rot, t, float(np.sqrt(w @ np.sum(resid * resid, axis=1)))


def rigid_fit(source, target, weights=None):
    """Least-squares rotation and translation ``target ≈ R source + t`` (Kabsch).

    Returns ``(R (3, 3), t (3,))``.
    """
    _, _, _, mu_s, mu_d, _, _, _, rot = _weighted(source, target, weights)
    return rot, mu_d - rot @ mu_s
