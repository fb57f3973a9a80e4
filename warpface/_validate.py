"""Small validation helpers shared by the constructors (boundary checks, clear messages)."""

from __future__ import annotations

import numpy as np

__all__ = ["as_finite_array", "as_vec3", "as_positive", "unit_vector", "orthogonal_unit_vector"]


def as_finite_array(value, name: str, *, shape: tuple | None = None, dtype=np.float64) -> np.ndarray:
    """``value`` as an array of ``dtype``; raises ValueError naming ``name`` on bad shape or non-finite values.

    ``shape`` may contain ``None`` for a free dimension.
    """
    try:
        array = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot convert to a numeric array ({exc})") from None
    if shape is not None:
        if array.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, array.shape)):
            expected = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
            raise ValueError(f"{name}: expected shape {expected}, got {array.shape}")
    if np.issubdtype(array.dtype, np.floating) and not np.all(np.isfinite(array)):
        bad = np.argwhere(~np.isfinite(array))
        raise ValueError(f"{name}: non-finite value at index {tuple(int(i) for i in bad[0])}")
    return array


def as_vec3(value, name: str) -> np.ndarray:
    """A finite 3-vector, float64, shape (3,)."""
    return as_finite_array(value, name, shape=(3,))


def as_positive(value, name: str, *, allow_zero: bool = False) -> float:
    """A finite scalar that is > 0 (or ≥ 0 with ``allow_zero``)."""
    number = float(as_finite_array(value, name, shape=()))
    if number < 0.0 or (number == 0.0 and not allow_zero):
        raise ValueError(f"{name}: must be {'≥' if allow_zero else '>'} 0, got {number}")
    return number


def unit_vector(value, name: str) -> np.ndarray:
    """``value`` normalised to unit length; raises ValueError if it has zero length.

    A vector whose length already rounds to 1 is returned unchanged: dividing it by that length can
    flip its last bit, and validated records (muscles, projections) must survive re-validation exactly
    (e.g. a USD round trip).
    """
    vector = as_vec3(value, name)
    length = float(np.linalg.norm(vector))
    if length <= 1e-12 * max(1.0, float(np.abs(vector).max())):
        raise ValueError(f"{name}: zero-length vector")
    if abs(length - 1.0) <= 2.0 * np.finfo(np.float64).eps:
        return vector
    return vector / length


def orthogonal_unit_vector(value, axis: np.ndarray, name: str) -> np.ndarray:
    """``value`` with its component along the unit vector ``axis`` removed, normalised (Gram–Schmidt).

    A vector already orthogonal to ``axis`` to within 1e-12 (relative) is only normalised, so that
    re-validating a validated frame is exact. Raises ValueError if ``value`` is parallel to ``axis``.
    """
    vector = as_vec3(value, name)
    along = float(np.dot(vector, axis))
    if abs(along) > 1e-12 * float(np.linalg.norm(vector)):
        vector = vector - along * axis
    return unit_vector(vector, name)
