"""Evaluation metrics: Kato's left/right symmetry ξ (SPEC §4) and surface distances.

Landmarks follow the thesis's table 2.2 (anthropometric names, Farkas), defined as affine
combinations of the 68 iBUG points in :mod:`warpface.landmarks` (:data:`KATO_LANDMARKS`,
:func:`kato_landmarks`, re-exported here). "L" / "R" are the subject's left (+x in warpface) and right.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np

from ._validate import MAX_COORDINATE, as_finite_array, as_indices
from .landmarks import KATO_LANDMARKS, kato_landmarks

__all__ = [
    "KATO_LANDMARKS",
    "SYMMETRY_PAIRS",
    "SymmetryResult",
    "kato_landmarks",
    "symmetry",
    "symmetry_side",
    "point_distances",
    "SurfaceError",
    "surface_error",
]

SYMMETRY_PAIRS = ("ex", "pi", "al", "cphi")
"""The landmarks whose distance from the cheilion (ch) of the same side enters ξ (SPEC §4, k = 1..4)."""


def _track(landmarks, name: str) -> np.ndarray:
    if name not in landmarks:
        raise ValueError(f"symmetry: landmark {name!r} missing; have {sorted(landmarks)}")
    track = np.asarray(landmarks[name], dtype=np.float64)
    if track.ndim != 2 or track.shape[1] != 3 or len(track) < 1:
        raise ValueError(f"symmetry: landmark {name!r} must be a track of shape (T, 3), got {track.shape}")
    if not np.isfinite(track).all():
        raise ValueError(
            f"symmetry: landmark {name!r} has non-finite positions (frame {np.argwhere(~np.isfinite(track))[0, 0]})"
        )
    return track


def symmetry_side(landmarks, side: str, *, reference: int = 0) -> np.ndarray:
    """Kato's ξ for one side (eq. 4.38): ``ξ(t) = Σ_k (r_k(t) / r_k(t0) − 1)``.

    ``r_k(t)`` is the distance from the side's cheilion to its ex, pi, al and cphi at frame t.

    Args:
        landmarks: Name -> track of shape (T, 3) (as from :func:`kato_landmarks` on a (T, 68, 3) track).
        side: ``"L"`` or ``"R"``.
        reference: Index of the reference frame t0.

    Returns:
        ξ per frame, shape (T,), float64 (0 at the reference frame).

    Raises:
        ValueError: unknown side, missing landmark, tracks of different lengths, non-finite
            positions, a reference index out of range, or a zero reference distance.
    """
    if side not in ("L", "R"):
        raise ValueError(f"symmetry: side must be 'L' or 'R', got {side!r}")
    ch = _track(landmarks, f"ch_{side}")
    if isinstance(reference, bool) or not isinstance(reference, numbers.Integral):
        raise TypeError(f"symmetry: reference frame must be an integer, got {type(reference).__name__}")
    if not -len(ch) <= int(reference) < len(ch):
        raise ValueError(f"symmetry: reference frame {reference} out of range for {len(ch)} frames")
    xi = np.zeros(len(ch))
    for key in SYMMETRY_PAIRS:
        other = _track(landmarks, f"{key}_{side}")
        if len(other) != len(ch):
            raise ValueError(f"symmetry: track {key}_{side} has {len(other)} frames, ch_{side} has {len(ch)}")
        r = np.linalg.norm(other - ch, axis=1)
        r0 = r[int(reference)]
        if not r0 > 0.0:
            raise ValueError(f"symmetry: ch_{side} and {key}_{side} coincide at the reference frame")
        xi += r / r0 - 1.0
    return xi


@dataclass(frozen=True)
class SymmetryResult:
    """Kato's symmetry measures over a track (SPEC §4)."""

    xi_left: np.ndarray
    """ξ_L(t), shape (T,), float64."""
    xi_right: np.ndarray
    """ξ_R(t), shape (T,), float64."""
    cost: np.ndarray
    """ξ_cost(t) = log|ξ_L(t) − ξ_R(t)|, shape (T,), float64; differences below ``floor`` (always the
    reference frame, where both are 0) are clamped to it, so the value there is ``log(floor)``."""
    floor: float
    """The clamp of |ξ_L − ξ_R| applied before the logarithm."""


def symmetry(landmarks, *, reference: int = 0, floor: float = 1e-12) -> SymmetryResult:
    """Kato's left/right symmetry (eq. 4.38–4.39): ξ_L, ξ_R and ``ξ_cost = log|ξ_L − ξ_R|``.

    Smaller ξ_cost means more symmetric motion. The thesis defines it for t ≠ t0 (at t0 both ξ are
    0); here every frame gets a value, with |ξ_L − ξ_R| clamped below at ``floor`` (> 0) so the
    result is finite.

    Args:
        landmarks: Name -> track (T, 3) for ch, ex, pi, al, cphi on both sides (``*_L``, ``*_R``).
        reference: Index of the reference frame t0.
        floor: Lower clamp of |ξ_L − ξ_R| (> 0).
    """
    if not (np.isfinite(floor) and floor > 0.0):
        raise ValueError(f"symmetry: floor must be finite and > 0, got {floor}")
    left = symmetry_side(landmarks, "L", reference=reference)
    right = symmetry_side(landmarks, "R", reference=reference)
    if len(left) != len(right):
        raise ValueError(f"symmetry: left tracks have {len(left)} frames, right tracks {len(right)}")
    cost = np.log(np.maximum(np.abs(left - right), floor))
    return SymmetryResult(xi_left=left, xi_right=right, cost=cost, floor=float(floor))


# ---------------------------------------------------------------------------------------------- surfaces


def point_distances(points, reference) -> np.ndarray:
    """Distance between corresponding points [m]: (..., V, 3) × (..., V, 3) → (..., V), float64."""
    a = as_finite_array(points, "point_distances: points", max_abs=MAX_COORDINATE)
    b = as_finite_array(reference, "point_distances: reference", max_abs=MAX_COORDINATE)
    if a.shape != b.shape or a.ndim < 2 or a.shape[-1] != 3:
        raise ValueError(
            f"point_distances: points and reference need the same shape (..., V, 3), got {a.shape} and {b.shape}"
        )
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise ValueError("point_distances: positions must be finite")
    return np.linalg.norm(a - b, axis=-1)


@dataclass(frozen=True)
class SurfaceError:
    """Point-to-point error of a surface against a reference with the same vertices [m]."""

    mean: float
    """Mean distance."""
    max: float
    """Largest distance."""
    rms: float
    """Root-mean-square distance."""
    argmax: int
    """Vertex with the largest distance."""

    def __str__(self) -> str:
        mean, rms, worst = self.mean * 1e3, self.rms * 1e3, self.max * 1e3
        return f"mean {mean:.3f} mm, rms {rms:.3f} mm, max {worst:.3f} mm (vertex {self.argmax})"


def surface_error(points, reference, *, vertices=None) -> SurfaceError:
    """Mean / rms / max point-to-point distance between two (V, 3) surfaces, optionally over a vertex subset."""
    d = point_distances(points, reference)
    if d.ndim != 1:
        raise ValueError(f"surface_error: expected (V, 3) surfaces, got {np.shape(points)}")
    index = np.arange(len(d)) if vertices is None else as_indices(vertices, len(d), "surface_error: vertices")
    if index.size == 0:
        raise ValueError("surface_error: no vertices selected")
    sel = d[index]
    worst = int(np.argmax(sel))
    return SurfaceError(
        mean=float(sel.mean()), max=float(sel[worst]), rms=float(np.sqrt(np.mean(sel**2))), argmax=int(index[worst])
    )
