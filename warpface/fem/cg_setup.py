"""What the device CG solvers build once: the Newmark operators and the preconditioner factors.

:func:`newmark_operators` gives the free-free system ``A_oo`` and the predictor-residual operator ``P`` of
:mod:`warpface.fem.solver_cg`'s step; :func:`preconditioner_factor` and :func:`per_model_fsai` a lower-triangular
``G`` with ``Gᵀ G ≈ A_oo⁻¹``; :func:`grouped_factor_rows` lays such factors out for the kernels (by 3-row
blocks), :func:`stack_values` the matrices of a batch (one pattern, values per model).
"""

from __future__ import annotations

import numpy as np
import warp as wp
import warp.sparse as wps
from warp.optim.linear import FSAI

from .assembly import SystemMatrices, bsr_to_scipy, partition_bsr
from .newmark import NewmarkCoefficients

__all__ = [
    "FSAI_ROW_SIZE",
    "grouped_factor_rows",
    "newmark_operators",
    "per_model_fsai",
    "preconditioner_factor",
    "stack_values",
]

FSAI_ROW_SIZE = 32
"""Entries per row of the FSAI factor: on a GPU a step is bound by latency rather than by the arithmetic of a
longer row, so the fewer iterations of a denser factor win (measurements: ``benchmarks/README.md``)."""


def preconditioner_factor(A_oo: wps.BsrMatrix, kind: str):
    """Lower-triangular ``G`` with ``Gᵀ G ≈ A_oo⁻¹``, as a SciPy CSR matrix (3F x 3F, float64).

    Args:
        A_oo: The SPD system matrix, 3x3 float64 blocks.
        kind: One of :data:`PRECONDITIONERS`.

    Raises:
        ValueError: ``A_oo`` has a diagonal block that is not positive definite.
    """
    import scipy.sparse as sps

    if kind == "fsai":
        return bsr_to_scipy(FSAI(A_oo, max_row_size=FSAI_ROW_SIZE).G)
    A = bsr_to_scipy(A_oo)
    n = A.shape[0] // 3
    if kind == "diag":
        diagonal = A.diagonal()
        if not np.all(diagonal > 0.0):
            raise ValueError(f"the system matrix has a non-positive diagonal entry at dof {np.argmin(diagonal)}")
        return sps.diags(1.0 / np.sqrt(diagonal), format="csr")
    dofs = np.arange(3 * n).reshape(n, 3)
    blocks = np.empty((n, 3, 3))  # the diagonal blocks
    for i in range(3):
        for j in range(3):
            blocks[:, i, j] = np.asarray(A[dofs[:, i], dofs[:, j]]).ravel()
    try:
        factors = np.linalg.inv(np.linalg.cholesky(blocks))
    except np.linalg.LinAlgError:
        raise ValueError("a 3x3 diagonal block of the system matrix is not positive definite") from None
    rows = np.broadcast_to(dofs[:, :, None], (n, 3, 3))
    cols = np.broadcast_to(dofs[:, None, :], (n, 3, 3))
    lower = np.tril(np.ones((3, 3), dtype=bool))
    return sps.csr_matrix((factors[:, lower].ravel(), (rows[:, lower].ravel(), cols[:, lower].ravel())), shape=A.shape)


def newmark_operators(
    matrices: SystemMatrices, coefficients: NewmarkCoefficients, free_index: np.ndarray, driven_slot: np.ndarray
) -> tuple[wps.BsrMatrix, wps.BsrMatrix]:
    """``(A_oo, P)`` of the device Newmark step (module docstring), float64 BSR on the matrices' device.

    Args:
        matrices: K, M, C.
        coefficients: The Newmark constants.
        free_index: Row of each node in ``A_oo`` (-1: constrained), shape (N,), int32.
        driven_slot: Column of each node in the driven block of ``P`` (-1: not driven), shape (N,), int32.

    ``A_oo`` is F x F blocks; ``P`` is F x (3N + D) blocks, its columns multiplying ``[d; v; a; d_driven]``.
    For one mesh and node split the sparsity of both depends only on the mesh, not on the material
    (the batched solver relies on that).
    """
    c = coefficients
    dev = matrices.device
    n = matrices.node_count
    n_free = int(np.count_nonzero(free_index >= 0))
    n_driven = int(np.count_nonzero(driven_slot >= 0))
    free_column = np.where(free_index >= 0, np.arange(n, dtype=np.int32), -1)
    A = wps.bsr_copy(matrices.K)
    wps.bsr_axpy(matrices.M, A, alpha=c.mass_displacement)
    wps.bsr_axpy(matrices.C, A, alpha=c.damping_displacement)
    identity = np.arange(n, dtype=np.int32)
    A_oo = partition_bsr([(A, free_index, 0, 1.0)], free_index, n_free, n_free, device=dev)
    parts = []
    predictor = (
        (c.mass_displacement, c.damping_displacement, 1.0),
        (c.mass_velocity, c.damping_velocity, c.dt),
        (c.mass_acceleration, c.damping_acceleration, c.half_dt_squared),
    )
    for block, (cm, cc, ca) in enumerate(predictor):
        shift = block * n
        parts += [(matrices.M, identity, shift, cm), (matrices.C, identity, shift, cc), (A, free_column, shift, -ca)]
    parts.append((A, driven_slot, 3 * n, -1.0))
    P = partition_bsr(parts, free_index, n_free, 3 * n + n_driven, device=dev)
    return A_oo, P


def grouped_factor_rows(factors, dtype, *, device) -> tuple[wp.array, wp.array, wp.array]:
    """``(offsets, keys, values)`` of scalar CSR matrices (SciPy) of one sparsity pattern grouped by 3-row blocks
    (see :mod:`~warpface.fem.kernels_cg`): shared ``offsets`` (rows / 3 + 1,) and ``keys`` (nnz,), ``values`` of shape
    (len(factors), nnz) in ``dtype`` — one factor per model of a batch, or one shared by all.

    Raises:
        ValueError: a key does not fit in 32 bits.
    """
    grouped = []
    for G in factors:
        G = G.tocsr()
        G.sort_indices()
        grouped.append(G)
    first = grouped[0]
    rows = np.repeat(np.arange(first.shape[0]), np.diff(first.indptr))
    keys = 3 * first.indices.astype(np.int64) + rows % 3
    if keys.size and keys.max() >= 2**31:
        raise ValueError("the preconditioner is too large for 32-bit indices")
    return (
        wp.array(first.indptr[0::3].astype(np.int32), dtype=wp.int32, device=device),
        wp.array(keys.astype(np.int32), dtype=wp.int32, device=device),
        wp.array(np.stack([G.data for G in grouped]), dtype=dtype, device=device),
    )


def per_model_fsai(systems: list, reference: int) -> list:
    """One FSAI factor per model on the support chosen for model ``reference`` (SciPy CSR, float64).

    The support is selected once (``warp.optim.linear.FSAI`` with ``reuse_pattern``) and refitted to
    each model's values, so all factors share one pattern and the batch kernels share its indices. A
    model whose refit fails (or whose factor comes back with another pattern) keeps the reference
    model's factor: any SPD preconditioner keeps CG exact.
    """
    fsai = FSAI(systems[reference], max_row_size=FSAI_ROW_SIZE, reuse_pattern=True)
    shared = bsr_to_scipy(fsai.G)
    factors = []
    for index, system in enumerate(systems):
        if index == reference:
            factors.append(shared)
            continue
        try:
            G = bsr_to_scipy(fsai.update(system).G)
        except ValueError:
            G = None
        same = (
            G is not None
            and np.array_equal(G.indptr, shared.indptr)
            and np.array_equal(G.indices, shared.indices)
            and np.all(np.isfinite(G.data))
        )
        factors.append(G if same else shared)
    return factors


def stack_values(matrices, label: str):
    """Shared ``(offsets, columns)`` and per-model values (B, nnz) of BSR matrices with one pattern."""
    first = matrices[0]
    nnz = first.nnz_sync()
    offsets, columns = first.offsets.numpy()[: first.nrow + 1], first.columns.numpy()[:nnz]
    values = wp.empty((len(matrices), nnz), dtype=wp.mat33d, device=first.device)
    for b, matrix in enumerate(matrices):
        if (
            matrix.nnz_sync() != nnz
            or not np.array_equal(matrix.offsets.numpy()[: matrix.nrow + 1], offsets)
            or not np.array_equal(matrix.columns.numpy()[:nnz], columns)
        ):
            raise ValueError(f"model {b}: its {label} matrix does not share model 0's sparsity pattern")
        wp.copy(values, matrix.values, dest_offset=b * nnz, count=nnz)
    return first.offsets, first.columns, values
