"""Eyelid hinges on a USD stage: ``WarpFaceLidMuscle`` prims among the muscles (docs/RIG.md §10).

The per-vertex data (vertex indices, turn angles [rad], slides and lifts [stage units], per unit K)
are uniform arrays; the centre and axis are in the skin's local space like every muscle's.
"""

from __future__ import annotations

import numpy as np
from pxr import Sdf, Usd, Vt

from ..errors import RigError
from ..expression.lids import LidMuscle
from ._prim_values import array_value

__all__ = ["LID_TYPE", "author_lid", "read_lid"]

LID_TYPE = "WarpFaceLidMuscle"


def author_lid(prim: Usd.Prim, lid: LidMuscle) -> None:
    """Write ``lid``'s hinge onto its (already defined) prim."""
    types = Sdf.ValueTypeNames

    def uniform(name, type_name, value):
        prim.CreateAttribute(name, type_name, custom=False, variability=Sdf.VariabilityUniform).Set(value)

    uniform("center", types.Double3, tuple(lid.centre))
    uniform("axis", types.Double3, tuple(lid.axis))
    uniform("vertices", types.IntArray, Vt.IntArray.FromNumpy(np.ascontiguousarray(lid.vertices, dtype=np.int32)))
    for name in ("angles", "slides", "lifts"):
        values = np.ascontiguousarray(getattr(lid, name), dtype=np.float64)
        uniform(name, types.DoubleArray, Vt.DoubleArray.FromNumpy(values))


def read_lid(prim: Usd.Prim, place, to_units: float, name: str) -> LidMuscle:
    """The hinge of a ``WarpFaceLidMuscle`` prim in the skin's space and the caller's units.

    Raises:
        RigError: missing or malformed values (the message starts with the attribute's path).
    """
    length = place.scale * to_units
    vertices = array_value(prim, "vertices", (None,), dtype=np.float64)
    if not np.all(vertices == np.round(vertices)):
        raise RigError(f"{prim.GetPath()}.vertices: expected integers")
    return LidMuscle(
        name=name,
        centre=place.point(array_value(prim, "center", (3,))) * to_units,
        axis=place.direction(array_value(prim, "axis", (3,))),
        vertices=vertices.astype(np.int64),
        angles=array_value(prim, "angles", (None,)),
        slides=array_value(prim, "slides", (None,)) * length,
        lifts=array_value(prim, "lifts", (None,)) * length,
    )
