"""Sparse LDLᵀ of an SPD matrix of 3x3 node blocks, solved in float32 and refined to float64 accuracy.

The direct solver's time step is bound by the triangular sweeps, and those by the bytes of the
factor they stream. :class:`BlockLDLT` stores ``L`` once (SuperLU's ``L`` and ``U`` both stream,
and ``U = D Lᵀ`` for an SPD matrix), as 3x3 node blocks with one column index per run of
consecutive blocks (not one per scalar), in float32. A solve is refinement: the float64 residual
``r = b − A x`` (:data:`~warpface.fem.kernels_ldlt.block_residual`), one float32 sweep pair for the
correction (:data:`~warpface.fem.kernels_ldlt.ldlt_refine`), repeated until the correction is
negligible. Each round shrinks the error by the factor's measured contraction (~1e-6), so from a
good guess — in a time step, the extrapolated displacement — one round is float64-accurate.

The node ordering is the cheaper to stream (fill, and loop set-up per run) of minimum degree
(MMD on ``A + Aᵀ``) and reverse Cuthill–McKee (an envelope whose rows are single runs: on the 2-ring
ANP shell of 6.7k nodes its fill is 9 % below MMD's; on larger or 1-ring meshes MMD wins), judged on
the node graph. SuperLU computes the numerical factor of the reordered matrix (natural order,
symmetric mode, no pivoting), from which ``L`` and ``D`` are read. Measurements:
``benchmarks/README.md``.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spla
import warp as wp
from scipy.sparse.csgraph import reverse_cuthill_mckee

from .._validate import as_count
from ..errors import UnsuitableFactor
from .kernels_ldlt import block_residual, ldlt_refine

__all__ = ["BlockLDLT", "DEFAULT_ORDERINGS", "ORDERINGS", "UnsuitableFactor", "node_ordering"]

MAX_CONTRACTION = 1.0e-2
"""A float32 factor whose measured contraction is weaker than this is not used (:class:`UnsuitableFactor`)."""

CONTRACTION_SAFETY = 10.0
"""Factor on the measured contraction when a solve estimates its remaining error."""

RUN_COST = 4
"""Blocks that one run of a factor row costs in the sweeps (loop set-up), when orderings are compared."""

_SUPERLU_SPD = dict(diag_pivot_thresh=0.0, options={"SymmetricMode": True})


ORDERINGS = ("mmd", "colamd", "rcm")
"""Node orderings :func:`node_ordering` knows."""

DEFAULT_ORDERINGS = ("mmd", "rcm")
"""The orderings :class:`BlockLDLT` compares by default. COLAMD is left out: on the benchmark's shells it is never
clearly the cheapest (6.7k-node ANP: 620k blocks, as RCM; 26k: 4.71 M against MMD's 4.13 M) and its symbolic pass
costs 1.4 s at 26k nodes."""


def node_ordering(pattern, candidates=DEFAULT_ORDERINGS) -> tuple[np.ndarray, str, int]:
    """The node order whose factor streams fastest (fewest blocks plus :data:`RUN_COST` per run) for a node graph.

    Args:
        pattern: SciPy sparse (n x n) whose non-zeros are the coupled node pairs (symmetric, diagonal included).
        candidates: Orderings to compare, a subset of :data:`ORDERINGS` (default :data:`DEFAULT_ORDERINGS`).

    Returns:
        ``(order, name, blocks)``: factor row ``k`` is node ``order[k]`` (shape (n,), int64); the ordering's
        name, ``"mmd"``, ``"colamd"`` or ``"rcm"``; the off-diagonal blocks of ``L`` it produces (for ``"rcm"``
        the envelope, an upper bound).
    """
    graph = sps.csr_matrix(pattern, dtype=np.float64, copy=True)
    n = graph.shape[0]
    graph.data[:] = -1.0
    graph.setdiag(0.0)
    graph.eliminate_zeros()
    # a graph Laplacian plus identity: SPD with the pattern's structure, so SuperLU's symbolic fill is the graph's
    laplacian = (graph + sps.diags(1.0 - np.asarray(graph.sum(axis=1)).ravel())).tocsc()
    costs = []
    for name, spec in (("mmd", "MMD_AT_PLUS_A"), ("colamd", "COLAMD")):
        if name in candidates:
            lu = spla.splu(laplacian, permc_spec=spec, **_SUPERLU_SPD)
            lower = sps.tril(lu.L, -1).tocsr()
            lower.sort_indices()
            costs.append((lower.nnz, _run_starts(lower.indptr, lower.indices).size, name, np.argsort(lu.perm_c)))
    if "rcm" in candidates:
        order = reverse_cuthill_mckee(graph.tocsr(), symmetric_mode=True).astype(np.int64)
        lower = sps.tril(laplacian.tocsr()[order][:, order]).tocsr()
        lower.sort_indices()
        span = np.arange(n) - lower.indices[lower.indptr[:-1]]  # every row holds its diagonal
        costs.append((int(span.sum()), int(np.count_nonzero(span)), "rcm", order))  # the envelope fills completely
    if not costs:
        raise ValueError(f"node_ordering: candidates must name some of {ORDERINGS}, got {candidates!r}")
    blocks, _, name, order = min(costs, key=lambda c: c[0] + RUN_COST * c[1])
    return order.astype(np.int64), name, int(blocks)


def _run_starts(row_start: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """Entries that open a run of consecutive columns in the rows of a CSR pattern with sorted columns."""
    opens_run = np.ones(columns.size, dtype=bool)
    opens_run[1:] = np.diff(columns) != 1
    opens_run[row_start[:-1][np.diff(row_start) > 0]] = True
    return np.flatnonzero(opens_run)


def _int32(values) -> wp.array:
    return wp.array(np.asarray(values, dtype=np.int32), dtype=wp.int32, device="cpu")


def _reordered_factor(blocks, order: np.ndarray):
    """SuperLU's factor of the matrix of 3x3 ``blocks`` in node ``order`` (natural order, symmetric mode, no pivoting).

    Returns:
        ``(order, factored_dofs, lu, pivots, lower)``: the node order of the factor rows (SuperLU may postorder);
        the dof order given to SuperLU; its factor; ``D``, shape (3n,); ``L`` as a BSR matrix of 3x3 blocks
        with its unit diagonal.
    """
    # every entry of every block stays structural, so SuperLU keeps a node's three dofs together
    factored_dofs = (3 * order[:, None] + np.arange(3)).ravel()
    lu = spla.splu(blocks.tocsr()[factored_dofs][:, factored_dofs].tocsc(), permc_spec="NATURAL", **_SUPERLU_SPD)
    dofs = factored_dofs[np.argsort(lu.perm_c)]  # SuperLU's elimination-tree postorder, if any
    order = dofs[0::3] // 3
    if not np.array_equal(dofs, (3 * order[:, None] + np.arange(3)).ravel()):
        raise UnsuitableFactor("BlockLDLT: SuperLU's postorder split a node's dofs")
    # U = D Lᵀ without pivoting, so U's columns (CSC) are L's rows scaled by the pivots: L by rows, no transpose
    upper = lu.U
    pivots = upper.diagonal()
    bad = np.flatnonzero(~(pivots > 0.0) | ~np.isfinite(pivots))
    if bad.size:
        raise ValueError(
            f"BlockLDLT: the matrix is not positive definite (pivot {pivots[bad[0]]:.3g} at dof {dofs[bad[0]]})"
        )
    unit = sps.csr_matrix((upper.data / pivots[upper.indices], upper.indices, upper.indptr), shape=upper.shape)
    lower = sps.bsr_matrix(unit, blocksize=(3, 3))
    lower.sort_indices()
    return order, factored_dofs, lu, pivots, lower


def _symmetric_half(blocks) -> list:
    """The arguments of :data:`~warpface.fem.kernels_ldlt.block_residual` for a symmetric BSR matrix with sorted
    indices: block-row offsets and columns of the strictly lower blocks, those blocks, the diagonal blocks."""
    n = blocks.shape[0] // 3
    rows = np.repeat(np.arange(n), np.diff(blocks.indptr))
    strictly_lower = blocks.indices < rows
    on_diagonal = blocks.indices == rows
    diagonal = np.zeros((n, 3, 3))
    diagonal[rows[on_diagonal]] = blocks.data[on_diagonal]
    return [
        _int32(np.concatenate([[0], np.cumsum(np.bincount(rows[strictly_lower], minlength=n))])),
        _int32(blocks.indices[strictly_lower]),
        wp.array(np.ascontiguousarray(blocks.data[strictly_lower]), dtype=wp.mat33d, device="cpu"),
        wp.array(diagonal, dtype=wp.mat33d, device="cpu"),
    ]


class BlockLDLT:
    """``A = P L D Lᵀ Pᵀ`` of an SPD matrix of 3x3 node blocks, solved on the CPU with a float32 factor.

    Args:
        matrix: SciPy sparse SPD matrix, shape (3n, 3n), dofs ``3 * node + axis``.
        rtol: A solve stops once its estimated error is below ``rtol`` times the larger of the
            solution's largest component and ``reference`` (see :meth:`solve`).
        max_rounds: Refinement rounds per solve at most.
        orderings: Node orderings to choose from (:func:`node_ordering`; default :data:`DEFAULT_ORDERINGS`).

    Raises:
        TypeError: ``matrix`` is not a matrix, ``rtol`` not a number or ``max_rounds`` not an integer.
        ValueError: the matrix is empty, not square with a multiple of 3 rows, has non-finite entries or is
            not positive definite; ``rtol`` or ``max_rounds`` is out of range.
        UnsuitableFactor: the float32 factor's measured contraction is weaker than
            :data:`MAX_CONTRACTION` (or SuperLU split a node's dofs): factorise in float64 instead.
    """

    device = wp.get_device("cpu")

    def __init__(self, matrix, *, rtol: float = 1.0e-10, max_rounds: int = 8, orderings=DEFAULT_ORDERINGS):
        start = time.perf_counter()
        try:
            matrix = sps.csr_matrix(matrix, dtype=np.float64)
        except (TypeError, ValueError):
            raise TypeError(f"BlockLDLT needs a sparse or dense matrix, got {type(matrix).__name__}") from None
        if matrix.shape[0] != matrix.shape[1] or matrix.shape[0] % 3 or matrix.shape[0] == 0:
            raise ValueError(f"BlockLDLT needs a square matrix of 3x3 node blocks, got shape {matrix.shape}")
        if isinstance(rtol, bool) or not isinstance(rtol, (int, float)):
            raise TypeError(f"BlockLDLT: rtol must be a number, got {type(rtol).__name__}")
        if not 0.0 < rtol < 1.0:
            raise ValueError(f"BlockLDLT: rtol must be in (0, 1), got {rtol!r}")
        max_rounds = as_count(max_rounds, "BlockLDLT: max_rounds", minimum=1)
        self.rtol = float(rtol)
        self.max_rounds = int(max_rounds)
        if not np.all(np.isfinite(matrix.data)):
            raise ValueError("BlockLDLT: the matrix has non-finite entries")
        # exactly symmetric, as the residual reads half of it
        blocks = sps.bsr_matrix(0.5 * (matrix + matrix.T), blocksize=(3, 3))
        blocks.sort_indices()
        n = blocks.shape[0] // 3
        self.node_count = n
        pattern = sps.csr_matrix((np.ones(blocks.indices.size), blocks.indices, blocks.indptr), shape=(n, n))
        order, self.ordering, _ = node_ordering(pattern + pattern.T, orderings)
        """Name of the node ordering in use: "mmd", "colamd" or "rcm"."""
        order, factored_dofs, lu, pivots, lower = _reordered_factor(blocks, order)
        rows = np.repeat(np.arange(n), np.diff(lower.indptr))
        off = lower.indices != rows
        columns = lower.indices[off].astype(np.int64)
        rows = rows[off]
        row_start = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=n))])
        run_first = _run_starts(row_start, columns)

        self.block_count = int(columns.size)
        """Off-diagonal 3x3 blocks of ``L``."""
        self.run_count = int(run_first.size)
        """Runs of consecutive blocks in the rows of ``L``."""
        self.factor_nnz = 9 * self.block_count + 6 * n
        """Stored non-zeros of the factor: ``L``'s off-diagonal blocks, the strictly lower part of its
        diagonal blocks and the pivots (``L`` once: no ``U``)."""

        cpu = self.device
        with np.errstate(over="ignore", under="ignore"):  # out of float32's range: the contraction check rejects it
            single = [
                lower.data[off].astype(np.float32),
                np.linalg.inv(lower.data[~off]).astype(np.float32),
                (1.0 / pivots).reshape(n, 3).astype(np.float32),
            ]
        self._factor_arrays = [
            _int32(order),
            _int32(np.concatenate([[0], np.cumsum(np.bincount(rows[run_first], minlength=n))])),
            _int32(columns[run_first]),
            _int32(np.append(run_first, columns.size)),
            wp.array(single[0], dtype=wp.mat33f, device=cpu),
            wp.array(single[1], dtype=wp.mat33f, device=cpu),
            wp.array(single[2], dtype=wp.vec3f, device=cpu),
        ]
        self._matrix_arrays = _symmetric_half(blocks)
        self._rhs = wp.zeros(n, dtype=wp.vec3d, device=cpu)
        self._x = wp.zeros(n, dtype=wp.vec3d, device=cpu)
        self._residual = wp.zeros(n, dtype=wp.vec3d, device=cpu)
        self._work = wp.zeros(n, dtype=wp.vec3f, device=cpu)
        self._correction = wp.zeros(1, dtype=wp.float64, device=cpu)
        self._rhs_view = self._rhs.numpy().reshape(-1)
        self._x_view = self._x.numpy().reshape(-1)
        self._correction_view = self._correction.numpy()
        self._residual_launch = wp.launch(
            block_residual,
            dim=1,
            inputs=[*self._matrix_arrays, self._rhs, self._x],
            outputs=[self._residual],
            device=cpu,
            record_cmd=True,
        )
        self._refine_launch = wp.launch(
            ldlt_refine,
            dim=1,
            inputs=[*self._factor_arrays, self._residual, self._work],
            outputs=[self._x, self._correction],
            device=cpu,
            record_cmd=True,
        )

        self.contraction = self._measure_contraction(blocks, lu, factored_dofs)
        """Measured error reduction of one refinement round (largest relative error of a float32
        solve against SuperLU's float64 one, on a random solution and a random right-hand side)."""
        if not self.contraction <= MAX_CONTRACTION:
            raise UnsuitableFactor(
                f"BlockLDLT: the float32 factor's contraction {self.contraction:.2g} is weaker than "
                f"{MAX_CONTRACTION:g} (ill-conditioned matrix)"
            )
        self.rounds = 0
        """Refinement rounds of all solves so far."""
        self.solves = 0
        """Solves so far."""
        self.factor_seconds = time.perf_counter() - start
        """Wall time of ordering, factorisation, conversion and the contraction measurement [s]."""

    def _measure_contraction(self, blocks, lu, factored_dofs) -> float:
        """One round from zero against SuperLU's float64 solve (``lu``: of ``A[factored_dofs][:, factored_dofs]``)."""
        rng = np.random.default_rng(0)
        dofs, inverse = factored_dofs, np.argsort(factored_dofs)
        worst = 0.0
        truth_random = rng.standard_normal(blocks.shape[0])
        rhs_random = rng.standard_normal(blocks.shape[0])
        for truth, rhs in ((truth_random, blocks @ truth_random), (lu.solve(rhs_random[dofs])[inverse], rhs_random)):
            self._rhs_view[:] = rhs
            self._x_view[:] = 0.0
            self._residual_launch.launch()
            self._refine_launch.launch()
            error = np.abs(self._x_view - truth).max() / max(np.abs(truth).max(), np.finfo(float).tiny)
            worst = max(worst, float(error)) if np.isfinite(error) else np.inf
        return worst

    def solve(self, rhs: np.ndarray, guess: np.ndarray | None = None, *, reference: float = 0.0) -> np.ndarray:
        """``A⁻¹ rhs`` by refinement from ``guess`` (default zero), float64.

        Args:
            rhs: Right-hand side, shape (3n,), float64.
            guess: Start, shape (3n,); the closer, the fewer rounds (one, from a time step's extrapolation).
            reference: A magnitude of the solution's units [same units] below which errors need not go,
                e.g. the largest prescribed displacement of a time step.

        Returns:
            The solution, shape (3n,): a view that the next solve overwrites.

        Rounds stop when ``CONTRACTION_SAFETY * contraction * max|correction| <= rtol * max(max|x|, reference)``
        or after ``max_rounds``.

        Raises:
            ValueError: ``rhs`` or ``guess`` has the wrong shape or a non-finite value.
        """
        for name, vector in (("rhs", rhs), ("guess", guess)):
            if vector is not None and (np.shape(vector) != self._rhs_view.shape or not np.all(np.isfinite(vector))):
                raise ValueError(f"BlockLDLT.solve: {name} must be {self._rhs_view.size} finite numbers")
        self._rhs_view[:] = rhs
        if guess is None:
            self._x_view[:] = 0.0
        else:
            self._x_view[:] = guess
        estimate_per_correction = CONTRACTION_SAFETY * self.contraction
        for rounds in range(1, self.max_rounds + 1):  # noqa: B007 (the count is read after the loop)
            self._residual_launch.launch()
            self._refine_launch.launch()
            scale = max(np.abs(self._x_view).max(), reference)
            if estimate_per_correction * self._correction_view[0] <= self.rtol * scale:
                break
        self.rounds += rounds
        self.solves += 1
        return self._x_view
