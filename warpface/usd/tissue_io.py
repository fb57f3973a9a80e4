"""Tissue tetrahedral meshes with ``WarpFaceTetMaterialAPI``: write and read, validated.

Two levels: :func:`write_tissue` / :func:`read_tissue` take and return plain arrays (:class:`Tissue`);
:func:`write_tissue_mesh` / :func:`read_tissue_mesh` take and return the FEM's types
(:class:`~warpface.fem.TetMesh`, :class:`~warpface.fem.TissueMaterial`, region masks), so what is read
back is a validated, positively oriented mesh ready to simulate. USD's ``rightHanded`` tets and
warpface's positively oriented tets (``det[p1 − p0, p2 − p0, p3 − p0] > 0``) are the same
convention, which the writer checks with ``UsdGeom.TetMesh.FindInvertedElements``.

Material values are SI regardless of the stage's ``metersPerUnit`` (Young's modulus and viscosity
in Pa and Pa·s, density in kg/m³); point positions are lengths and are converted like the rig's.
Each material property is a ``constant`` primvar (one value) or a ``uniform`` one (a value per tet).
Named regions are ``GeomSubset`` children of element type ``tetrahedron`` in the family
``warpFace:region``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from pxr import Sdf, Usd, UsdGeom, Vt

from .._validate import as_finite_array, as_indices, as_positive, expect_instance
from ..errors import RigError
from ..fem.material import MATERIAL_RANGES, TissueMaterial
from ..fem.tetmesh import TetMesh
from ._files import checked_prim_path, open_stage
from .rig_io import SKIN_API, stage_meters_per_unit
from .schema import ensure_schema

__all__ = [
    "MATERIAL_PRIMVARS",
    "REGION_FAMILY",
    "TET_MATERIAL_API",
    "Tissue",
    "TissueMeshData",
    "find_inverted_elements",
    "read_tissue",
    "read_tissue_mesh",
    "write_tissue",
    "write_tissue_mesh",
]

TET_MATERIAL_API = "WarpFaceTetMaterialAPI"
REGION_FAMILY = "warpFace:region"
MATERIAL_PRIMVARS = {
    "youngs_modulus": "warpFace:youngsModulus",
    "poisson_ratio": "warpFace:poissonRatio",
    "viscosity": "warpFace:viscosity",
    "density": "warpFace:density",
}
"""Tissue field → primvar name (without the ``primvars:`` namespace)."""

# Tissue field -> the TissueMaterial field whose range (warpface.fem.MATERIAL_RANGES) it must satisfy.
_MATERIAL_FIELD = {"youngs_modulus": "E", "poisson_ratio": "nu", "viscosity": "eta", "density": "rho"}


@dataclass(eq=False)
class Tissue:
    """A tetrahedral tissue mesh with its viscoelastic material."""

    points: np.ndarray
    """Node positions [length units], shape (N, 3), float64."""
    tets: np.ndarray
    """Node indices per tetrahedron, shape (M, 4), int64."""
    youngs_modulus: float | np.ndarray
    """Young's modulus E [Pa], scalar or shape (M,)."""
    poisson_ratio: float | np.ndarray
    """Poisson's ratio ν, scalar or shape (M,)."""
    viscosity: float | np.ndarray
    """Shear viscosity η [Pa s], scalar or shape (M,)."""
    density: float | np.ndarray
    """Density ρ [kg/m³], scalar or shape (M,)."""
    regions: dict[str, np.ndarray] = field(default_factory=dict)
    """Region name → tet indices, each shape (K,), int64."""

    def material(self, **kwargs):
        """A :class:`warpface.fem.material.TissueMaterial` with these values (keyword arguments pass through)."""
        return TissueMaterial(self.youngs_modulus, self.poisson_ratio, self.viscosity, self.density, **kwargs)


def write_tissue(
    stage: Usd.Stage,
    path: str,
    points,
    tets,
    *,
    youngs_modulus,
    poisson_ratio,
    viscosity,
    density,
    regions: dict | None = None,
    skin_path: str | None = None,
) -> Usd.Prim:
    """Define a ``TetMesh`` with ``WarpFaceTetMaterialAPI`` at ``path`` (authored in the edit target).

    Args:
        stage: the stage.
        path: prim path of the tissue mesh.
        points: node positions in stage units, shape (N, 3).
        tets: node indices, shape (M, 4).
        youngs_modulus, poisson_ratio, viscosity, density: scalar (constant primvar) or shape (M,)
            (uniform primvar), SI units.
        regions: optional name → tet indices, written as GeomSubsets of the ``warpFace:region`` family.
        skin_path: a skin mesh whose ``warpFace:tissue`` relationship should target this mesh.

    Returns:
        The TetMesh prim.

    Raises:
        ValueError: bad shapes, indices out of range, values out of range.
    """
    expect_instance(stage, Usd.Stage, "stage")
    checked_prim_path(path, "path")
    ensure_schema()
    tissue = _validated(points, tets, youngs_modulus, poisson_ratio, viscosity, density, regions or {}, path)
    mesh = UsdGeom.TetMesh.Define(stage, path)
    prim = mesh.GetPrim()
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(tissue.points, dtype=np.float32)))
    mesh.CreateTetVertexIndicesAttr(Vt.Vec4iArray.FromNumpy(np.ascontiguousarray(tissue.tets, dtype=np.int32)))
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    mesh.CreateSurfaceFaceVertexIndicesAttr(UsdGeom.TetMesh.ComputeSurfaceFaces(mesh, Usd.TimeCode.Default()))
    lo, hi = tissue.points.min(axis=0), tissue.points.max(axis=0)
    mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([lo, hi]).astype(np.float32)))
    prim.ApplyAPI(TET_MATERIAL_API)
    primvars = UsdGeom.PrimvarsAPI(prim)
    for field_name, primvar_name in MATERIAL_PRIMVARS.items():
        value = np.atleast_1d(getattr(tissue, field_name)).astype(np.float64)
        interpolation = UsdGeom.Tokens.constant if np.ndim(getattr(tissue, field_name)) == 0 else UsdGeom.Tokens.uniform
        primvar = primvars.CreatePrimvar(primvar_name, Sdf.ValueTypeNames.DoubleArray, interpolation)
        primvar.SetInterpolation(interpolation)  # explicit, for readers without the plugin
        primvar.Set(Vt.DoubleArray.FromNumpy(value))
    imageable = UsdGeom.Imageable(prim)
    for name, indices in tissue.regions.items():
        UsdGeom.Subset.CreateGeomSubset(
            imageable,
            name,
            UsdGeom.Tokens.tetrahedron,
            Vt.IntArray.FromNumpy(indices.astype(np.int32)),
            REGION_FAMILY,
            UsdGeom.Tokens.nonOverlapping,
        )
    if skin_path is not None:
        skin = stage.GetPrimAtPath(checked_prim_path(skin_path, "skin_path"))
        if not skin or not skin.HasAPI(SKIN_API):
            raise ValueError(f"{skin_path}: not a skin mesh with {SKIN_API}")
        skin.CreateRelationship("warpFace:tissue", custom=False).SetTargets([prim.GetPath()])
    return prim


def _validated(points, tets, youngs_modulus, poisson_ratio, viscosity, density, regions: dict, label: str) -> Tissue:
    points = as_finite_array(points, f"{label}: points", shape=(None, 3))
    tets = np.asarray(tets)
    if tets.ndim != 2 or tets.shape[1] != 4 or not np.issubdtype(tets.dtype, np.integer):
        raise ValueError(f"{label}: tets must be integers of shape (M, 4), got {tets.dtype} {tets.shape}")
    if len(tets) == 0:
        raise ValueError(f"{label}: no tetrahedra")
    bad = np.flatnonzero(np.any((tets < 0) | (tets >= len(points)), axis=1))
    if len(bad):
        raise ValueError(
            f"{label}: tet {int(bad[0])} has node index out of range [0, {len(points)}): {tets[bad[0]].tolist()}"
        )
    values = {}
    for name, raw in (
        ("youngs_modulus", youngs_modulus),
        ("poisson_ratio", poisson_ratio),
        ("viscosity", viscosity),
        ("density", density),
    ):
        value = as_finite_array(raw, f"{label}: {name}")
        if value.ndim not in (0, 1) or (value.ndim == 1 and len(value) != len(tets)):
            raise ValueError(
                f"{label}: {name} must be a scalar or one value per tet ({len(tets)},), got shape {value.shape}"
            )
        allowed = MATERIAL_RANGES[_MATERIAL_FIELD[name]]
        wrong = allowed.outside(value)
        if len(wrong):
            where = f" at tet {int(wrong[0])}" if value.ndim else ""
            raise ValueError(
                f"{label}: {name}{where} must be {allowed.describe()}, got {np.atleast_1d(value)[wrong[0]]}"
            )
        values[name] = float(value) if value.ndim == 0 else value
    checked = {}
    for name, indices in regions.items():
        checked[name] = as_indices(indices, len(tets), f"{label}: region {name!r} tet indices")
    return Tissue(points=points, tets=tets.astype(np.int64), regions=checked, **values)


def read_tissue(stage_or_path, path: str | None = None, *, meters_per_unit: float = 1.0) -> Tissue:
    """Read and validate a tissue mesh.

    Args:
        stage_or_path: a ``Usd.Stage`` or a USD file.
        path: the TetMesh; default the target of the only skin's ``warpFace:tissue``, else the only
            TetMesh with ``WarpFaceTetMaterialAPI``.
        meters_per_unit: length unit of the returned points in metres (material values stay SI).

    Raises:
        RigError: missing prim, wrong type, bad primvar interpolation or length, values out of range,
            bad regions (the message names the prim path).
    """
    ensure_schema()
    stage = open_stage(stage_or_path)
    prim = _find_tissue(stage, path)
    label = str(prim.GetPath())
    if not prim.IsA(UsdGeom.TetMesh):
        raise RigError(f"{label}: is a {prim.GetTypeName() or 'typeless prim'}, expected TetMesh")
    if not prim.HasAPI(TET_MATERIAL_API):
        raise RigError(f"{label}: has no {TET_MATERIAL_API} applied")
    mesh = UsdGeom.TetMesh(prim)
    points = mesh.GetPointsAttr().Get(Usd.TimeCode.Default())
    tets = mesh.GetTetVertexIndicesAttr().Get(Usd.TimeCode.Default())
    if points is None or tets is None:
        raise RigError(f"{label}: points and tetVertexIndices are required")
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    tets = np.asarray(tets, dtype=np.int64).reshape(-1, 4)
    values = {}
    for field_name, primvar_name in MATERIAL_PRIMVARS.items():
        primvar = UsdGeom.PrimvarsAPI(prim).GetPrimvar(primvar_name)
        value = primvar.ComputeFlattened(Usd.TimeCode.Default()) if primvar else None
        if value is None:
            raise RigError(f"{label}.primvars:{primvar_name}: missing")
        value = np.asarray(value, dtype=np.float64).reshape(-1)
        interpolation = primvar.GetInterpolation()
        if interpolation == UsdGeom.Tokens.constant and len(value) == 1:
            values[field_name] = float(value[0])
        elif interpolation == UsdGeom.Tokens.uniform and len(value) == len(tets):
            values[field_name] = value
        else:
            raise RigError(
                f"{label}.primvars:{primvar_name}: {interpolation!r} primvar with {len(value)} values; expected "
                f"'constant' with 1 or 'uniform' with one per tet ({len(tets)})"
            )
    regions = {}
    for subset in UsdGeom.Subset.GetGeomSubsets(UsdGeom.Imageable(prim), UsdGeom.Tokens.tetrahedron, REGION_FAMILY):
        indices = subset.GetIndicesAttr().Get(Usd.TimeCode.Default())
        regions[subset.GetPrim().GetName()] = np.asarray(indices if indices is not None else [], dtype=np.int64)
    to_units = stage_meters_per_unit(stage) / as_positive(meters_per_unit, "meters_per_unit")
    try:
        return _validated(
            points * to_units if to_units != 1.0 else points, tets, regions=regions, label=label, **values
        )
    except (TypeError, ValueError) as exc:  # a value of the wrong type on the stage is a bad rig
        raise RigError(str(exc)) from None


def _find_tissue(stage: Usd.Stage, path: str | None) -> Usd.Prim:
    if path is not None:
        prim = stage.GetPrimAtPath(checked_prim_path(path, "path"))
        if not prim:
            raise RigError(f"{path}: no prim at this path on the stage")
        return prim
    skins = [p for p in stage.Traverse() if p.HasAPI(SKIN_API)]
    if len(skins) == 1:
        rel = skins[0].GetRelationship("warpFace:tissue")
        targets = rel.GetTargets() if rel else []
        if targets:
            prim = stage.GetPrimAtPath(targets[0])
            if not prim:
                raise RigError(f"{skins[0].GetPath()}.warpFace:tissue: points at {targets[0]}, which does not exist")
            return prim
    candidates = [p for p in stage.Traverse() if p.HasAPI(TET_MATERIAL_API)]
    if len(candidates) != 1:
        raise RigError(
            f"stage {stage.GetRootLayer().identifier}: {len(candidates)} TetMesh prims with {TET_MATERIAL_API}; pass "
            "path"
        )
    return candidates[0]


# ---------------------------------------------------------------------------------------------- FEM types


@dataclass(frozen=True, eq=False)
class TissueMeshData:
    """A tissue mesh read from a stage."""

    tetmesh: TetMesh
    """The validated mesh [m]."""
    material: TissueMaterial
    """Uniform or per-tet material."""
    regions: dict
    """Region name -> boolean mask over tets, shape (M,)."""


def _region_indices(regions: Mapping[str, object] | None, tet_count: int) -> dict[str, np.ndarray]:
    out = {}
    for name, selection in (regions or {}).items():
        sel = np.asarray(selection)
        if sel.dtype == bool:
            if sel.shape != (tet_count,):
                raise ValueError(f"region {name!r}: mask has shape {sel.shape}, expected ({tet_count},)")
            out[name] = np.flatnonzero(sel)
        else:
            out[name] = sel.astype(np.int64).ravel()
    return out


def write_tissue_mesh(
    stage, path: str, tetmesh: TetMesh, material: TissueMaterial, *, regions=None, skin_path: str | None = None
):
    """Author ``tetmesh`` with ``material`` as a ``UsdGeom.TetMesh`` at ``path``.

    Points are written as float32 (USD ``point3f[]``); material values as SI doubles, ``constant``
    primvars for a uniform material and ``uniform`` (per tet) otherwise.

    Args:
        stage: A ``Usd.Stage`` (edits go to its edit target).
        path: Prim path of the tissue mesh.
        tetmesh: The mesh [m] (stage lengths are metres: warpface stages use ``metersPerUnit = 1``).
        material: Uniform or per-tet material; its ``damping`` law is not stored (the schema has
            no slot for it) and is chosen again on reading.
        regions: Region name -> boolean mask (M,) or tet indices; written as GeomSubsets.
        skin_path: A skin mesh (``WarpFaceSkinAPI``) whose ``warpFace:tissue`` should target it.

    Returns:
        The ``Usd.Prim``.

    Raises:
        ValueError: material of the wrong size, bad regions, or a tet USD reports as inverted.
    """
    expect_instance(stage, Usd.Stage, "stage")
    checked_prim_path(path, "path")
    if not isinstance(tetmesh, TetMesh):
        raise TypeError(f"tetmesh: expected a TetMesh, got {type(tetmesh).__name__}")
    if not isinstance(material, TissueMaterial):
        raise TypeError(f"material: expected a TissueMaterial, got {type(material).__name__}")
    material.per_tet(tetmesh.tet_count)  # size check with a clear message
    prim = write_tissue(
        stage,
        path,
        tetmesh.points,
        tetmesh.tets,
        youngs_modulus=material.E,
        poisson_ratio=material.nu,
        viscosity=material.eta,
        density=material.rho,
        regions=_region_indices(regions, tetmesh.tet_count),
        skin_path=skin_path,
    )
    if material.is_uniform:
        _bind_physics_material(stage, prim, material)
    inverted = UsdGeom.TetMesh.FindInvertedElements(UsdGeom.TetMesh(prim), Usd.TimeCode.Default())
    if len(inverted):
        raise ValueError(
            f"{path}: USD reports {len(inverted)} inverted tets after writing (first {inverted[0]}); "
            "float32 rounding of the points collapsed a sliver"
        )
    return prim


def _bind_physics_material(stage, prim, material: TissueMaterial) -> None:
    """A uniform ``material`` also as the deformable physics material other simulators read (Newton's ``add_usd``):
    ``physics:youngsModulus`` [Pa], ``physics:poissonsRatio``, ``physics:density`` [kg/m³] on a
    ``PhysicsVolumeDeformableMaterialAPI`` material beside the tet mesh (``<name>PhysicsMaterial``), bound to it for
    the ``physics`` purpose. warpface reads its own primvars; a per-tet material has no single value to give."""
    from pxr import UsdShade

    path = prim.GetPath()
    shade = UsdShade.Material.Define(stage, path.GetParentPath().AppendChild(f"{path.name}PhysicsMaterial"))
    shade.GetPrim().AddAppliedSchema("PhysicsVolumeDeformableMaterialAPI")
    for name, value in (("youngsModulus", material.E), ("poissonsRatio", material.nu), ("density", material.rho)):
        shade.GetPrim().CreateAttribute(f"physics:{name}", Sdf.ValueTypeNames.Float).Set(float(value))
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(shade, UsdShade.Tokens.weakerThanDescendants, "physics")


def read_tissue_mesh(stage_or_path, path: str | None = None, *, damping: str = "stokes") -> TissueMeshData:
    """Read a tissue mesh written by :func:`write_tissue_mesh` (or any conforming TetMesh prim).

    Args:
        stage_or_path: A ``Usd.Stage`` or a USD file path.
        path: The TetMesh prim; default: the target of the skin's ``warpFace:tissue``, else the
            only TetMesh with ``WarpFaceTetMaterialAPI``.
        damping: Viscous law of the returned material ("stokes" or "thesis").

    Returns:
        :class:`TissueMeshData`; points in metres whatever the stage's ``metersPerUnit``.

    Raises:
        warpface.RigError: the prim is missing or malformed (see :func:`warpface.usd.read_tissue`).
        ValueError: the tets are inverted, degenerate or leave nodes unused (from :class:`TetMesh`),
            or the material is out of range.
    """
    tissue = read_tissue(stage_or_path, path, meters_per_unit=1.0)
    tetmesh = TetMesh(tissue.points, tissue.tets)
    material = TissueMaterial(
        tissue.youngs_modulus, tissue.poisson_ratio, tissue.viscosity, tissue.density, damping=damping
    )
    material.per_tet(tetmesh.tet_count)
    regions = {}
    for name, indices in tissue.regions.items():
        mask = np.zeros(tetmesh.tet_count, dtype=bool)
        mask[indices] = True
        regions[name] = mask
    return TissueMeshData(tetmesh=tetmesh, material=material, regions=regions)


def find_inverted_elements(points, tets) -> np.ndarray:
    """Indices of tets that ``UsdGeom.TetMesh.FindInvertedElements`` reports as inverted, shape (K,), int64.

    An independent check of orientation (USD's own code, on float32 points, in a throwaway
    in-memory stage) to compare with :func:`~warpface.fem.tetmesh.tet_signed_volumes`.
    """
    stage = Usd.Stage.CreateInMemory()
    mesh = UsdGeom.TetMesh.Define(stage, "/Tissue")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(points, dtype=np.float32)))
    mesh.CreateTetVertexIndicesAttr(Vt.Vec4iArray.FromNumpy(np.ascontiguousarray(tets, dtype=np.int32)))
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    return np.asarray(UsdGeom.TetMesh.FindInvertedElements(mesh, Usd.TimeCode.Default()), dtype=np.int64)
