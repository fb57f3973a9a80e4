"""Independent float64 NumPy oracles for the FEM tests: explicit B (6x12) and D (6x6) matrices.

Written from the textbook definitions (engineering shear strains, Voigt order xx, yy, zz, yz,
xz, xy), without the block identities used by the Warp kernels.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sps

from warpface.fem import TetMesh


def shape_gradients(p: np.ndarray) -> tuple[np.ndarray, float]:
    """Gradients of the four linear shape functions (4, 3) and the signed volume of tet ``p`` (4, 3).

    Solves ``[1 x y z] c = e_i`` for each node: the coefficient rows are the gradients.
    """
    P = np.hstack([np.ones((4, 1)), p])
    coeff = np.linalg.inv(P)  # column i holds the coefficients of N_i
    volume = np.linalg.det(P) / 6.0
    return coeff[1:, :].T, volume


def strain_matrix(grads: np.ndarray) -> np.ndarray:
    """B (6, 12): engineering strain of the tet from nodal displacements (node-major)."""
    B = np.zeros((6, 12))
    for i, (gx, gy, gz) in enumerate(grads):
        c = 3 * i
        B[0, c] = gx
        B[1, c + 1] = gy
        B[2, c + 2] = gz
        B[3, c + 1], B[3, c + 2] = gz, gy
        B[4, c], B[4, c + 2] = gz, gx
        B[5, c], B[5, c + 1] = gy, gx
    return B


def elastic_D(E: float, nu: float) -> np.ndarray:
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    D = np.zeros((6, 6))
    D[:3, :3] = lam
    D[:3, :3] += 2 * mu * np.eye(3)
    D[3:, 3:] = mu * np.eye(3)
    return D


def stokes_D(eta: float) -> np.ndarray:
    D = np.zeros((6, 6))
    D[:3, :3] = (2 * eta / 3) * np.array([[2, -1, -1], [-1, 2, -1], [-1, -1, 2]])
    D[3:, 3:] = eta * np.eye(3)
    return D


def thesis_D(eta: float) -> np.ndarray:
    D = stokes_D(eta)
    D[:3, :3] /= 2.0
    return D


def element_matrices(p, E, nu, eta, rho, damping="stokes"):
    """(K, M, C) of one tet, each (12, 12)."""
    g, V = shape_gradients(p)
    B = strain_matrix(g)
    K = V * B.T @ elastic_D(E, nu) @ B
    C = V * B.T @ (stokes_D(eta) if damping == "stokes" else thesis_D(eta)) @ B
    # consistent mass: integral of N_i N_j over a tet = V (1 + delta_ij) / 20
    m = rho * V / 20.0 * (np.ones((4, 4)) + np.eye(4))
    M = np.kron(m, np.eye(3))
    return K, M, C


def assemble_reference(mesh: TetMesh, E, nu, eta, rho, damping="stokes"):
    """Global (K, M, C) as SciPy CSR by summing :func:`element_matrices` (per-tet or scalar params)."""
    m = mesh.tet_count
    params = [np.broadcast_to(np.asarray(x, dtype=float), (m,)) for x in (E, nu, eta, rho)]
    rows, cols, kv, mv, cv = [], [], [], [], []
    for e, tet in enumerate(mesh.tets):
        K, M, C = element_matrices(mesh.points[tet], *(x[e] for x in params), damping=damping)
        dofs = (3 * tet[:, None] + np.arange(3)).ravel()
        r, c = np.meshgrid(dofs, dofs, indexing="ij")
        rows.append(r.ravel())
        cols.append(c.ravel())
        kv.append(K.ravel())
        mv.append(M.ravel())
        cv.append(C.ravel())
    n = 3 * mesh.node_count
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    return tuple(sps.csr_matrix((np.concatenate(v), (rows, cols)), shape=(n, n)) for v in (kv, mv, cv))


def anp_reference(mesh: TetMesh, E, nu) -> sps.csr_matrix:
    """Average-nodal-pressure stiffness from its definition, dense loops (small meshes only).

    K = sum_e V_e B^T D_dev B  +  sum_a kappa_a V_a w_a w_a^T, with
    w_a = (1/V_a) sum_{e ni a} (V_e/4) b_e (b_e: divergence row of tet e) and
    kappa_a V_a = sum_{e ni a} kappa_e V_e / 4.
    """
    n = mesh.node_count
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    kappa = lam + 2 * mu / 3
    D_dev = np.zeros((6, 6))
    D_dev[:3, :3] = mu * (2 * np.eye(3) - 2.0 / 3.0)
    D_dev[3:, 3:] = mu * np.eye(3)
    K = np.zeros((3 * n, 3 * n))
    W = np.zeros((n, 3 * n))
    Va = np.zeros(n)
    for tet in mesh.tets:
        g, V = shape_gradients(mesh.points[tet])
        B = strain_matrix(g)
        dofs = (3 * tet[:, None] + np.arange(3)).ravel()
        K[np.ix_(dofs, dofs)] += V * B.T @ D_dev @ B
        div = B[:3].sum(axis=0)
        for a in tet:
            W[a, dofs] += V / 4 * div
            Va[a] += V / 4
    W /= Va[:, None]
    K += W.T @ np.diag(kappa * Va) @ W
    return sps.csr_matrix(K)


def rigid_modes(points: np.ndarray) -> np.ndarray:
    """The six rigid-body displacement fields, shape (6, 3N)."""
    n = len(points)
    modes = []
    for axis in range(3):
        t = np.zeros((n, 3))
        t[:, axis] = 1.0
        modes.append(t.ravel())
    c = points - points.mean(axis=0)
    for axis in range(3):
        w = np.zeros(3)
        w[axis] = 1.0
        modes.append(np.cross(w, c).ravel())
    return np.array(modes)


def random_tet_mesh(rng, cells=(3, 2, 2), jitter=0.15, size=(0.03, 0.02, 0.02)) -> TetMesh:
    """A box mesh with interior and boundary nodes jittered within their cells (irregular tets)."""
    from warpface.fem import box_tet_mesh

    base = box_tet_mesh(size, cells)
    h = np.asarray(size) / np.asarray(cells)
    pts = base.points + rng.uniform(-jitter, jitter, base.points.shape) * h
    return TetMesh(pts, base.tets)
