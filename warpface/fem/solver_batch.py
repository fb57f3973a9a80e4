"""Batched device Newmark solver: B material models on one mesh stepped together by preconditioned CG.

All B models share the mesh, the node split, ``dt`` and the Newmark parameters; each has its own
matrices (values per model, one sparsity pattern), state, driven trajectory and CG convergence.
A time step of all B models is two launches (captured once as a graph on CUDA): the persistent CG
kernel of the single-model solver (:mod:`warpface.fem.kernels_persistent`), launched over every
model at once — each model gets its own group of blocks, its own grid barrier and its own
convergence test, so a model that has converged stops while the others go on — and the end-of-step
update (:data:`~warpface.fem.kernels_integrator.cg_newmark_update`) over ``(B, nodes)``. A model's
arithmetic is exactly that of :class:`~warpface.fem.solver_cg.CGSolver` with the same factor.

On CUDA every block must be resident: the models share the blocks the GPU holds at once
(:func:`~warpface.fem.kernels_persistent.grid_capacity`), at least one each; a batch with more models
than that is stepped in waves of launches. On the CPU each model is one block of one thread.

The state lives in arrays of shape (B, N) of ``vec3d`` (model-major, coalesced per model). Driven
displacements come through a ring of ``chunk`` slots ``(chunk, B, D)``, and every step's
displacements are recorded into a ring ``(chunk, B, N)``, as in the single-model CG solver.
"""

from __future__ import annotations

import numpy as np
import warp as wp
from warp.optim.linear import FSAI

from ..errors import ConvergenceError
from .assembly import SystemMatrices, bsr_to_scipy
from .chunks import ChunkedRun
from .kernels_cg import SLOT_SPREAD
from .kernels_integrator import cg_newmark_update
from .kernels_persistent import WORK_ROWS, WORK_X, grid_capacity, persistent_pcg_kernel
from .newmark import NewmarkCoefficients
from .solver_cg import (
    FSAI_ROW_SIZE,
    PERSISTENT_LANES,
    PERSISTENT_ROWS,
    grouped_factor_rows,
    newmark_operators,
    preconditioner_factor,
)

__all__ = ["BATCH_PRECONDITIONERS", "BatchedCGSolver", "per_model_fsai"]

BATCH_PRECONDITIONERS = ("fsai", "fsai_each", "block_jacobi")

BATCH_LANES, BATCH_ROWS, BATCH_RESIDENT_THREADS = 8, 32, 1024
"""Thread-block shape (lanes x rows) of the persistent CG kernel on CUDA for :data:`WIDE_BATCH` models or more,
and the threads per multiprocessor it is compiled to keep resident (fewer models use the single-model solver's
shape, 16 x 16 and 512). H200, 6.7k-node shell, ms per step of x1 / x3 / x10 / x100 models: 16x16 and 512 threads
0.195 / 0.453 / 1.22 / 14.1; 8x32, 1024: 0.273 / 0.690 / 1.25 / 7.6; other shapes at x1 / x10 / x100: 16x16, 1024:
0.259 / 1.17 / 8.6; 4x32, 1024: 0.362 / 1.56 / 7.5; 8x32, 2048: 0.357 / 2.55 / 15.0. With many models each gets
only a few blocks, which walk many row groups one after another: more resident blocks hide more of that latency,
but fewer registers slow each thread."""
WIDE_BATCH = 16
"""Models from which the batch uses the wider residency above (between the measured 10 and 100)."""


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


def _stack_values(matrices, label: str):
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
        ValueError: no model, models whose matrices differ in sparsity (different meshes), or a model
            whose system matrix has a 3x3 diagonal block that is not positive definite.
    """

    def __init__(
        self,
        matrices: list[SystemMatrices],
        coefficients: NewmarkCoefficients,
        free_nodes,
        driven_nodes,
        *,
        tol: float = 1.0e-5,
        maxiter: int = 500,
        chunk: int = 64,
        use_graph: bool = True,
        preconditioner: str = "fsai",
    ):
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
        self._P = _stack_values([P for _, P in operators], "right-hand-side")
        block_jacobi = []
        for b, (A, _) in enumerate(operators):
            try:
                block_jacobi.append(preconditioner_factor(A, "block_jacobi"))
            except ValueError:
                raise ValueError(
                    f"model {b}: a 3x3 diagonal block of its system matrix is not positive definite"
                ) from None
        self.reference_model = None
        """Model whose FSAI factor (``"fsai"``) or support (``"fsai_each"``) preconditions every model."""
        if preconditioner == "block_jacobi":
            factors = block_jacobi
        else:
            # the model of median system diagonal (K, M and C with the Newmark constants). Every 3x3 block's
            # diagonal of K (as before) sums to about zero per row, which picked an arbitrary model: on the
            # 10-model sweep of benchmarks/fem.py the softest one, whose sparser FSAI support cost the stiffest
            # model 19 instead of 13 iterations (refitted) or 24 (shared) on a 1.2k-node shell.
            stiffness = [float(bsr_to_scipy(A).diagonal().mean()) for A, _ in operators]
            median = int(np.argsort(stiffness, kind="stable")[len(stiffness) // 2])
            self.reference_model = median
            if preconditioner == "fsai":
                factors = [preconditioner_factor(operators[median][0], "fsai")]
            else:
                factors = per_model_fsai([A for A, _ in operators], median)
        self._factor = (
            grouped_factor_rows(factors, wp.float64, device=dev),
            grouped_factor_rows([G.T for G in factors], wp.float64, device=dev),
        )
        """``(G, Gᵀ)`` as ``(offsets, keys, values)``, values (1, nnz) for a shared factor or (B, nnz)."""
        del operators, block_jacobi

        def vectors(*shape):
            return wp.zeros(shape, dtype=wp.vec3d, device=dev)

        self.d, self.v, self.a = vectors(batch, n), vectors(batch, n), vectors(batch, n)
        """State of every model [m, m/s, m/s²], shape (B, N) of vec3d (updated in place)."""
        self._guess = vectors(batch, n_free)
        # each model's CG vectors as rows of its work array, and their flat scalar views (index 3 node + axis)
        self._work = vectors(batch, WORK_ROWS, n_free)
        self._work_flat = self._work.view(wp.float64).reshape((batch, WORK_ROWS, 3 * n_free))
        self._x = self._work[:, WORK_X]  # each model's CG solution (B, F), a strided view
        self._history = vectors(2, batch, n_free)
        self._slots = wp.zeros((batch, 4, self.maxiter + 1, SLOT_SPREAD), dtype=wp.float64, device=dev)
        self._cg_iter = wp.zeros((batch, 2), dtype=wp.int32, device=dev)
        self._barrier = wp.zeros((batch, 3), dtype=wp.int32, device=dev)  # per model: arrivals, gave up, departures
        self._ring = wp.zeros(2, dtype=wp.int32, device=dev)
        self._step_count = wp.zeros(batch, dtype=wp.int32, device=dev)
        self._status = wp.zeros((batch, 5), dtype=wp.int32, device=dev)
        self._failure = wp.zeros((batch, 2), dtype=wp.float64, device=dev)
        self.trajectory = wp.zeros((self.chunk, batch, max(n_driven, 1)), dtype=wp.vec3d, device=dev)
        """Ring of driven displacements [m], shape (chunk, B, max(D, 1)); a step reads slot ``ring[0]``."""
        self.record = wp.zeros((self.chunk, batch, n), dtype=wp.vec3d, device=dev)
        """Ring of recorded displacements [m], shape (chunk, B, N)."""
        self._chunked = None  # run_chunks' buffers, allocated on its first call (a stepping-only batch needs none)
        self._free_index = wp.array(free_index, dtype=wp.int32, device=dev)
        self._driven_slot = wp.array(driven_slot, dtype=wp.int32, device=dev)
        self._update_constants = [
            *coefficients.update_scalars(wp.float64),
            wp.float64(coefficients.dt),
            wp.float64(coefficients.half_dt_squared),
        ]

        if not dev.is_cuda:
            shape = (1, 1)  # one CPU thread walks every row of a model
        elif batch < WIDE_BATCH:
            shape = (PERSISTENT_LANES, PERSISTENT_ROWS)
        else:
            shape = (BATCH_LANES, BATCH_ROWS, BATCH_RESIDENT_THREADS)
        self._kernel = persistent_pcg_kernel(wp.float64, *shape, single=batch == 1)
        groups = -(-n_free // self._kernel.rows)
        if dev.is_cuda:
            capacity = grid_capacity(self._kernel.cg_step, self._kernel.block_dim, device=dev)
            self.blocks_per_model = max(1, min(groups, capacity // batch))
            per_wave = max(1, capacity // self.blocks_per_model)
        else:  # blocks run one after the other: no residency limit
            self.blocks_per_model, per_wave = 1, batch
        self.waves = [(first, min(per_wave, batch - first)) for first in range(0, batch, per_wave)]
        """``(first model, models)`` of each launch of the CG kernel per step (one launch unless B exceeds
        the blocks the GPU holds at once)."""
        self._use_graph = bool(use_graph) and dev.is_cuda
        self._graph = None
        self._launch_sequence()  # loads every kernel before any capture; restart clears what it touched
        self.restart()

    # ------------------------------------------------------------------ the step
    def _launch_sequence(self) -> None:
        dev, kernel, tol_sq = self.device, self._kernel, wp.float64(self.tol**2)
        (g_offsets, g_keys, g_values), (t_offsets, t_keys, t_values) = self._factor
        self._slots.zero_()
        for first, models in self.waves:
            wp.launch_tiled(
                kernel.cg_step,
                dim=models * self.blocks_per_model,
                block_dim=kernel.block_dim,
                device=dev,
                inputs=[
                    *self._P,
                    *self._A,
                    g_offsets,
                    g_keys,
                    g_values,
                    t_offsets,
                    t_keys,
                    t_values,
                    self.d,
                    self.v,
                    self.a,
                    self.trajectory,
                    self._guess,
                    self._ring,
                    self._work,
                    self._work_flat,
                    self._slots,
                    self._cg_iter,
                    self._barrier,
                    tol_sq,
                    self.maxiter,
                    self.blocks_per_model,
                    first,
                ],
            )
        wp.launch(
            cg_newmark_update,
            dim=(self.model_count, self.node_count),
            inputs=[
                self._x,
                self._history,
                self._guess,
                self._free_index,
                self._driven_slot,
                self.trajectory,
                self._ring,
                *self._update_constants,
                self._slots,
                self._cg_iter,
                tol_sq,
                self.chunk,
                self.d,
                self.v,
                self.a,
            ],
            outputs=[self.d, self.v, self.a, self.record, self._step_count, self._status, self._failure],
            device=dev,
        )

    def step(self) -> None:
        """Queue one step of every model, driven by ring slot ``ring[0]`` (advanced by the step); never waits."""
        if not self._use_graph:
            self._launch_sequence()
            return
        if self._graph is None:
            with wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
                self._launch_sequence()
            self._graph = capture.graph
        wp.capture_launch(self._graph)

    def run_chunks(self, driven: np.ndarray):
        """Advance every model through driven displacements (T, B, D, 3) [m], ``chunk`` steps at a time; yields
        each chunk's displacements (k, B, N, 3) float32, a view of a host staging buffer valid until the next one.
        Each chunk is queued before the previous one is waited for (:class:`~warpface.fem.chunks.ChunkedRun`).

        Raises:
            ConvergenceError: a model's step did not converge.
        """
        self.synchronize()
        if self._chunked is None:
            self._chunked = ChunkedRun(
                self.trajectory, self.record, self._ring, self._barrier, self._status, self._failure
            )
        return self._chunked.run(driven, self.step, self._raise_on_failure)

    # ------------------------------------------------------------------ status and restart
    def synchronize(self) -> None:
        """Wait for queued steps; raise :class:`~warpface.fem.solver_cg.ConvergenceError` naming the first
        model that failed."""
        wp.synchronize_device(self.device)
        self._raise_on_failure(self._barrier.numpy(), self._status.numpy(), self._failure.numpy())

    def _raise_on_failure(self, barrier: np.ndarray, status: np.ndarray, failure: np.ndarray) -> None:
        """Raise for the first model whose failure the device booked (``barrier`` (B, 3), ``status`` (B, 5),
        ``failure`` (B, 2) as read from the device)."""
        if np.any(barrier[:, 1]):
            raise RuntimeError(
                f"the persistent CG loop waited too long at a grid barrier on {self.device} (its "
                f"{self.blocks_per_model} blocks per model were not all resident)"
            )
        failed = np.flatnonzero(status[:, 0])
        if failed.size:
            b = int(failed[0])
            residual, tolerance = failure[b]
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
        for array in (
            self._guess,
            self._ring,
            self._step_count,
            self._status,
            self._failure,
            self._cg_iter,
            self._barrier,
        ):
            array.zero_()
