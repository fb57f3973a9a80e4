"""USD I/O for warpface: the codeless schema plugin, rigs as prims, animation as time samples, bakes.

``plugin_path``, ``register_schema`` and ``ensure_schema`` need no ``pxr`` import to be looked up;
everything else loads ``pxr`` (usd-core) on first access, so ``import warpface.usd`` works on
machines without it.
"""

from __future__ import annotations

import importlib

from .schema import (
    API_SCHEMAS,
    CONCRETE_SCHEMAS,
    TYPED_SCHEMAS,
    SchemaRegistrationError,
    ensure_schema,
    plugin_path,
    regenerate_schema,
    register_schema,
)

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
    "frame_range": "animation",
    "MAX_FRAMES": "animation",
    "bake": "baking",
    "check_bake": "baking",
    "write_tissue": "tissue_io",
    "read_tissue": "tissue_io",
    "Tissue": "tissue_io",
    "TissueMeshData": "tissue_io",
    "write_tissue_mesh": "tissue_io",
    "read_tissue_mesh": "tissue_io",
    "validate_stage": "validate",
    "ValidationProblem": "validate",
    "read_driver": "skel_io",
    "open_stage": "_files",
    "usd_error_message": "_files",
    "open_layer": "_files",
    "export_layer_atomically": "_files",
}

__all__ = [
    "plugin_path",
    "register_schema",
    "ensure_schema",
    "regenerate_schema",
    "SchemaRegistrationError",
    "TYPED_SCHEMAS",
    "CONCRETE_SCHEMAS",
    "API_SCHEMAS",
    *_LAZY,
]


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
