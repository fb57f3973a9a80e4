"""A linear muscle's lobes (:class:`~warpface.MuscleLobe`) as ``lobes:*`` array attributes of its muscle prim.

One entry per lobe, in order: ``lobes:gain`` (schema fallback ``[]``: no lobes), ``lobes:attachment``,
``lobes:insertion`` [stage units, the muscle prim's local space], ``lobes:zoneAngle`` [degrees],
``lobes:falloffStart``, ``lobes:falloffFinish`` [stage units].
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from pxr import Sdf, Usd, Vt

from ..errors import RigError
from ..expression.muscles import MAX_LOBES, MuscleLobe

__all__ = ["author_lobes", "read_lobes", "LOBE_ATTRIBUTES"]

LOBE_ATTRIBUTES = ("lobes:gain", "lobes:attachment", "lobes:insertion", "lobes:zoneAngle", "lobes:falloffStart",
                   "lobes:falloffFinish")
_DEFAULT = Usd.TimeCode.Default()


def author_lobes(prim: Usd.Prim, lobes: tuple[MuscleLobe, ...]) -> None:
    """Write ``lobes`` on the muscle ``prim`` (uniform arrays); nothing for none."""
    if not lobes:
        return
    types = Sdf.ValueTypeNames
    columns = (
        (types.DoubleArray, Vt.DoubleArray([lobe.gain for lobe in lobes])),
        (types.Double3Array, Vt.Vec3dArray.FromNumpy(np.array([lobe.attachment for lobe in lobes]))),
        (types.Double3Array, Vt.Vec3dArray.FromNumpy(np.array([lobe.insertion for lobe in lobes]))),
        (types.DoubleArray, Vt.DoubleArray([lobe.zone_angle_deg for lobe in lobes])),
        (types.DoubleArray, Vt.DoubleArray([lobe.falloff_start for lobe in lobes])),
        (types.DoubleArray, Vt.DoubleArray([lobe.falloff_finish for lobe in lobes])),
    )
    for name, (type_name, value) in zip(LOBE_ATTRIBUTES, columns):
        prim.CreateAttribute(name, type_name, custom=False, variability=Sdf.VariabilityUniform).Set(value)


def read_lobes(prim: Usd.Prim, point: Callable[[np.ndarray], np.ndarray], to_units: float, length: float) -> tuple[MuscleLobe, ...]:
    """The lobes of the muscle ``prim`` (empty where ``lobes:gain`` is empty or absent).

    Args:
        point: maps points of the prim's local space (N, 3) into the skin's; to_units: stage → output
            units for points; length: stage → output units for lengths (the placement's scale included).

    Raises:
        RigError: a ``lobes:*`` attribute is missing, not finite, or of another length than ``lobes:gain``
            (ValueError from :class:`~warpface.MuscleLobe` for out-of-range values).
    """
    gains = _column(prim, "lobes:gain", (None,), required=False)
    if gains is None or len(gains) == 0:
        return ()
    count = len(gains)
    if count > MAX_LOBES:
        raise RigError(f"{prim.GetPath()}.lobes:gain: at most {MAX_LOBES} lobes, got {count}")
    attachments = point(_column(prim, "lobes:attachment", (count, 3))) * to_units
    insertions = point(_column(prim, "lobes:insertion", (count, 3))) * to_units
    zones, starts, finishes = (_column(prim, name, (count,)) for name in LOBE_ATTRIBUTES[3:])
    return tuple(MuscleLobe(attachments[k], insertions[k], zones[k], starts[k] * length, finishes[k] * length, gains[k])
                 for k in range(count))


def _column(prim: Usd.Prim, name: str, shape: tuple, required: bool = True) -> np.ndarray | None:
    attr = prim.GetAttribute(name)
    value = attr.Get(_DEFAULT) if attr else None
    if value is None:
        if required:
            raise RigError(f"{prim.GetPath()}.{name}: attribute is missing (the muscle has lobes)")
        return None
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise RigError(f"{prim.GetPath()}.{name}: expected numbers, got {type(value).__name__}") from None
    if array.ndim != len(shape) or any(want is not None and got != want for got, want in zip(array.shape, shape)):
        raise RigError(f"{prim.GetPath()}.{name}: expected shape {tuple(s or 'n' for s in shape)} (one entry per lobe), "
                       f"got {array.shape}")
    if not np.isfinite(array).all():
        raise RigError(f"{prim.GetPath()}.{name}: non-finite value")
    return array
