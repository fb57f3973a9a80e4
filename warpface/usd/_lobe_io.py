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
from ._prim_values import array_value

__all__ = ["author_lobes", "read_lobes", "LOBE_ATTRIBUTES"]

LOBE_ATTRIBUTES = (
    "lobes:gain",
    "lobes:attachment",
    "lobes:insertion",
    "lobes:zoneAngle",
    "lobes:falloffStart",
    "lobes:falloffFinish",
)
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


def read_lobes(
    prim: Usd.Prim, point: Callable[[np.ndarray], np.ndarray], to_units: float, length: float
) -> tuple[MuscleLobe, ...]:
    """The lobes of the muscle ``prim`` (empty where ``lobes:gain`` is empty or absent).

    Args:
        point: maps points of the prim's local space (N, 3) into the skin's; to_units: stage → output
            units for points; length: stage → output units for lengths (the placement's scale included).

    Raises:
        RigError: a ``lobes:*`` attribute is missing, not finite, or of another length than ``lobes:gain``
            (ValueError from :class:`~warpface.MuscleLobe` for out-of-range values).
    """
    gain = prim.GetAttribute(LOBE_ATTRIBUTES[0])
    if not gain or gain.Get(_DEFAULT) is None:
        return ()
    gains = array_value(prim, LOBE_ATTRIBUTES[0], (None,))
    count = len(gains)
    if count == 0:
        return ()
    if count > MAX_LOBES:
        raise RigError(f"{prim.GetPath()}.{LOBE_ATTRIBUTES[0]}: at most {MAX_LOBES} lobes, got {count}")
    for name in LOBE_ATTRIBUTES[1:]:
        attr = prim.GetAttribute(name)
        if not attr or attr.Get(_DEFAULT) is None:
            raise RigError(f"{prim.GetPath()}.{name}: attribute is missing (the muscle has lobes)")
    columns = [
        array_value(prim, name, (None, 3) if name in LOBE_ATTRIBUTES[1:3] else (None,)) for name in LOBE_ATTRIBUTES[1:]
    ]
    for name, column in zip(LOBE_ATTRIBUTES[1:], columns):
        if len(column) != count:
            raise RigError(f"{prim.GetPath()}.{name}: {len(column)} entries for {count} lobes (one entry per lobe)")
    attachments, insertions, zones, starts, finishes = columns
    attachments, insertions = point(attachments) * to_units, point(insertions) * to_units
    return tuple(
        MuscleLobe(attachments[k], insertions[k], zones[k], starts[k] * length, finishes[k] * length, gains[k])
        for k in range(count)
    )
