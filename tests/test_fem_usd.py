"""FEM tissue on USD: TetMesh + TissueMaterial + regions round trip; orientation agrees with USD's."""

from __future__ import annotations

import numpy as np
import pytest

pxr = pytest.importorskip("pxr", reason="usd-core is not installed")

from pxr import Usd, UsdGeom  # noqa: E402

from warpface.fem import TetMesh, TissueMaterial, box_tet_mesh, shell_tet_mesh  # noqa: E402
from warpface.fem.tetmesh import tet_signed_volumes  # noqa: E402


def _schema_or_skip():
    from warpface.usd.schema import SchemaRegistrationError, ensure_schema

    try:
        ensure_schema()
    except SchemaRegistrationError as exc:
        pytest.skip(f"warpface USD schema not available: {exc}")
    return pytest.importorskip("warpface.usd.tissue_io")


def float32_mesh(mesh: TetMesh) -> TetMesh:
    """The mesh with points rounded to float32 (USD stores point3f), so a round trip is exact."""
    return TetMesh(mesh.points.astype(np.float32).astype(np.float64), mesh.tets)


def stage():
    s = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageMetersPerUnit(s, 1.0)
    UsdGeom.SetStageUpAxis(s, UsdGeom.Tokens.y)
    return s


def test_round_trip_per_tet_material_and_regions(tmp_path):
    usd_io = _schema_or_skip()
    mesh = float32_mesh(shell_tet_mesh(6, 5, 2))
    m = mesh.tet_count
    rng = np.random.default_rng(0)
    material = TissueMaterial(rng.uniform(9e4, 2.2e5, m), 0.495, rng.uniform(350.0, 460.0, m), 1100.0)
    regions = {"cheilion": rng.random(m) < 0.1, "cphs_R": np.arange(m) % 7 == 0}
    s = stage()
    prim = usd_io.write_tissue_mesh(s, "/Face/Tissue", mesh, material, regions=regions)
    assert prim.HasAPI("WarpFaceTetMaterialAPI")
    path = tmp_path / "tissue.usda"
    s.GetRootLayer().Export(str(path))

    data = usd_io.read_tissue_mesh(str(path), "/Face/Tissue")
    np.testing.assert_array_equal(data.tetmesh.points, mesh.points)
    np.testing.assert_array_equal(data.tetmesh.tets, mesh.tets)
    np.testing.assert_array_equal(data.material.E, material.E)
    np.testing.assert_array_equal(data.material.eta, material.eta)
    assert data.material.nu == 0.495 and data.material.rho == 1100.0  # uniform values stay scalars
    assert set(data.regions) == set(regions)
    for name, mask in regions.items():
        np.testing.assert_array_equal(data.regions[name], mask)
    # surface faces are authored (for viewers) and match the mesh's boundary faces
    reopened = Usd.Stage.Open(str(path))
    faces = np.asarray(UsdGeom.TetMesh(reopened.GetPrimAtPath("/Face/Tissue")).GetSurfaceFaceVertexIndicesAttr().Get())
    faces = faces.reshape(-1, 3)
    assert {tuple(sorted(f)) for f in faces.tolist()} == {tuple(sorted(f)) for f in mesh.boundary_faces.tolist()}


def test_uniform_material_round_trip_and_default_prim_lookup():
    usd_io = _schema_or_skip()
    mesh = float32_mesh(box_tet_mesh((0.02, 0.01, 0.01), (2, 1, 1)))
    s = stage()
    usd_io.write_tissue_mesh(s, "/Tissue", mesh, TissueMaterial(192.4e3, 0.495, 476.8, 1100.0))
    data = usd_io.read_tissue_mesh(s, damping="thesis")  # the only TetMesh with the API
    assert data.material.is_uniform and data.material.E == 192.4e3 and data.material.damping == "thesis"
    assert data.regions == {}


def test_usd_inverted_elements_agree_with_signed_volumes():
    usd_io = _schema_or_skip()
    mesh = shell_tet_mesh(5, 5, 2)
    tets = mesh.tets.copy()
    flip = np.arange(len(tets)) % 5 == 0
    tets[flip] = tets[flip][:, [1, 0, 2, 3]]
    inverted = usd_io.find_inverted_elements(mesh.points, tets)
    np.testing.assert_array_equal(inverted, np.flatnonzero(tet_signed_volumes(mesh.points, tets) < 0))
    assert len(usd_io.find_inverted_elements(mesh.points, mesh.tets)) == 0


def test_reading_inverted_tets_is_rejected():
    usd_io = _schema_or_skip()
    mesh = float32_mesh(box_tet_mesh((0.02, 0.01, 0.01), (2, 1, 1)))
    s = stage()
    usd_io.write_tissue_mesh(s, "/Tissue", mesh, TissueMaterial(1e5, 0.45, 10.0, 1000.0))
    tets = np.asarray(mesh.tets).copy()
    tets[3] = tets[3][[1, 0, 2, 3]]
    from pxr import Vt

    UsdGeom.TetMesh(s.GetPrimAtPath("/Tissue")).GetTetVertexIndicesAttr().Set(Vt.Vec4iArray.FromNumpy(tets))
    with pytest.raises(ValueError, match="tet 3 is inverted"):
        usd_io.read_tissue_mesh(s)


def test_write_checks_types_and_sizes():
    usd_io = _schema_or_skip()
    mesh = box_tet_mesh((0.02, 0.01, 0.01), (2, 1, 1))
    with pytest.raises(TypeError, match="TetMesh"):
        usd_io.write_tissue_mesh(stage(), "/T", mesh.points, TissueMaterial(1e5, 0.4, 1.0, 1e3))
    with pytest.raises(ValueError, match="per-tet values"):
        usd_io.write_tissue_mesh(stage(), "/T", mesh, TissueMaterial(np.ones(3) * 1e5, 0.4, 1.0, 1e3))
    with pytest.raises(ValueError, match="mask has shape"):
        usd_io.write_tissue_mesh(
            stage(), "/T", mesh, TissueMaterial(1e5, 0.4, 1.0, 1e3), regions={"a": np.ones(2, bool)}
        )
