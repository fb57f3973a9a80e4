"""Length units and axis directions as a user names them, and the unit a head's size implies.

A head's unit is read from its inter-ocular (eye-centre) distance once the template is fitted:
adults measure 55–72 mm, so the candidates metre, centimetre and millimetre (a factor 10 apart)
cannot be confused. A size that fits none of them is reported instead of guessed.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["UNITS", "TYPICAL_EYE_DISTANCE", "parse_units", "infer_units", "parse_axis"]

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
"""Units a head mesh may be in: name → metres per unit."""

TYPICAL_EYE_DISTANCE = 0.063
"""Typical adult inter-ocular (eye-centre) distance [m]."""

PLAUSIBLE_RATIO = 2.0
"""A face whose eye distance, read in the best unit, is more than this factor off the typical one is refused."""


def parse_units(name) -> float:
    """Metres per unit for ``"m"``, ``"cm"`` or ``"mm"``; ValueError naming the choices otherwise."""
    if not isinstance(name, str):
        raise TypeError(f"units: expected one of {', '.join(UNITS)}, got {type(name).__name__}")
    key = name.strip().lower()
    if key not in UNITS:
        raise ValueError(f"units: expected one of {', '.join(UNITS)}, got {name!r}")
    return UNITS[key]


def infer_units(eye_distance: float, label: str = "mesh") -> tuple[str, float]:
    """The unit (name, metres per unit) in which an inter-ocular distance of ``eye_distance`` is human-sized.

    Raises:
        ValueError: no candidate unit gives a plausible face (a mesh in km or µm, or not a face).
    """
    if not (math.isfinite(eye_distance) and eye_distance > 0.0):
        raise ValueError(f"{label}: could not measure the face (eye distance {eye_distance})")
    name = min(UNITS, key=lambda unit: abs(math.log(eye_distance * UNITS[unit] / TYPICAL_EYE_DISTANCE)))
    ratio = eye_distance * UNITS[name] / TYPICAL_EYE_DISTANCE
    if not 1.0 / PLAUSIBLE_RATIO <= ratio <= PLAUSIBLE_RATIO:
        metres = eye_distance / TYPICAL_EYE_DISTANCE * 0.25
        raise ValueError(
            f"{label}: the eyes are {eye_distance:.4g} units apart, so the head would be ~{metres:.3g} units tall: "
            f"not a human head in m, cm or mm; rescale the mesh to one of them or pass --units"
        )
    return name, UNITS[name]


_AXES = {"x": 0, "y": 1, "z": 2}


def parse_axis(value, name: str) -> np.ndarray | None:
    """A direction from ``"y"``, ``"+z"``, ``"-x"`` … or a 3-vector (None passes through) as a unit vector."""
    if value is None:
        return None
    if isinstance(value, str):
        text = value.strip().lower()
        sign = -1.0 if text.startswith("-") else 1.0
        axis = text.lstrip("+-")
        if axis not in _AXES:
            raise ValueError(f"{name}: expected x, y or z with an optional sign (e.g. '+z', '-y'), got {value!r}")
        vector = np.zeros(3)
        vector[_AXES[axis]] = sign
        return vector
    try:
        vector = np.asarray(value, dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        raise TypeError(f"{name}: expected an axis name or 3 numbers, got {type(value).__name__}") from None
    length = float(np.linalg.norm(vector))
    if not (math.isfinite(length) and length > 0.0):
        raise ValueError(f"{name}: expected a non-zero finite direction, got {vector.tolist()}")
    return vector / length
