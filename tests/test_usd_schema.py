"""The codeless USD schema plugin: registration, definitions, fallbacks, API applicability, drift, packaging."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

pxr = pytest.importorskip("pxr")

from pxr import Sdf, Tf, Usd, UsdGeom  # noqa: E402

import warpface  # noqa: E402,F401  (registers the plugin)
from warpface.usd import ensure_schema, plugin_path  # noqa: E402
from warpface.usd.schema import API_SCHEMAS, CONCRETE_SCHEMAS, TYPED_SCHEMAS, regenerate_schema  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
SCHEMA_SOURCE = plugin_path() / "schema.usda"


def _clean_env() -> dict:
    """Environment for a subprocess that has not been told where the plugin is."""
    env = {k: v for k, v in os.environ.items() if k != "PXR_PLUGINPATH_NAME"}
    env["PYTHONPATH"] = str(REPO)
    return env


def _run(code: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", code], env=env or _clean_env(), capture_output=True, text=True, timeout=120
    )


def test_plugin_path_holds_the_plugin_files():
    assert {p.name for p in plugin_path().iterdir()} >= {"schema.usda", "generatedSchema.usda", "plugInfo.json"}
    # The documented location usd_schemas/warpface/ at the repository root is the same folder.
    assert (REPO / "usd_schemas" / "warpface" / "schema.usda").resolve() == SCHEMA_SOURCE.resolve()


def test_schema_registry_finds_every_type():
    ensure_schema()
    registry = Usd.SchemaRegistry()
    for name in CONCRETE_SCHEMAS:
        assert registry.FindConcretePrimDefinition(name) is not None, name
        assert registry.IsConcrete(Tf.Type.FindByName(name))
    assert registry.IsAbstract(Tf.Type.FindByName("WarpFaceMuscle"))
    for name in TYPED_SCHEMAS:
        assert Tf.Type.FindByName(name).IsA(Tf.Type.FindByName("UsdGeomXformable")), name
    for name in ("WarpFaceLinearMuscle", "WarpFaceSphincterMuscle"):
        assert Tf.Type.FindByName(name).IsA(Tf.Type.FindByName("WarpFaceMuscle"))
    for name in API_SCHEMAS:
        assert registry.FindAppliedAPIPrimDefinition(name) is not None, name
        assert registry.GetSchemaKind(Tf.Type.FindByName(name)) == Usd.SchemaKind.SingleApplyAPI


def _source_defaults() -> dict[tuple[str, str], object]:
    """(class, property) → default value, read straight from schema.usda (independent of the registry)."""
    layer = Sdf.Layer.FindOrOpen(str(SCHEMA_SOURCE))
    defaults = {}
    for prim in layer.rootPrims:
        for attr in prim.attributes:
            if attr.HasDefaultValue():
                defaults[(prim.name, attr.name)] = attr.default
    return defaults


def test_fallbacks_come_from_the_schema():
    defaults = _source_defaults()
    assert defaults[("WarpFaceMuscle", "purpose")] == "guide"
    assert defaults[("WarpFaceWrinkle", "projection")] == "planar"
    stage = Usd.Stage.CreateInMemory()
    checked = 0
    for (schema, name), value in defaults.items():
        inherited = ["WarpFaceLinearMuscle", "WarpFaceSphincterMuscle"] if schema == "WarpFaceMuscle" else [schema]
        for type_name in inherited:
            if type_name in API_SCHEMAS:
                prim = stage.DefinePrim(f"/{type_name}", "TetMesh" if "Tet" in type_name else "Mesh")
                prim.ApplyAPI(type_name)
            else:
                prim = stage.DefinePrim(f"/{type_name}", type_name)
            attr = prim.GetAttribute(name)
            assert not attr.HasAuthoredValue()
            assert attr.Get() == value, (type_name, name)
            checked += 1
    assert checked >= 20
    muscle = stage.GetPrimAtPath("/WarpFaceLinearMuscle")
    assert UsdGeom.Imageable(muscle).ComputePurpose() == UsdGeom.Tokens.guide
    assert muscle.GetAttribute("contraction").GetVariability() == Sdf.VariabilityVarying
    assert muscle.GetAttribute("zoneAngle").GetVariability() == Sdf.VariabilityUniform
    skin = UsdGeom.Mesh.Define(stage, "/Skin").GetPrim()
    skin.ApplyAPI("WarpFaceSkinAPI")
    thickness = UsdGeom.PrimvarsAPI(skin).GetPrimvar("warpFace:thickness")
    assert thickness and thickness.GetInterpolation() == UsdGeom.Tokens.vertex  # metadata fallback from the schema
    assert thickness.Get() is None  # no fallback value: thickness must be authored


def test_can_apply_api_refuses_wrong_prim_types():
    stage = Usd.Stage.CreateInMemory()
    mesh = UsdGeom.Mesh.Define(stage, "/Mesh").GetPrim()
    tets = UsdGeom.TetMesh.Define(stage, "/Tets").GetPrim()
    xform = UsdGeom.Xform.Define(stage, "/Xform").GetPrim()
    muscle = stage.DefinePrim("/Muscle", "WarpFaceLinearMuscle")
    assert mesh.CanApplyAPI("WarpFaceSkinAPI")
    assert tets.CanApplyAPI("WarpFaceTetMaterialAPI")
    for prim in (tets, xform, muscle):
        assert not prim.CanApplyAPI("WarpFaceSkinAPI")
        refused = prim.CanApplyAPI("WarpFaceSkinAPI")
        assert "Mesh" in refused.whyNot
    for prim in (mesh, xform, muscle):
        assert not prim.CanApplyAPI("WarpFaceTetMaterialAPI")


def test_generated_files_match_the_source(tmp_path):
    pytest.importorskip("jinja2")
    regenerate_schema(tmp_path)
    for name in ("generatedSchema.usda", "plugInfo.json"):
        assert (tmp_path / name).read_text() == (plugin_path() / name).read_text(), (
            f"{name} drifted from schema.usda; run python -m warpface.usd"
        )


def test_drift_is_detected(tmp_path):
    """The drift check is not vacuous: editing the source changes the generated files."""
    pytest.importorskip("jinja2")
    source = tmp_path / "schema.usda"
    source.write_text(
        SCHEMA_SOURCE.read_text().replace("uniform double zoneAngle = 40", "uniform double zoneAngle = 45")
    )
    regenerate_schema(tmp_path / "out", source=source)
    assert (tmp_path / "out" / "generatedSchema.usda").read_text() != (
        plugin_path() / "generatedSchema.usda"
    ).read_text()


def test_import_without_pxr_skips_registration_and_gives_plugin_path():
    code = (
        "import sys; sys.modules['pxr'] = None\n"  # as on a machine without usd-core
        "import warpface, warpface.usd\n"
        "print(warpface.usd.plugin_path())\n"
        "assert 'pxr' not in [m for m in sys.modules if sys.modules[m] is not None]\n"
    )
    result = _run(code)
    assert result.returncode == 0, result.stderr
    assert Path(result.stdout.strip().splitlines()[-1]) == plugin_path()


def test_late_registration_raises_error_naming_the_environment_variable():
    code = (
        "from pxr import Usd; Usd.SchemaRegistry()\n"  # the registry is built before warpface registers
        "import warpface.usd as wu\nfrom warpface.errors import SchemaRegistrationError\n"
        "try:\n    wu.ensure_schema()\nexcept SchemaRegistrationError as exc:\n    print('ERROR', exc)\n"
    )
    result = _run(code)
    assert result.returncode == 0, result.stderr
    assert "ERROR" in result.stdout and "PXR_PLUGINPATH_NAME" in result.stdout and str(plugin_path()) in result.stdout


def test_environment_variable_registers_without_importing_warpface():
    env = _clean_env()
    env["PXR_PLUGINPATH_NAME"] = str(plugin_path())
    code = (
        "import sys\nfrom pxr import Usd\n"
        "print(all(Usd.SchemaRegistry().FindConcretePrimDefinition(n) is not None for n in "
        f"{list(CONCRETE_SCHEMAS)!r}), 'warpface' in sys.modules)\n"
    )
    result = _run(code, env)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["True", "False"]


def test_wheel_contains_the_schema_plugin(tmp_path):
    """Build a wheel from a copy of the package (keeps the working tree clean) and list it."""
    pytest.importorskip("build")
    source = tmp_path / "src"
    source.mkdir()
    for name in ("pyproject.toml", "README.md"):
        if (REPO / name).exists():
            shutil.copy(REPO / name, source / name)
    shutil.copytree(REPO / "warpface", source / "warpface", ignore=shutil.ignore_patterns("__pycache__"))
    out = tmp_path / "dist"
    attempts = (
        [sys.executable, "-m", "build", "--wheel", "--outdir", str(out), str(source)],
        [
            sys.executable,
            "-m",
            "build",
            "--wheel",
            "--no-isolation",
            "--skip-dependency-check",
            "--outdir",
            str(out),
            str(source),
        ],
    )
    logs = []
    for command in attempts:  # the isolated build needs setuptools from an index; fall back to the local one
        result = subprocess.run(command, capture_output=True, text=True, timeout=300)
        logs.append(result.stdout[-2000:] + result.stderr[-2000:])
        if result.returncode == 0:
            break
    wheels = list(out.glob("*.whl"))
    if not wheels:
        pytest.skip("cannot build a wheel here (no build backend available offline):\n" + "\n".join(logs))
    names = set(zipfile.ZipFile(wheels[0]).namelist())
    for name in ("schema.usda", "generatedSchema.usda", "plugInfo.json"):
        assert f"warpface/usd_schemas/warpface/{name}" in names
    assert "warpface/usd/schema.py" in names
