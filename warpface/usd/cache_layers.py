"""Where a bake's cache layer goes in the layer stack: sublayered under the rig's root layer, or under a small
shot stage ``[cache, stage]`` that leaves every layer of the stage as it is (``warpface bake``'s default)."""

from __future__ import annotations

import os
from pathlib import Path

from pxr import Sdf, Usd

from ._files import export_layer_atomically
from .animation import cover_time_range

__all__ = [
    "attach_cache",
    "check_shot_path",
    "default_shot_path",
    "find_sublayer",
    "same_file",
    "sublayer_files",
    "write_shot",
]


def default_shot_path(stage_path) -> Path:
    """``<stage stem>_shot.usda`` beside the stage file: where ``warpface bake`` writes its shot stage."""
    stage_path = Path(stage_path)
    return stage_path.with_name(stage_path.stem + "_shot.usda")


def check_shot_path(stage: Usd.Stage, shot_path: Path, cache_path: Path) -> None:
    """The shot stage must not be the cache or any layer the stage uses, and needs a stage saved to a file."""
    root = stage.GetRootLayer()
    if root.anonymous:
        raise ValueError("shot: the stage's root layer is in memory; save the stage to a file first")
    if root.dirty:
        raise ValueError(f"shot: {root.realPath} has unsaved edits; save the stage first (the shot layers the file)")
    if same_file(shot_path, cache_path):
        raise ValueError(f"shot {shot_path}: is the cache file; choose another shot file")
    for layer in stage.GetUsedLayers():
        if layer.realPath and same_file(layer.realPath, shot_path):
            raise ValueError(f"shot {shot_path}: is one of the stage's own layers; choose another shot file")


SHOT_METADATA = ("metersPerUnit", "upAxis", "defaultPrim", "timeCodesPerSecond", "framesPerSecond")
"""Stage metadata a shot stage copies from the stage it layers (a stage reads them off its root layer)."""


def write_shot(root: Sdf.Layer, cache_path: Path, shot_path: Path) -> None:
    """Write the shot stage: sublayers ``[cache, root]`` (the cache only when the root does not already
    sublayer it), the root's metadata and a time range covering the root's and the cache's."""
    shot = Sdf.Layer.CreateAnonymous(shot_path.suffix)
    for key in SHOT_METADATA:
        if root.pseudoRoot.HasInfo(key):
            shot.pseudoRoot.SetInfo(key, root.pseudoRoot.GetInfo(key))
    cache = Sdf.Layer.FindOrOpen(str(cache_path))
    entries = [] if find_sublayer(root, cache_path) is not None else [relative_entry(cache_path, shot_path)]
    shot.subLayerPaths[:] = entries + [relative_entry(Path(root.realPath), shot_path)]
    low, high = cache.startTimeCode, cache.endTimeCode
    if root.HasStartTimeCode() and root.HasEndTimeCode():
        low, high = min(low, root.startTimeCode), max(high, root.endTimeCode)
    cover_time_range(shot, low, high, None)
    export_layer_atomically(shot, shot_path)


def relative_entry(path: Path, anchor_file: Path) -> str:
    entry = os.path.relpath(path, anchor_file.parent)
    return entry if entry.startswith(".") else "./" + entry


def same_file(a, b) -> bool:
    return os.path.realpath(a) == os.path.realpath(b)


def sublayer_files(root: Sdf.Layer) -> list[str]:
    return [
        entry if root.anonymous else (Sdf.ComputeAssetPathRelativeToLayer(root, entry) or entry)
        for entry in root.subLayerPaths
    ]


def find_sublayer(root: Sdf.Layer, cache_path: Path) -> str | None:
    """The root layer's subLayerPaths entry naming ``cache_path``, if any."""
    for entry, resolved in zip(root.subLayerPaths, sublayer_files(root)):
        if resolved and same_file(resolved, cache_path):
            return entry
    return None


def attach_cache(root: Sdf.Layer, root_file: Path | None, cache_path: Path, low: float, high: float) -> None:
    """Sublayer the cache under the root layer (strongest sublayer), cover the time range, save the root."""
    changed = False
    if find_sublayer(root, cache_path) is None:
        entry = str(cache_path)
        if root_file is not None:
            entry = relative_entry(cache_path, root_file)
        root.subLayerPaths.insert(0, entry)
        changed = True
    before = _time_metadata(root)
    cover_time_range(root, low, high, None)
    changed |= before != _time_metadata(root)
    if root_file is not None and (changed or root.dirty):
        export_layer_atomically(root, root_file)


def _time_metadata(layer: Sdf.Layer) -> tuple:
    """The layer's time range and rates, and whether each is authored."""
    return (
        layer.startTimeCode,
        layer.endTimeCode,
        layer.timeCodesPerSecond,
        layer.framesPerSecond,
        layer.HasStartTimeCode(),
        layer.HasEndTimeCode(),
        layer.HasTimeCodesPerSecond(),
        layer.HasFramesPerSecond(),
    )
