"""The jaw on a USD stage: a ``WarpFaceJaw`` prim (SPEC §6.2) next to the skin it moves.

The skin lists it in its ``warpFace:jaw`` relationship; the prim carries the hinge (pivot, axis,
forward), one weight per skin point and the animatable controls ``jawOpen`` [rad], ``jawForward`` and
``jawLeft`` [stage units]. Values are in the skin's local space, like the muscles'.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
from pxr import Sdf, Usd, UsdGeom, Vt

from ..errors import RigError
from ..expression.jaw import Jaw

__all__ = ["author_jaw", "read_jaw", "jaw_prim", "JAW_TYPE", "JAW_RELATIONSHIP", "JAW_CONTROL_ATTRIBUTES"]

JAW_TYPE = "WarpFaceJaw"
JAW_RELATIONSHIP = "warpFace:jaw"
JAW_CONTROL_ATTRIBUTES = {"jaw_open": "jawOpen", "jaw_forward": "jawForward", "jaw_left": "jawLeft"}
"""Jaw control name (:data:`warpface.expression.JAW_CONTROL_NAMES`) → its animatable attribute."""


def author_jaw(stage: Usd.Stage, path: Sdf.Path | None, jaw: Jaw | None, skin: Usd.Prim) -> Usd.Prim | None:
    """Define the jaw prim at ``path`` (controls 0 at the default time) and link it from ``skin``; nothing
    for no jaw."""
    if jaw is None:
        return None
    types = Sdf.ValueTypeNames
    prim = stage.DefinePrim(path, JAW_TYPE)
    if jaw.name != prim.GetName():
        prim.SetDisplayName(jaw.name)

    def uniform(name, type_name, value):
        prim.CreateAttribute(name, type_name, custom=False, variability=Sdf.VariabilityUniform).Set(value)

    uniform("pivot", types.Double3, tuple(jaw.pivot))
    uniform("axis", types.Double3, tuple(jaw.axis))
    uniform("forward", types.Double3, tuple(jaw.forward))
    uniform("weights", types.DoubleArray, Vt.DoubleArray.FromNumpy(np.ascontiguousarray(jaw.weights, dtype=np.float64)))
    for attribute in JAW_CONTROL_ATTRIBUTES.values():
        prim.CreateAttribute(attribute, types.Double, custom=False).Set(0.0)
    prim.CreateRelationship("targetMesh", custom=False).SetTargets([skin.GetPath()])
    UsdGeom.Imageable(prim).CreatePurposeAttr(UsdGeom.Tokens.guide)
    skin.CreateRelationship(JAW_RELATIONSHIP, custom=False).SetTargets([path])
    return prim


def jaw_prim(stage: Usd.Stage, skin: Usd.Prim) -> Usd.Prim | None:
    """The jaw prim ``skin`` links to (``warpFace:jaw``), or ``None`` (no link, or a link to nothing)."""
    relationship = skin.GetRelationship(JAW_RELATIONSHIP)
    targets = relationship.GetTargets() if relationship else []
    prim = stage.GetPrimAtPath(targets[0]) if targets else None
    return prim if prim else None


def read_jaw(
    stage: Usd.Stage, skin: Usd.Prim, placement_of: Callable, to_units: float, vertex_count: int
) -> Jaw | None:
    """The jaw linked from ``skin``, in the skin's space and the caller's units, or ``None``.

    Args:
        placement_of: maps a prim to its placement relative to the skin (``.point``, ``.direction``).
        to_units: stage units → the caller's units.
        vertex_count: points of the skin (one weight each).

    Raises:
        RigError: several or missing targets, a wrong prim type, missing or malformed values.
    """
    rel = skin.GetRelationship(JAW_RELATIONSHIP)
    targets = rel.GetTargets() if rel else []
    if not targets:
        return None
    if len(targets) > 1:
        raise RigError(f"{skin.GetPath()}.{JAW_RELATIONSHIP}: at most one jaw, got {len(targets)} targets")
    prim = stage.GetPrimAtPath(targets[0])
    if not prim:
        raise RigError(f"{skin.GetPath()}.{JAW_RELATIONSHIP}: target {targets[0]} does not exist")
    if prim.GetTypeName() != JAW_TYPE:
        raise RigError(f"{prim.GetPath()}: is a {prim.GetTypeName() or 'typeless prim'}, expected {JAW_TYPE}")

    def values(name: str, shape: tuple) -> np.ndarray:
        attr = prim.GetAttribute(name)
        value = attr.Get() if attr else None
        if value is None:
            raise RigError(f"{prim.GetPath()}.{name}: no value authored")
        try:
            array = np.array(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise RigError(f"{prim.GetPath()}.{name}: expected numbers, got a {type(value).__name__}") from None
        if array.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, array.shape)):
            raise RigError(f"{prim.GetPath()}.{name}: expected shape {shape}, got {array.shape}")
        if not np.all(np.isfinite(array)):
            raise RigError(f"{prim.GetPath()}.{name}: non-finite value")
        return array

    weights = values("weights", (None,))
    if len(weights) != vertex_count:
        raise RigError(f"{prim.GetPath()}.weights: has {len(weights)} values, the skin has {vertex_count} points")
    place = placement_of(prim)
    if not math.isfinite(to_units) or to_units <= 0.0:
        raise RigError(f"{prim.GetPath()}: unit conversion must be > 0, got {to_units}")
    name = prim.GetDisplayName() or prim.GetName()
    try:
        return Jaw(
            pivot=place.point(values("pivot", (3,))) * to_units,
            axis=place.direction(values("axis", (3,))),
            forward=place.direction(values("forward", (3,))),
            weights=weights,
            name=name,
        )
    except (TypeError, ValueError) as exc:  # a value of the wrong type on the stage is a bad rig
        raise RigError(f"{prim.GetPath()}: {exc}") from None
