"""Named expression presets on a rig stage: fitted (or hand-made) controls any USD tool can read.

Layout (beside the rig written by :func:`warpface.usd.write_rig`)::

    /<Face>/Presets/<name>   Scope
        string   warpFace:presetName   the preset's name as given (prim names must be identifiers)
        token[]  warpFace:muscles      muscle names (as on the muscle prims)
        double[] warpFace:contractions their values, in the muscle prim's own units (like the
                                       ``contraction`` attribute: linear muscles a length, sphincters 1)
        double   warpFace:residual     optional: RMS distance of the fit the preset came from [stage units]
        double   warpFace:jawOpen, warpFace:jawForward, warpFace:jawLeft
                                       optional, on a rig with a jaw: the preset's jaw controls (the angle in
                                       radians, the slides in the jaw prim's own units, like its attributes)

Presets are plain data: applying one is writing its values to the muscles' ``contraction`` (or as time
samples with :func:`warpface.usd.write_animation`). Writing a preset of an existing name replaces it.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
from pxr import Sdf, Tf, Usd, UsdGeom, Vt

from .._validate import as_positive, expect_instance
from .jaw_io import JAW_CONTROL_ATTRIBUTES, jaw_prim
from .rig_io import ItemPlacements, rig_prims, stage_meters_per_unit
from .schema import ensure_schema

__all__ = ["write_presets", "read_presets", "PRESETS_SCOPE"]

PRESETS_SCOPE = "Presets"
_NAME = "warpFace:presetName"
_MUSCLES = "warpFace:muscles"
_VALUES = "warpFace:contractions"
_RESIDUAL = "warpFace:residual"
_LINEAR = "WarpFaceLinearMuscle"


def _scales(stage: Usd.Stage, prims, meters_per_unit: float) -> np.ndarray:
    """Per muscle: the factor turning a stored contraction into ``meters_per_unit`` units."""
    to_units = stage_meters_per_unit(stage) / as_positive(meters_per_unit, "meters_per_unit")
    placements = ItemPlacements(stage, prims.skin)
    return np.array([placements.of(p).scale * to_units if p.GetTypeName() == _LINEAR else 1.0 for p in prims.muscles])


def _jaw_scales(stage: Usd.Stage, prims, meters_per_unit: float) -> dict[str, float]:
    """Jaw control → the factor turning its stored value into ``meters_per_unit`` units (empty without a jaw)."""
    jaw = jaw_prim(stage, prims.skin)
    if jaw is None:
        return {}
    slide = ItemPlacements(stage, prims.skin).of(jaw).scale * stage_meters_per_unit(stage) / meters_per_unit
    return {"jaw_open": 1.0, "jaw_forward": slide, "jaw_left": slide}


def _scope_path(prims) -> Sdf.Path:
    return prims.skin.GetPath().GetParentPath().AppendChild(PRESETS_SCOPE)


def write_presets(
    stage: Usd.Stage,
    presets: Mapping[str, Mapping[str, float]],
    *,
    residuals: Mapping[str, float] | None = None,
    skin_path: str | None = None,
    meters_per_unit: float = 1.0,
) -> list[Sdf.Path]:
    """Author named presets ``{preset: {muscle or jaw control: value}}`` on the rig stage (edit target; not saved).

    Args:
        stage: the rig stage.
        presets: values in ``meters_per_unit`` units (as :func:`~warpface.usd.read_rig` returns the rig);
            muscles a preset leaves out are 0.
        residuals: optional ``{preset: RMS distance}`` in the same units.
        skin_path: the rig's skin (default: the only one).
        meters_per_unit: length unit of the given values in metres.

    Returns:
        The preset prims' paths.

    Raises:
        ValueError: empty or non-string preset names, unknown muscles, non-finite values.
    """
    expect_instance(stage, Usd.Stage, "stage")
    expect_instance(presets, Mapping, "presets")
    ensure_schema()
    prims = rig_prims(stage, skin_path)
    names = prims.muscle_names
    index = {name: i for i, name in enumerate(names)}
    scales = _scales(stage, prims, meters_per_unit)
    jaw_scales = _jaw_scales(stage, prims, as_positive(meters_per_unit, "meters_per_unit"))
    tokens = Vt.TokenArray(names)
    scope = UsdGeom.Scope.Define(stage, _scope_path(prims)).GetPrim()
    written = []
    for preset, controls in presets.items():
        if not isinstance(preset, str):
            raise TypeError(f"presets: expected preset names (str), got {type(preset).__name__}")
        if not preset:
            raise ValueError("presets: a preset name is empty")
        values, jaw = np.zeros(len(names)), {}
        for muscle, value in controls.items():
            if muscle not in index and muscle not in jaw_scales:
                raise ValueError(f"preset {preset!r}: unknown muscle {muscle!r}")
            number = float(value)
            if not np.isfinite(number):
                raise ValueError(f"preset {preset!r}: non-finite value for muscle {muscle!r}")
            if muscle in index:
                values[index[muscle]] = number
            else:
                jaw[muscle] = number / jaw_scales[muscle]
        path = scope.GetPath().AppendChild(Tf.MakeValidIdentifier(preset))
        prim = UsdGeom.Scope.Define(stage, path).GetPrim()
        prim.CreateAttribute(_NAME, Sdf.ValueTypeNames.String, custom=True).Set(preset)
        prim.CreateAttribute(_MUSCLES, Sdf.ValueTypeNames.TokenArray, custom=True).Set(tokens)
        prim.CreateAttribute(_VALUES, Sdf.ValueTypeNames.DoubleArray, custom=True).Set(
            Vt.DoubleArray((values / scales).tolist())
        )
        for control, attribute in JAW_CONTROL_ATTRIBUTES.items():
            if control in jaw:
                prim.CreateAttribute(f"warpFace:{attribute}", Sdf.ValueTypeNames.Double, custom=True).Set(jaw[control])
            elif prim.GetAttribute(f"warpFace:{attribute}"):
                prim.RemoveProperty(f"warpFace:{attribute}")
        if residuals is not None and preset in residuals:
            to_stage = stage_meters_per_unit(stage) / meters_per_unit
            prim.CreateAttribute(_RESIDUAL, Sdf.ValueTypeNames.Double, custom=True).Set(
                float(residuals[preset]) / to_stage
            )
        written.append(path)
    return written


def read_presets(stage, *, skin_path: str | None = None, meters_per_unit: float = 1.0) -> dict[str, dict[str, float]]:
    """The stage's presets ``{preset: {muscle or jaw control: value}}`` in ``meters_per_unit`` units (empty if none).

    Raises:
        RigError: the rig is invalid. ValueError: a preset names a muscle the rig lacks or has
            mismatched arrays.
    """
    from ._files import open_stage

    stage = open_stage(stage)
    prims = rig_prims(stage, skin_path)
    scale = dict(zip(prims.muscle_names, _scales(stage, prims, meters_per_unit)))
    jaw_scales = _jaw_scales(stage, prims, as_positive(meters_per_unit, "meters_per_unit"))
    scope = stage.GetPrimAtPath(_scope_path(prims))
    presets: dict[str, dict[str, float]] = {}
    if not scope:
        return presets
    for prim in scope.GetChildren():
        name_attr, muscles_attr, values_attr = (prim.GetAttribute(a) for a in (_NAME, _MUSCLES, _VALUES))
        if not (muscles_attr and values_attr):
            continue
        name = name_attr.Get() if name_attr else prim.GetName()
        muscles = list(muscles_attr.Get() or [])
        values = np.asarray(values_attr.Get() or [], dtype=np.float64)
        if len(muscles) != len(values):
            raise ValueError(f"{prim.GetPath()}: {len(muscles)} muscles but {len(values)} contractions")
        unknown = [m for m in muscles if m not in scale]
        if unknown:
            raise ValueError(f"{prim.GetPath()}: preset names muscle {unknown[0]!r}, which the rig lacks")
        presets[name] = {muscle: float(value * scale[muscle]) for muscle, value in zip(muscles, values)}
        for control, attribute in JAW_CONTROL_ATTRIBUTES.items():
            stored = prim.GetAttribute(f"warpFace:{attribute}")
            if stored and stored.HasAuthoredValue() and control in jaw_scales:
                presets[name][control] = float(stored.Get()) * jaw_scales[control]
    return presets
