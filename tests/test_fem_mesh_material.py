"""TetMesh validation, geometry and quality; TissueMaterial validation and regions."""

from __future__ import annotations

import numpy as np
import pytest

from warpface.fem import TetMesh, TissueMaterial, box_tet_mesh, shell_tet_mesh
from warpface.fem.tetmesh import tet_dihedral_angles

UNIT = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)


def test_box_mesh_volume_boundary_and_orientation():
    mesh = box_tet_mesh((0.3, 0.2, 0.1), (3, 2, 1))
    assert mesh.node_count == 4 * 3 * 2 and mesh.tet_count == 6 * 6
    assert mesh.total_volume == pytest.approx(0.3 * 0.2 * 0.1, rel=1e-14)
    assert np.all(mesh.volumes > 0)
    faces = mesh.boundary_faces
    assert len(faces) == 2 * 2 * (3 * 2 + 2 * 1 + 3 * 1)
    # outward winding: the divergence theorem gives the volume from the boundary alone
    p = mesh.points[faces]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]) / 2.0
    assert np.einsum("ij,ij->", p.mean(axis=1), n) / 3.0 == pytest.approx(mesh.total_volume, rel=1e-12)
    assert set(mesh.surface_nodes) | set(mesh.interior_nodes) == set(range(mesh.node_count))
    assert mesh.nodal_volumes.sum() == pytest.approx(mesh.total_volume, rel=1e-14)
    assert len(mesh.edges) == len({tuple(e) for e in mesh.edges})


def test_quality_of_regular_and_kuhn_tets():
    regular = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
    mesh, _ = TetMesh.repaired(regular, [[0, 1, 2, 3]])
    q = mesh.quality()
    assert q.min_dihedral_deg == pytest.approx(np.degrees(np.arccos(1 / 3)), abs=1e-9)
    assert q.max_dihedral_deg == pytest.approx(q.min_dihedral_deg, abs=1e-9)
    assert q.inverted_count == 0
    box = box_tet_mesh((1, 1, 1), (2, 2, 2)).quality()
    assert box.min_dihedral_deg == pytest.approx(45.0, abs=1e-9)
    assert box.max_dihedral_deg == pytest.approx(90.0, abs=1e-9)
    # angles do not depend on node order
    np.testing.assert_allclose(
        np.sort(tet_dihedral_angles(UNIT, [[0, 1, 2, 3]])), np.sort(tet_dihedral_angles(UNIT, [[0, 2, 1, 3]]))
    )


def test_shell_mesh_is_valid_and_face_sized():
    mesh = shell_tet_mesh()
    assert 6000 < mesh.node_count < 7000
    q = mesh.quality()
    assert q.inverted_count == 0 and q.min_dihedral_deg > 10.0


@pytest.mark.parametrize(
    "points, tets, message",
    [
        (UNIT[:3], [[0, 1, 2, 0]], "at least 4 points"),
        (np.r_[UNIT, [[np.nan, 0, 0]]], [[0, 1, 2, 3]], "point 4 is not finite"),
        (UNIT, [[0, 1, 2]], r"shape \(M, 4\)"),
        (UNIT, [[0, 1, 2, 4]], "tet 0 has node index out of range"),
        (UNIT, [[0, 1, 2, -1]], "out of range"),
        (UNIT, [[0, 1, 1, 3]], "tet 0 repeats a node"),
        (UNIT, [[0, 2, 1, 3]], "tet 0 is inverted"),
        (np.r_[UNIT[:3], [[0.5, 0.5, 0.0]]], [[0, 1, 2, 3]], "tet 0 is degenerate"),
        (np.r_[UNIT, [[2, 2, 2]]], [[0, 1, 2, 3]], "node 4 belongs to no tet"),
        (UNIT, [[0.0, 1.5, 2.0, 3.0]], "integer node indices"),
    ],
)
def test_tetmesh_rejects_bad_input(points, tets, message):
    with pytest.raises(ValueError, match=message):
        TetMesh(points, tets)


def test_repaired_flips_and_drops_orphans():
    pts = np.r_[[[5.0, 5.0, 5.0]], UNIT]
    mesh, node_map = TetMesh.repaired(pts, [[1, 3, 2, 4]])
    assert mesh.node_count == 4 and node_map[0] == -1
    assert mesh.volumes[0] == pytest.approx(1 / 6)
    with pytest.raises(ValueError, match="degenerate"):
        TetMesh.repaired(np.r_[UNIT[:3], [[0.5, 0.5, 0.0]]], [[0, 1, 2, 3]])


def test_material_validation():
    TissueMaterial(192.4e3, 0.495, 476.8, 1100.0)
    TissueMaterial(1.0, 0.0, 0.0, 1.0)
    for kwargs, message in [
        (dict(E=0.0), r"E must be in \[0.001, 1e\+12\] Pa"),
        (dict(E=1e13), "E must be in"),
        (dict(E=np.nan), "E must be"),
        (dict(nu=0.5), r"nu must be in \[0, 0.4999\]"),
        (dict(nu=-0.1), "nu must be"),
        (dict(eta=-1.0), r"eta must be in \[0, 1e\+09\] Pa s"),
        (dict(rho=0.0), "rho must be in"),
        (dict(rho=1e7), "rho must be in"),
        (dict(E=np.array([1e5, -1.0, 1e5])), "E at tet 1"),
        (dict(E=np.ones(3), nu=np.zeros(4)), "differ in length"),
        (dict(damping="rayleigh"), "damping"),
        (dict(E=np.ones((2, 2))), "1-D per-tet"),
    ]:
        args = dict(E=1e5, nu=0.3, eta=1.0, rho=1000.0) | kwargs
        with pytest.raises(ValueError, match=message):
            TissueMaterial(**args)
    with pytest.raises(TypeError, match="damping"):
        TissueMaterial(1e5, 0.3, 1.0, 1000.0, damping=1)


def test_material_per_tet_and_lame():
    mat = TissueMaterial(np.array([1e5, 2e5]), 0.25, 3.0, 1000.0)
    assert mat.tet_count == 2 and not mat.is_uniform
    f = mat.per_tet(2)
    np.testing.assert_array_equal(f["nu"], [0.25, 0.25])
    lam, mu = mat.lame(2)
    np.testing.assert_allclose(mu, [4e4, 8e4])
    np.testing.assert_allclose(lam, [4e4, 8e4])
    with pytest.raises(ValueError, match="per-tet values"):
        mat.per_tet(3)


def test_material_from_regions_kato_table():
    base = TissueMaterial(162.7e3, 0.495, 430.3, 1100.0)  # cheek everywhere
    regions = {"cphs_R": [0, 1], "cheilion": np.array([False, True, True, False])}
    mat = TissueMaterial.from_regions(
        4, base, regions, {"cphs_R": {"E": 205.6e3, "eta": 427.8}, "cheilion": {"E": 116.5e3, "eta": 362.9}}
    )
    np.testing.assert_allclose(mat.E, [205.6e3, 116.5e3, 116.5e3, 162.7e3])  # later region wins
    np.testing.assert_allclose(mat.eta, [427.8, 362.9, 362.9, 430.3])
    np.testing.assert_allclose(mat.rho, 1100.0)
    with pytest.raises(ValueError, match="not defined"):
        TissueMaterial.from_regions(4, base, regions, {"alare": {"E": 1.0}})
    with pytest.raises(ValueError, match="unknown fields"):
        TissueMaterial.from_regions(4, base, regions, {"cphs_R": {"young": 1.0}})
    with pytest.raises(ValueError, match="out of range"):
        TissueMaterial.from_regions(4, base, {"x": [4]}, {"x": {"E": 1.0}})
    with pytest.raises(ValueError, match="nu"):
        TissueMaterial.from_regions(4, base, regions, {"cphs_R": {"nu": 0.5}})
