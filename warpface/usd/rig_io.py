"""A :class:`~warpface.FaceRig` as USD prims, and back, with every value validated on the way in.

Layout written by :func:`write_rig` (``<Face>`` is the rig's name as a prim identifier)::

    /<Face>                 Xform, kind=component, the stage's default prim
    /<Face>/Skin            Mesh + WarpFaceSkinAPI (rest shape, thickness primvar, landmark indices)
    /<Face>/Muscles/<name>  WarpFaceLinearMuscle | WarpFaceSphincterMuscle
    /<Face>/Wrinkles/<name> WarpFaceWrinkle

The skin's rest ``points`` and ``extent`` are authored inside the variant ``warpFaceShape = "rest"``.
Variant opinions are weaker than every local opinion, so a point cache sublayered under the rig
layer (:func:`warpface.usd.bake`) shows through, while the rest shape is what a stage without the
cache — and ``points.Get(Usd.TimeCode.Default())`` — returns.

``warpface rig`` makes the skin a reference to the user's own mesh instead (no copied geometry or
variant; :mod:`warpface.usd.asset_io`); :func:`rig_prims` refuses such a rig whose asset is missing.

Values are read in the skin mesh's local space: muscle and wrinkle prims may carry their own
transforms (rigid motion and uniform scale), which are composed into that space. Lengths are
converted from the stage's ``metersPerUnit`` (USD's fallback is 0.01, centimetres) to the units asked
for (metres by default). Mesh points are ``point3f`` on the stage (USD's type), so they round-trip
exactly when they are representable in float32; every other value is stored as double.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pxr import Kind, Sdf, Tf, Usd, UsdGeom, UsdPhysics, Vt

from .._validate import as_positive, expect_instance
from ..errors import RigError
from ..expression.muscles import FALLOFFS, LinearMuscle, SphincterMuscle
from ..expression.wrinkles import CylindricalProjection, PlanarProjection, Wrinkle
from ..geometry.triangles import weld_seams
from ..mesh import FaceMesh, fan_triangles
from ..rig import FaceRig
from ._files import LAYER_SUFFIXES, checked_prim_path, export_layer_atomically, open_stage, writable_path
from ._lobe_io import author_lobes, read_lobes
from ._prim_values import array_value, check_finite, scalar_value, token_value
from .asset_io import check_asset
from .jaw_io import author_jaw, read_jaw
from .lid_io import LID_TYPE, LidMuscle, author_lid, read_lid
from .schema import ensure_schema

__all__ = [
    "write_rig",
    "read_rig",
    "rig_prims",
    "RigPrims",
    "stage_meters_per_unit",
    "SKIN_API",
    "SHAPE_VARIANT_SET",
    "REST_VARIANT",
]

SKIN_API = "WarpFaceSkinAPI"
SHAPE_VARIANT_SET = "warpFaceShape"
"""Variant set on the skin mesh holding the rest ``points`` and ``extent``."""
REST_VARIANT = "rest"

_LINEAR = "WarpFaceLinearMuscle"
_SPHINCTER = "WarpFaceSphincterMuscle"
_WRINKLE = "WarpFaceWrinkle"
_THICKNESS = "warpFace:thickness"
_LANDMARKS = "warpFace:landmarkIndices"
_MUSCLES_REL = "warpFace:muscles"
_WRINKLES_REL = "warpFace:wrinkles"
_RESPONSE = ("sliding", "bunching", "thickening")
_DEFAULT = Usd.TimeCode.Default()


# ---------------------------------------------------------------------------------------------- writing


def write_rig(
    stage_or_path, rig: FaceRig, *, root_path: str | None = None, meters_per_unit: float = 1.0, fps: float = 30.0
) -> Usd.Stage:
    """Author ``rig`` as warpface prims.

    Args:
        stage_or_path: a ``Usd.Stage`` (authored in its edit target; not saved) or a ``.usda`` /
            ``.usdc`` path (written through a temporary file and a rename).
        rig: the rig, in units of ``meters_per_unit`` metres.
        root_path: prim path of the rig root (default ``/<rig name>``); an existing prim there is
            replaced.
        meters_per_unit: the rig's length unit in metres, written as the stage's ``metersPerUnit``.
        fps: ``timeCodesPerSecond`` and ``framesPerSecond`` of the stage.

    Returns:
        The stage (for a path, the stage opened from the written file).

    Raises:
        TypeError: ``rig`` not a FaceRig. ValueError: bad units, fps or root path, unwritable path.
    """
    ensure_schema()
    if not isinstance(rig, FaceRig):
        raise TypeError(f"rig: expected a FaceRig, got {type(rig).__name__}")
    meters_per_unit = as_positive(meters_per_unit, "meters_per_unit")
    fps = as_positive(fps, "fps")
    target = None
    if isinstance(stage_or_path, Usd.Stage):
        stage = stage_or_path
    else:
        target = writable_path(stage_or_path, LAYER_SUFFIXES)
        stage = Usd.Stage.CreateInMemory(f"rig{target.suffix}")
    root = checked_prim_path(root_path, "root_path") if root_path is not None else Sdf.Path("/" + _identifier(rig.name))
    _author_rig(stage, rig, root, meters_per_unit, fps)
    if target is None:
        return stage
    export_layer_atomically(stage.GetRootLayer(), target)
    return Usd.Stage.Open(str(target))


def _author_rig(stage: Usd.Stage, rig: FaceRig, root: Sdf.Path, meters_per_unit: float, fps: float) -> None:
    if not root.IsAbsolutePath() or not root.IsPrimPath():
        raise ValueError(f"root_path: expected an absolute prim path, got {root}")
    if stage.GetPrimAtPath(root):
        stage.RemovePrim(root)
    UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdPhysics.SetStageKilogramsPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    stage.WriteFallbackPrimTypes()  # readers without the plugin see the schema's fallback types (Xform)

    root_prim = UsdGeom.Xform.Define(stage, root).GetPrim()
    Usd.ModelAPI(root_prim).SetKind(Kind.Tokens.component)
    _set_name(root_prim, rig.name)
    if root.pathElementCount == 1:
        stage.SetDefaultPrim(root_prim)

    skin = UsdGeom.Mesh.Define(stage, root.AppendChild("Skin"))
    skin_prim = skin.GetPrim()
    _set_name(skin_prim, rig.mesh.name)
    mesh = rig.mesh
    skin.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(mesh.triangle_count, 3, dtype=np.int32)))
    skin.CreateFaceVertexIndicesAttr(
        Vt.IntArray.FromNumpy(np.ascontiguousarray(mesh.triangles.reshape(-1), dtype=np.int32))
    )
    skin.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    skin.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    points = np.ascontiguousarray(mesh.points, dtype=np.float32)
    variant_set = skin_prim.GetVariantSets().AddVariantSet(SHAPE_VARIANT_SET)
    variant_set.AddVariant(REST_VARIANT)
    variant_set.SetVariantSelection(REST_VARIANT)
    with variant_set.GetVariantEditContext():
        skin.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points))
        skin.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([points.min(axis=0), points.max(axis=0)])))

    skin_prim.ApplyAPI(SKIN_API)
    thickness = UsdGeom.PrimvarsAPI(skin_prim).CreatePrimvar(
        _THICKNESS, Sdf.ValueTypeNames.DoubleArray, UsdGeom.Tokens.vertex
    )
    thickness.SetInterpolation(UsdGeom.Tokens.vertex)  # explicit, for readers without the plugin
    thickness.Set(Vt.DoubleArray.FromNumpy(np.ascontiguousarray(rig.thickness, dtype=np.float64)))
    if rig.landmarks is not None:
        landmarks = skin_prim.CreateAttribute(
            _LANDMARKS, Sdf.ValueTypeNames.IntArray, custom=False, variability=Sdf.VariabilityUniform
        )
        landmarks.Set(Vt.IntArray.FromNumpy(np.ascontiguousarray(rig.landmarks, dtype=np.int32)))

    skin_path = skin_prim.GetPath()
    muscle_paths = _author_items(stage, root.AppendChild("Muscles"), rig.muscles, skin_path, _author_muscle)
    wrinkle_paths = _author_items(stage, root.AppendChild("Wrinkles"), rig.wrinkles, skin_path, _author_wrinkle)
    skin_prim.CreateRelationship(_MUSCLES_REL, custom=False).SetTargets(muscle_paths)
    skin_prim.CreateRelationship(_WRINKLES_REL, custom=False).SetTargets(wrinkle_paths)
    author_jaw(stage, root.AppendChild(_identifier(rig.jaw.name)) if rig.jaw else None, rig.jaw, skin_prim)


def _author_items(stage, scope_path: Sdf.Path, items, skin_path: Sdf.Path, author) -> list[Sdf.Path]:
    UsdGeom.Scope.Define(stage, scope_path)
    paths, used = [], set()
    for item in items:
        identifier = _identifier(item.name)
        unique, suffix = identifier, 1
        while unique in used:
            unique, suffix = f"{identifier}_{suffix}", suffix + 1
        used.add(unique)
        path = scope_path.AppendChild(unique)
        prim = author(stage, path, item)
        _set_name(prim, item.name)
        prim.CreateRelationship("targetMesh", custom=False).SetTargets([skin_path])
        UsdGeom.Imageable(prim).CreatePurposeAttr(UsdGeom.Tokens.guide)  # explicit, for readers without the plugin
        paths.append(path)
    return paths


def _set(prim: Usd.Prim, name: str, type_name, value, uniform: bool = True) -> None:
    variability = Sdf.VariabilityUniform if uniform else Sdf.VariabilityVarying
    prim.CreateAttribute(name, type_name, custom=False, variability=variability).Set(value)


def _author_muscle(stage, path, muscle) -> Usd.Prim:
    types = Sdf.ValueTypeNames
    if isinstance(muscle, LidMuscle):
        prim = author_lid(stage, path, muscle)
    elif isinstance(muscle, LinearMuscle):
        prim = stage.DefinePrim(path, _LINEAR)
        _set(prim, "attachment", types.Double3, tuple(muscle.attachment))
        _set(prim, "insertion", types.Double3, tuple(muscle.insertion))
        _set(prim, "zoneAngle", types.Double, muscle.zone_angle_deg)
        _set(prim, "falloffStart", types.Double, muscle.falloff_start)
        _set(prim, "falloffFinish", types.Double, muscle.falloff_finish)
        author_lobes(prim, muscle.lobes)
    else:
        prim = stage.DefinePrim(path, _SPHINCTER)
        _set(prim, "center", types.Double3, tuple(muscle.center))
        _set(prim, "axisX", types.Double3, tuple(muscle.axis_x))
        _set(prim, "axisY", types.Double3, tuple(muscle.axis_y))
        _set(prim, "semiAxes", types.Double2, tuple(muscle.semi_axes))
        _set(prim, "ring", types.Double, muscle.ring)
    _set(prim, "contraction", types.Double, 0.0, uniform=False)
    _set(prim, "falloff", types.Token, muscle.falloff)
    for name in _RESPONSE:
        _set(prim, name, types.Double, getattr(muscle, name))
    return prim


def _author_wrinkle(stage, path, wrinkle: Wrinkle) -> Usd.Prim:
    types = Sdf.ValueTypeNames
    prim = stage.DefinePrim(path, _WRINKLE)
    _set(
        prim, "controlPoints", types.Double2Array, Vt.Vec2dArray.FromNumpy(np.ascontiguousarray(wrinkle.control_points))
    )
    projection = wrinkle.projection
    if isinstance(projection, PlanarProjection):
        _set(prim, "projection", types.Token, "planar")
        _set(prim, "projection:origin", types.Double3, tuple(projection.origin))
        _set(prim, "projection:uAxis", types.Double3, tuple(projection.u_axis))
        _set(prim, "projection:vAxis", types.Double3, tuple(projection.v_axis))
    else:
        _set(prim, "projection", types.Token, "cylindrical")
        _set(prim, "projection:origin", types.Double3, tuple(projection.origin))
        _set(prim, "projection:axis", types.Double3, tuple(projection.axis))
        _set(prim, "projection:reference", types.Double3, tuple(projection.reference))
        _set(prim, "projection:radius", types.Double, projection.radius)
    _set(prim, "depth", types.Double, wrinkle.depth, uniform=False)
    _set(prim, "width", types.Double, wrinkle.width)
    _set(prim, "kr", types.Double, wrinkle.kr)
    return prim


def _identifier(name: str) -> str:
    return Tf.MakeValidIdentifier(name) if name else "_"


def _set_name(prim: Usd.Prim, name: str) -> None:
    """Keep a name that is not a valid prim identifier as the prim's ``displayName``."""
    if name != prim.GetName():
        prim.SetDisplayName(name)


def item_name(prim: Usd.Prim) -> str:
    """The warpface name of a prim: its ``displayName`` when authored, else its prim name."""
    return prim.GetDisplayName() or prim.GetName()


# ---------------------------------------------------------------------------------------------- locating


@dataclass(frozen=True)
class RigPrims:
    """The prims of one rig on a stage, in rig order."""

    skin: Usd.Prim
    """The Mesh with WarpFaceSkinAPI."""
    muscles: tuple[Usd.Prim, ...]
    """Muscle prims in contraction order (the skin's ``warpFace:muscles`` targets)."""
    wrinkles: tuple[Usd.Prim, ...]
    """Wrinkle prims in depth order (the skin's ``warpFace:wrinkles`` targets)."""

    @property
    def muscle_names(self) -> list[str]:
        return [item_name(p) for p in self.muscles]

    @property
    def wrinkle_names(self) -> list[str]:
        return [item_name(p) for p in self.wrinkles]


def rig_prims(stage: Usd.Stage, skin_path: str | None = None) -> RigPrims:
    """Find a rig's skin, muscles and wrinkles, checking prim types and relationships.

    Args:
        stage: the stage.
        skin_path: the skin mesh; by default the only Mesh with WarpFaceSkinAPI on the stage.

    Raises:
        RigError: no or several skins, wrong prim types, relationships to missing prims or to the
            wrong mesh (the message names the prim path).
    """
    ensure_schema()
    if expect_instance(stage, Usd.Stage, "stage") and skin_path is not None:
        skin = stage.GetPrimAtPath(checked_prim_path(skin_path, "skin_path"))
        if not skin:
            raise RigError(f"{skin_path}: no prim at this path on the stage")
        if not skin.HasAPI(SKIN_API):
            raise RigError(f"{skin.GetPath()}: has no {SKIN_API} applied")
    else:
        skins = [p for p in stage.Traverse() if p.HasAPI(SKIN_API)]
        if not skins:
            typed = [p for p in stage.Traverse() if p.GetTypeName().startswith("WarpFace")]
            hint = f" ({len(typed)} WarpFace prims found, e.g. {typed[0].GetPath()})" if typed else ""
            raise RigError(f"{_stage_label(stage)}: no Mesh with {SKIN_API} applied; not a warpface rig{hint}")
        if len(skins) > 1:
            raise RigError(
                f"{_stage_label(stage)}: several skins ({', '.join(str(p.GetPath()) for p in skins)}); pass skin_path"
            )
        skin = skins[0]
    check_asset(skin)  # a missing referenced asset, before its absence reads as a missing mesh
    if not skin.IsA(UsdGeom.Mesh):
        raise RigError(
            f"{skin.GetPath()}: {SKIN_API} is applied to a {skin.GetTypeName() or 'typeless prim'}; it applies only "
            "to Mesh"
        )
    muscles = _related(
        stage, skin, _MUSCLES_REL, (_LINEAR, _SPHINCTER, LID_TYPE), "WarpFaceLinearMuscle, SphincterMuscle or LidMuscle"
    )
    wrinkles = _related(stage, skin, _WRINKLES_REL, (_WRINKLE,), "WarpFaceWrinkle")
    return RigPrims(skin=skin, muscles=tuple(muscles), wrinkles=tuple(wrinkles))


def _related(stage, skin: Usd.Prim, rel_name: str, type_names: tuple[str, ...], expected: str) -> list[Usd.Prim]:
    rel = skin.GetRelationship(rel_name)
    if rel and rel.HasAuthoredTargets():
        prims = []
        for target in rel.GetTargets():
            prim = stage.GetPrimAtPath(target)
            if not prim:
                raise RigError(f"{skin.GetPath()}.{rel_name}: target {target} does not exist")
            prims.append(prim)
    else:  # no list on the skin: every item whose targetMesh is this skin, in stage order
        prims = [
            p
            for p in stage.Traverse()
            if p.GetTypeName() in type_names and skin.GetPath() in p.GetRelationship("targetMesh").GetTargets()
        ]
    for prim in prims:
        if prim.GetTypeName() not in type_names:
            raise RigError(f"{prim.GetPath()}: is a {prim.GetTypeName() or 'typeless prim'}, expected {expected}")
        rel = prim.GetRelationship("targetMesh")
        targets = rel.GetTargets() if rel else []
        if len(targets) != 1:
            raise RigError(f"{prim.GetPath()}.targetMesh: needs exactly one target (the skin mesh), has {len(targets)}")
        if not stage.GetPrimAtPath(targets[0]):
            raise RigError(f"{prim.GetPath()}.targetMesh: points at {targets[0]}, which does not exist")
        if targets[0] != skin.GetPath():
            raise RigError(f"{prim.GetPath()}.targetMesh: points at {targets[0]}, not at the skin {skin.GetPath()}")
    return prims


def _stage_label(stage: Usd.Stage) -> str:
    layer = stage.GetRootLayer()
    return f"stage {layer.realPath or layer.identifier}"


def stage_meters_per_unit(stage: Usd.Stage) -> float:
    """The stage's ``metersPerUnit`` (USD's fallback 0.01 when not authored); raises RigError if not > 0."""
    value = UsdGeom.GetStageMetersPerUnit(expect_instance(stage, Usd.Stage, "stage"))
    if not (math.isfinite(value) and value > 0.0):
        raise RigError(f"{_stage_label(stage)}: metersPerUnit must be > 0, got {value}")
    return float(value)


# ---------------------------------------------------------------------------------------------- reading


def read_rig(
    stage_or_path, *, skin_path: str | None = None, meters_per_unit: float = 1.0, degenerate: str = "error"
) -> FaceRig:
    """Read and validate a rig from a stage.

    Args:
        stage_or_path: a ``Usd.Stage`` or a path to a USD file.
        skin_path: the skin mesh (default: the only Mesh with WarpFaceSkinAPI).
        meters_per_unit: unit of the returned rig in metres (default 1: SI). The stage's own
            ``metersPerUnit`` is converted from, so a stage in centimetres reads correctly.
        degenerate: :class:`~warpface.FaceMesh` policy for zero-area triangles.

    Returns:
        The rig, in the skin mesh's local space. Wrinkle depths are the ``depth`` default values;
        contraction and depth time samples are read by :func:`warpface.usd.read_animation`.

    Raises:
        RigError: anything missing, of the wrong type or shape, non-finite or out of range; the
            message starts with the prim (or attribute) path.
    """
    ensure_schema()
    stage = open_stage(stage_or_path)
    target_unit = as_positive(meters_per_unit, "meters_per_unit")
    prims = rig_prims(stage, skin_path)
    to_units = stage_meters_per_unit(stage) / target_unit
    skin = prims.skin
    mesh = _read_mesh(skin, to_units, degenerate)
    thickness = _read_thickness(skin, mesh.vertex_count) * to_units
    landmarks = _read_landmarks(skin)
    placements = ItemPlacements(stage, skin)
    muscles = [_read_muscle(p, placements.of(p), to_units) for p in prims.muscles]
    wrinkles = [_read_wrinkle(p, placements.of(p), to_units) for p in prims.wrinkles]
    parent = skin.GetParent()
    name = item_name(parent) if parent and not parent.IsPseudoRoot() else item_name(skin)
    try:
        return FaceRig(
            mesh,
            muscles,
            wrinkles,
            thickness,
            landmarks,
            name,
            read_jaw(stage, skin, placements.of, to_units, mesh.vertex_count),
        )
    except (TypeError, ValueError) as exc:  # a value of the wrong type on the stage is a bad rig
        raise RigError(f"{skin.GetPath()}: {exc}") from None


def _read_mesh(skin: Usd.Prim, to_units: float, degenerate: str) -> FaceMesh:
    geom = UsdGeom.Mesh(skin)
    points = array_value(skin, "points", (None, 3))
    counts = array_value(skin, "faceVertexCounts", (None,), np.int64)
    indices = array_value(skin, "faceVertexIndices", (None,), np.int64)
    if len(counts) and counts.min() < 3:
        face = int(np.argmin(counts))
        raise RigError(f"{skin.GetPath()}.faceVertexCounts: face {face} has {int(counts[face])} vertices (needs ≥ 3)")
    if int(counts.sum()) != len(indices):
        raise RigError(
            f"{skin.GetPath()}: faceVertexCounts sum to {int(counts.sum())} but faceVertexIndices has {len(indices)} "
            "entries"
        )
    triangles = fan_triangles(counts, indices)
    triangles = weld_seams(points, triangles)  # as `warpface rig` built it: a skin split along seams is one piece
    if geom.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded:
        triangles = triangles[:, [0, 2, 1]]
    try:
        return FaceMesh(
            points * to_units if to_units != 1.0 else points, triangles, name=item_name(skin), degenerate=degenerate
        )
    except (TypeError, ValueError) as exc:  # a value of the wrong type on the stage is a bad rig
        raise RigError(f"{skin.GetPath()}: {exc}") from None


def _read_thickness(skin: Usd.Prim, vertex_count: int) -> np.ndarray:
    primvar = UsdGeom.PrimvarsAPI(skin).GetPrimvar(_THICKNESS)
    label = f"{skin.GetPath()}.primvars:{_THICKNESS}"
    if not primvar or not primvar.HasAuthoredValue():
        raise RigError(f"{label}: missing (one thickness value per point is required)")
    values = primvar.ComputeFlattened(_DEFAULT)
    if values is None:
        raise RigError(f"{label}: has no value")
    try:
        values = np.asarray(values, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise RigError(f"{label}: expected an array of numbers, got {primvar.GetTypeName()}") from None
    interpolation = primvar.GetInterpolation()
    if interpolation == UsdGeom.Tokens.constant and len(values) == 1:
        values = np.full(vertex_count, values[0])
    elif interpolation not in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
        raise RigError(f"{label}: interpolation must be 'vertex', got {interpolation!r}")
    if len(values) != vertex_count:
        raise RigError(f"{label}: has {len(values)} values, the mesh has {vertex_count} points")
    check_finite(values, label)
    negative = np.flatnonzero(values < 0.0)
    if len(negative):
        raise RigError(f"{label}: negative thickness {values[negative[0]]} at point {int(negative[0])}")
    return values


def _read_landmarks(skin: Usd.Prim) -> np.ndarray | None:
    attr = skin.GetAttribute(_LANDMARKS)
    if not attr or not attr.HasAuthoredValue():
        return None
    if attr.GetTypeName() != Sdf.ValueTypeNames.IntArray:
        raise RigError(f"{attr.GetPath()}: expected an int[] of point indices, got {attr.GetTypeName()}")
    value = attr.Get(_DEFAULT)
    return None if value is None else np.asarray(value, dtype=np.int64).reshape(-1)


@dataclass(frozen=True)
class Placement:
    """Similarity transform from an item prim's local space to the skin's local space (row vectors)."""

    linear: np.ndarray | None
    """``A`` in ``p_skin = p_item @ A + t``, shape (3, 3); ``None`` when the transform is the identity."""
    translation: np.ndarray
    """``t``, shape (3,)."""
    scale: float
    """Uniform scale ``s`` of ``A`` (lengths multiply by it)."""

    def point(self, value: np.ndarray) -> np.ndarray:
        return value if self.linear is None else value @ self.linear + self.translation

    def direction(self, value: np.ndarray) -> np.ndarray:
        return value if self.linear is None else value @ self.linear


_IDENTITY = Placement(None, np.zeros(3), 1.0)


class ItemPlacements:
    """Placements of muscle and wrinkle prims relative to a skin (transforms at the default time)."""

    def __init__(self, stage: Usd.Stage, skin: Usd.Prim):
        self._cache = UsdGeom.XformCache(_DEFAULT)
        self._skin_inverse = self._cache.GetLocalToWorldTransform(skin).GetInverse()

    def of(self, prim: Usd.Prim) -> Placement:
        """The placement of ``prim``; raises RigError for shear, non-uniform scale or mirroring."""
        matrix = np.array(self._cache.GetLocalToWorldTransform(prim) * self._skin_inverse, dtype=np.float64)
        if np.array_equal(matrix, np.eye(4)):
            return _IDENTITY
        linear = matrix[:3, :3]
        scale_squared = float(np.trace(linear @ linear.T)) / 3.0
        if not np.isfinite(matrix).all() or not np.allclose(matrix[:, 3], [0, 0, 0, 1]):
            raise RigError(f"{prim.GetPath()}: transform to the skin is not affine")
        if scale_squared <= 0.0 or not np.allclose(
            linear @ linear.T, scale_squared * np.eye(3), rtol=0.0, atol=1e-9 * scale_squared
        ):
            raise RigError(
                f"{prim.GetPath()}: transform to the skin must be a rotation, translation and uniform scale "
                f"(no shear or non-uniform scale)"
            )
        if np.linalg.det(linear) < 0.0:
            raise RigError(f"{prim.GetPath()}: transform to the skin mirrors (negative determinant)")
        return Placement(linear, matrix[3, :3].copy(), math.sqrt(scale_squared))


def _read_muscle(prim: Usd.Prim, place: Placement, to_units: float):
    length = place.scale * to_units
    try:
        if prim.GetTypeName() == LID_TYPE:
            return read_lid(prim, place, to_units, item_name(prim))
        if prim.GetTypeName() == _LINEAR:
            return LinearMuscle(
                name=item_name(prim),
                attachment=place.point(array_value(prim, "attachment", (3,))) * to_units,
                insertion=place.point(array_value(prim, "insertion", (3,))) * to_units,
                zone_angle_deg=scalar_value(prim, "zoneAngle"),
                falloff_start=scalar_value(prim, "falloffStart") * length,
                falloff_finish=scalar_value(prim, "falloffFinish") * length,
                lobes=read_lobes(prim, place.point, to_units, length),
                **_muscle_response(prim),
            )
        return SphincterMuscle(
            name=item_name(prim),
            center=place.point(array_value(prim, "center", (3,))) * to_units,
            axis_x=place.direction(array_value(prim, "axisX", (3,))),
            axis_y=place.direction(array_value(prim, "axisY", (3,))),
            semi_axes=array_value(prim, "semiAxes", (2,)) * length,
            ring=scalar_value(prim, "ring"),
            **_muscle_response(prim),
        )
    except RigError:
        raise
    except (TypeError, ValueError) as exc:  # a value of the wrong type on the stage is a bad rig
        raise RigError(f"{prim.GetPath()}: {exc}") from None


def _muscle_response(prim: Usd.Prim) -> dict:  # zone form, sliding, bunching, thickening (fallbacks: SPEC §1.1)
    return dict(
        falloff=token_value(prim, "falloff", FALLOFFS), **{name: scalar_value(prim, name) for name in _RESPONSE}
    )


def _read_wrinkle(prim: Usd.Prim, place: Placement, to_units: float) -> Wrinkle:
    length = place.scale * to_units
    control_points = array_value(prim, "controlPoints", (None, 2))
    if len(control_points) != 4:
        raise RigError(
            f"{prim.GetPath()}.controlPoints: a cubic Bézier needs 4 control points, got {len(control_points)}"
        )
    kind = token_value(prim, "projection", ("planar", "cylindrical"))
    origin = place.point(array_value(prim, "projection:origin", (3,))) * to_units
    try:
        if kind == "planar":
            projection = PlanarProjection(
                origin,
                place.direction(array_value(prim, "projection:uAxis", (3,))),
                place.direction(array_value(prim, "projection:vAxis", (3,))),
            )
        else:
            projection = CylindricalProjection(
                origin,
                place.direction(array_value(prim, "projection:axis", (3,))),
                place.direction(array_value(prim, "projection:reference", (3,))),
                scalar_value(prim, "projection:radius") * length,
            )
        return Wrinkle(
            name=item_name(prim),
            control_points=control_points * length,
            projection=projection,
            depth=scalar_value(prim, "depth") * length,
            width=scalar_value(prim, "width") * length,
            kr=scalar_value(prim, "kr"),
        )
    except RigError:
        raise
    except (TypeError, ValueError) as exc:  # a value of the wrong type on the stage is a bad rig
        raise RigError(f"{prim.GetPath()}: {exc}") from None
