"""Batched device Newmark solver: B material models on one mesh stepped together by preconditioned CG.

All B models share the mesh, the node split, ``dt`` and the Newmark parameters; each has its own
matrices (values per model, one sparsity pattern), state, driven displacements and CG convergence.
A time step of all B models is two launches (captured once as a graph on CUDA): the persistent CG
kernel of the single-model solver (:mod:`warpface.fem.kernels_persistent`), launched over every
model at once — each model gets its own group of blocks, its own grid barrier and its own
convergence test, so a model that has converged stops while the others go on — and the end-of-step
update (:data:`~warpface.fem.kernels_integrator.cg_newmark_update`) over ``(B, nodes)``. A model's
arithmetic is exactly that of :class:`~warpface.fem.solver_cg.CGSolver` with the same factor.

On CUDA every block must be resident: the models share the blocks the GPU holds at once (the driver's
occupancy query, :func:`~warpface.fem.kernels_persistent.grid_capacity`), at least one each; a batch with
more models than that is stepped in waves of launches. On the CPU each model is one block of one thread.

The state is a batched :class:`~warpface.fem.state.TissueState` (arrays of shape (B, N), model-major), the
control a batched :class:`~warpface.fem.state.TissueControl` (B, D); stepping, graphs, chunked runs and the
status are those of :class:`~warpface.fem.solver_device.DeviceSolver`.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .assembly import SystemMatrices, bsr_to_scipy
from .cg_setup import grouped_factor_rows, newmark_operators, per_model_fsai, preconditioner_factor, stack_values
from .kernels_cg import SLOT_SPREAD, WORK_ROWS, WORK_X
from .kernels_cg_rows import cg_matrix, cg_matrix_types
from .kernels_integrator import cg_newmark_update, newmark_constants
from .kernels_persistent import grid_capacity, persistent_pcg_kernel
from .newmark import NewmarkCoefficients
from .options import BATCH_PRECONDITIONERS, CGOptions
from .solver_cg import PERSISTENT_LANES, PERSISTENT_ROWS
from .solver_device import DeviceSolver
from .state import TissueControl, TissueState

__all__ = ["BatchedCGSolver"]

BATCH_LANES, BATCH_ROWS, BATCH_RESIDENT_THREADS = 8, 32, 1024
"""Thread-block shape (lanes x rows) of the persistent CG kernel on CUDA for :data:`WIDE_BATCH` models or more,
and the threads per multiprocessor it is compiled to keep resident (fewer models use the single-model solver's
shape, 16 x 16 and 512). With many models each gets only a few blocks, which walk many row groups one after
another: more resident blocks hide more of that latency, fewer registers slow each thread (measurements:
``benchmarks/README.md``)."""
WIDE_BATCH = 16
"""Models from which the batch uses the wider residency above."""


class BatchedCGSolver(DeviceSolver):
    """Newmark steps of B models on a Warp device (module docstring).

    Args:
        matrices: One :class:`~warpface.fem.assembly.SystemMatrices` per model, same mesh and device.
        coefficients: The Newmark constants (shared).
        free_nodes: Nodes solved for, shape (F,), int.
        driven_nodes: Nodes with prescribed displacement, shape (D,), int.
        options: :class:`~warpface.fem.options.CGOptions`, float64, preconditioner one of
            :data:`~warpface.fem.options.BATCH_PRECONDITIONERS`: ``"fsai"`` (one FSAI factor, of the model of
            median mean system diagonal, shared by all models: far fewer iterations than block Jacobi on
            tissue), ``"fsai_each"`` (that factor's support refitted to every model: each model converges as
            fast as alone, at the cost of a factor's values per model) or ``"block_jacobi"`` (per model).

    Raises:
        TypeError: ``options`` is not a CGOptions.
        ValueError: no model, models whose matrices differ in sparsity (different meshes), a model whose system
            matrix has a 3x3 diagonal block that is not positive definite, options the batch does not implement.
        RuntimeError: on CUDA, the occupancy query finds no resident block for the persistent kernel.
    """

    def __init__(
        self,
        matrices: list[SystemMatrices],
        coefficients: NewmarkCoefficients,
        free_nodes,
        driven_nodes,
        options: CGOptions | None = None,
    ):
        options = CGOptions() if options is None else options
        if not isinstance(options, CGOptions):
            raise TypeError(f"options must be a CGOptions, got {type(options).__name__}")
        options.require("BatchedCGSolver", BATCH_PRECONDITIONERS, ("auto", "persistent"), (wp.float64,))
        if not matrices:
            raise ValueError("matrices: a batch needs at least one model")
        self.options = options
        """The :class:`~warpface.fem.options.CGOptions`."""
        self.device = dev = matrices[0].device
        self.model_count = batch = len(matrices)
        self.coefficients = coefficients
        self._vec = wp.vec3d
        self.loop = "persistent"
        n = self.node_count = matrices[0].node_count
        self.free_nodes = np.asarray(free_nodes, dtype=np.int64)
        self.driven_nodes = np.asarray(driven_nodes, dtype=np.int64)
        n_free, n_driven = self.free_nodes.size, self.driven_nodes.size
        free_index = np.full(n, -1, dtype=np.int32)
        free_index[self.free_nodes] = np.arange(n_free, dtype=np.int32)
        driven_slot = np.full(n, -1, dtype=np.int32)
        driven_slot[self.driven_nodes] = np.arange(n_driven, dtype=np.int32)
        operators = [newmark_operators(m, coefficients, free_index, driven_slot) for m in matrices]
        structs = cg_matrix_types(wp.float64)
        self._A = cg_matrix(structs.BatchBlockRows, *stack_values([A for A, _ in operators], "system"))
        self._P = cg_matrix(structs.BatchBlockRows, *stack_values([P for _, P in operators], "right-hand-side"))
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
        if options.preconditioner == "block_jacobi":
            factors = block_jacobi
        else:
            # the model of median system diagonal (K, M and C with the Newmark constants): the diagonal of K
            # alone sums to about zero per row and picked an arbitrary model, whose sparser FSAI support cost
            # the stiffest models more iterations (benchmarks/README.md)
            stiffness = [float(bsr_to_scipy(A).diagonal().mean()) for A, _ in operators]
            median = int(np.argsort(stiffness, kind="stable")[len(stiffness) // 2])
            self.reference_model = median
            if options.preconditioner == "fsai":
                factors = [preconditioner_factor(operators[median][0], "fsai")]
            else:
                factors = per_model_fsai([A for A, _ in operators], median)
        self._factor = (
            cg_matrix(structs.BatchFactorRows, *grouped_factor_rows(factors, wp.float64, device=dev)),
            cg_matrix(structs.BatchFactorRows, *grouped_factor_rows([G.T for G in factors], wp.float64, device=dev)),
        )
        """``(G, Gᵀ)``, values (1, nnz) for a shared factor or (B, nnz)."""
        del operators, block_jacobi

        def vectors(*shape):
            return wp.zeros(shape, dtype=wp.vec3d, device=dev)

        self._guess = vectors(batch, n_free)
        # each model's CG vectors as rows of its work array, and their flat scalar views (index 3 node + axis)
        self._work = vectors(batch, WORK_ROWS, n_free)
        self._work_flat = self._work.view(wp.float64).reshape((batch, WORK_ROWS, 3 * n_free))
        self._x = self._work[:, WORK_X]  # each model's CG solution (B, F), a strided view
        self._history = vectors(2, batch, n_free)
        self._slots = wp.zeros((batch, 4, options.maxiter + 1, SLOT_SPREAD), dtype=wp.float64, device=dev)
        self._cg_iter = wp.zeros((batch, 2), dtype=wp.int32, device=dev)
        self._barrier = wp.zeros((batch, 3), dtype=wp.int32, device=dev)  # per model: arrivals, gave up, departures
        self._ring = wp.zeros(2, dtype=wp.int32, device=dev)
        self._step_ring = wp.zeros(2, dtype=wp.int32, device=dev)  # step(): a ring of one slot, always 0
        self._step_count = wp.zeros(batch, dtype=wp.int32, device=dev)
        self._status = wp.zeros((batch, 5), dtype=wp.int32, device=dev)
        self._failure = wp.zeros((batch, 2), dtype=wp.float64, device=dev)
        self._trajectory = vectors(options.chunk, batch, max(n_driven, 1))  # run_chunks' rings
        self._record = vectors(options.chunk, batch, n)
        self._free_index = wp.array(free_index, dtype=wp.int32, device=dev)
        self._driven_slot = wp.array(driven_slot, dtype=wp.int32, device=dev)
        self._update_constants = newmark_constants(coefficients, wp.float64)

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
            if capacity < 1:
                raise RuntimeError(
                    f"the batched CG kernel cannot keep a block resident on {dev} (occupancy query), and its grid "
                    "barrier needs every block resident; step the models one by one with TissueSimulation"
                )
            self.blocks_per_model = max(1, min(groups, capacity // batch))
            per_wave = max(1, capacity // self.blocks_per_model)
        else:  # blocks run one after the other: no residency limit
            self.blocks_per_model, per_wave = 1, batch
        self.waves = [(first, min(per_wave, batch - first)) for first in range(0, batch, per_wave)]
        """``(first model, models)`` of each launch of the CG kernel per step (one launch unless B exceeds
        the blocks the GPU holds at once)."""
        self._init_bindings()

        # One eager step loads every kernel before any capture; reset clears the counters it touches.
        scratch = TissueState(n, models=batch, device=dev)
        control = TissueControl(n_driven, models=batch, device=dev)
        self._launch_sequence(self._binding_for_step(scratch, scratch, control))
        self._bindings.clear()
        self.reset(scratch)

    # ------------------------------------------------------------------ the step
    def _launch_sequence(self, b) -> None:
        dev, kernel, tol_sq = self.device, self._kernel, wp.float64(self.options.tolerance**2)
        maxiter = self.options.maxiter
        self._slots.zero_()
        for first, models in self.waves:
            wp.launch_tiled(
                kernel.cg_step,
                dim=models * self.blocks_per_model,
                block_dim=kernel.block_dim,
                device=dev,
                inputs=[
                    *(self._P, self._A, *self._factor),
                    *(b.d_in, b.v_in, b.a_in, b.trajectory, self._guess, b.force, self._free_nodes_device),
                    *(b.ring, self._work, self._work_flat),
                    *(self._slots, self._cg_iter, self._barrier, tol_sq, maxiter, self.blocks_per_model, first),
                ],
            )
        wp.launch(
            cg_newmark_update,
            dim=(self.model_count, self.node_count),
            inputs=[
                *(self._x, self._history, self._guess, self._free_index, self._driven_slot, b.trajectory, b.ring),
                *(self._update_constants, self._slots, self._cg_iter, tol_sq, b.chunk, b.d_in, b.v_in, b.a_in),
            ],
            outputs=[b.d_out, b.v_out, b.a_out, b.record, self._step_count, self._status, self._failure],
            device=dev,
        )

    @property
    def iterations(self) -> np.ndarray:
        """Per model ``[most, last, total]`` CG iterations since the last reset, shape (B, 3) (synchronises)."""
        return self._status.numpy()[:, 2:5].copy()
