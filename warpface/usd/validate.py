"""Stage validation: OpenUSD's validators (``pxr.UsdValidation``) plus warpface's rig checks."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pxr import Usd, UsdGeom, UsdValidation

from ..errors import RigError
from ._files import open_stage, without_usd_warnings
from .animation import read_animation
from .asset_io import check_asset
from .baking import check_bake, existing_cache_path
from .frames import capture_problems, is_capture
from .rig_io import SKIN_API, read_rig, rig_prims
from .schema import CONCRETE_SCHEMAS, ensure_schema
from .tissue_io import TET_MATERIAL_API, read_tissue
from .validate_face import face_problems

__all__ = ["ValidationProblem", "validate_stage"]


@dataclass(frozen=True)
class ValidationProblem:
    """One finding about a stage."""

    severity: str
    """``"error"`` or ``"warning"``."""
    path: str
    """Prim or property path (or the layer) the finding is about."""
    message: str
    source: str
    """``"warpface"`` or the name of the OpenUSD validator."""

    def __str__(self) -> str:
        return f"{self.severity}: {self.path}: {self.message} [{self.source}]"


def validate_stage(
    stage_or_path, *, usd_validators: bool = True, bake_checks: bool = True, device=None, progress: bool = False
) -> list[ValidationProblem]:
    """Check a stage; an empty list means no problems.

    Runs every registered ``pxr.UsdValidation`` validator (errors and warnings) and warpface's own
    checks. A rig stage: every layer and sublayer reads, each skin reads as a valid rig whose landmarks are in
    iBUG order and whose face is human-sized in the stated unit (:mod:`warpface.usd.validate_face`), its animation
    controls are finite, an animated stage authors ``timeCodesPerSecond``, ``framesPerSecond``,
    ``startTimeCode`` and ``endTimeCode``, cached skin points have the rest point count and are
    finite, warpface prims are reachable from a skin, tissue meshes read as valid materials, and
    everything :func:`~warpface.usd.bake` would refuse (:func:`~warpface.usd.check_bake`: time range,
    frame count, the default cache file, controls giving non-finite positions). A capture written by
    ``warpface track``: see :func:`~warpface.usd.frames.capture_problems`.

    Args:
        stage_or_path: a ``Usd.Stage`` or a path to a USD file.
        usd_validators: also run OpenUSD's validators.
        bake_checks: also run the bake checks (they evaluate the expression model).
        device: Warp device for the bake checks' model evaluation.
        progress: show a progress bar while checking a capture's frames.
    """
    try:
        stage = open_stage(stage_or_path)
    except ValueError as exc:
        return [ValidationProblem("error", str(stage_or_path), str(exc), "warpface")]
    ensure_schema()
    problems: list[ValidationProblem] = []
    for skin in [p for p in stage.Traverse() if p.HasAPI(SKIN_API)]:
        try:
            check_asset(skin)
        except RigError as exc:  # nothing else reads without the asset: the one line says what to do
            message = str(exc).removeprefix(f"{skin.GetPath()}: ")
            return [ValidationProblem("error", str(skin.GetPath()), message, "warpface")]
    if is_capture(stage):
        problems += [
            ValidationProblem("error", path, message, "warpface")
            for path, message in capture_problems(stage, progress=progress)
        ]
        return problems
    if usd_validators:  # their findings are reported as problems; the same diagnostics on stderr are noise
        problems += without_usd_warnings(lambda: _usd_problems(stage), dropping=("Warning: in ",))
    problems += _rig_problems(stage, device)
    if bake_checks and not any(p.severity == "error" for p in problems):
        problems += _bake_problems(stage, device)
    return problems


def _bake_problems(stage: Usd.Stage, device) -> list[ValidationProblem]:
    problems = []
    for skin in [p for p in stage.Traverse() if p.HasAPI(SKIN_API)]:
        try:
            cache = existing_cache_path(stage, skin.GetPath())  # re-baking goes there; else the default cache file
            check_bake(stage, skin_path=str(skin.GetPath()), cache_path=cache, device=device)
        except (ValueError, RigError) as exc:
            message = str(exc)
            prefix = f"{skin.GetPath()}: "
            message = message[len(prefix) :] if message.startswith(prefix) else message
            if "nothing to bake" in message:
                continue  # a rig without animation is valid; there is just nothing to bake
            problems.append(ValidationProblem("error", str(skin.GetPath()), message, "warpface (bake)"))
    return problems


def _usd_problems(stage: Usd.Stage) -> list[ValidationProblem]:
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    severities = {UsdValidation.ValidationErrorType.Error: "error", UsdValidation.ValidationErrorType.Warn: "warning"}
    problems = []
    for error in UsdValidation.ValidationContext(validators).Validate(stage):
        severity = severities.get(error.GetType())
        if severity is None:
            continue
        sites = [s for s in error.GetSites() if s.IsValid()]
        path = str(stage.GetRootLayer().identifier)
        if sites:
            site = sites[0]
            path = str(
                site.GetProperty().GetPath()
                if site.IsProperty()
                else site.GetPrim().GetPath()
                if site.IsPrim()
                else path
            )
        problems.append(ValidationProblem(severity, path, error.GetMessage(), error.GetIdentifier() or error.GetName()))
    return problems


def _rig_problems(stage: Usd.Stage, device=None) -> list[ValidationProblem]:
    problems = []

    def error(path, message):
        problems.append(ValidationProblem("error", str(path), message, "warpface"))

    layer_label = stage.GetRootLayer().realPath or stage.GetRootLayer().identifier
    skins = [p for p in stage.Traverse() if p.HasAPI(SKIN_API)]
    if not skins:
        error(layer_label, f"no Mesh with {SKIN_API}: not a warpface rig")
    reached = set()
    animated = False
    for skin in skins:
        try:
            prims = rig_prims(stage, skin.GetPath())
            rig = read_rig(stage, skin_path=skin.GetPath(), meters_per_unit=1.0)
        except RigError as exc:
            error(skin.GetPath(), str(exc))
            continue
        reached.update(p.GetPath() for p in prims.muscles + prims.wrinkles)
        meters_per_unit = UsdGeom.GetStageMetersPerUnit(stage)
        for severity, message in face_problems(
            rig, meters_per_unit, stage.HasAuthoredMetadata("metersPerUnit"), device=device
        ):
            problems.append(ValidationProblem(severity, str(skin.GetPath()), message, "warpface"))
        controls = [p.GetAttribute("contraction") for p in prims.muscles] + [
            p.GetAttribute("depth") for p in prims.wrinkles
        ]
        times = sorted({t for attr in controls for t in attr.GetTimeSamples()})
        if times:
            animated = True
            try:
                read_animation(stage, np.array(times), skin_path=skin.GetPath())
            except RigError as exc:
                error(skin.GetPath(), str(exc))
        points = UsdGeom.Mesh(skin).GetPointsAttr()
        for time in points.GetTimeSamples():
            animated = True
            value = points.Get(time)
            if value is None or len(value) != rig.mesh.vertex_count:
                error(
                    points.GetPath(),
                    f"time sample {time} has {0 if value is None else len(value)} points, "
                    f"the rest shape has {rig.mesh.vertex_count}",
                )
                break
            if not np.isfinite(np.asarray(value)).all():
                error(points.GetPath(), f"time sample {time} has non-finite points")
                break
    if animated:
        root = stage.GetRootLayer()
        missing = [
            name
            for name, has in (
                ("timeCodesPerSecond", root.HasTimeCodesPerSecond()),
                ("framesPerSecond", root.HasFramesPerSecond()),
                ("startTimeCode", root.HasStartTimeCode()),
                ("endTimeCode", root.HasEndTimeCode()),
            )
            if not has
        ]
        if missing:
            error(layer_label, f"animated stage does not author {', '.join(missing)}")
    for prim in stage.Traverse():
        if prim.GetTypeName() in CONCRETE_SCHEMAS and prim.GetPath() not in reached and skins:
            problems.append(
                ValidationProblem(
                    "warning", str(prim.GetPath()), "not used by any skin's muscles or wrinkles", "warpface"
                )
            )
        if prim.HasAPI(TET_MATERIAL_API):
            try:
                read_tissue(stage, str(prim.GetPath()))
            except RigError as exc:
                error(prim.GetPath(), str(exc))
    return problems
