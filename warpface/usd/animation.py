"""Animation on a rig stage: contractions and wrinkle depths as time samples, and point-cache bakes.

Controls live on the rig prims (``contraction`` on muscles, ``depth`` on wrinkles), authored in the
stage's edit target. :func:`bake` evaluates the expression model at every requested time code and
writes the skin's ``points`` and ``extent`` time samples into a ``.usdc`` cache layer, sublayered
(strongest sublayer) under the rig layer. The rest shape lives in the skin's ``warpFaceShape``
variant (see :mod:`warpface.usd.rig_io`), which every sublayer opinion overrides.

Every file is written through a temporary file and a rename: interrupting a bake (Ctrl-C, crash,
error) leaves the previous rig layer and cache exactly as they were.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np
from pxr import Sdf, Usd, UsdGeom, Vt

from .._validate import as_finite_array, as_positive
from ..errors import RigError
from ._files import export_layer_atomically, open_stage, writable_path
from .rig_io import ItemPlacements, RigPrims, read_rig, rig_prims, stage_meters_per_unit
from .schema import ensure_schema

__all__ = ["Animation", "write_animation", "read_animation", "frame_times", "bake", "DEFAULT_FPS", "CACHE_SUFFIX"]

DEFAULT_FPS = 30.0
"""``timeCodesPerSecond`` / ``framesPerSecond`` given to an animated stage that has none."""

CACHE_SUFFIX = "_anim.usdc"
"""Default cache file: ``<rig layer stem>_anim.usdc`` beside the rig layer."""

_LINEAR = "WarpFaceLinearMuscle"


@dataclass(frozen=True)
class Animation:
    """Rig controls sampled at time codes."""

    times: np.ndarray
    """Time codes, shape (F,), float64 (frames; seconds = time / timeCodesPerSecond)."""
    contractions: np.ndarray
    """Muscle contractions in muscle order, shape (F, M), float64 (linear: length units; sphincter: 1)."""
    wrinkle_depths: np.ndarray
    """Wrinkle depths ``k_d`` in wrinkle order [length units], shape (F, W), float64."""
    muscle_names: list[str]
    wrinkle_names: list[str]


# ---------------------------------------------------------------------------------------------- controls


def _length_scales(stage: Usd.Stage, prims: RigPrims, meters_per_unit: float) -> tuple[np.ndarray, np.ndarray]:
    """Factors turning stored control values into values in ``meters_per_unit`` units, per muscle and wrinkle.

    Linear-muscle contractions and wrinkle depths are lengths in their prim's local space; sphincter
    contractions are dimensionless.
    """
    to_units = stage_meters_per_unit(stage) / as_positive(meters_per_unit, "meters_per_unit")
    placements = ItemPlacements(stage, prims.skin)
    muscle = np.array([placements.of(p).scale * to_units if p.GetTypeName() == _LINEAR else 1.0 for p in prims.muscles])
    wrinkle = np.array([placements.of(p).scale * to_units for p in prims.wrinkles])
    return muscle, wrinkle


def _control_table(values, names: list[str], frame_count: int, label: str, kind: str) -> tuple[list[int], np.ndarray]:
    """(columns, values (F, len(columns))) from an (F, N) array or a mapping name → (F,) values."""
    if isinstance(values, Mapping):
        index = {name: i for i, name in enumerate(names)}
        columns, rows = [], []
        for name, series in values.items():
            if name not in index:
                raise ValueError(f"{label}: unknown {kind} name {name!r} (known: {', '.join(names) or 'none'})")
            columns.append(index[name])
            rows.append(as_finite_array(series, f"{label}[{name!r}]", shape=(frame_count,)))
        return columns, np.stack(rows, axis=1) if rows else np.zeros((frame_count, 0))
    table = as_finite_array(values, label, shape=(frame_count, len(names)))
    return list(range(len(names))), table


def _times(times, label: str = "times") -> np.ndarray:
    times = as_finite_array(times, label, shape=(None,))
    if len(times) == 0:
        raise ValueError(f"{label}: no time codes given")
    if len(np.unique(times)) != len(times):
        raise ValueError(f"{label}: time codes repeat")
    return times


def write_animation(stage: Usd.Stage, times, *, contractions=None, wrinkle_depths=None, skin_path: str | None = None,
                    fps: float | None = None, meters_per_unit: float = 1.0) -> None:
    """Author contractions and wrinkle depths as time samples on the rig prims.

    Existing samples of an animated attribute between ``min(times)`` and ``max(times)`` are replaced;
    samples outside that range are kept. The stage's ``startTimeCode``/``endTimeCode`` grow to cover
    ``times``; ``timeCodesPerSecond`` and ``framesPerSecond`` are set to ``fps`` (or to 30 when the
    stage has none).

    Args:
        stage: the rig stage; samples go to its edit target, time metadata to its root layer. Not saved.
        times: time codes, shape (F,).
        contractions: shape (F, M) in muscle order, or ``{muscle name: (F,) values}``.
        wrinkle_depths: shape (F, W) in wrinkle order, or ``{wrinkle name: (F,) values}``.
        skin_path: the rig's skin mesh (default: the only one).
        fps: frames per second.
        meters_per_unit: length unit of the given values in metres (as returned by ``read_rig``).

    Raises:
        ValueError: wrong shapes, unknown names, non-finite values, repeated times.
        RigError: the stage's rig is invalid.
    """
    ensure_schema()
    times = _times(times)
    prims = rig_prims(stage, skin_path)
    muscle_scale, wrinkle_scale = _length_scales(stage, prims, meters_per_unit)
    series = []
    if contractions is not None:
        columns, table = _control_table(contractions, prims.muscle_names, len(times), "contractions", "muscle")
        series += [(prims.muscles[c], "contraction", table[:, k] / muscle_scale[c]) for k, c in enumerate(columns)]
    if wrinkle_depths is not None:
        columns, table = _control_table(wrinkle_depths, prims.wrinkle_names, len(times), "wrinkle_depths", "wrinkle")
        series += [(prims.wrinkles[c], "depth", table[:, k] / wrinkle_scale[c]) for k, c in enumerate(columns)]

    layer = stage.GetEditTarget().GetLayer()
    paths = []
    for prim, name, _ in series:  # specs first: never create specs inside a change block
        paths.append(stage.GetEditTarget().MapToSpecPath(prim.GetPath().AppendProperty(name)))
        if layer.GetAttributeAtPath(paths[-1]) is None:
            prim.CreateAttribute(name, Sdf.ValueTypeNames.Double, custom=False)
    low, high = float(times.min()), float(times.max())
    with Sdf.ChangeBlock():
        for path, (_, _, values) in zip(paths, series):
            for time in layer.ListTimeSamplesForPath(path):
                if low <= time <= high:
                    layer.EraseTimeSample(path, time)
            for time, value in zip(times.tolist(), values.tolist()):
                layer.SetTimeSample(path, time, value)
    _cover_time_range(stage.GetRootLayer(), low, high, fps)


def _cover_time_range(layer: Sdf.Layer, low: float, high: float, fps: float | None) -> None:
    """Grow the layer's start/end time codes to cover [low, high]; author both rates."""
    if fps is not None:
        fps = as_positive(fps, "fps")
        layer.timeCodesPerSecond = fps
        layer.framesPerSecond = fps
    else:
        rate = layer.timeCodesPerSecond if layer.HasTimeCodesPerSecond() else (
            layer.framesPerSecond if layer.HasFramesPerSecond() else DEFAULT_FPS)
        if not layer.HasTimeCodesPerSecond():
            layer.timeCodesPerSecond = rate
        if not layer.HasFramesPerSecond():
            layer.framesPerSecond = layer.timeCodesPerSecond
    if layer.HasStartTimeCode() and layer.HasEndTimeCode():
        low, high = min(low, layer.startTimeCode), max(high, layer.endTimeCode)
    layer.startTimeCode = low
    layer.endTimeCode = high


def frame_times(stage: Usd.Stage, skin_path: str | None = None) -> np.ndarray:
    """The time codes an animation plays at, shape (F,), float64.

    Whole frames from ``startTimeCode`` to ``endTimeCode`` when the stage authors them; otherwise the
    union of the contraction and depth time samples; empty when nothing is animated.
    """
    if stage.HasAuthoredTimeCodeRange():
        start, end = stage.GetStartTimeCode(), stage.GetEndTimeCode()
        if not (math.isfinite(start) and math.isfinite(end)) or end < start:
            raise RigError(f"stage {stage.GetRootLayer().identifier}: invalid time range [{start}, {end}]")
        return np.arange(math.ceil(start), math.floor(end) + 1, dtype=np.float64)
    prims = rig_prims(stage, skin_path)
    samples = set()
    for prim, name in [(p, "contraction") for p in prims.muscles] + [(p, "depth") for p in prims.wrinkles]:
        samples.update(prim.GetAttribute(name).GetTimeSamples())
    return np.array(sorted(samples), dtype=np.float64)


def read_animation(stage_or_path, times=None, *, skin_path: str | None = None, meters_per_unit: float = 1.0) -> Animation:
    """Sample contractions and wrinkle depths at time codes (USD value resolution: held or interpolated).

    Args:
        stage_or_path: the rig stage or its file.
        times: time codes, shape (F,); default :func:`frame_times`.
        skin_path: the rig's skin mesh (default: the only one).
        meters_per_unit: length unit of the returned values in metres (default SI).

    Raises:
        RigError: a value is missing or non-finite (named by attribute path and time).
    """
    ensure_schema()
    stage = open_stage(stage_or_path)
    prims = rig_prims(stage, skin_path)
    times = frame_times(stage, skin_path) if times is None else as_finite_array(times, "times", shape=(None,))
    muscle_scale, wrinkle_scale = _length_scales(stage, prims, meters_per_unit)
    contractions = _sample(prims.muscles, "contraction", times) * muscle_scale
    depths = _sample(prims.wrinkles, "depth", times) * wrinkle_scale
    return Animation(times=times, contractions=contractions, wrinkle_depths=depths,
                     muscle_names=prims.muscle_names, wrinkle_names=prims.wrinkle_names)


def _sample(prims, name: str, times: np.ndarray) -> np.ndarray:
    table = np.empty((len(times), len(prims)), dtype=np.float64)
    for column, prim in enumerate(prims):
        attr = prim.GetAttribute(name)
        if not attr:
            raise RigError(f"{prim.GetPath()}.{name}: attribute is missing")
        query = Usd.AttributeQuery(attr)
        for row, time in enumerate(times.tolist()):
            value = query.Get(time)
            if value is None or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise RigError(f"{attr.GetPath()}: bad value {value!r} at time {time}")
            table[row, column] = value
    return table


# ---------------------------------------------------------------------------------------------- bake


def bake(stage_or_path, frames=None, *, cache_path=None, skin_path: str | None = None, model=None, device=None,
         progress: bool = True, chunk_frames: int = 32) -> Path:
    """Evaluate the expression model at every time code and write the skin's points and extent as a cache.

    The cache layer (``.usdc``: raw float32, memory-mapped) is sublayered as the strongest sublayer of
    the rig (root) layer, and the rig layer's time range grows to cover ``frames``. Re-baking a range
    replaces the cached samples in ``[min(frames), max(frames)]`` and keeps the others. Files are
    written through a temporary file and a rename; on any interruption the previous files stay intact.

    Args:
        stage_or_path: the rig stage or its file. A file-backed root layer is saved (it gains the
            sublayer); an in-memory one is only edited and needs ``cache_path``.
        frames: time codes to bake, shape (F,); default :func:`frame_times` of the stage.
        cache_path: the cache file (``.usdc``, or ``.usda`` for inspection); default
            ``<rig layer stem>_anim.usdc`` beside the rig layer.
        skin_path: the rig's skin mesh (default: the only one).
        model: a prebuilt :class:`~warpface.ExpressionModel` of this rig in stage units (optional).
        device: Warp device for the model (default: Warp's preferred device).
        progress: show a progress bar.
        chunk_frames: frames evaluated per batch.

    Returns:
        The cache file path.

    Raises:
        ValueError: no frames, unwritable paths, bad arguments.
        RigError: the rig on the stage is invalid, or the rig layer authors the skin's points
            directly (which would hide the cache).
    """
    ensure_schema()
    stage = open_stage(stage_or_path)
    prims = rig_prims(stage, skin_path)
    skin_path = prims.skin.GetPath()
    times = frame_times(stage, skin_path) if frames is None else _times(frames, "frames")
    if len(times) == 0:
        raise ValueError(f"nothing to bake: stage {stage.GetRootLayer().identifier} has no time range or time samples; pass frames")
    chunk_frames = int(chunk_frames)
    if chunk_frames < 1:
        raise ValueError(f"chunk_frames must be ≥ 1, got {chunk_frames}")
    root = stage.GetRootLayer()
    root_file = None if root.anonymous else Path(root.realPath)
    if cache_path is None:
        if root_file is None:
            raise ValueError("bake: the stage's root layer is in memory; pass cache_path")
        cache_path = root_file.with_name(root_file.stem + CACHE_SUFFIX)
    cache_path = writable_path(cache_path, (".usdc", ".usda"))
    if root_file is not None:
        writable_path(root_file)
    _check_not_masked(stage, skin_path, cache_path)

    stage_unit = stage_meters_per_unit(stage)
    if model is None:
        from ..expression.model import ExpressionModel

        model = ExpressionModel.from_rig(read_rig(stage, skin_path=str(skin_path), meters_per_unit=stage_unit), device=device)
    elif model.mesh.vertex_count != len(prims.skin.GetAttribute(UsdGeom.Tokens.points).Get(Usd.TimeCode.Default()) or ()):
        raise ValueError(f"bake: the model has {model.mesh.vertex_count} vertices, the skin {skin_path} a different count")
    animation = read_animation(stage, times, skin_path=str(skin_path), meters_per_unit=stage_unit)
    if animation.muscle_names != list(model.muscle_names) or animation.wrinkle_names != list(model.wrinkle_names):
        raise ValueError("bake: model's muscles or wrinkles differ from the stage's rig")

    cache = _cache_layer(cache_path, skin_path, stage)
    points_path = skin_path.AppendProperty(UsdGeom.Tokens.points)
    extent_path = skin_path.AppendProperty(UsdGeom.Tokens.extent)
    low, high = float(times.min()), float(times.max())
    with Sdf.ChangeBlock():
        for path in (points_path, extent_path):
            for time in cache.ListTimeSamplesForPath(path):
                if low <= time <= high:
                    cache.EraseTimeSample(path, time)

    from tqdm import tqdm

    with tqdm(total=len(times), desc="bake", unit="frame", disable=not progress, leave=False) as bar:
        for start in range(0, len(times), chunk_frames):
            stop = min(start + chunk_frames, len(times))
            controls = animation.contractions[start:stop]  # a jaw's controls (after the muscles) stay at rest
            controls = np.pad(controls, ((0, 0), (0, len(getattr(model, "control_names", model.muscle_names)) - controls.shape[1])))
            positions = model.evaluate_batch(controls, wrinkle_depths=animation.wrinkle_depths[start:stop])
            bounds = _extents(positions)
            finite = np.isfinite(bounds).all(axis=(1, 2))  # min/max propagate NaN and reach ±inf
            if not finite.all():
                raise RuntimeError(f"bake: non-finite positions at time {times[start + int(np.argmin(finite))]}; nothing was written")
            with Sdf.ChangeBlock():
                for offset, time in enumerate(times[start:stop].tolist()):
                    cache.SetTimeSample(points_path, time, Vt.Vec3fArray.FromNumpy(positions[offset]))
                    cache.SetTimeSample(extent_path, time, Vt.Vec3fArray.FromNumpy(bounds[offset]))
            bar.update(stop - start)

    samples = cache.ListTimeSamplesForPath(points_path)
    cache.startTimeCode, cache.endTimeCode = min(samples), max(samples)
    export_layer_atomically(cache, cache_path)
    _attach_cache(root, root_file, cache_path, low, high)
    return cache_path


def _extents(positions: np.ndarray) -> np.ndarray:
    """Per-frame bounding boxes, (F, V, 3) → (F, 2, 3) float32 (min row, max row)."""
    # Reducing over the long, contiguous axis is ~20× faster than over axis 1 of (F, V, 3).
    columns = np.ascontiguousarray(positions.transpose(0, 2, 1))
    return np.stack([columns.min(axis=2), columns.max(axis=2)], axis=1)


def _cache_layer(cache_path: Path, skin_path: Sdf.Path, stage: Usd.Stage) -> Sdf.Layer:
    """An in-memory copy of the existing cache (or a new one), with the point and extent specs."""
    layer = Sdf.Layer.CreateAnonymous(cache_path.suffix)
    if cache_path.exists():
        existing = Sdf.Layer.Find(str(cache_path)) or Sdf.Layer.OpenAsAnonymous(str(cache_path))
        if existing is None:
            raise ValueError(f"{cache_path}: exists but cannot be read as a USD layer; remove it or choose another cache_path")
        layer.TransferContent(existing)
    # A sublayer's time codes are scaled by the ratio of its rate to the root's: keep them equal.
    layer.timeCodesPerSecond = stage.GetTimeCodesPerSecond()
    layer.framesPerSecond = stage.GetFramesPerSecond()
    prim = Sdf.CreatePrimInLayer(layer, skin_path)
    for name, type_name in ((UsdGeom.Tokens.points, Sdf.ValueTypeNames.Point3fArray), (UsdGeom.Tokens.extent, Sdf.ValueTypeNames.Float3Array)):
        if prim.attributes.get(name) is None:
            Sdf.AttributeSpec(prim, name, type_name)
    return layer


def _check_not_masked(stage: Usd.Stage, skin_path: Sdf.Path, cache_path: Path) -> None:
    """Raise if a layer stronger than the cache authors the skin's points or extent (it would hide the cache)."""
    root = stage.GetRootLayer()
    if _find_sublayer(root, cache_path) is None:
        stronger = [root]  # the cache will become the strongest sublayer
    else:
        stronger = []
        for layer in stage.GetLayerStack(includeSessionLayers=False):
            if layer.realPath and _same_file(layer.realPath, cache_path):
                break
            stronger.append(layer)
    for layer in stronger:
        for name in (UsdGeom.Tokens.points, UsdGeom.Tokens.extent):
            spec = layer.GetAttributeAtPath(skin_path.AppendProperty(name))
            if spec is not None and (spec.HasDefaultValue() or layer.GetNumTimeSamplesForPath(spec.path)):
                raise RigError(
                    f"{spec.path}: authored directly in layer {layer.identifier}, which is stronger than the cache and "
                    f"would hide it; author the rest shape in the skin's '{_variant_set()}' variant (write_rig does)"
                )


def _variant_set() -> str:
    from .rig_io import SHAPE_VARIANT_SET

    return SHAPE_VARIANT_SET


def _same_file(a, b) -> bool:
    return os.path.realpath(a) == os.path.realpath(b)


def _find_sublayer(root: Sdf.Layer, cache_path: Path) -> str | None:
    """The root layer's subLayerPaths entry naming ``cache_path``, if any."""
    for entry in root.subLayerPaths:
        resolved = entry if root.anonymous else Sdf.ComputeAssetPathRelativeToLayer(root, entry)
        if resolved and _same_file(resolved, cache_path):
            return entry
    return None


def _attach_cache(root: Sdf.Layer, root_file: Path | None, cache_path: Path, low: float, high: float) -> None:
    """Sublayer the cache under the root layer (strongest sublayer), cover the time range, save the root."""
    changed = False
    if _find_sublayer(root, cache_path) is None:
        entry = str(cache_path)
        if root_file is not None:
            entry = os.path.relpath(cache_path, root_file.parent)
            entry = entry if entry.startswith(".") else "./" + entry
        root.subLayerPaths.insert(0, entry)
        changed = True
    old = (root.startTimeCode, root.endTimeCode, root.timeCodesPerSecond, root.framesPerSecond, root.HasStartTimeCode(),
           root.HasEndTimeCode(), root.HasTimeCodesPerSecond(), root.HasFramesPerSecond())
    _cover_time_range(root, low, high, None)
    changed |= old != (root.startTimeCode, root.endTimeCode, root.timeCodesPerSecond, root.framesPerSecond,
                       root.HasStartTimeCode(), root.HasEndTimeCode(), root.HasTimeCodesPerSecond(), root.HasFramesPerSecond())
    if root_file is not None and (changed or root.dirty):
        export_layer_atomically(root, root_file)
