"""Assembly of stiffness K, consistent mass M and Stokes damping C as Warp BSR matrices.

Degrees of freedom are node-major, ``3 * node + axis``; every matrix is a
``warp.sparse.BsrMatrix`` of 3x3 float64 blocks (``N x N`` blocks for ``N`` nodes).

Formulations (``formulation=``):

* ``"linear"``: standard constant-strain tets, ``K_e = V B^T D B``. Locks volumetrically
  as ``nu -> 0.5`` (SPEC §2.1: a cantilever reaches 6–32 % of the Euler–Bernoulli deflection
  at ``nu = 0.495``).
* ``"anp"``: average nodal pressure tets (J. Bonet and A. J. Burton, "A simple average
  nodal pressure tetrahedral element for incompressible and nearly incompressible dynamic
  explicit applications", Commun. Numer. Meth. Engng 14 (1998) 437–449), linearised. The
  deviatoric part stays element-wise; the volumetric strain is averaged over the tets around
  each node (volume-weighted), ``theta_a = (1/V_a) sum_e (V_e/4) div_e(d)``, and the
  volumetric energy is ``1/2 sum_a kappa_a V_a theta_a^2``. So ``K = K_dev + W^T diag(kappa V) W``:
  symmetric, positive semidefinite with the six rigid modes as its null space, exact for
  linear fields (it passes the patch test), and free of volumetric locking because the
  incompressibility constraint is imposed once per node instead of once per tet.
  ``kappa_a`` is the volume-weighted mean of ``lambda + 2 mu / 3`` over the tets around ``a``.

M and C do not depend on the formulation. C follows ``material.damping`` (see
:mod:`warpface.fem.material`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp
import warp.sparse as wps

from .._validate import as_device, expect_instance
from .kernels_assembly import (
    element_triplets,
    mat13d,
    nodal_volumetric_stiffness_triplets,
    remap_bsr_triplets,
    volumetric_operator_triplets,
)
from .material import TissueMaterial
from .tetmesh import TetMesh

__all__ = ["FORMULATIONS", "SystemMatrices", "assemble", "bsr_to_scipy", "partition_bsr"]

FORMULATIONS = ("linear", "anp")


@dataclass(frozen=True)
class SystemMatrices:
    """Global FEM matrices of a tet mesh, dofs ``3 * node + axis``."""

    K: wps.BsrMatrix
    """Stiffness [N/m], (N x N) blocks of 3x3 float64."""
    M: wps.BsrMatrix
    """Consistent mass [kg], (N x N) blocks of 3x3 float64."""
    C: wps.BsrMatrix
    """Viscous damping [N s/m], (N x N) blocks of 3x3 float64."""
    formulation: str
    """Formulation of K: "linear" or "anp"."""

    @property
    def node_count(self) -> int:
        """Number of nodes N."""
        return self.K.nrow

    @property
    def device(self):
        """Warp device holding the matrices."""
        return self.K.device

    def to_scipy(self):
        """``(K, M, C)`` as SciPy CSR float64 matrices of shape (3N, 3N)."""
        return bsr_to_scipy(self.K), bsr_to_scipy(self.M), bsr_to_scipy(self.C)


def bsr_to_scipy(matrix: wps.BsrMatrix):
    """A compact Warp BSR matrix as a SciPy CSR matrix (float64, scalar shape)."""
    import scipy.sparse as sps

    nnz = matrix.nnz_sync()
    br, bc = matrix.block_shape
    values = matrix.values.numpy()[:nnz].reshape(nnz, br, bc).astype(np.float64)
    columns = matrix.columns.numpy()[:nnz]
    offsets = matrix.offsets.numpy()[: matrix.nrow + 1]
    bsr = sps.bsr_matrix((values, columns, offsets), shape=(matrix.nrow * br, matrix.ncol * bc))
    csr = bsr.tocsr()
    csr.sort_indices()
    return csr


def _empty_triplets(count: int, value_type, device, value_arrays: int = 1) -> list:
    """``[rows, cols, values, ...]``: uninitialised COO arrays of ``count`` blocks for a triplet kernel to fill, the
    block rows and columns int32 and ``value_arrays`` arrays of ``value_type`` blocks."""
    indices = [wp.empty(count, dtype=wp.int32, device=device) for _ in range(2)]
    return indices + [wp.empty(count, dtype=value_type, device=device) for _ in range(value_arrays)]


def _from_triplets(row_count: int, col_count: int, rows, cols, values) -> wps.BsrMatrix:
    """The BSR matrix of the triplets (duplicates summed, explicit zeros kept: the sparsity pattern depends only on
    the mesh)."""
    return wps.bsr_from_triplets(row_count, col_count, rows, cols, values, prune_numerical_zeros=False)


def _stiffness_coeffs(lam: np.ndarray, mu: np.ndarray, formulation: str) -> np.ndarray:
    if formulation == "linear":
        return np.stack([lam, mu, mu], axis=1)
    # deviatoric part only; the volumetric part is nodal (see module docstring)
    return np.stack([-2.0 * mu / 3.0, mu, mu], axis=1)


def _damping_coeffs(eta: np.ndarray, damping: str) -> np.ndarray:
    if damping == "stokes":
        return np.stack([-2.0 * eta / 3.0, eta, eta], axis=1)
    # thesis eq. 4.26: normal block eta/3 [[2,-1,-1],...] = (-eta/3) 11^T + 2 (eta/2) I; shear eta
    return np.stack([-eta / 3.0, eta / 2.0, eta], axis=1)


def assemble(
    tetmesh: TetMesh,
    material: TissueMaterial,
    *,
    formulation: str = "linear",
    device=None,
) -> SystemMatrices:
    """Assemble K, M and C of a tet mesh on a Warp device.

    Args:
        tetmesh: The mesh.
        material: Uniform or per-tet material (``material.tet_count`` must match the mesh).
        formulation: ``"linear"`` (constant-strain tets) or ``"anp"`` (average nodal pressure,
            locking-free; see module docstring).
        device: Warp device; ``None`` uses Warp's preferred device.

    Returns:
        :class:`SystemMatrices` with float64 3x3-block BSR matrices on ``device``.

    Raises:
        TypeError: ``tetmesh``, ``material`` or ``formulation`` of the wrong type (also a ValueError).
        ValueError: unknown formulation, or material/mesh size mismatch.
    """
    expect_instance(tetmesh, TetMesh, "tetmesh")
    expect_instance(material, TissueMaterial, "material")
    expect_instance(formulation, str, "formulation")
    if formulation not in FORMULATIONS:
        raise ValueError(f"assemble: formulation must be one of {FORMULATIONS}, got {formulation!r}")
    device = as_device(device)
    n, m = tetmesh.node_count, tetmesh.tet_count
    fields = material.per_tet(m)
    lam, mu = material.lame(m)

    points = wp.array(tetmesh.points, dtype=wp.vec3d, device=device)
    tets = wp.array(tetmesh.tets, dtype=wp.int32, device=device)
    kc = wp.array(_stiffness_coeffs(lam, mu, formulation), dtype=wp.vec3d, device=device)
    cc = wp.array(_damping_coeffs(fields["eta"], material.damping), dtype=wp.vec3d, device=device)
    rho = wp.array(fields["rho"], dtype=wp.float64, device=device)

    triplets = _empty_triplets(16 * m, wp.mat33d, device, value_arrays=3)
    wp.launch(element_triplets, dim=(m, 4, 4), inputs=[points, tets, kc, cc, rho], outputs=triplets, device=device)
    rows, cols, *values = triplets
    K, M, C = (_from_triplets(n, n, rows, cols, blocks) for blocks in values)

    if formulation == "anp":
        K = wps.bsr_axpy(_nodal_volumetric_stiffness(tetmesh, lam + 2.0 * mu / 3.0, points, tets, device), K)
    for matrix in (K, M, C):
        matrix.nnz_sync()
    return SystemMatrices(K=K, M=M, C=C, formulation=formulation)


def _nodal_volumetric_stiffness(tetmesh: TetMesh, kappa: np.ndarray, points, tets, device) -> wps.BsrMatrix:
    """``W^T diag(kappa_a V_a) W`` of the average-nodal-pressure formulation, (N x N) 3x3 blocks."""
    n, m = tetmesh.node_count, tetmesh.tet_count
    nodal_volumes = wp.array(tetmesh.nodal_volumes, dtype=wp.float64, device=device)
    # kappa_a V_a = sum over incident tets of kappa_e V_e / 4
    weight = np.bincount(tetmesh.tets.ravel(), weights=np.repeat(kappa * tetmesh.volumes / 4.0, 4), minlength=n)

    triplets = _empty_triplets(16 * m, mat13d, device)
    wp.launch(
        volumetric_operator_triplets,
        dim=(m, 4, 4),
        inputs=[points, tets, nodal_volumes],
        outputs=triplets,
        device=device,
    )
    W = _from_triplets(n, n, *triplets)
    w_offsets = W.offsets.numpy()[: n + 1]
    lengths = np.diff(w_offsets)
    triplet_offsets = np.concatenate([[0], np.cumsum(lengths.astype(np.int64) ** 2)])
    total = int(triplet_offsets[-1])
    if total >= 2**31:
        raise ValueError("assemble: mesh too large for the average-nodal-pressure operator (int32 indices)")
    triplets = _empty_triplets(total, wp.mat33d, device)
    wp.launch(
        nodal_volumetric_stiffness_triplets,
        dim=n,
        inputs=[
            W.offsets,
            W.columns,
            W.values,
            wp.array(weight, dtype=wp.float64, device=device),
            wp.array(triplet_offsets[:-1].astype(np.int32), dtype=wp.int32, device=device),
        ],
        outputs=triplets,
        device=device,
    )
    return _from_triplets(n, n, *triplets)


def partition_bsr(
    parts,
    row_map: np.ndarray,
    row_count: int,
    col_count: int,
    *,
    device=None,
) -> wps.BsrMatrix:
    """Sum of renumbered blocks of several compact BSR matrices, as one BSR matrix.

    Used to extract ``A_oo`` / ``A_oc`` and to stack ``[M_o*, C_o*, -A_oc]`` for the
    right-hand side of the Newmark step without leaving the device.

    Args:
        parts: Sequence of ``(matrix, col_map, col_shift, scale)``: every block (r, c) of
            ``matrix`` goes to ``(row_map[r], col_map[c] + col_shift)`` times ``scale``; a -1
            in a map drops the block.
        row_map: New row per source block row, shape (N,), int, -1 to drop.
        row_count: Block rows of the result.
        col_count: Block columns of the result.
        device: Warp device of the matrices.

    Returns:
        A (row_count x col_count)-block BSR matrix of 3x3 float64 blocks.
    """
    device = as_device(device)
    total = sum(int(matrix.nnz_sync()) for matrix, *_ in parts)
    triplets = _empty_triplets(total, wp.mat33d, device)
    row_map_wp = wp.array(np.asarray(row_map, dtype=np.int32), dtype=wp.int32, device=device)
    offset = 0
    for matrix, col_map, col_shift, scale in parts:
        wp.launch(
            remap_bsr_triplets,
            dim=matrix.nrow,
            inputs=[
                matrix.offsets,
                matrix.columns,
                matrix.values,
                row_map_wp,
                wp.array(np.asarray(col_map, dtype=np.int32), dtype=wp.int32, device=device),
                int(col_shift),
                float(scale),
                offset,
            ],
            outputs=triplets,
            device=device,
        )
        offset += int(matrix.nnz_sync())
    return _from_triplets(row_count, col_count, *triplets)
