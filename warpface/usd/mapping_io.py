"""Channel → control mappings on the rig stage, where any USD tool can read and edit them.

Layout (one ``Scope`` per mapping, one child ``Scope`` per channel; plain attributes, no schema)::

    def Scope "Drivers" {
        def Scope "default" (doc = "c = M·s + c0 ...") {
            custom uniform string[] warpFace:offsetControls = ["orbicularis_oris"]   # c0, optional
            custom uniform double[] warpFace:offsets = [0.02]
            def Scope "mouthSmileLeft" {
                custom uniform string warpFace:channel = "mouthSmileLeft"
                custom uniform string[] warpFace:controls = ["zygomaticus_major_L"]
                custom uniform double[] warpFace:weights = [0.0134]
            }
        }
    }

under the rig's root prim (the skin's parent): ``/Face/Drivers/default``. A channel's column of
``M`` is its ``controls``/``weights`` pairs; control names are the muscles' names (jaw controls on
rigs with a jaw). Weights are control values per unit of the channel in the stage's units: linear
contractions in stage lengths (``metersPerUnit``), sphincters and angles dimensionless.
"""

from __future__ import annotations

import math

import numpy as np
from pxr import Sdf, Tf, Usd, UsdGeom, Vt

from .._validate import expect_instance
from ..drivers.mapping import Mapping
from ..errors import RigError
from .rig_io import rig_prims

__all__ = ["write_mapping", "read_mapping", "mapping_names", "drivers_scope_path"]

_CHANNEL = "warpFace:channel"
_CONTROLS = "warpFace:controls"
_WEIGHTS = "warpFace:weights"
_OFFSET_CONTROLS = "warpFace:offsetControls"
_OFFSETS = "warpFace:offsets"
_DOC = (
    "Animation driver mapping (SPEC 6.4): controls = M * channels + offsets. Each child names a channel "
    "and the controls it drives with their weights (stage units per unit channel)."
)


def drivers_scope_path(stage: Usd.Stage, skin_path: str | None = None) -> Sdf.Path:
    """``<rig root>/Drivers``: the scope holding a rig's mappings (the rig root is the skin's parent)."""
    expect_instance(stage, Usd.Stage, "stage")
    skin = rig_prims(stage, skin_path).skin
    parent = skin.GetPath().GetParentPath()
    return (parent if parent != Sdf.Path.absoluteRootPath else skin.GetPath()).AppendChild("Drivers")


def _checked_name(name: str) -> str:
    if not isinstance(name, str):
        raise TypeError(f"name: expected a mapping name (str), got {type(name).__name__}")
    if not name or not Tf.IsValidIdentifier(name):
        raise ValueError(f"name: mapping name {name[:60]!r} must be a valid USD identifier (letters, digits, _)")
    return name


def write_mapping(
    stage: Usd.Stage, mapping: Mapping, *, name: str | None = None, skin_path: str | None = None
) -> Sdf.Path:
    """Author ``mapping`` at ``<rig root>/Drivers/<name>`` (replacing one of that name) in the edit target.

    Only non-zero weights are written. The stage is not saved.

    Returns:
        The mapping prim's path.

    Raises:
        ValueError: an invalid name. RigError: the stage has no (single) rig.
    """
    expect_instance(stage, Usd.Stage, "stage")
    if not isinstance(mapping, Mapping):
        raise TypeError(f"mapping: expected a Mapping, got {type(mapping).__name__}")
    name = _checked_name(name or mapping.name)
    path = drivers_scope_path(stage, skin_path).AppendChild(name)
    if stage.GetPrimAtPath(path):
        stage.RemovePrim(path)
    UsdGeom.Scope.Define(stage, path.GetParentPath())
    prim = UsdGeom.Scope.Define(stage, path).GetPrim()
    prim.SetDocumentation(_DOC)
    if np.any(mapping.offsets != 0.0):
        keep = np.flatnonzero(mapping.offsets)
        _set(
            prim, _OFFSET_CONTROLS, Sdf.ValueTypeNames.StringArray, Vt.StringArray([mapping.controls[k] for k in keep])
        )
        _set(prim, _OFFSETS, Sdf.ValueTypeNames.DoubleArray, Vt.DoubleArray([float(mapping.offsets[k]) for k in keep]))
    used = set()
    for column, channel in enumerate(mapping.channels):
        rows = np.flatnonzero(mapping.matrix[:, column])
        identifier = Tf.MakeValidIdentifier(channel)
        while identifier in used:
            identifier += "_"
        used.add(identifier)
        child = UsdGeom.Scope.Define(stage, path.AppendChild(identifier)).GetPrim()
        _set(child, _CHANNEL, Sdf.ValueTypeNames.String, channel)
        _set(child, _CONTROLS, Sdf.ValueTypeNames.StringArray, Vt.StringArray([mapping.controls[k] for k in rows]))
        _set(
            child,
            _WEIGHTS,
            Sdf.ValueTypeNames.DoubleArray,
            Vt.DoubleArray([float(mapping.matrix[k, column]) for k in rows]),
        )
    return path


def _set(prim: Usd.Prim, name: str, type_name, value) -> None:
    prim.CreateAttribute(name, type_name, custom=True, variability=Sdf.VariabilityUniform).Set(value)


def mapping_names(stage: Usd.Stage, skin_path: str | None = None) -> list[str]:
    """Names of the mappings stored on the rig stage (children of ``<rig root>/Drivers``)."""
    expect_instance(stage, Usd.Stage, "stage")
    scope = stage.GetPrimAtPath(drivers_scope_path(stage, skin_path))
    return [child.GetName() for child in scope.GetChildren()] if scope else []


def read_mapping(stage: Usd.Stage, name: str = "default", *, skin_path: str | None = None) -> Mapping:
    """Read the mapping ``name`` stored by :func:`write_mapping` (or edited by hand).

    A channel prim without ``warpFace:channel`` uses its prim name. Controls are returned in first-seen
    order; repeated (channel, control) pairs add up.

    Raises:
        RigError: no such mapping, arrays of different lengths, a weight that is not a finite number
            (the message names the prim and attribute).
    """
    expect_instance(stage, Usd.Stage, "stage")
    name = _checked_name(name)
    path = drivers_scope_path(stage, skin_path).AppendChild(name)
    prim = stage.GetPrimAtPath(path)
    if not prim:
        known = mapping_names(stage, skin_path)
        raise RigError(f"{path}: no mapping named {name!r} on the stage (stored: {', '.join(known) or 'none'})")
    entries, channels = [], []
    for child in prim.GetChildren():
        channel_attr = child.GetAttribute(_CHANNEL)
        channel = channel_attr.Get() if channel_attr and channel_attr.HasAuthoredValue() else child.GetName()
        if not isinstance(channel, str) or not channel.strip():
            raise RigError(f"{child.GetPath()}.{_CHANNEL}: must be a non-empty string")
        if channel in channels:
            raise RigError(f"{child.GetPath()}: channel {channel!r} appears twice in mapping {name!r}")
        channels.append(channel)
        controls = _array(child, _CONTROLS, str)
        weights = _array(child, _WEIGHTS, float)
        if len(controls) != len(weights):
            raise RigError(f"{child.GetPath()}: {len(controls)} {_CONTROLS} but {len(weights)} {_WEIGHTS}")
        entries += [(channel, control, weight) for control, weight in zip(controls, weights)]
    offset_controls = _array(prim, _OFFSET_CONTROLS, str)
    offsets = _array(prim, _OFFSETS, float)
    if len(offset_controls) != len(offsets):
        raise RigError(f"{prim.GetPath()}: {len(offset_controls)} {_OFFSET_CONTROLS} but {len(offsets)} {_OFFSETS}")
    if len(set(offset_controls)) != len(offset_controls):
        raise RigError(f"{prim.GetPath()}.{_OFFSET_CONTROLS}: a control appears twice")
    mapping = Mapping.from_entries(entries, name=name, offsets=dict(zip(offset_controls, offsets)))
    missing = [c for c in channels if c not in mapping.channels]  # channels with no weights still count
    if missing:
        mapping = mapping.merged(Mapping(channels=missing, controls=[], matrix=np.zeros((0, len(missing)))), name=name)
    return mapping


def _array(prim: Usd.Prim, name: str, kind) -> list:
    attribute = prim.GetAttribute(name)
    if not attribute or not attribute.HasAuthoredValue():
        return []
    value = attribute.Get()
    try:
        items = [kind(v) for v in value]
    except (TypeError, ValueError):
        raise RigError(
            f"{attribute.GetPath()}: expected an array of {'strings' if kind is str else 'numbers'}"
        ) from None
    if kind is float and not all(math.isfinite(v) for v in items):
        raise RigError(
            f"{attribute.GetPath()}: entry {next(i for i, v in enumerate(items) if not math.isfinite(v))} is not a "
            "finite number"
        )
    return items
