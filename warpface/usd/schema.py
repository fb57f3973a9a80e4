"""Registration of warpface's codeless USD schema plugin.

The plugin (``schema.usda`` → ``generatedSchema.usda`` + ``plugInfo.json``) ships inside the package
at ``warpface/usd_schemas/warpface``. OpenUSD builds ``Usd.SchemaRegistry`` once, on first use, from
the plugins registered at that moment; a plugin registered later is silently ignored (no prim
definitions, no fallbacks). ``import warpface`` therefore registers it first thing, and every USD entry
point of warpface calls :func:`ensure_schema`, which fails loudly when the registry came up without it.

:func:`plugin_path` does not import ``pxr``: host applications can put it into
``PXR_PLUGINPATH_NAME`` before they start.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

from .._files import atomic_path
from ..errors import SchemaRegistrationError

__all__ = [
    "PLUGIN_NAME",
    "TYPED_SCHEMAS",
    "CONCRETE_SCHEMAS",
    "API_SCHEMAS",
    "SchemaRegistrationError",
    "plugin_path",
    "register_schema",
    "ensure_schema",
    "regenerate_schema",
]

PLUGIN_NAME = "warpFace"
"""Plug name of the schema plugin (``libraryName`` in schema.usda)."""

CONCRETE_SCHEMAS = ("WarpFaceLinearMuscle", "WarpFaceSphincterMuscle", "WarpFaceLidMuscle", "WarpFaceWrinkle")
"""Prim type names that can be defined on a stage."""

TYPED_SCHEMAS = ("WarpFaceMuscle",) + CONCRETE_SCHEMAS
"""All typed schemas (``WarpFaceMuscle`` is abstract)."""

API_SCHEMAS = ("WarpFaceSkinAPI", "WarpFaceTetMaterialAPI")
"""Single-apply API schemas: skin (only on Mesh) and tissue material (only on TetMesh)."""

_ENV_VAR = "PXR_PLUGINPATH_NAME"
_verified = False


def plugin_path() -> Path:
    """Folder holding the schema plugin's ``plugInfo.json`` (no ``pxr`` import).

    Add it to the ``PXR_PLUGINPATH_NAME`` environment variable of applications that should know the
    warpface prim types without importing warpface (usdview, DCCs).
    """
    return Path(__file__).resolve().parent.parent / "usd_schemas" / "warpface"


def _problem(detail: str) -> SchemaRegistrationError:
    return SchemaRegistrationError(
        f"warpface USD schemas are not registered with OpenUSD: {detail}. OpenUSD reads schema plugins "
        f"once, when Usd.SchemaRegistry is first used; import warpface before anything touches USD schemas, "
        f"or set the environment variable {_ENV_VAR}={plugin_path()} before the process starts."
    )


def register_schema() -> None:
    """Register the plugin with ``Plug.Registry`` (idempotent) and check that its types are declared.

    Raises:
        SchemaRegistrationError: the plugin files are missing or its types did not register
            (the message names ``PXR_PLUGINPATH_NAME``).
    """
    from pxr import Plug, Tf

    registry = Plug.Registry()
    if registry.GetPluginWithName(PLUGIN_NAME) is None:
        path = plugin_path()
        if not (path / "plugInfo.json").is_file():
            raise _problem(f"plugInfo.json not found in {path}")
        registry.RegisterPlugins(str(path))
    if registry.GetPluginWithName(PLUGIN_NAME) is None:
        raise _problem(f"Plug.Registry did not accept the plugin at {plugin_path()}")
    unknown = [name for name in TYPED_SCHEMAS + API_SCHEMAS if Tf.Type.FindByName(name).isUnknown]
    if unknown:
        raise _problem(f"types {', '.join(unknown)} are not declared")


def ensure_schema() -> None:
    """Check (once per process) that ``Usd.SchemaRegistry`` has a definition for every warpface schema.

    Registers the plugin first if that has not happened yet (e.g. ``pxr`` was installed after
    ``import warpface`` skipped it).

    Raises:
        SchemaRegistrationError: the registry was built before the plugin was registered, or the
            plugin is broken. The message says how to fix it (``PXR_PLUGINPATH_NAME``).
    """
    global _verified
    if _verified:
        return
    register_schema()
    from pxr import Usd

    registry = Usd.SchemaRegistry()
    missing = [name for name in CONCRETE_SCHEMAS if registry.FindConcretePrimDefinition(name) is None]
    missing += [name for name in API_SCHEMAS if registry.FindAppliedAPIPrimDefinition(name) is None]
    if missing:
        raise _problem(f"Usd.SchemaRegistry has no prim definition for {', '.join(missing)}")
    _verified = True


def register_at_import() -> None:
    """Called by ``import warpface``: register when usd-core is installed, skip silently when not.

    A failure here must not make warpface unimportable (its kernels need no USD), so it becomes a
    warning now and a :class:`SchemaRegistrationError` at the first USD call.
    """
    if importlib.util.find_spec("pxr") is None:
        return
    try:
        register_schema()
    except SchemaRegistrationError as exc:
        warnings.warn(str(exc), RuntimeWarning, stacklevel=3)


# ---------------------------------------------------------------------------------------------- generation

_PLACEHOLDERS = {
    # usdGenSchema leaves CMake placeholders in plugInfo.json; a codeless plugin has no library and
    # keeps generatedSchema.usda beside plugInfo.json.
    '"@PLUG_INFO_LIBRARY_PATH@"': '""',
    '"@PLUG_INFO_RESOURCE_PATH@"': '"."',
    '"@PLUG_INFO_ROOT@"': '"."',
}


def regenerate_schema(out_dir: str | Path | None = None, *, source: str | Path | None = None) -> list[Path]:
    """Run ``python -m pxr.Usd.usdGenSchema`` on ``schema.usda`` and write the plugin files.

    Generation runs in a scratch folder (usdGenSchema needs jinja2, a development dependency);
    ``generatedSchema.usda`` and ``plugInfo.json`` are then moved into ``out_dir`` (default: the
    shipped plugin folder) with the plugInfo placeholders filled in for a codeless plugin.

    Returns:
        The two written paths.

    Raises:
        RuntimeError: usdGenSchema failed (its output is in the message).
    """
    source = Path(source) if source is not None else plugin_path() / "schema.usda"
    out_dir = Path(out_dir) if out_dir is not None else plugin_path()
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="warpface-schema-") as scratch:
        scratch = Path(scratch)
        (scratch / "schema.usda").write_bytes(source.read_bytes())
        env = {k: v for k, v in os.environ.items() if k != _ENV_VAR}
        result = subprocess.run(
            [sys.executable, "-m", "pxr.Usd.usdGenSchema", "-q", "schema.usda", "."],
            cwd=scratch,
            env=env,
            capture_output=True,
            text=True,
        )
        if result.returncode != 0 or not (scratch / "generatedSchema.usda").is_file():
            raise RuntimeError(f"usdGenSchema failed ({result.returncode}):\n{result.stdout}\n{result.stderr}")
        plug_info = (scratch / "plugInfo.json").read_text()
        for placeholder, value in _PLACEHOLDERS.items():
            plug_info = plug_info.replace(placeholder, value)
        json.loads("\n".join(line for line in plug_info.splitlines() if not line.lstrip().startswith("#")))
        written = []
        for name, text in (
            ("generatedSchema.usda", (scratch / "generatedSchema.usda").read_text()),
            ("plugInfo.json", plug_info),
        ):
            target = out_dir / name
            with atomic_path(target, target.suffix) as temporary:
                temporary.write_text(text)
            written.append(target)
    return written
