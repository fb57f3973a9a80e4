"""USD I/O for warpface: the codeless schema plugin, rigs as prims, animation as time samples, bakes,
tissue meshes, and the one reader of driver files.

``plugin_path`` and ``ensure_schema`` need no ``pxr`` import to be looked up; everything else loads
``pxr`` (usd-core) on first access, so ``import warpface.usd`` works on machines without it
(``read_driver`` reads the CSV and MediaPipe formats without it too).
"""

from __future__ import annotations

import importlib

from .schema import ensure_schema, plugin_path

_LAZY = {
    "write_rig": "rig_io",
    "read_rig": "rig_io",
    "rig_prims": "rig_io",
    "RigPrims": "rig_io",
    "stage_meters_per_unit": "rig_io",
    "write_animation": "animation",
    "read_animation": "animation",
    "Animation": "animation",
    "frame_times": "animation",
    "bake": "baking",
    "write_point_cache": "baking",
    "check_bake": "baking",
    "write_tissue": "tissue_io",
    "read_tissue": "tissue_io",
    "Tissue": "tissue_io",
    "TissueMeshData": "tissue_io",
    "write_tissue_mesh": "tissue_io",
    "read_tissue_mesh": "tissue_io",
    "validate_stage": "validate",
    "ValidationProblem": "validate",
    "read_driver": "driver_files",
    "write_obj_asset": "asset_io",
    "attach_asset": "asset_io",
    "asset_link": "asset_io",
    "AssetLink": "asset_io",
    "check_asset": "asset_io",
    "open_stage": "_files",
    "export_layer_atomically": "_files",
}

_FOR_COMMANDS = {"usd_error_message": "_files"}
"""Reachable as attributes for warpface's command line (which may not import the private module), but not
part of the public surface."""

__all__ = ["plugin_path", "ensure_schema", *_LAZY]


def __getattr__(name: str):
    module = _LAZY.get(name) or _FOR_COMMANDS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
