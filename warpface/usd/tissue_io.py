"""Tissue tetrahedral meshes with ``WarpFaceTetMaterialAPI``: write and read, validated.

Material values are SI regardless of the stage's ``metersPerUnit`` (Young's modulus and viscosity
in Pa and Pa·s, density in kg/m³); point positions are lengths and are converted like the rig's.
Each material property is a ``constant`` primvar (one value) or a ``uniform`` one (a value per tet).
Named regions are ``GeomSubset`` children of element type ``tetrahedron`` in the family
``warpFace:region``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pxr import Sdf, Usd, UsdGeom, Vt

from .._validate import as_finite_array, as_positive
from ..errors import RigError
from ..fem.material import MATERIAL_RANGES
from ._files import open_stage
from .rig_io import SKIN_API, stage_meters_per_unit
from .schema import ensure_schema

__all__ = ["Tissue", "write_tissue", "read_tissue", "TET_MATERIAL_API", "REGION_FAMILY", "MATERIAL_PRIMVARS"]

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
        from ..fem.material import TissueMaterial

        return TissueMaterial(self.youngs_modulus, self.poisson_ratio, self.viscosity, self.density, **kwargs)


def write_tissue(stage: Usd.Stage, path: str, points, tets, *, youngs_modulus, poisson_ratio, viscosity, density,
                 regions: dict | None = None, skin_path: str | None = None) -> Usd.Prim:
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
        UsdGeom.Subset.CreateGeomSubset(imageable, name, UsdGeom.Tokens.tetrahedron,
                                        Vt.IntArray.FromNumpy(indices.astype(np.int32)), REGION_FAMILY, UsdGeom.Tokens.nonOverlapping)
    if skin_path is not None:
        skin = stage.GetPrimAtPath(skin_path)
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
        raise ValueError(f"{label}: tet {int(bad[0])} has node index out of range [0, {len(points)}): {tets[bad[0]].tolist()}")
    values = {}
    for name, raw in (("youngs_modulus", youngs_modulus), ("poisson_ratio", poisson_ratio), ("viscosity", viscosity), ("density", density)):
        value = as_finite_array(raw, f"{label}: {name}")
        if value.ndim not in (0, 1) or (value.ndim == 1 and len(value) != len(tets)):
            raise ValueError(f"{label}: {name} must be a scalar or one value per tet ({len(tets)},), got shape {value.shape}")
        allowed = MATERIAL_RANGES[_MATERIAL_FIELD[name]]
        wrong = allowed.outside(value)
        if len(wrong):
            where = f" at tet {int(wrong[0])}" if value.ndim else ""
            raise ValueError(f"{label}: {name}{where} must be {allowed.describe()}, got {np.atleast_1d(value)[wrong[0]]}")
        values[name] = float(value) if value.ndim == 0 else value
    checked = {}
    for name, indices in regions.items():
        indices = np.asarray(indices)
        if indices.ndim != 1 or not np.issubdtype(indices.dtype, np.integer) and len(indices):
            raise ValueError(f"{label}: region {name!r} must be a 1-D array of tet indices")
        indices = indices.astype(np.int64)
        outside = np.flatnonzero((indices < 0) | (indices >= len(tets)))
        if len(outside):
            raise ValueError(f"{label}: region {name!r} tet index {int(indices[outside[0]])} out of range [0, {len(tets)})")
        checked[name] = indices
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
            raise RigError(f"{label}.primvars:{primvar_name}: {interpolation!r} primvar with {len(value)} values; expected "
                           f"'constant' with 1 or 'uniform' with one per tet ({len(tets)})")
    regions = {}
    for subset in UsdGeom.Subset.GetGeomSubsets(UsdGeom.Imageable(prim), UsdGeom.Tokens.tetrahedron, REGION_FAMILY):
        indices = subset.GetIndicesAttr().Get(Usd.TimeCode.Default())
        regions[subset.GetPrim().GetName()] = np.asarray(indices if indices is not None else [], dtype=np.int64)
    to_units = stage_meters_per_unit(stage) / as_positive(meters_per_unit, "meters_per_unit")
    try:
        return _validated(points * to_units if to_units != 1.0 else points, tets, regions=regions, label=label, **values)
    except ValueError as exc:
        raise RigError(str(exc)) from None


def _find_tissue(stage: Usd.Stage, path: str | None) -> Usd.Prim:
    if path is not None:
        prim = stage.GetPrimAtPath(path)
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
        raise RigError(f"stage {stage.GetRootLayer().identifier}: {len(candidates)} TetMesh prims with {TET_MATERIAL_API}; pass path")
    return candidates[0]
