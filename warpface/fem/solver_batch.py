"""Batched device Newmark solver: B material models on one mesh stepped together by block-Jacobi CG.

All B models share the mesh, the node split, ``dt`` and the Newmark parameters; each has its own
matrices (values per model, one sparsity pattern), state, driven trajectory and CG convergence.
One time step for all B models is one sequence of launches over ``(B, nodes)``
(:mod:`warpface.fem.kernels_batch`), captured once as a graph on CUDA: the CG loop is a
``wp.capture_while`` that runs while any model has not converged, and converged models skip their
work. Launch latency, which bounds a single small model on a GPU, is thus shared by the batch.

The state lives in arrays of shape (B, N) of ``vec3d`` (model-major, coalesced per model). Driven
displacements come through a ring of ``chunk`` slots ``(chunk, B, D)``, and every step's
displacements are recorded into a ring ``(chunk, B, N)``, as in the single-model CG solver.
"""

from __future__ import annotations

import numpy as np
import warp as wp
from warp.optim.linear import FSAI

from . import kernels_batch
from .assembly import SystemMatrices
from .kernels_batch import (
    S_RZ,
    S_RZ_NEW,
    SCALARS,
    batch_begin,
    batch_block_jacobi,
    batch_check,
    batch_direction,
    batch_factor_finish,
    batch_factor_product,
    batch_newmark_update,
    batch_product,
    batch_residual,
    batch_start,
    batch_update,
)
from .newmark import NewmarkCoefficients
from .assembly import bsr_to_scipy
from .solver_cg import FSAI_ROW_SIZE, ConvergenceError, newmark_operators, preconditioner_factor

__all__ = ["BATCH_PRECONDITIONERS", "BatchedCGSolver", "per_model_fsai"]

BATCH_PRECONDITIONERS = ("fsai", "fsai_each", "block_jacobi")


def _grouped_rows(factors, device):
    """``(offsets, keys, values)`` of scalar CSR matrices of one pattern grouped by 3-row blocks (see
    kernels_batch): shared ``offsets`` and ``keys``, ``values`` of shape (len(factors), nnz)."""
    grouped = []
    for G in factors:
        G = G.tocsr()
        G.sort_indices()
        grouped.append(G)
    first = grouped[0]
    rows = np.repeat(np.arange(first.shape[0]), np.diff(first.indptr))
    keys = 3 * first.indices.astype(np.int64) + rows % 3
    return (wp.array(first.indptr[0::3].astype(np.int32), dtype=wp.int32, device=device),
            wp.array(keys.astype(np.int32), dtype=wp.int32, device=device),
            wp.array(np.stack([G.data for G in grouped]), dtype=wp.float64, device=device))


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
        same = (G is not None and np.array_equal(G.indptr, shared.indptr) and np.array_equal(G.indices, shared.indices)
                and np.all(np.isfinite(G.data)))
        factors.append(G if same else shared)
    return factors


def _stack_values(matrices, label: str):
    """Shared ``(offsets, columns)`` and per-model values (B, nnz) of BSR matrices with one pattern."""
    first = matrices[0]
    nnz = first.nnz_sync()
    offsets, columns = first.offsets.numpy()[: first.nrow + 1], first.columns.numpy()[:nnz]
    values = wp.empty((len(matrices), nnz), dtype=wp.mat33d, device=first.device)
    for b, matrix in enumerate(matrices):
        if (matrix.nnz_sync() != nnz or not np.array_equal(matrix.offsets.numpy()[: matrix.nrow + 1], offsets)
                or not np.array_equal(matrix.columns.numpy()[:nnz], columns)):
            raise ValueError(f"model {b}: its {label} matrix does not share model 0's sparsity pattern")
        wp.copy(values, matrix.values, dest_offset=b * nnz, count=nnz)
    return first.offsets, first.columns, values


class BatchedCGSolver:
    """Newmark steps of B models on a Warp device (module docstring).

    Args:
        matrices: One :class:`~warpface.fem.assembly.SystemMatrices` per model, same mesh and device.
        coefficients: The Newmark constants (shared).
        free_nodes: Nodes solved for, shape (F,), int.
        driven_nodes: Nodes with prescribed displacement, shape (D,), int.
        tol: CG tolerance relative to each model's predictor residual norm.
        preconditioner: ``"fsai"`` (one FSAI factor, of the model of median mean system diagonal, shared
            by all models: far fewer iterations than block Jacobi on tissue), ``"fsai_each"`` (that
            factor's support refitted to every model: each model converges as fast as alone, at the
            cost of a factor's values per model) or ``"block_jacobi"`` (per model).
        maxiter: CG iteration limit per step.
        chunk: Ring slots of driven input and recorded displacement.
        use_graph: Capture the step as a graph (CUDA).

    Raises:
        ValueError: no model, or models whose matrices differ in sparsity (different meshes).
    """

    def __init__(self, matrices: list[SystemMatrices], coefficients: NewmarkCoefficients, free_nodes, driven_nodes, *,
                 tol: float = 1.0e-5, maxiter: int = 500, chunk: int = 64, use_graph: bool = True,
                 preconditioner: str = "fsai"):
        if preconditioner not in BATCH_PRECONDITIONERS:
            raise ValueError(f"batched preconditioner must be one of {BATCH_PRECONDITIONERS}, got {preconditioner!r}")
        if not matrices:
            raise ValueError("a batch needs at least one model")
        dev = matrices[0].device
        self.device = dev
        self.model_count = batch = len(matrices)
        self.coefficients = coefficients
        self.tol, self.maxiter, self.chunk = float(tol), int(maxiter), int(chunk)
        n = matrices[0].node_count
        self.node_count = n
        self.free_nodes = np.asarray(free_nodes, dtype=np.int64)
        self.driven_nodes = np.asarray(driven_nodes, dtype=np.int64)
        n_free, n_driven = self.free_nodes.size, self.driven_nodes.size
        free_index = np.full(n, -1, dtype=np.int32)
        free_index[self.free_nodes] = np.arange(n_free, dtype=np.int32)
        driven_slot = np.full(n, -1, dtype=np.int32)
        driven_slot[self.driven_nodes] = np.arange(n_driven, dtype=np.int32)
        operators = [newmark_operators(m, coefficients, free_index, driven_slot) for m in matrices]
        self._A = _stack_values([A for A, _ in operators], "system")
        self._factor = None
        self.reference_model = None
        if preconditioner in ("fsai", "fsai_each"):
            # the model of median system diagonal (K, M and C with the Newmark constants). Every 3x3 block's
            # diagonal of K (as before) sums to about zero per row, which picked an arbitrary model: on the
            # 10-model sweep of benchmarks/fem.py the softest one, whose sparser FSAI support cost the stiffest
            # model 19 instead of 13 iterations (refitted) or 24 (shared) on a 1.2k-node shell.
            stiffness = [float(bsr_to_scipy(A).diagonal().mean()) for A, _ in operators]
            median = int(np.argsort(stiffness, kind="stable")[len(stiffness) // 2])
            self.reference_model = median
            """Model whose FSAI factor (``"fsai"``) or support (``"fsai_each"``) preconditions every model."""
            if preconditioner == "fsai":
                factors = [preconditioner_factor(operators[median][0], "fsai")]
            else:
                factors = per_model_fsai([A for A, _ in operators], median)
            self._factor = (_grouped_rows(factors, dev), _grouped_rows([G.T for G in factors], dev))
        self._P = _stack_values([P for _, P in operators], "right-hand-side")
        del operators
        self._inverse = wp.empty((batch, n_free), dtype=wp.mat33d, device=dev)
        wp.launch(batch_block_jacobi, dim=(batch, n_free), inputs=[*self._A], outputs=[self._inverse], device=dev)
        if not np.all(np.isfinite(self._inverse.numpy())):
            bad = int(np.flatnonzero(~np.isfinite(self._inverse.numpy()).reshape(batch, -1).all(axis=1))[0])
            raise ValueError(f"model {bad}: a 3x3 diagonal block of its system matrix is not positive definite")

        def vectors(rows):
            return wp.zeros((batch, rows), dtype=wp.vec3d, device=dev)

        self.d, self.v, self.a = vectors(n), vectors(n), vectors(n)
        """State of every model [m, m/s, m/s²], shape (B, N) of vec3d (updated in place)."""
        self._x, self._r, self._z, self._p, self._q, self._y = (vectors(n_free) for _ in range(6))
        self._r_flat = self._r.view(wp.float64).reshape((batch, 3 * n_free))
        self._y_flat = self._y.view(wp.float64).reshape((batch, 3 * n_free))
        self._predicted, self._guess = vectors(n_free), vectors(n_free)
        self._history = wp.zeros((2, batch, n_free), dtype=wp.vec3d, device=dev)
        self._scalars = wp.zeros((batch, SCALARS), dtype=wp.float64, device=dev)
        self._active = wp.zeros(batch, dtype=wp.int32, device=dev)
        self._condition = wp.zeros(1, dtype=wp.int32, device=dev)
        self._ring = wp.zeros(2, dtype=wp.int32, device=dev)
        self._step_count = wp.zeros(2, dtype=wp.int32, device=dev)
        self._status = wp.zeros((batch, 5), dtype=wp.int32, device=dev)
        self._failure = wp.zeros((batch, 2), dtype=wp.float64, device=dev)
        self.trajectory = wp.zeros((self.chunk, batch, max(n_driven, 1)), dtype=wp.vec3d, device=dev)
        """Ring of driven displacements [m], shape (chunk, B, max(D, 1)); a step reads slot ``ring[0]``."""
        self.record = wp.zeros((self.chunk, batch, n), dtype=wp.vec3d, device=dev)
        """Ring of recorded displacements [m], shape (chunk, B, N)."""
        self._free_index = wp.array(free_index, dtype=wp.int32, device=dev)
        self._driven_slot = wp.array(driven_slot, dtype=wp.int32, device=dev)
        c = coefficients
        self._update_constants = [*c.update_scalars(wp.float64), wp.float64(c.dt), wp.float64(c.half_dt_squared)]
        self._use_graph = bool(use_graph) and dev.is_cuda
        self._graph = None
        self.restart()

    # ------------------------------------------------------------------ the step
    def _iteration(self) -> None:
        b, f, dev = self.model_count, self.free_nodes.size, self.device
        wp.launch(batch_product, dim=(b, f), inputs=[*self._A, self._p, self._active],
                  outputs=[self._q, self._scalars, self._condition], device=dev)
        wp.launch(batch_update, dim=(b, f), inputs=[self._p, self._q, self._inverse, self._active, self._x, self._r,
                                                    self._z, self._scalars, int(self._factor is None)], device=dev)
        self._apply_factor(S_RZ_NEW, 0)
        wp.launch(batch_check, dim=b, inputs=[self._scalars, self._active, wp.float64(self.tol**2), self.maxiter, 0],
                  outputs=[self._condition], device=dev)
        wp.launch(batch_direction, dim=(b, f), inputs=[self._z, self._active, self._scalars], outputs=[self._p],
                  device=dev)

    def _apply_factor(self, which: int, set_direction: int) -> None:
        """``z = Gᵀ G r`` and ``r·z`` into ``scalars[:, which]`` with the FSAI factor(s) (no-op for block Jacobi)."""
        if self._factor is None:
            return
        b, f, dev = self.model_count, self.free_nodes.size, self.device
        lower, upper = self._factor
        wp.launch(batch_factor_product, dim=(b, f), inputs=[*lower, self._r_flat, self._active], outputs=[self._y],
                  device=dev)
        wp.launch(batch_factor_finish, dim=(b, f),
                  inputs=[*upper, self._y_flat, self._r, self._active, int(which), int(set_direction)],
                  outputs=[self._z, self._p, self._scalars], device=dev)

    def _launch_sequence(self) -> None:
        b, f, n, dev = self.model_count, self.free_nodes.size, self.node_count, self.device
        wp.launch(batch_begin, dim=b, inputs=[self._scalars, self._active, self._ring, self._step_count,
                                              self._condition], device=dev)
        wp.launch(batch_residual, dim=(b, f),
                  inputs=[*self._P, *self._A, self.d, self.v, self.a, self.trajectory, self._ring, self._guess],
                  outputs=[self._predicted, self._r, self._scalars], device=dev)
        wp.launch(batch_start, dim=(b, f), inputs=[self._guess, self._predicted, self._inverse, self._r, self._x,
                                                   self._z, self._p, self._scalars, int(self._factor is None)],
                  device=dev)
        self._apply_factor(S_RZ, 1)
        wp.launch(batch_check, dim=b, inputs=[self._scalars, self._active, wp.float64(self.tol**2), self.maxiter, 1],
                  outputs=[self._condition], device=dev)
        wp.capture_while(self._condition, self._iteration)
        wp.launch(batch_newmark_update, dim=(b, n),
                  inputs=[self._x, self._history, self._guess, self._free_index, self._driven_slot, self.trajectory,
                          self._ring, *self._update_constants, self._scalars, self.chunk],
                  outputs=[self.d, self.v, self.a, self.record, self._status, self._failure, self._step_count],
                  device=dev)

    def step(self) -> None:
        """Queue one step of every model, driven by ring slot ``ring[0]`` (advanced by the step); never waits."""
        if not self._use_graph:
            self._launch_sequence()
            return
        if self._graph is None:
            wp.load_module(kernels_batch, device=self.device)  # compiled before, not during, the capture
            with wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
                self._launch_sequence()
            self._graph = capture.graph
        wp.capture_launch(self._graph)

    def run_chunk(self, driven: np.ndarray, staging_in, staging_out) -> np.ndarray:
        """Advance every model by ``k <= chunk`` steps with driven displacements (k, B, D, 3) [m]; returns the
        displacements (k, B, N, 3), a view of ``staging_out`` (host, shape (chunk, B, N) vec3d).

        Raises:
            ConvergenceError: a model's step did not converge.
        """
        k = driven.shape[0]
        self.synchronize()
        self._ring.zero_()
        width = self.trajectory.shape[1] * self.trajectory.shape[2]
        if driven.shape[2]:
            staging_in.numpy()[:k, :, : driven.shape[2]] = driven
            wp.copy(self.trajectory, staging_in, count=k * width)
        for _ in range(k):
            self.step()
        wp.copy(staging_out, self.record, count=k * self.model_count * self.node_count)
        self.synchronize()
        return staging_out.numpy()[:k]

    # ------------------------------------------------------------------ status and restart
    def synchronize(self) -> None:
        """Wait for queued steps; raise :class:`~warpface.fem.solver_cg.ConvergenceError` naming the first
        model that failed."""
        wp.synchronize_device(self.device)
        status = self._status.numpy()
        failed = np.flatnonzero(status[:, 0])
        if failed.size:
            b = int(failed[0])
            residual, tolerance = self._failure.numpy()[b]
            raise ConvergenceError(
                f"model {b}: CG did not converge at step {int(status[b, 1])} ({int(status[b, 0])} failed steps): "
                f"residual {residual:.3e} > tolerance {tolerance:.3e} after {self.maxiter} iterations"
            )

    @property
    def iterations(self) -> np.ndarray:
        """Per model ``[most, last, total]`` CG iterations since the last restart, shape (B, 3) (synchronises)."""
        return self._status.numpy()[:, 2:5].copy()

    def restart(self) -> None:
        """Start new trajectories from the current states: clear counters, failures and the ring, and seed
        the extrapolation as for a motion of constant acceleration (synchronises)."""
        wp.synchronize_device(self.device)
        c = self.coefficients
        v = self.v.numpy()[:, self.free_nodes]
        a = self.a.numpy()[:, self.free_nodes]
        self._history.assign(np.stack([c.dt * v - c.half_dt_squared * a, c.dt * v - 3.0 * c.half_dt_squared * a]))
        for array in (self._guess, self._ring, self._step_count, self._status, self._failure):
            array.zero_()
