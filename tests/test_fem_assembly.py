"""Assembly of K, M, C: float64 NumPy oracles, rigid modes, mass, damping modes, patch test."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sps
import scipy.sparse.linalg as spla
import warp as wp
from fem_reference import anp_reference, assemble_reference, random_tet_mesh, rigid_modes

from warpface.fem import TetMesh, TissueMaterial, assemble, box_tet_mesh
from warpface.fem.assembly import bsr_to_scipy


def _rel(a, b):
    a, b = sps.csr_matrix(a), sps.csr_matrix(b)
    return abs(a - b).max() / abs(b).max()


@pytest.fixture(scope="module")
def irregular_mesh():
    return random_tet_mesh(np.random.default_rng(7))


def test_element_matrices_match_numpy_reference(irregular_mesh):
    rng = np.random.default_rng(3)
    m = irregular_mesh.tet_count
    E = rng.uniform(5e4, 3e5, m)
    nu = rng.uniform(0.0, 0.49, m)
    eta = rng.uniform(0.0, 800.0, m)
    rho = rng.uniform(900.0, 1200.0, m)
    for damping in ("stokes", "thesis"):
        mat = TissueMaterial(E, nu, eta, rho, damping=damping)
        K, M, C = assemble(irregular_mesh, mat, device="cpu").to_scipy()
        Kr, Mr, Cr = assemble_reference(irregular_mesh, E, nu, eta, rho, damping=damping)
        assert _rel(K, Kr) < 1e-12
        assert _rel(M, Mr) < 1e-12
        assert _rel(C, Cr) < 1e-12


def test_single_tet_against_hand_values():
    # unit right tet: V = 1/6, gradients -1-1-1, e1, e2, e3
    mesh = TetMesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float), [[0, 1, 2, 3]])
    E, nu = 6.0, 0.25  # lam = 2.4, mu = 2.4
    K, M, _ = assemble(mesh, TissueMaterial(E, nu, 0.0, 20.0), device="cpu").to_scipy()
    K = K.toarray()
    lam = mu = 2.4
    # K_11 block (node 1, gradient e1): V [lam e1e1 + mu(e1e1 + I)]
    expected = (1 / 6) * (lam * np.diag([1, 0, 0]) + mu * (np.diag([1, 0, 0]) + np.eye(3)))
    np.testing.assert_allclose(K[3:6, 3:6], expected, rtol=1e-14)
    # consistent mass: rho V / 20 * 2 on the diagonal, rho V / 20 off it
    M = M.toarray()
    assert M[0, 0] == pytest.approx(20 * (1 / 6) / 10)
    assert M[0, 3] == pytest.approx(20 * (1 / 6) / 20)
    assert M[0, 1] == 0.0


@pytest.mark.parametrize("formulation", ["linear", "anp"])
def test_stiffness_symmetric_psd_with_six_rigid_modes(irregular_mesh, formulation):
    mat = TissueMaterial(1.9e5, 0.45, 400.0, 1100.0)
    K, _, _ = assemble(irregular_mesh, mat, formulation=formulation, device="cpu").to_scipy()
    Kd = K.toarray()
    assert np.abs(Kd - Kd.T).max() <= 1e-12 * np.abs(Kd).max()
    eig = np.linalg.eigvalsh(0.5 * (Kd + Kd.T))
    scale = eig[-1]
    assert eig[0] > -1e-10 * scale
    assert np.count_nonzero(np.abs(eig) < 1e-10 * scale) == 6
    assert eig[6] > 1e-6 * scale
    # and the null space is exactly the rigid motions
    modes = rigid_modes(irregular_mesh.points)
    assert np.abs(K @ modes.T).max() < 1e-9 * scale * np.abs(modes).max()


def test_anp_matches_reference_definition(irregular_mesh):
    E, nu = 1.5e5, 0.495
    K = assemble(irregular_mesh, TissueMaterial(E, nu, 0.0, 1000.0), formulation="anp", device="cpu").to_scipy()[0]
    assert _rel(K, anp_reference(irregular_mesh, E, nu)) < 1e-11


def test_mass_sums_to_total_mass(irregular_mesh):
    rng = np.random.default_rng(5)
    rho = rng.uniform(900.0, 1300.0, irregular_mesh.tet_count)
    _, M, _ = assemble(irregular_mesh, TissueMaterial(1e5, 0.3, 1.0, rho), device="cpu").to_scipy()
    total = float(rho @ irregular_mesh.volumes)
    for axis in range(3):
        e = np.zeros((irregular_mesh.node_count, 3))
        e[:, axis] = 1.0
        assert e.ravel() @ (M @ e.ravel()) == pytest.approx(total, rel=1e-13)
    assert M.sum() == pytest.approx(3 * total, rel=1e-13)
    assert np.linalg.eigvalsh(M.toarray())[0] > 0.0


def test_stokes_damping_spares_volume_change_and_damps_shear(irregular_mesh):
    eta = 476.8
    mesh = irregular_mesh
    _, _, C = assemble(mesh, TissueMaterial(1e5, 0.3, eta, 1000.0), device="cpu").to_scipy()
    x = mesh.points - mesh.points.mean(axis=0)
    dilation = x.ravel()  # strain rate = I: purely volumetric
    shear = np.c_[x[:, 1], np.zeros(len(x)), np.zeros(len(x))].ravel()  # gamma_xy rate = 1
    V = mesh.total_volume
    assert abs(dilation @ (C @ dilation)) < 1e-12 * eta * V * 3
    # dissipation 2 eta dev(e):dev(e) V with e_xy = 1/2 -> eta * gamma^2 * V
    assert shear @ (C @ shear) == pytest.approx(eta * V, rel=1e-12)
    # rigid motions are not damped either
    assert np.abs(C @ rigid_modes(mesh.points).T).max() < 1e-10 * eta * np.abs(x).max()


def test_thesis_damping_is_not_isotropic():
    """The thesis's eta/3 matrix dissipates a rotated uniaxial strain rate differently; Stokes does not."""
    mesh = box_tet_mesh((1.0, 1.0, 1.0), (2, 2, 2))
    x = mesh.points - 0.5
    out = {}
    for damping in ("stokes", "thesis"):
        C = assemble(mesh, TissueMaterial(1e5, 0.3, 1.0, 1000.0, damping=damping), device="cpu").to_scipy()[2]
        rates = []
        for n in (np.array([1.0, 0.0, 0.0]), np.array([1.0, 1.0, 1.0]) / np.sqrt(3.0)):
            field = (x @ n)[:, None] * n[None, :]  # strain rate n n^T
            rates.append(field.ravel() @ (C @ field.ravel()))
        out[damping] = rates
    assert out["stokes"][0] == pytest.approx(out["stokes"][1], rel=1e-12)
    assert abs(out["thesis"][0] / out["thesis"][1] - 1.0) > 0.3


@pytest.mark.parametrize("formulation", ["linear", "anp"])
def test_patch_test_linear_field_reproduced_inside(formulation):
    rng = np.random.default_rng(11)
    mesh = random_tet_mesh(rng, cells=(3, 3, 3), size=(0.02, 0.02, 0.02))
    K = assemble(mesh, TissueMaterial(2e5, 0.49, 0.0, 1000.0), formulation=formulation, device="cpu").to_scipy()[0]
    G = rng.normal(size=(3, 3)) * 0.01
    exact = mesh.points @ G.T + np.array([1e-3, -2e-3, 5e-4])
    boundary = mesh.surface_nodes
    inside = mesh.interior_nodes
    assert inside.size >= 8
    b = (3 * boundary[:, None] + np.arange(3)).ravel()
    i = (3 * inside[:, None] + np.arange(3)).ravel()
    K = K.tocsr()
    u_i = spla.spsolve(K[i][:, i].tocsc(), -K[i][:, b] @ exact.ravel()[b])
    np.testing.assert_allclose(u_i.reshape(-1, 3), exact[inside], rtol=0, atol=1e-12 * np.abs(exact).max() * 1e3)


def test_bsr_to_scipy_roundtrip_and_device_arrays(irregular_mesh):
    S = assemble(irregular_mesh, TissueMaterial(1e5, 0.3, 2.0, 1000.0), device="cpu")
    assert S.K.block_shape == (3, 3) and S.K.scalar_type == wp.float64
    assert S.node_count == irregular_mesh.node_count
    K = bsr_to_scipy(S.K)
    x = np.random.default_rng(0).normal(size=K.shape[0])
    y = wp.zeros(K.shape[0] // 3, dtype=wp.vec3d, device="cpu")
    wp.sparse.bsr_mv(S.K, wp.array(x.reshape(-1, 3), dtype=wp.vec3d, device="cpu"), y)
    np.testing.assert_allclose(y.numpy().ravel(), K @ x, rtol=1e-12, atol=1e-12 * np.abs(K @ x).max())


def test_assemble_rejects_bad_arguments(irregular_mesh):
    mat = TissueMaterial(1e5, 0.3, 1.0, 1000.0)
    with pytest.raises(ValueError, match="formulation"):
        assemble(irregular_mesh, mat, formulation="quadratic", device="cpu")
    with pytest.raises(ValueError, match="per-tet values"):
        assemble(irregular_mesh, TissueMaterial(np.ones(3) * 1e5, 0.3, 1.0, 1000.0), device="cpu")
    with pytest.raises(TypeError, match="TetMesh"):
        assemble("mesh", mat, device="cpu")
