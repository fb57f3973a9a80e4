"""Device Newmark stepper: preconditioned CG from ``warp.optim.linear``, whole step in one graph.

Everything lives on the Warp device. One step is

1. :func:`newmark_predict` — stacked input ``z = [c0 d + c1 v + c2 a; c3 d + c4 v + c5 a; d_driven]``
   and the warm start ``x~ = d + dt v + dt²/2 a`` of the free nodes;
2. ``b = R z − A_oo x~`` with ``R = [M_o*, C_o*, −A_od]`` stacked into one BSR matrix (one product
   instead of three) — the residual of the warm start;
3. CG on ``A_oo δ = b`` from ``δ = 0`` with ``check_every=0``: convergence is tested on the device
   (a conditional while-node on CUDA), so the tolerance is relative to the warm start's residual,
   not to the size of the displacement;
4. :func:`cg_status` — failed-step count, residual and iteration counts, kept on the device;
5. :func:`newmark_update` — ``d = x~ + δ`` (or the driven/fixed value), Newmark ``a`` and ``v``
   in place, and the displacement recorded into a ring buffer of ``chunk`` steps.

On CUDA the sequence is captured once with ``wp.ScopedCapture`` and each step is one
``wp.capture_launch``: no allocation, no host read-back. The host looks at the status only
at synchronisation points (reading the state, the end of each ``chunk`` in
:meth:`CGStepper.run_chunk`, or when the trajectory ring wraps in :meth:`CGStepper.step`).
"""

from __future__ import annotations

import numpy as np
import warp as wp
import warp.sparse as wps
from warp.optim.linear import FSAI, cg
from warp.optim.linear import preconditioner as make_preconditioner

from .assembly import SystemMatrices, partition_bsr
from .kernels_integrator import advance_counter, cg_status, newmark_predict, newmark_update

__all__ = ["CGStepper", "ConvergenceError", "PRECONDITIONERS"]

PRECONDITIONERS = ("fsai", "block_jacobi", "diag")

# FSAI factor entries per row. On the 6.7k-node face shell at dt = 1e-3 (Kato's material), CG to a
# 1e-6 relative residual took 148 iterations with Jacobi, 129 with 3x3 block Jacobi and 54 / 43 / 33
# with FSAI rows of 8 / 16 / 32 entries. A step on a GPU is bound by launch latency, not by the
# arithmetic of a longer row, so fewer iterations win.
FSAI_ROW_SIZE = 32


class ConvergenceError(RuntimeError):
    """The iterative solver did not reach its tolerance within its iteration limit."""


class CGStepper:
    """Newmark steps on a Warp device with graph-captured preconditioned CG.

    Args:
        matrices: K, M, C assembled on the target device (float64).
        coeffs: :func:`~warpface.fem.newmark.newmark_coefficients`.
        free_nodes: Nodes solved for, shape (F,), int.
        driven_nodes: Nodes with prescribed displacement, shape (D,), int.
        dtype: ``wp.float32`` or ``wp.float64`` for the solver and the state.
        tol: CG tolerance relative to the warm start's residual norm.
        maxiter: CG iteration limit per step.
        preconditioner: ``"fsai"`` (adaptive factorised sparse approximate inverse, ``FSAI_ROW_SIZE``),
            ``"block_jacobi"`` (inverse 3x3 diagonal blocks) or ``"diag"`` (Jacobi).
        chunk: Steps per ring buffer of driven input and recorded displacement.
        use_graph: Capture the step as a graph (CPU capture is supported by Warp, but the CG
            loop then runs ``maxiter`` iterations unconditionally).
    """

    def __init__(
        self,
        matrices: SystemMatrices,
        coeffs: np.ndarray,
        free_nodes: np.ndarray,
        driven_nodes: np.ndarray,
        *,
        dtype=wp.float64,
        tol: float = 1.0e-5,
        maxiter: int = 200,
        preconditioner: str = "fsai",
        chunk: int = 64,
        use_graph: bool = True,
    ):
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
        vec = wp.types.vector(length=3, dtype=dtype)
        n = matrices.node_count
        self.node_count = n
        self.free_nodes = np.asarray(free_nodes, dtype=np.int64)
        self.driven_nodes = np.asarray(driven_nodes, dtype=np.int64)
        n_free, n_driven = self.free_nodes.size, self.driven_nodes.size

        free_index = np.full(n, -1, dtype=np.int32)
        free_index[self.free_nodes] = np.arange(n_free, dtype=np.int32)
        driven_slot = np.full(n, -1, dtype=np.int32)
        driven_slot[self.driven_nodes] = np.arange(n_driven, dtype=np.int32)

        # A = K + c0 M + c3 C, then its free/driven blocks and the stacked right-hand-side operator.
        A = wps.bsr_copy(matrices.K)
        wps.bsr_axpy(matrices.M, A, alpha=float(coeffs[0]))
        wps.bsr_axpy(matrices.C, A, alpha=float(coeffs[3]))
        identity = np.arange(n, dtype=np.int32)
        A_oo = partition_bsr([(A, free_index, 0, 1.0)], free_index, n_free, n_free, device=dev)
        R = partition_bsr(
            [(matrices.M, identity, 0, 1.0), (matrices.C, identity, n, 1.0), (A, driven_slot, 2 * n, -1.0)],
            free_index,
            n_free,
            2 * n + n_driven,
            device=dev,
        )
        if dtype != wp.float64:
            A_oo = wps.bsr_copy(A_oo, scalar_type=dtype)
            R = wps.bsr_copy(R, scalar_type=dtype)
        A_oo.nnz_sync()
        R.nnz_sync()
        self._A_oo, self._R = A_oo, R
        if preconditioner == "fsai":
            self._precond = FSAI(A_oo, max_row_size=FSAI_ROW_SIZE)
        elif preconditioner == "block_jacobi":
            self._precond = make_preconditioner(A_oo, "block_jacobi_direct")
        else:
            self._precond = make_preconditioner(A_oo, "diag")

        # Device state and work arrays (allocated once; the captured graph binds these pointers).
        self._free_index = wp.array(free_index, dtype=wp.int32, device=dev)
        self._driven_slot = wp.array(driven_slot, dtype=wp.int32, device=dev)
        self._coeffs = wp.array(np.asarray(coeffs), dtype=dtype, device=dev)
        self._d = wp.zeros(n, dtype=vec, device=dev)
        self._v = wp.zeros(n, dtype=vec, device=dev)
        self._a = wp.zeros(n, dtype=vec, device=dev)
        self._stacked = wp.zeros(2 * n + n_driven, dtype=vec, device=dev)
        self._predicted = wp.zeros(n_free, dtype=vec, device=dev)
        self._rhs = wp.zeros(n_free, dtype=vec, device=dev)
        self._delta = wp.zeros(n_free, dtype=vec, device=dev)
        self._trajectory = wp.zeros((self.chunk, max(n_driven, 1)), dtype=vec, device=dev)
        self._record = wp.zeros((self.chunk, n), dtype=vec, device=dev)
        self._counter = wp.zeros(1, dtype=wp.int32, device=dev)
        self._step_count = wp.zeros(1, dtype=wp.int32, device=dev)
        self._status = wp.zeros(4, dtype=wp.int32, device=dev)
        self._failure = wp.zeros(2, dtype=wp.float64, device=dev)
        pinned = dev.is_cuda
        self._staging_in = wp.zeros((self.chunk, max(n_driven, 1)), dtype=vec, device="cpu", pinned=pinned)
        self._staging_out = wp.zeros((self.chunk, n), dtype=vec, device="cpu", pinned=pinned)
        self._slot = 0  # host mirror of _counter

        self._cg = cg(
            A_oo,
            self._rhs,
            self._delta,
            tol=self.tol,
            atol=0.0,
            maxiter=self.maxiter,
            M=self._precond,
            check_every=0,
            use_cuda_graph=True,
            run=False,
        )

        # One eager step loads every kernel (generic overloads included) before capture; the
        # state it touches is restored afterwards.
        self._graph = None
        self._launch_sequence()
        self.set_state(np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)))
        if use_graph:
            with wp.ScopedCapture(device=dev, force_module_load=False) as capture:
                self._launch_sequence()
            self._graph = capture.graph

    # ------------------------------------------------------------------ the step
    def _launch_sequence(self) -> None:
        dev, n = self.device, self.node_count
        wp.launch(
            newmark_predict,
            dim=n,
            inputs=[self._d, self._v, self._a, self._free_index, self._driven_slot, self._trajectory,
                    self._counter, self._coeffs],
            outputs=[self._stacked, self._predicted],
            device=dev,
        )
        wps.bsr_mv(self._R, self._stacked, self._rhs, alpha=1.0, beta=0.0)
        wps.bsr_mv(self._A_oo, self._predicted, self._rhs, alpha=-1.0, beta=1.0)
        self._delta.zero_()
        iterations, residual_sq, tolerance_sq = self._cg()
        wp.launch(
            cg_status,
            dim=1,
            inputs=[iterations, residual_sq, tolerance_sq, self._step_count],
            outputs=[self._status, self._failure],
            device=dev,
        )
        wp.launch(
            newmark_update,
            dim=n,
            inputs=[self._predicted, self._delta, self._free_index, self._driven_slot, self._trajectory,
                    self._counter, self._coeffs],
            outputs=[self._d, self._v, self._a, self._record],
            device=dev,
        )
        wp.launch(advance_counter, dim=1, inputs=[self._counter, self._step_count, self.chunk], device=dev)

    def _launch_step(self) -> None:
        if self._graph is not None:
            wp.capture_launch(self._graph)
        else:
            self._launch_sequence()

    def step(self, driven: np.ndarray) -> None:
        """Queue one step with driven displacements [m], shape (D, 3); does not wait for the device.

        The driven values go through a pinned ring of ``chunk`` slots; when it wraps, the host
        waits for the device once and checks convergence of the last ``chunk`` steps.
        """
        slot = self._slot
        if driven.size:
            self._staging_in.numpy()[slot] = driven
            wp.copy(self._trajectory, self._staging_in, dest_offset=slot * self._trajectory.shape[1],
                    src_offset=slot * self._trajectory.shape[1], count=self._trajectory.shape[1])
        self._launch_step()
        self._slot = (slot + 1) % self.chunk
        if self._slot == 0:
            self.synchronize()

    def run_chunk(self, driven: np.ndarray) -> np.ndarray:
        """Run ``k <= chunk`` steps, driven displacements shape (k, D, 3); returns displacements (k, N, 3).

        The result is a view of a host staging buffer, valid until the next call.

        Raises:
            ConvergenceError: a step of this chunk (or an earlier queued one) did not converge.
        """
        k = driven.shape[0]
        if not 0 < k <= self.chunk:
            raise ValueError(f"run_chunk needs 1..{self.chunk} steps, got {k}")
        self.synchronize()
        self._counter.zero_()
        self._slot = 0
        width = self._trajectory.shape[1]
        if driven.shape[1]:
            self._staging_in.numpy()[:k] = driven
            wp.copy(self._trajectory, self._staging_in, count=k * width)
        for _ in range(k):
            self._launch_step()
        wp.copy(self._staging_out, self._record, count=k * self.node_count)
        self._slot = k % self.chunk
        self.synchronize()
        return self._staging_out.numpy()[:k]

    # ------------------------------------------------------------------ status and state
    def synchronize(self) -> None:
        """Wait for queued steps and raise :class:`ConvergenceError` if any failed."""
        wp.synchronize_device(self.device)
        status = self._status.numpy()
        if status[0]:
            residual, tolerance = self._failure.numpy()
            raise ConvergenceError(
                f"CG did not converge at step {int(status[1])} ({int(status[0])} failed steps): residual "
                f"{residual:.3e} > tolerance {tolerance:.3e} after {self.maxiter} iterations; raise cg_maxiter, "
                "loosen cg_tol or use another preconditioner"
            )

    @property
    def iterations(self) -> tuple[int, int]:
        """``(most, last)`` CG iterations per step since the last state reset (synchronises)."""
        status = self._status.numpy()
        return int(status[2]), int(status[3])

    def state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(d, v, a)`` as float64 NumPy arrays, shape (N, 3) each (synchronises, checks status)."""
        self.synchronize()
        return tuple(x.numpy().astype(np.float64) for x in (self._d, self._v, self._a))

    def set_state(self, d: np.ndarray, v: np.ndarray, a: np.ndarray) -> None:
        """Replace the state (each (N, 3)) and clear counters and failure status."""
        wp.synchronize_device(self.device)
        for dest, src in ((self._d, d), (self._v, v), (self._a, a)):
            dest.assign(np.asarray(src, dtype=np.float64).astype(np.float64 if self.dtype == wp.float64 else np.float32))
        self._counter.zero_()
        self._step_count.zero_()
        self._status.zero_()
        self._failure.zero_()
        self._slot = 0
