"""Blendshape weight curves as ``UsdSkel.Animation`` prims: ``blendShapes`` + time-sampled ``blendShapeWeights``.

This is what NVIDIA Audio2Face-3D exports (channel names are ARKit's lowerCamel ones, e.g.
``browInnerUp``), and what warpface exports for other rigs. Times in seconds are time codes divided
by the stage's ``timeCodesPerSecond``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdSkel, Vt

from .._validate import as_path, expect_instance
from ..drivers.channels import Curves, canonical_channel
from ._files import LAYER_SUFFIXES, checked_prim_path, export_layer_atomically, open_stage, writable_path

__all__ = ["read_skel_animation", "write_skel_animation", "find_skel_animations", "export_arkit_weights"]


def find_skel_animations(stage: Usd.Stage) -> list[Usd.Prim]:
    """Every ``SkelAnimation`` prim on the stage that authors ``blendShapes``, in traversal order."""
    expect_instance(stage, Usd.Stage, "stage")
    return [
        prim
        for prim in stage.Traverse()
        if prim.IsA(UsdSkel.Animation) and UsdSkel.Animation(prim).GetBlendShapesAttr().HasAuthoredValue()
    ]


def read_skel_animation(stage_or_path, *, prim_path: str | None = None) -> Curves:
    """Read blendshape weights from a ``SkelAnimation`` (default: the only one that has ``blendShapes``).

    Returns:
        Curves with one channel per ``blendShapes`` entry (canonical spelling), times [s] = the
        weights' time samples / ``timeCodesPerSecond`` (a single default value is one frame at 0 s);
        ``fps`` = ``timeCodesPerSecond``.

    Raises:
        ValueError: not a USD file, no (or several, without ``prim_path``) blendshape animations,
            weights of the wrong length or not finite, repeated names.
    """
    stage = open_stage(stage_or_path)
    label = Path(stage.GetRootLayer().identifier).name
    if prim_path is not None:
        prim = stage.GetPrimAtPath(checked_prim_path(prim_path, "prim_path"))
        if not prim or not prim.IsA(UsdSkel.Animation):
            raise ValueError(f"{label}: no SkelAnimation at {prim_path}")
    else:
        found = find_skel_animations(stage)
        if not found:
            raise ValueError(f"{label}: no SkelAnimation with blendShapes on the stage")
        if len(found) > 1:
            raise ValueError(
                f"{label}: {len(found)} SkelAnimations with blendShapes "
                f"({', '.join(str(p.GetPath()) for p in found[:4])}); choose one"
            )
        prim = found[0]
    animation = UsdSkel.Animation(prim)
    names = [canonical_channel(n) for n in (animation.GetBlendShapesAttr().Get() or [])]
    if not names:
        raise ValueError(f"{label}: {prim.GetPath()}.blendShapes is empty")
    weights = animation.GetBlendShapeWeightsAttr()
    samples = weights.GetTimeSamples()
    codes = list(samples) if samples else [Usd.TimeCode.Default()]
    values = np.empty((len(codes), len(names)))
    for row, code in enumerate(codes):
        value = weights.Get(code)
        if value is None:
            raise ValueError(f"{label}: {weights.GetPath()} has no value" + (f" at time {code}" if samples else ""))
        array = np.asarray(value, dtype=np.float64)
        if array.shape != (len(names),):
            raise ValueError(
                f"{label}: {weights.GetPath()} at time {code} has {array.size} weights for {len(names)} blendShapes"
            )
        values[row] = array
    rate = stage.GetTimeCodesPerSecond()
    if not (math.isfinite(rate) and rate > 0):
        raise ValueError(f"{label}: timeCodesPerSecond {rate} is not a positive number")
    times = np.array(codes, dtype=np.float64) / rate if samples else np.zeros(1)
    return Curves(times=times, names=names, values=values, source=f"{label}:{prim.GetPath()}", fps=float(rate))


def write_skel_animation(path, curves: Curves, *, prim_path: str = "/Animation", fps: float | None = None) -> Path:
    """Write ``curves`` as a ``SkelAnimation`` at ``prim_path`` in a new layer (``.usda``/``.usdc``).

    Time codes are ``times · fps`` (default ``curves.fps``, else 60), and the layer's
    ``timeCodesPerSecond``/``framesPerSecond`` are set to ``fps``. Written via temporary file + rename.
    """
    target = writable_path(path, LAYER_SUFFIXES)
    rate = float(fps if fps is not None else (curves.fps or 60.0))
    if not (math.isfinite(rate) and rate > 0):
        raise ValueError(f"fps must be a positive number, got {rate!r}")
    checked_prim_path(prim_path, "prim_path")
    stage = Usd.Stage.CreateInMemory(f"skel{target.suffix}")
    animation = UsdSkel.Animation.Define(stage, prim_path)
    stage.SetDefaultPrim(stage.GetPrimAtPath(Sdf.Path(prim_path).GetPrefixes()[0]))
    animation.CreateBlendShapesAttr(Vt.TokenArray(list(curves.names)))
    attribute = animation.CreateBlendShapeWeightsAttr()
    layer = stage.GetRootLayer()
    codes = curves.times * rate
    with Sdf.ChangeBlock():
        for row, code in enumerate(codes.tolist()):
            layer.SetTimeSample(
                attribute.GetPath(), code, Vt.FloatArray.FromNumpy(curves.values[row].astype(np.float32))
            )
    layer.timeCodesPerSecond = rate
    layer.framesPerSecond = rate
    layer.startTimeCode, layer.endTimeCode = float(codes[0]), float(codes[-1])
    export_layer_atomically(layer, target)
    return target


def export_arkit_weights(stage_or_path, out_path, *, mapping: str | None = None, fps: float | None = None) -> Path:
    """Export an animated (or solved) rig's controls as ARKit weights: a Live Link Face CSV (``.csv``) or a
    ``SkelAnimation`` layer (``.usda``/``.usdc``).

    The weights are the bounded least-squares projection of the controls onto the mapping's ARKit columns
    (:func:`warpface.drivers.project_controls`): the rig's stored ``mapping`` (default: its ``default``
    mapping when stored, else the default table for the rig).

    Raises:
        ValueError: nothing animated, no ARKit channel in the mapping, bad output path.
    """
    from ..drivers import ARKIT_CHANNELS, Mapping, controls_to_curves, mapping_for_rig, write_live_link
    from .animation import read_animation
    from .mapping_io import mapping_names, read_mapping
    from .rig_io import read_rig, stage_meters_per_unit

    stage = open_stage(stage_or_path)
    out = as_path(out_path, "out_path")
    if out.suffix.lower() not in (".csv",) + LAYER_SUFFIXES:
        raise ValueError(f"{out}: export to .csv (Live Link Face) or .usda/.usdc (SkelAnimation)")
    units = stage_meters_per_unit(stage)
    animation = read_animation(stage, meters_per_unit=units)
    if len(animation.times) == 0:
        raise ValueError(f"{Path(stage.GetRootLayer().identifier).name}: the rig is not animated")
    if mapping is not None or "default" in mapping_names(stage):
        table = read_mapping(stage, mapping or "default")
    else:
        table = mapping_for_rig(read_rig(stage, meters_per_unit=units), "arkit")[0]
    keep = [c for c, name in enumerate(table.channels) if name in set(ARKIT_CHANNELS)]
    if not keep:
        raise ValueError(f"mapping {table.name!r} has no ARKit channel to export")
    arkit = Mapping(
        channels=[table.channels[c] for c in keep],
        controls=table.controls,
        matrix=table.matrix[:, keep],
        offsets=table.offsets,
        name=table.name,
    )
    controls = {
        name: animation.controls[:, k] for k, name in enumerate(animation.control_names) if name in arkit.controls
    }
    rate = float(fps or stage.GetTimeCodesPerSecond())
    curves = controls_to_curves(
        arkit,
        animation.times / stage.GetTimeCodesPerSecond(),
        controls,
        source=Path(stage.GetRootLayer().identifier).name,
        fps=rate,
    )
    if out.suffix.lower() == ".csv":
        return write_live_link(out, curves, fps=round(rate))
    return write_skel_animation(out, curves, fps=rate)
