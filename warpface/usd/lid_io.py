"""Eyelid hinges and the lip seal on a USD stage: ``WarpFaceLidMuscle`` prims among the muscles (docs/RIG.md
§11–12); a seal also carries its ``sealPairs``.

The per-vertex data (vertex indices, turn angles [rad], slides and lifts [stage units], per unit K)
are uniform arrays; the centre and axis are in the skin's local space like every muscle's; ``taperShare`` is the
hinge's share of the wrinkle and bulge taper (a stage without it reads as 1), ``fitLimit`` the largest K a fit may
use (a stage without it reads as 1).
"""

from __future__ import annotations

import numpy as np
from pxr import Sdf, Usd, Vt

from ..errors import RigError
from ..expression.lids import MAX_FIT_LIMIT, LidMuscle
from ..expression.seal import LipSeal
from ._prim_values import array_value, scalar_value

__all__ = ["LID_TYPE", "LidMuscle", "author_lid", "read_lid"]

LID_TYPE = "WarpFaceLidMuscle"


def author_lid(stage: Usd.Stage, path: Sdf.Path, lid: LidMuscle) -> Usd.Prim:
    """Define ``lid``'s prim at ``path`` with its hinge (the muscle's shared attributes are the caller's)."""
    types = Sdf.ValueTypeNames
    prim = stage.DefinePrim(path, LID_TYPE)

    def uniform(name, type_name, value):
        prim.CreateAttribute(name, type_name, custom=False, variability=Sdf.VariabilityUniform).Set(value)

    uniform("center", types.Double3, tuple(lid.center))
    uniform("axis", types.Double3, tuple(lid.axis))
    uniform("vertices", types.IntArray, Vt.IntArray.FromNumpy(np.ascontiguousarray(lid.vertices, dtype=np.int32)))
    for name in ("angles", "slides", "lifts"):
        values = np.ascontiguousarray(getattr(lid, name), dtype=np.float64)
        uniform(name, types.DoubleArray, Vt.DoubleArray.FromNumpy(values))
    uniform("taperShare", types.Double, float(lid.taper_share))
    uniform("fitLimit", types.Double, float(lid.fit_limit))
    if isinstance(lid, LipSeal):
        pairs = np.ascontiguousarray(lid.pairs.reshape(-1), dtype=np.int32)
        uniform("sealPairs", types.IntArray, Vt.IntArray.FromNumpy(pairs))
    return prim


def read_lid(prim: Usd.Prim, place, to_units: float, name: str) -> LidMuscle:
    """The hinge of a ``WarpFaceLidMuscle`` prim in the skin's space and the caller's units.

    Raises:
        RigError: missing or malformed values (the message starts with the attribute's path).
    """
    length = place.scale * to_units
    vertices = _indices(prim, "vertices")
    seal = prim.GetAttribute("sealPairs")
    pairs = _indices(prim, "sealPairs") if seal and seal.HasAuthoredValue() else None
    if pairs is not None and len(pairs) % 2:
        raise RigError(f"{prim.GetPath()}.sealPairs: expected (upper, lower) pairs, got {len(pairs)} values")
    kind, extra = (LidMuscle, {}) if pairs is None else (LipSeal, {"pairs": pairs.reshape(-1, 2)})
    share = prim.GetAttribute("taperShare")
    if share and share.HasAuthoredValue():  # a stage written before the attribute keeps the taper it had
        extra["taper_share"] = scalar_value(prim, "taperShare")
        if not 0.0 < extra["taper_share"] <= 1.0:
            raise RigError(f"{prim.GetPath()}.taperShare: expected a value in (0, 1], got {extra['taper_share']}")
    limit = prim.GetAttribute("fitLimit")
    if limit and limit.HasAuthoredValue():  # a stage written before the attribute keeps the full turn
        extra["fit_limit"] = scalar_value(prim, "fitLimit")
        if not 0.0 < extra["fit_limit"] <= MAX_FIT_LIMIT:
            raise RigError(
                f"{prim.GetPath()}.fitLimit: expected a value in (0, {MAX_FIT_LIMIT:g}], got {extra['fit_limit']}"
            )
    return kind(
        name=name,
        center=place.point(array_value(prim, "center", (3,))) * to_units,
        axis=place.direction(array_value(prim, "axis", (3,))),
        vertices=vertices.astype(np.int64),
        angles=array_value(prim, "angles", (None,)),
        slides=array_value(prim, "slides", (None,)) * length,
        lifts=array_value(prim, "lifts", (None,)) * length,
        **extra,
    )


def _indices(prim: Usd.Prim, name: str) -> np.ndarray:
    values = array_value(prim, name, (None,), dtype=np.float64)
    if not np.all(values == np.round(values)):
        raise RigError(f"{prim.GetPath()}.{name}: expected integers")
    return values.astype(np.int64)
