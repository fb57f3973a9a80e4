"""A linear muscle's lobe (:class:`~warpface.MuscleLobe`) as ``lobe:*`` attributes of its muscle prim.

``lobe:gain`` (schema fallback 0: no lobe) and, when it is above 0, the lobe's own zone:
``lobe:attachment``, ``lobe:insertion`` [stage units, the muscle prim's local space], ``lobe:zoneAngle``
[degrees], ``lobe:falloffStart``, ``lobe:falloffFinish`` [stage units].
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
from pxr import Sdf, Usd

from ..errors import RigError
from ..expression.muscles import MuscleLobe

__all__ = ["author_lobe", "read_lobe", "LOBE_GAIN"]

LOBE_GAIN = "lobe:gain"
_DEFAULT = Usd.TimeCode.Default()


def author_lobe(prim: Usd.Prim, lobe: MuscleLobe | None) -> None:
    """Write ``lobe`` on the muscle ``prim`` (uniform attributes); nothing for no lobe."""
    if lobe is None:
        return
    types = Sdf.ValueTypeNames
    values = ((LOBE_GAIN, types.Double, lobe.gain), ("lobe:attachment", types.Double3, tuple(lobe.attachment)),
              ("lobe:insertion", types.Double3, tuple(lobe.insertion)), ("lobe:zoneAngle", types.Double, lobe.zone_angle_deg),
              ("lobe:falloffStart", types.Double, lobe.falloff_start), ("lobe:falloffFinish", types.Double, lobe.falloff_finish))
    for name, type_name, value in values:
        prim.CreateAttribute(name, type_name, custom=False, variability=Sdf.VariabilityUniform).Set(value)


def read_lobe(prim: Usd.Prim, point: Callable[[np.ndarray], np.ndarray], to_units: float, length: float) -> MuscleLobe | None:
    """The lobe of the muscle ``prim``, or ``None`` where ``lobe:gain`` is 0 or absent.

    Args:
        point: maps a point of the prim's local space into the skin's; to_units: stage → output units
            for points; length: stage → output units for lengths (the placement's scale included).

    Raises:
        RigError: a lobe attribute is missing or not a finite number / 3-vector (ValueError from
            :class:`~warpface.MuscleLobe` for out-of-range values).
    """
    gain = _number(prim, LOBE_GAIN, required=False)
    if gain is None or gain == 0.0:
        return None
    return MuscleLobe(
        attachment=point(_vector(prim, "lobe:attachment")) * to_units,
        insertion=point(_vector(prim, "lobe:insertion")) * to_units,
        zone_angle_deg=_number(prim, "lobe:zoneAngle"),
        falloff_start=_number(prim, "lobe:falloffStart") * length,
        falloff_finish=_number(prim, "lobe:falloffFinish") * length,
        gain=gain,
    )


def _number(prim: Usd.Prim, name: str, required: bool = True) -> float | None:
    attr = prim.GetAttribute(name)
    value = attr.Get(_DEFAULT) if attr else None
    if value is None:
        if required:
            raise RigError(f"{prim.GetPath()}.{name}: attribute is missing (the muscle has a lobe)")
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise RigError(f"{prim.GetPath()}.{name}: expected a finite number, got {value!r}")
    return float(value)


def _vector(prim: Usd.Prim, name: str) -> np.ndarray:
    attr = prim.GetAttribute(name)
    value = attr.Get(_DEFAULT) if attr else None
    if value is None:
        raise RigError(f"{prim.GetPath()}.{name}: attribute is missing (the muscle has a lobe)")
    try:
        vector = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise RigError(f"{prim.GetPath()}.{name}: expected 3 numbers, got {value!r}") from None
    if vector.shape != (3,) or not np.isfinite(vector).all():
        raise RigError(f"{prim.GetPath()}.{name}: expected 3 finite numbers, got {value!r}")
    return vector
