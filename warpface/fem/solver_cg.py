"""Device Newmark solver: preconditioned CG in fused Warp kernels, the whole time step in one graph.

Everything lives on the Warp device. One time step (kernels in :mod:`warpface.fem.kernels_cg` and
:mod:`warpface.fem.kernels_integrator`) is

1. ``residual`` — the residual of the Newmark predictor ``x~ = d + dt v + dt²/2 a`` of the free
   nodes, ``r_p = q_o − A_od d_driven − A_oo x~``, as one product ``P [d; v; a; d_driven]``
   with ``P = [c0 M + c3 C − A_o·free, c1 M + c4 C − dt A_o·free, c2 M + c5 C − dt²/2 A_o·free,
   −A_od]`` assembled once in float64 (so the large ``c0 M d`` terms cancel at setup, not in
   every step's arithmetic), and the residual ``r_p − A_oo g`` of the extrapolated start
   ``x~ + g`` (``g``: cubic extrapolation of the last four displacements minus the predictor,
   left by the previous step's update);
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

With ``loop="persistent"`` (the default on CUDA) steps 1–3 are one kernel
(:mod:`warpface.fem.kernels_persistent`): the same phases and arithmetic, separated by grid-wide
barriers instead of launches, at most as many blocks as the GPU holds at once; a step is then a
memset of the dot-product slots, that kernel and the update.

:meth:`CGSolver.step` reads ``state_in`` and the control and writes ``state_out``. On CUDA the
sequence is captured with ``wp.ScopedCapture`` once per combination of state and control arrays
(a simulation stepping one state in place, or two in turn, has one or two graphs), and each step
is one ``wp.capture_launch``: no allocation, no host read-back. :meth:`CGSolver.run_chunks` binds
a ring of ``chunk`` driven inputs and recorded displacements instead. The host looks at the
status only at synchronisation points (:meth:`CGSolver.synchronize`).

Every preconditioner is used in factored form ``M⁻¹ = Gᵀ G`` with a lower-triangular ``G``:
FSAI (``warp.optim.linear.FSAI``), or the inverse Cholesky factors of the 3x3 diagonal blocks
(block Jacobi) or of the diagonal (Jacobi).

Compared with Warp's stock ``warp.optim.linear.cg`` (about eleven dependent launches per
iteration), an iteration here is three kernels (or three barriers of the persistent kernel), and
the extrapolated start cuts the iteration count by more than half during smooth motion
(measurements: ``benchmarks/README.md``).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import warp as wp
import warp.sparse as wps
from warp.optim.linear import FSAI

from ..errors import ConvergenceError
from .assembly import SystemMatrices, bsr_to_scipy, partition_bsr
from .chunks import ChunkedRun
from .kernels_cg import SLOT_SPREAD, pcg_kernels
from .kernels_integrator import cg_newmark_update
from .kernels_persistent import (
    WORK_P,
    WORK_Q,
    WORK_R,
    WORK_ROWS,
    WORK_X,
    WORK_Y,
    WORK_Z,
    grid_capacity,
    persistent_pcg_kernel,
)
from .newmark import NewmarkCoefficients
from .state import TissueControl, TissueState

__all__ = ["CG_LOOPS", "CGSolver", "PRECONDITIONERS", "grouped_factor_rows", "newmark_operators"]

PRECONDITIONERS = ("fsai", "block_jacobi", "diag")

CG_LOOPS = ("auto", "persistent", "launched")
"""How the CG iterations run: ``"persistent"`` (one kernel for all iterations, grid-wide barriers
between phases, :mod:`warpface.fem.kernels_persistent`), ``"launched"`` (three kernels per iteration
in a ``wp.capture_while`` loop) or ``"auto"`` (persistent on CUDA, launched on the CPU)."""

# FSAI factor entries per row. On the 6.7k-node face shell at dt = 1e-3 (Kato's material), CG to a
# 1e-6 relative residual took 148 iterations with Jacobi, 129 with 3x3 block Jacobi and 54 / 43 / 33
# with FSAI rows of 8 / 16 / 32 entries. A step on a GPU is bound by latency, not by the arithmetic
# of a longer row (H200: 22.1 / 22.7 / 23.5 µs per iteration for rows of 8 / 16 / 32, mean
# iterations 16.3 / 12.9 / 10.2 over the benchmark's mouth opening), so fewer iterations win.
FSAI_ROW_SIZE = 32

# Thread-block shape of the CG kernels: threads sharing a matrix row, and rows per block (see
# warpface.fem.kernels_cg). H200, 6.7k / 26k nodes, µs per iteration: 16x8 22.6 / 53.6,
# 8x16 24.6 / 49.8, 32x4 27.3 / 73.5, one 32-thread block per row 47 / -.
LANES, ROWS_PER_BLOCK = 16, 8

# Thread-block shape (lanes x rows) of the persistent CG kernel (cg_loop="persistent"). H200, 6.7k nodes
# (3.9k free), ms per step of the benchmark's mouth opening (10.2 iterations), kernel compiled for 512
# resident threads per multiprocessor: 16x16 0.185, 8x16 0.204, 8x32 0.202, 16x8 0.206 (a first version
# without the residual phase: 16x16 0.192, 16x8 0.208, 8x16 0.215, 8x8 0.227, 16x4 0.264, 32x4 0.275,
# 4x32 0.374). The launched loop: 0.297.
PERSISTENT_LANES, PERSISTENT_ROWS = 16, 16

# CG iterations per pass of the device loop: the loop's condition node costs about a kernel
# launch, and at most UNROLL - 1 finished (empty) iterations are launched after convergence.
UNROLL = 2


def _as_one_model(array: wp.array) -> wp.array:
    """A view of ``array`` with a leading dimension of 1: the only model of a batch."""
    return array.reshape((1, *array.shape))


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


def _block_shape(device) -> tuple[int, int]:
    """``(lanes, rows)`` of the CG kernels' thread blocks: one thread on a CPU without block support."""
    if device.is_cuda or wp.config.enable_cpu_blocks:
        return LANES, ROWS_PER_BLOCK
    return 1, 1


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


class CGSolver:
    """Newmark steps on a Warp device with graph-captured preconditioned CG.

    Args:
        matrices: K, M, C assembled on the target device (float64).
        coefficients: :class:`~warpface.fem.newmark.NewmarkCoefficients`.
        free_nodes: Nodes solved for, shape (F,), int.
        driven_nodes: Nodes with prescribed displacement, shape (D,), int.
        dtype: ``wp.float32`` or ``wp.float64`` for the solver and the state.
        tol: CG tolerance relative to the warm start's residual norm.
        maxiter: CG iteration limit per step.
        preconditioner: ``"fsai"`` (adaptive factorised sparse approximate inverse, ``FSAI_ROW_SIZE``),
            ``"block_jacobi"`` (inverse 3x3 diagonal blocks) or ``"diag"`` (Jacobi).
        chunk: Steps per ring buffer of driven input and recorded displacement.
        use_graph: Capture the step as a graph.
        loop: One of :data:`CG_LOOPS`.
    """

    def __init__(
        self,
        matrices: SystemMatrices,
        coefficients: NewmarkCoefficients,
        free_nodes: np.ndarray,
        driven_nodes: np.ndarray,
        *,
        dtype=wp.float64,
        tol: float = 1.0e-5,
        maxiter: int = 200,
        preconditioner: str = "fsai",
        chunk: int = 64,
        use_graph: bool = True,
        loop: str = "auto",
    ):
        if loop not in CG_LOOPS:
            raise ValueError(f"CG loop must be one of {CG_LOOPS}, got {loop!r}")
        if dtype not in (wp.float32, wp.float64):
            raise ValueError(f"CG dtype must be wp.float32 or wp.float64, got {dtype}")
        if preconditioner not in PRECONDITIONERS:
            raise ValueError(f"preconditioner must be one of {PRECONDITIONERS}, got {preconditioner!r}")
        if not (tol > 0.0 and np.isfinite(tol)):
            raise ValueError(f"CG tolerance must be > 0, got {tol}")
        if int(maxiter) < 1:
            raise ValueError(f"CG maxiter must be >= 1, got {maxiter}")
        if int(chunk) < 1:
            raise ValueError(f"chunk must be >= 1, got {chunk}")
        self.device = matrices.device
        dev = self.device
        self.dtype = dtype
        self.maxiter = int(maxiter)
        self.tol = float(tol)
        self.chunk = int(chunk)
        self._kernels = pcg_kernels(dtype, *_block_shape(dev))
        if loop == "auto":
            loop = "persistent" if dev.is_cuda else "launched"
        self.loop = loop
        """``"persistent"`` or ``"launched"`` (see :data:`CG_LOOPS`)."""
        vec = self._kernels.vec
        n = matrices.node_count
        self.node_count = n
        self.free_nodes = np.asarray(free_nodes, dtype=np.int64)
        self.driven_nodes = np.asarray(driven_nodes, dtype=np.int64)
        n_free, n_driven = self.free_nodes.size, self.driven_nodes.size
        self.free_count = n_free

        free_index = np.full(n, -1, dtype=np.int32)
        free_index[self.free_nodes] = np.arange(n_free, dtype=np.int32)
        driven_slot = np.full(n, -1, dtype=np.int32)
        driven_slot[self.driven_nodes] = np.arange(n_driven, dtype=np.int32)

        A_oo, P = newmark_operators(matrices, coefficients, free_index, driven_slot)
        G = preconditioner_factor(A_oo, preconditioner)
        if dtype != wp.float64:
            A_oo = wps.bsr_copy(A_oo, scalar_type=dtype)
            P = wps.bsr_copy(P, scalar_type=dtype)
        A_oo.nnz_sync()
        P.nnz_sync()
        self._A_oo, self._P = A_oo, P
        lower, upper = grouped_factor_rows([G], dtype, device=dev), grouped_factor_rows([G.T], dtype, device=dev)
        self._G = (lower[0], lower[1], lower[2][0])  # the launched loop's kernels take one factor's values
        self._GT = (upper[0], upper[1], upper[2][0])

        # Work arrays (allocated once; captured graphs bind these pointers).
        self.coefficients = coefficients
        scalar = wp.float64 if dtype == wp.float64 else wp.float32
        self._update_constants = [
            *coefficients.update_scalars(scalar),
            scalar(coefficients.dt),
            scalar(coefficients.half_dt_squared),
        ]
        self._free_index = wp.array(free_index, dtype=wp.int32, device=dev)
        self._driven_slot = wp.array(driven_slot, dtype=wp.int32, device=dev)
        # the CG vectors as rows of one work array (the persistent kernel's layout) and their flat scalar views
        # (index 3 node + axis) for the scalar preconditioner factors
        self._work = wp.zeros((WORK_ROWS, n_free), dtype=vec, device=dev)
        self._work_flat = self._work.view(dtype).reshape((WORK_ROWS, 3 * n_free))
        self._r, self._p = self._work[WORK_R : WORK_R + 2], self._work[WORK_P : WORK_P + 2]
        self._x, self._y, self._z, self._q = (self._work[row] for row in (WORK_X, WORK_Y, WORK_Z, WORK_Q))
        self._r_flat = self._work_flat[WORK_R : WORK_R + 2]
        self._q_flat, self._y_flat = self._work_flat[WORK_Q], self._work_flat[WORK_Y]
        self._history = wp.zeros((2, n_free), dtype=vec, device=dev)
        self._guess = wp.zeros(n_free, dtype=vec, device=dev)
        self._slots = wp.zeros((4, self.maxiter + 1, SLOT_SPREAD), dtype=wp.float64, device=dev)
        self._cg_iter = wp.zeros(2, dtype=wp.int32, device=dev)
        self._barrier = wp.zeros(3, dtype=wp.int32, device=dev)  # persistent: [arrivals, gave up, departures]
        if loop == "persistent":
            shape = (PERSISTENT_LANES, PERSISTENT_ROWS) if dev.is_cuda else (1, 1)  # one CPU thread walks every row
            self._persistent = persistent_pcg_kernel(dtype, *shape, single=True)
            wanted = -(-n_free // self._persistent.rows)
            self._persistent_blocks = max(
                1, min(wanted, grid_capacity(self._persistent.cg_step, self._persistent.block_dim, device=dev))
            )
        self._condition = wp.zeros(1, dtype=wp.int32, device=dev)
        self._step_count = wp.zeros(1, dtype=wp.int32, device=dev)
        self._status = wp.zeros(5, dtype=wp.int32, device=dev)
        self._failure = wp.zeros(2, dtype=wp.float64, device=dev)
        # the solver's arrays as the only model of a batch, for the persistent and update kernels
        one = _as_one_model
        self._as_batch = SimpleNamespace(
            P_values=one(P.values),
            A_values=one(A_oo.values),
            G_values=lower[2],
            GT_values=upper[2],
            x=one(self._x),
            work=one(self._work),
            work_flat=one(self._work_flat),
            guess=one(self._guess),
            history=self._history.reshape((2, 1, n_free)),
            slots=one(self._slots),
            cg_iter=one(self._cg_iter),
            barrier=one(self._barrier),
            status=one(self._status),
            failure=one(self._failure),
        )
        # run_chunks' ring of `chunk` driven inputs and recorded displacements (slot index on the device)
        self._trajectory = wp.zeros((self.chunk, max(n_driven, 1)), dtype=vec, device=dev)
        self._record = wp.zeros((self.chunk, n), dtype=vec, device=dev)
        self._ring = wp.zeros(2, dtype=wp.int32, device=dev)
        self._step_ring = wp.zeros(2, dtype=wp.int32, device=dev)  # step(): a ring of one slot, always 0
        self._chunked = None  # run_chunks' host buffers, allocated on its first call
        self._use_graph = bool(use_graph)
        self._graphs: dict = {}
        self._bindings: dict = {}

        # One eager step loads every kernel before any capture; the counters it touches are cleared.
        scratch = TissueState(n, dtype=dtype, device=dev)
        self._launch_sequence(
            self._binding_for_step(scratch, scratch, TissueControl(n_driven, dtype=dtype, device=dev))
        )
        self._bindings.clear()
        self.restart(scratch)

    # ------------------------------------------------------------------ the step
    def _launch_tiled(self, kernel, inputs) -> None:
        k = self._kernels
        blocks = -(-self.free_count // k.rows)
        wp.launch_tiled(kernel, dim=blocks, inputs=inputs, block_dim=k.block_dim, device=self.device)

    def _cg_iterations(self) -> None:
        k, A, tol_sq = self._kernels, self._A_oo, wp.float64(self.tol**2)
        for _ in range(UNROLL):
            self._launch_tiled(
                k.direction,
                [
                    A.offsets,
                    A.columns,
                    A.values,
                    self._z,
                    self._p,
                    self._q,
                    self._slots,
                    self._cg_iter,
                    self._condition,
                    tol_sq,
                    self.maxiter,
                ],
            )
            self._launch_tiled(
                k.lower,
                [
                    *self._G,
                    self._p,
                    self._q,
                    self._q_flat,
                    self._r,
                    self._r_flat,
                    self._x,
                    self._y,
                    self._slots,
                    self._cg_iter,
                    tol_sq,
                    self.maxiter,
                ],
            )
            self._launch_tiled(
                k.upper, [*self._GT, self._y_flat, self._r, self._z, self._slots, self._cg_iter, tol_sq, self.maxiter]
            )

    def _launch_sequence(self, b) -> None:
        k, P, tol_sq = self._kernels, self._P, wp.float64(self.tol**2)
        self._slots.zero_()
        A = self._A_oo
        if self.loop == "persistent":
            step, m = self._persistent, self._as_batch
            wp.launch_tiled(
                step.cg_step,
                dim=self._persistent_blocks,
                block_dim=step.block_dim,
                device=self.device,
                inputs=[
                    P.offsets,
                    P.columns,
                    m.P_values,
                    A.offsets,
                    A.columns,
                    m.A_values,
                    self._G[0],
                    self._G[1],
                    m.G_values,
                    self._GT[0],
                    self._GT[1],
                    m.GT_values,
                    b.d_in,
                    b.v_in,
                    b.a_in,
                    b.trajectory,
                    m.guess,
                    b.ring,
                    m.work,
                    m.work_flat,
                    m.slots,
                    m.cg_iter,
                    m.barrier,
                    tol_sq,
                    self.maxiter,
                    self._persistent_blocks,
                    0,
                ],
            )
        else:
            self._launch_tiled(
                k.residual,
                [
                    P.offsets,
                    P.columns,
                    P.values,
                    A.offsets,
                    A.columns,
                    A.values,
                    b.state[0],
                    b.state[1],
                    b.state[2],
                    b.driven,
                    self._guess,
                    b.ring,
                    self._r,
                    self._x,
                    self._slots,
                    self._cg_iter,
                    self._condition,
                ],
            )
            self._launch_tiled(k.lower_start, [*self._G, self._r, self._r_flat, self._x, self._slots, self._y])
            self._launch_tiled(
                k.upper, [*self._GT, self._y_flat, self._r, self._z, self._slots, self._cg_iter, tol_sq, self.maxiter]
            )
            wp.capture_while(self._condition, self._cg_iterations)
        m = self._as_batch
        wp.launch(
            cg_newmark_update,
            dim=(1, self.node_count),
            inputs=[
                m.x,
                m.history,
                m.guess,
                self._free_index,
                self._driven_slot,
                b.trajectory,
                b.ring,
                *self._update_constants,
                m.slots,
                m.cg_iter,
                tol_sq,
                b.chunk,
                b.d_in,
                b.v_in,
                b.a_in,
            ],
            outputs=[b.d_out, b.v_out, b.a_out, b.record, self._step_count, m.status, m.failure],
            device=self.device,
        )

    @staticmethod
    def _binding(
        state_in: TissueState,
        state_out: TissueState,
        driven: wp.array,
        ring: wp.array,
        record: wp.array,
        chunk: int,
        key,
    ) -> SimpleNamespace:
        """The arrays of one step: ``state`` (d, v, a of ``state_in``) and ``driven`` (chunk, D) for the launched
        loop's kernels; the states, ``trajectory`` (chunk, 1, D) and ``record`` (chunk, 1, N) as the only model of a
        batch for the persistent and update kernels (which also step batches)."""
        one = _as_one_model
        return SimpleNamespace(
            state=(state_in.d, state_in.v, state_in.a),
            driven=driven,
            d_in=one(state_in.d),
            v_in=one(state_in.v),
            a_in=one(state_in.a),
            d_out=one(state_out.d),
            v_out=one(state_out.v),
            a_out=one(state_out.a),
            trajectory=driven.reshape((driven.shape[0], 1, driven.shape[1])),
            ring=ring,
            record=record.reshape((record.shape[0], 1, record.shape[1])),
            chunk=chunk,
            key=key,
        )

    def _binding_for_step(self, state_in: TissueState, state_out: TissueState, control: TissueControl):
        key = ("step", state_in.d.ptr, state_out.d.ptr, control.driven.ptr)
        binding = self._bindings.get(key)
        if binding is None:
            vec, precision = self._kernels.vec, wp.types.type_repr(self.dtype)
            for name, state in (("state_in", state_in), ("state_out", state_out)):
                if (
                    state.node_count != self.node_count
                    or not wp.types.types_equal(state.d.dtype, vec)
                    or state.device != self.device
                ):
                    raise ValueError(f"{name} must hold {self.node_count} nodes of {precision} vec3 on {self.device}")
            if control.driven.shape[0] != self._trajectory.shape[1] or not wp.types.types_equal(
                control.driven.dtype, vec
            ):
                raise ValueError(f"control must hold {self.driven_nodes.size} driven displacements of {precision} vec3")
            binding = self._binding(
                state_in,
                state_out,
                control.driven.reshape((1, control.driven.shape[0])),
                self._step_ring,
                state_out.d.reshape((1, self.node_count)),
                1,
                key,
            )
            self._bindings[key] = binding
        return binding

    def _binding_for_chunks(self, state: TissueState):
        key = ("chunk", state.d.ptr)
        binding = self._bindings.get(key)
        if binding is None:
            binding = self._binding(state, state, self._trajectory, self._ring, self._record, self.chunk, key)
            self._bindings[key] = binding
        return binding

    def _launch(self, binding) -> None:
        if not self._use_graph:
            self._launch_sequence(binding)
            return
        graph = self._graphs.get(binding.key)
        if graph is None:
            with wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
                self._launch_sequence(binding)
            graph = self._graphs[binding.key] = capture.graph
        wp.capture_launch(graph)

    def step(self, state_in: TissueState, state_out: TissueState, control: TissueControl) -> None:
        """Queue one time step from ``state_in`` to ``state_out`` (may be the same object); never waits.

        The first step with a new combination of state and control arrays captures a graph for it
        (on CUDA); alternate between the same two states (or step one state in place) and every
        later step is one ``wp.capture_launch``: no allocation, no host synchronisation. A
        convergence failure is booked on the device and raised by :meth:`synchronize`.

        Raises:
            ValueError: a state or the control does not match the solver (size, type, device).
        """
        self._launch(self._binding_for_step(state_in, state_out, control))

    def run_chunks(self, state: TissueState, driven: np.ndarray):
        """Advance ``state`` in place through driven displacements (T, D, 3) [m], ``chunk`` steps at a time;
        yields each chunk's displacements (k, N, 3) float32, a view of a host staging buffer valid until the next one.

        A chunk is one host-to-device copy of its driven inputs, ``k`` graph launches and one copy back, queued
        before the previous chunk is waited for (:class:`~warpface.fem.chunks.ChunkedRun`): on CUDA the device
        steps on while the host copies a chunk out.

        Raises:
            ConvergenceError: a step of the yielded chunk (or an earlier one) did not converge.
        """
        self.synchronize()
        binding = self._binding_for_chunks(state)
        if self._chunked is None:
            self._chunked = ChunkedRun(
                self._trajectory, self._record, self._ring, self._barrier, self._status, self._failure
            )
        return self._chunked.run(driven, lambda: self._launch(binding), self._raise_on_failure)

    # ------------------------------------------------------------------ status and restart
    def synchronize(self) -> None:
        """Wait for queued steps and raise :class:`ConvergenceError` if any failed."""
        wp.synchronize_device(self.device)
        self._raise_on_failure(self._barrier.numpy(), self._status.numpy(), self._failure.numpy())

    def _raise_on_failure(self, barrier: np.ndarray, status: np.ndarray, failure: np.ndarray) -> None:
        """Raise if the device booked a failure: ``barrier``, ``status`` and ``failure`` as read from the device."""
        if barrier[1]:
            raise RuntimeError(
                f"the persistent CG loop waited too long at a grid barrier on {self.device} (its "
                f"{self._persistent_blocks} blocks were not all resident); use loop='launched' (cg_loop)"
            )
        if status[0]:
            residual, tolerance = failure
            raise ConvergenceError(
                f"CG did not converge at step {int(status[1])} ({int(status[0])} failed steps): residual "
                f"{residual:.3e} > tolerance {tolerance:.3e} after {self.maxiter} iterations; raise cg_maxiter, "
                "loosen cg_tol or use another preconditioner"
            )

    @property
    def iterations(self) -> tuple[int, int]:
        """``(most, last)`` CG iterations per step since the last restart (synchronises)."""
        status = self._status.numpy()
        return int(status[2]), int(status[3])

    @property
    def total_iterations(self) -> int:
        """CG iterations of all steps since the last restart (synchronises)."""
        return int(self._status.numpy()[4])

    def restart(self, state: TissueState) -> None:
        """Start a new trajectory from ``state``: clear counters and failure status, and seed the
        extrapolation with the increments of a motion of constant acceleration that ends in ``state``
        (so the first extrapolated start equals the Newmark predictor). Synchronises."""
        wp.synchronize_device(self.device)
        c = self.coefficients
        host = np.float64 if self.dtype == wp.float64 else np.float32
        _, v, a = state.numpy()
        free_v, free_a = v[self.free_nodes], a[self.free_nodes]
        increments = [c.dt * free_v - c.half_dt_squared * free_a, c.dt * free_v - 3.0 * c.half_dt_squared * free_a]
        self._history.assign(np.stack(increments).astype(host))
        self._guess.zero_()
        self._ring.zero_()
        self._step_ring.zero_()
        self._step_count.zero_()
        self._status.zero_()
        self._failure.zero_()
        self._barrier.zero_()
