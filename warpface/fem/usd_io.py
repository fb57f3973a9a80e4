"""FEM tissue on USD stages: a :class:`TetMesh` + :class:`TissueMaterial` + regions as ``UsdGeom.TetMesh``.

The prim layout (``WarpFaceTetMaterialAPI`` primvars, ``warpFace:region`` GeomSubsets of element
type ``tetrahedron``) is owned by :mod:`warpface.usd.tissue_io`; this module converts between it
and the FEM's types, so what is read back is a validated, positively oriented mesh ready to
simulate. ``pxr`` is imported only inside the functions.

Orientation: USD's ``rightHanded`` tets and warpface's positively oriented tets
(``det[p1 − p0, p2 − p0, p3 − p0] > 0``) are the same convention, which the writer checks with
``UsdGeom.TetMesh.FindInvertedElements``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .material import TissueMaterial
from .tetmesh import TetMesh

__all__ = ["TissueMeshData", "find_inverted_elements", "read_tissue_mesh", "write_tissue_mesh"]


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


def write_tissue_mesh(stage, path: str, tetmesh: TetMesh, material: TissueMaterial, *, regions=None,
                      skin_path: str | None = None):
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
    from pxr import Usd, UsdGeom

    from ..usd.tissue_io import write_tissue

    if not isinstance(tetmesh, TetMesh):
        raise ValueError(f"write_tissue_mesh: expected a TetMesh, got {type(tetmesh).__name__}")
    if not isinstance(material, TissueMaterial):
        raise ValueError(f"write_tissue_mesh: expected a TissueMaterial, got {type(material).__name__}")
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
    inverted = UsdGeom.TetMesh.FindInvertedElements(UsdGeom.TetMesh(prim), Usd.TimeCode.Default())
    if len(inverted):
        raise ValueError(
            f"{path}: USD reports {len(inverted)} inverted tets after writing (first {inverted[0]}); "
            "float32 rounding of the points collapsed a sliver"
        )
    return prim


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
    from ..usd.tissue_io import read_tissue

    tissue = read_tissue(stage_or_path, path, meters_per_unit=1.0)
    tetmesh = TetMesh(tissue.points, tissue.tets)
    material = TissueMaterial(tissue.youngs_modulus, tissue.poisson_ratio, tissue.viscosity, tissue.density,
                              damping=damping)
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
    from pxr import Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateInMemory()
    mesh = UsdGeom.TetMesh.Define(stage, "/Tissue")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(points, dtype=np.float32)))
    mesh.CreateTetVertexIndicesAttr(Vt.Vec4iArray.FromNumpy(np.ascontiguousarray(tets, dtype=np.int32)))
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    return np.asarray(UsdGeom.TetMesh.FindInvertedElements(mesh, Usd.TimeCode.Default()), dtype=np.int64)
