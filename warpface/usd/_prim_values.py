"""Default-time attribute values of a prim, read and checked: one RigError naming ``<prim path>.<attribute>``
for a missing attribute, a value of the wrong kind or shape, or a non-finite number."""

from __future__ import annotations

import math

import numpy as np
from pxr import Usd

from ..errors import RigError

__all__ = ["attribute_value", "array_value", "scalar_value", "token_value", "check_finite"]

_DEFAULT = Usd.TimeCode.Default()


def attribute_value(prim: Usd.Prim, name: str):
    """The attribute's value at the default time (its schema fallback where none is authored)."""
    attr = prim.GetAttribute(name)
    if not attr:
        raise RigError(f"{prim.GetPath()}.{name}: attribute is missing")
    value = attr.Get(_DEFAULT)
    if value is None:
        raise RigError(f"{prim.GetPath()}.{name}: no value authored and no schema fallback")
    return value


def array_value(prim: Usd.Prim, name: str, shape: tuple, dtype=np.float64) -> np.ndarray:
    """An attribute's default value as an array of ``shape`` (``None`` = any length), checked finite."""
    value = attribute_value(prim, name)
    label = f"{prim.GetPath()}.{name}"
    try:
        array = np.array(value, dtype=dtype)
    except (TypeError, ValueError):
        raise RigError(f"{label}: expected numbers, got a {type(value).__name__}") from None
    if array.size == 0 and len(shape) == 2:
        array = array.reshape(0, shape[1])
    if array.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, array.shape)):
        expected = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise RigError(f"{label}: expected shape {expected}, got {array.shape}")
    if np.issubdtype(array.dtype, np.floating):
        check_finite(array, label)
    return array


def scalar_value(prim: Usd.Prim, name: str) -> float:
    """An attribute's default value as a finite float."""
    value = attribute_value(prim, name)
    if not isinstance(value, (int, float)):
        raise RigError(f"{prim.GetPath()}.{name}: expected a number, got {type(value).__name__}")
    value = float(value)
    if not math.isfinite(value):
        raise RigError(f"{prim.GetPath()}.{name}: non-finite value {value}")
    return value


def token_value(prim: Usd.Prim, name: str, allowed: tuple[str, ...]) -> str:
    """An attribute's default value, which must be one of ``allowed``."""
    value = attribute_value(prim, name)
    if value not in allowed:
        raise RigError(f"{prim.GetPath()}.{name}: must be one of {', '.join(allowed)}, got {value!r}")
    return str(value)


def check_finite(array: np.ndarray, label: str) -> None:
    """RigError naming ``label`` and the first non-finite entry of ``array``."""
    bad = np.argwhere(~np.isfinite(array))
    if len(bad):
        index = tuple(int(i) for i in bad[0])
        raise RigError(f"{label}: non-finite value {array[index]} at index {index if len(index) > 1 else index[0]}")
