"""Device Newmark solver: preconditioned CG in fused Warp kernels, the whole time step in one graph.

Everything lives on the Warp device. One time step (kernels in :mod:`warpface.fem.kernels_cg` and
:mod:`warpface.fem.kernels_integrator`) is

1. ``residual`` — the residual of the Newmark predictor ``x~ = d + dt v + dt²/2 a`` of the free
   nodes, ``r_p = q_o − A_od d_driven − A_oo x~``, as one product ``P [d; v; a; d_driven]``
   with ``P = [c0 M + c3 C − A_o·free, c1 M + c4 C − dt A_o·free, c2 M + c5 C − dt²/2 A_o·free,
   −A_od]`` assembled once in float64 (so the large ``c0 M d`` terms cancel at setup, not in
   every step's arithmetic; :func:`~warpface.fem.cg_setup.newmark_operators`), and the residual
   ``r_p − A_oo g`` of the extrapolated start ``x~ + g`` (``g``: cubic extrapolation of the last four
   displacements minus the predictor, left by the previous step's update);
2. ``lower_start``, ``upper`` — CG starts from whichever of the two has the smaller residual
   (the extrapolation wins while the motion is smooth, by orders of magnitude), ``z = Gᵀ G r0``;
3. preconditioned CG on ``A_oo δ = r_p`` from that start: three kernels per iteration in a
   ``wp.capture_while`` loop (a conditional graph node on CUDA) that stops on the device when
   ``‖r‖ <= tol ‖r_p‖``. The tolerance is relative to the predictor's residual, as without the
   extrapolation, so the better start saves iterations without loosening the result;
4. ``cg_newmark_update`` — ``d = x~ + δ`` (or the driven/fixed value), then the shared Newmark
   update (:func:`~warpface.fem.kernels_integrator.newmark_advance`) into the output state, the
   displacement recorded, the extrapolation for the next step, and the step's convergence status
   booked on the device.

With the persistent loop (``CGOptions.loop``; chosen on CUDA when the driver's occupancy query says its
blocks fit) steps 1–3 are one kernel (:mod:`warpface.fem.kernels_persistent`): the same phases and
arithmetic, separated by grid-wide barriers instead of launches, at most as many blocks as the GPU holds
at once; a step is then a memset of the dot-product slots, that kernel and the update.

Stepping, graphs, chunked runs and the status are shared with the batched solver
(:class:`~warpface.fem.solver_device.DeviceSolver`). Every preconditioner is used in factored form
``M⁻¹ = Gᵀ G`` with a lower-triangular ``G`` (:func:`~warpface.fem.cg_setup.preconditioner_factor`).
Compared with Warp's stock ``warp.optim.linear.cg`` (about eleven dependent launches per iteration), an
iteration here is three kernels (or three barriers of the persistent kernel), and the extrapolated start
cuts the iteration count by more than half during smooth motion (measurements: ``benchmarks/README.md``).
"""

from __future__ import annotations

import numpy as np
import warp as wp
import warp.sparse as wps

from .assembly import SystemMatrices
from .cg_setup import grouped_factor_rows, newmark_operators, preconditioner_factor
from .kernels_cg import SLOT_SPREAD, WORK_ROWS, WORK_X, pcg_kernels
from .kernels_cg_rows import cg_matrix, cg_matrix_types
from .kernels_integrator import cg_newmark_update, newmark_constants
from .kernels_persistent import grid_capacity, persistent_pcg_kernel
from .newmark import NewmarkCoefficients
from .options import PRECONDITIONERS, CGOptions
from .solver_device import DeviceSolver
from .state import TissueControl, TissueState

__all__ = ["CGSolver", "choose_loop"]

LANES, ROWS_PER_BLOCK = 16, 8
"""Thread-block shape of the launched CG kernels: threads sharing a matrix row, and rows per block
(:mod:`warpface.fem.kernels_cg`; the shapes measured are in ``benchmarks/README.md``)."""

PERSISTENT_LANES, PERSISTENT_ROWS = 16, 16
"""Thread-block shape (lanes x rows) of the persistent CG kernel on CUDA (measurements: ``benchmarks/README.md``)."""

UNROLL = 2
"""CG iterations per pass of the launched loop: the loop's condition node costs about a kernel launch, and at
most ``UNROLL - 1`` finished (empty) iterations are launched after convergence."""


def _block_shape(device) -> tuple[int, int]:
    """``(lanes, rows)`` of the CG kernels' thread blocks: one thread on a CPU without block support."""
    if device.is_cuda or wp.config.enable_cpu_blocks:
        return LANES, ROWS_PER_BLOCK
    return 1, 1


def choose_loop(requested: str, capacity, *, device) -> str:
    """The CG loop to run: ``requested`` (one of :data:`~warpface.fem.options.CG_LOOPS`) resolved on ``device``.

    ``capacity()`` gives the persistent kernel's co-resident blocks (:func:`grid_capacity`), asked only on CUDA:
    ``"auto"`` is persistent when at least one block per multiprocessor fits and launched otherwise (and on the
    CPU); an explicit ``"persistent"`` on CUDA where nothing fits raises ValueError (its grid barrier would hang).
    """
    if requested == "launched" or (requested == "auto" and not device.is_cuda):
        return "launched"
    if not device.is_cuda:
        return "persistent"  # the CPU runs the kernel as one block: no barrier to wait at
    fits = capacity() >= device.sm_count
    if requested == "auto":
        return "persistent" if fits else "launched"
    if not fits:
        raise ValueError(
            f"CGOptions(loop='persistent'): the occupancy query finds no resident block per multiprocessor on "
            f"{device}, so its grid barrier is not safe; use loop='launched' or 'auto'"
        )
    return "persistent"


class CGSolver(DeviceSolver):
    """Newmark steps of one model on a Warp device with graph-captured preconditioned CG (module docstring).

    Args:
        matrices: K, M, C assembled on the target device (float64).
        coefficients: :class:`~warpface.fem.newmark.NewmarkCoefficients`.
        free_nodes: Nodes solved for, shape (F,), int.
        driven_nodes: Nodes with prescribed displacement, shape (D,), int.
        options: :class:`~warpface.fem.options.CGOptions` (preconditioner one of
            :data:`~warpface.fem.options.PRECONDITIONERS`); default ``CGOptions()``.

    Raises:
        TypeError: ``options`` is not a CGOptions.
        ValueError: a batch-only preconditioner, or ``loop="persistent"`` where its blocks cannot be resident.
    """

    def __init__(
        self,
        matrices: SystemMatrices,
        coefficients: NewmarkCoefficients,
        free_nodes: np.ndarray,
        driven_nodes: np.ndarray,
        options: CGOptions | None = None,
    ):
        options = CGOptions() if options is None else options
        if not isinstance(options, CGOptions):
            raise TypeError(f"options must be a CGOptions, got {type(options).__name__}")
        options.require("CGSolver", PRECONDITIONERS)
        self.options = options
        """The :class:`~warpface.fem.options.CGOptions`."""
        self.device = dev = matrices.device
        self.dtype = dtype = options.dtype
        self.coefficients = coefficients
        self.model_count = None
        self._kernels = pcg_kernels(dtype, *_block_shape(dev))
        vec = self._vec = self._kernels.vec
        n = self.node_count = matrices.node_count
        self.free_nodes = np.asarray(free_nodes, dtype=np.int64)
        self.driven_nodes = np.asarray(driven_nodes, dtype=np.int64)
        n_free, n_driven = self.free_nodes.size, self.driven_nodes.size
        self.free_count = n_free

        free_index = np.full(n, -1, dtype=np.int32)
        free_index[self.free_nodes] = np.arange(n_free, dtype=np.int32)
        driven_slot = np.full(n, -1, dtype=np.int32)
        driven_slot[self.driven_nodes] = np.arange(n_driven, dtype=np.int32)

        A_oo, P = newmark_operators(matrices, coefficients, free_index, driven_slot)
        G = preconditioner_factor(A_oo, options.preconditioner)
        if dtype != wp.float64:
            A_oo = wps.bsr_copy(A_oo, scalar_type=dtype)
            P = wps.bsr_copy(P, scalar_type=dtype)
        A_oo.nnz_sync()
        P.nnz_sync()
        lower, upper = grouped_factor_rows([G], dtype, device=dev), grouped_factor_rows([G.T], dtype, device=dev)
        structs = cg_matrix_types(dtype)
        # the launched loop's kernels take one model's matrices (the factors' values of model 0)
        self._P = cg_matrix(structs.BlockRows, P.offsets, P.columns, P.values)
        self._A = cg_matrix(structs.BlockRows, A_oo.offsets, A_oo.columns, A_oo.values)
        self._G = cg_matrix(structs.FactorRows, lower[0], lower[1], lower[2][0])
        self._GT = cg_matrix(structs.FactorRows, upper[0], upper[1], upper[2][0])

        # Work arrays (allocated once; captured graphs bind these pointers).
        self._update_constants = newmark_constants(coefficients, dtype)
        self._free_index = wp.array(free_index, dtype=wp.int32, device=dev)
        self._driven_slot = wp.array(driven_slot, dtype=wp.int32, device=dev)
        # the CG vectors as rows of one work array (the persistent kernel's layout) and their flat scalar views
        # (index 3 node + axis) for the scalar preconditioner factors
        self._work = wp.zeros((1, WORK_ROWS, n_free), dtype=vec, device=dev)
        self._work_flat = self._work.view(dtype).reshape((1, WORK_ROWS, 3 * n_free))
        self._work_one, self._work_flat_one = self._work[0], self._work_flat[0]  # the launched kernels' model
        self._history = wp.zeros((2, 1, n_free), dtype=vec, device=dev)
        self._guess = wp.zeros(n_free, dtype=vec, device=dev)
        self._slots = wp.zeros((1, 4, options.maxiter + 1, SLOT_SPREAD), dtype=wp.float64, device=dev)
        self._cg_iter = wp.zeros((1, 2), dtype=wp.int32, device=dev)
        self._barrier = wp.zeros((1, 3), dtype=wp.int32, device=dev)  # persistent: [arrivals, gave up, departures]
        self._condition = wp.zeros(1, dtype=wp.int32, device=dev)
        self._step_count = wp.zeros(1, dtype=wp.int32, device=dev)
        self._status = wp.zeros((1, 5), dtype=wp.int32, device=dev)
        self._failure = wp.zeros((1, 2), dtype=wp.float64, device=dev)
        # run_chunks' ring of `chunk` driven inputs and recorded displacements (slot index on the device)
        self._trajectory = wp.zeros((options.chunk, 1, max(n_driven, 1)), dtype=vec, device=dev)
        self._record = wp.zeros((options.chunk, 1, n), dtype=vec, device=dev)
        self._ring = wp.zeros(2, dtype=wp.int32, device=dev)
        self._step_ring = wp.zeros(2, dtype=wp.int32, device=dev)  # step(): a ring of one slot, always 0
        # views made once: the launched kernels' single-model arrays, the persistent kernel's batch of one
        self._slots_one, self._cg_iter_one = self._slots[0], self._cg_iter[0]
        self._guess_models = self._batch_view(self._guess)
        self._batch_matrices = (  # P, A, G, Gᵀ
            cg_matrix(structs.BatchBlockRows, P.offsets, P.columns, self._batch_view(P.values)),
            cg_matrix(structs.BatchBlockRows, A_oo.offsets, A_oo.columns, self._batch_view(A_oo.values)),
            cg_matrix(structs.BatchFactorRows, *lower),
            cg_matrix(structs.BatchFactorRows, *upper),
        )
        self._x_models = self._work[:, WORK_X]

        shape = (PERSISTENT_LANES, PERSISTENT_ROWS) if dev.is_cuda else (1, 1)  # one CPU thread walks every row
        persistent = persistent_pcg_kernel(dtype, *shape, single=True)
        capacity = {}

        def blocks_resident() -> int:
            if not capacity:
                capacity["blocks"] = grid_capacity(persistent.cg_step, persistent.block_dim, device=dev)
            return capacity["blocks"]

        self.loop = choose_loop(options.loop, blocks_resident, device=dev)
        """``"persistent"`` or ``"launched"``: :attr:`options`' loop resolved on the device (:func:`choose_loop`)."""
        if self.loop == "persistent":
            self._persistent = persistent
            self._persistent_blocks = max(1, min(-(-n_free // persistent.rows), blocks_resident()))
        self._init_bindings()

        # One eager step loads every kernel before any capture; reset clears the counters it touches.
        scratch = TissueState(n, dtype=dtype, device=dev)
        self._launch_sequence(
            self._binding_for_step(scratch, scratch, TissueControl(n_driven, dtype=dtype, device=dev))
        )
        self._bindings.clear()
        self.reset(scratch)

    # ------------------------------------------------------------------ the step
    def _launch_tiled(self, kernel, inputs) -> None:
        k = self._kernels
        blocks = -(-self.free_count // k.rows)
        wp.launch_tiled(kernel, dim=blocks, inputs=inputs, block_dim=k.block_dim, device=self.device)

    def _cg_iterations(self) -> None:
        k, tol_sq, maxiter = self._kernels, wp.float64(self.options.tolerance**2), self.options.maxiter
        w, w_flat, slots, cg_iter = self._work_one, self._work_flat_one, self._slots_one, self._cg_iter_one
        for _ in range(UNROLL):
            self._launch_tiled(k.direction, [self._A, w, slots, cg_iter, self._condition, tol_sq, maxiter])
            self._launch_tiled(k.lower, [self._G, w, w_flat, slots, cg_iter, tol_sq, maxiter])
            self._launch_tiled(k.upper, [self._GT, w, w_flat, slots, cg_iter, tol_sq, maxiter])

    def _launch_sequence(self, b) -> None:
        k = self._kernels
        tol_sq, maxiter = wp.float64(self.options.tolerance**2), self.options.maxiter
        self._slots.zero_()
        if self.loop == "persistent":
            step = self._persistent
            wp.launch_tiled(
                step.cg_step,
                dim=self._persistent_blocks,
                block_dim=step.block_dim,
                device=self.device,
                inputs=[
                    *self._batch_matrices,
                    *(b.d_in, b.v_in, b.a_in, b.trajectory, self._guess_models, b.force, self._free_nodes_device),
                    *(b.ring, self._work, self._work_flat),
                    *(self._slots, self._cg_iter, self._barrier, tol_sq, maxiter, self._persistent_blocks, 0),
                ],
            )
        else:
            w, w_flat, slots, cg_iter = self._work_one, self._work_flat_one, self._slots_one, self._cg_iter_one
            self._launch_tiled(
                k.residual,
                [self._P, self._A, *b.state, b.driven, self._guess, b.force_one, self._free_nodes_device, b.ring]
                + [w, slots, cg_iter, self._condition],
            )
            self._launch_tiled(k.lower_start, [self._G, w, w_flat, slots])
            self._launch_tiled(k.upper, [self._GT, w, w_flat, slots, cg_iter, tol_sq, maxiter])
            wp.capture_while(self._condition, self._cg_iterations)
        wp.launch(
            cg_newmark_update,
            dim=(1, self.node_count),
            inputs=[
                *(self._x_models, self._history, self._guess_models, self._free_index, self._driven_slot),
                *(b.trajectory, b.ring, self._update_constants, self._slots, self._cg_iter, tol_sq, b.chunk),
                *(b.d_in, b.v_in, b.a_in),
            ],
            outputs=[b.d_out, b.v_out, b.a_out, b.record, self._step_count, self._status, self._failure],
            device=self.device,
        )

    # ------------------------------------------------------------------ status
    @property
    def iterations(self) -> tuple[int, int]:
        """``(most, last)`` CG iterations per step since the last reset (synchronises)."""
        status = self._status.numpy()[0]
        return int(status[2]), int(status[3])

    @property
    def total_iterations(self) -> int:
        """CG iterations of all steps since the last reset (synchronises)."""
        return int(self._status.numpy()[0, 4])
