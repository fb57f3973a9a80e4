"""``A x = b`` on the tissue's free nodes, solved on the device with no host read: the capturable path's solves.

``A = A_oo + H`` is the free-free Newmark system of the tissue's step (:func:`warpface.fem.cg_setup.newmark_operators`)
plus an optional 3x3 term per node ``H_o`` (the capturable contacts' penalty, docs/NEWTON.md §3). The solve is the
preconditioned CG of the tissue's own device solver (:mod:`warpface.fem.kernels_cg`: its FSAI or block-Jacobi
factor of ``A_oo``, three kernels an iteration in a ``wp.capture_while`` loop that stops on the device), started
from the better of ``x = 0`` and the previous solution (a warm start), stopping at ``‖r‖ <= tol ‖b‖``. Every
launch has a fixed shape; nothing is read back, so the solve can be captured in a graph.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..fem.cg_setup import grouped_factor_rows, newmark_operators, preconditioner_factor
from ..fem.kernels_cg import RR, SLOT_SPREAD, START, WORK_P, WORK_R, WORK_ROWS, WORK_X, pcg_kernels, slot_total
from ..fem.kernels_cg_rows import cg_matrix, cg_matrix_types
from ..fem.solver_cg import LANES, ROWS_PER_BLOCK, UNROLL
from .kernels import Blocks, Indices, Vectors

__all__ = ["FreeSystem"]

_BlockRows = cg_matrix_types(wp.float64).BlockRows
_Work = wp.array2d(dtype=wp.vec3d)  # the CG's work vectors (WORK_ROWS, F)
_Slots = wp.array3d(dtype=wp.float64)  # its dot-product slots


@wp.kernel
def _start(
    A: _BlockRows,
    b: Vectors,
    x: Vectors,
    w: _Work,
    slots: _Slots,
    cg_iter: Indices,
    condition: Indices,
):
    """The two starting points of CG: ``r[0] = b − A x`` (warm start ``x``), ``r[1] = b`` (``x = 0``); slots
    ``START`` get ``|b|²`` (the tolerance's reference) and ``|r[0]|²``; the counters start."""
    o = wp.tid()
    ax = wp.vec3d()
    for e in range(A.offsets[o], A.offsets[o + 1]):
        ax += A.values[e] * x[A.indices[e]]
    r = b[o] - ax
    w[WORK_R, o] = r
    w[WORK_R + 1, o] = b[o]
    w[WORK_X, o] = x[o]
    w[WORK_P + 1, o] = wp.vec3d()  # the first direction's β p_old: finite
    wp.atomic_add(slots, START, 0, o % SLOT_SPREAD, wp.dot(b[o], b[o]))
    wp.atomic_add(slots, START, 1, o % SLOT_SPREAD, wp.dot(r, r))
    if o == 0:
        cg_iter[0] = 0
        cg_iter[1] = -1
        condition[0] = 1


@wp.kernel
def _finish(
    w: _Work,
    slots: _Slots,
    cg_iter: Indices,
    tol_sq: wp.float64,
    x: Vectors,
    failed: Indices,
):
    """``x`` = the solution; ``failed[0]`` counts solves that stopped above the tolerance (or at NaN)."""
    o = wp.tid()
    x[o] = w[WORK_X, o]
    if o == 0:
        k = cg_iter[0]
        if not (slot_total(slots, RR, k) <= tol_sq * slot_total(slots, START, 0)):
            failed[0] = failed[0] + 1


@wp.kernel
def _penalised_diagonal(base: Blocks, diagonal: Indices, extra: Blocks, values: Blocks):
    """The diagonal blocks of ``A_oo + H``: ``values[diag o] = base[diag o] + extra[o]``."""
    o = wp.tid()
    e = diagonal[o]
    values[e] = base[e] + extra[o]


class FreeSystem:
    """Device solves of ``(A_oo + H) x = b`` for one :class:`~warpface.fem.TissueSimulation` (module docstring).

    Args:
        simulation: The tissue's simulation (its matrices, Newmark constants, node split and CG options).

    Attributes ``diagonal_blocks`` (the 3x3 blocks ``A_oo[o, o]``, (F,) mat33d) and ``failed`` (a device counter
    of solves that did not reach the tolerance) are read by the caller's kernels.
    """

    def __init__(self, simulation):
        sim = simulation
        options = sim.solver.options
        device = self.device = sim.device
        n, free = sim.node_count, sim.free_nodes
        f = self.free_count = free.size
        free_index = np.full(n, -1, dtype=np.int32)
        free_index[free] = np.arange(f, dtype=np.int32)
        driven_slot = np.full(n, -1, dtype=np.int32)
        driven_slot[sim.driven_nodes] = np.arange(sim.driven_nodes.size, dtype=np.int32)
        A_oo, _ = newmark_operators(sim.matrices, sim.coefficients, free_index, driven_slot)
        G = preconditioner_factor(A_oo, options.preconditioner)
        structs = cg_matrix_types(wp.float64)
        self._base = A_oo.values
        self._values = wp.clone(A_oo.values)
        self._A = cg_matrix(structs.BlockRows, A_oo.offsets, A_oo.columns, A_oo.values)
        self._A_penalised = cg_matrix(structs.BlockRows, A_oo.offsets, A_oo.columns, self._values)
        self._factors = [
            cg_matrix(structs.FactorRows, offsets, keys, values[0])
            for offsets, keys, values in (grouped_factor_rows([M], wp.float64, device=device) for M in (G, G.T))
        ]
        offsets, columns = A_oo.offsets.numpy(), A_oo.columns.numpy()
        rows = np.repeat(np.arange(f), np.diff(offsets[: f + 1]))
        entries = np.flatnonzero(columns[: offsets[f]] == rows)
        self._diagonal = wp.array(entries.astype(np.int32), dtype=wp.int32, device=device)
        self.diagonal_blocks = wp.array(A_oo.values.numpy()[entries], dtype=wp.mat33d, device=device)
        """The 3x3 diagonal blocks of ``A_oo``, shape (F,)."""
        lanes, rows_per_block = (LANES, ROWS_PER_BLOCK) if device.is_cuda or wp.config.enable_cpu_blocks else (1, 1)
        self._kernels = pcg_kernels(wp.float64, lanes, rows_per_block)
        self._tol_sq = wp.float64(options.tolerance**2)
        self._maxiter = options.maxiter
        self._work = wp.zeros((WORK_ROWS, f), dtype=wp.vec3d, device=device)
        self._work_flat = self._work.view(wp.float64).reshape((WORK_ROWS, 3 * f))
        self._slots = wp.zeros((4, options.maxiter + 1, SLOT_SPREAD), dtype=wp.float64, device=device)
        self._cg_iter = wp.zeros(2, dtype=wp.int32, device=device)
        self._condition = wp.zeros(1, dtype=wp.int32, device=device)
        self.failed = wp.zeros(1, dtype=wp.int32, device=device)
        """Solves that stopped above the tolerance (device counter)."""
        self._graphs: dict = {}

    def vector(self) -> wp.array:
        """A zero free-node vector, shape (F,) vec3d."""
        return wp.zeros(self.free_count, dtype=wp.vec3d, device=self.device)

    def penalise(self, extra: wp.array) -> None:
        """Set ``H`` (per free node 3x3, (F,) mat33d) of the next :meth:`solve` with ``penalised=True``."""
        wp.launch(
            _penalised_diagonal,
            dim=self.free_count,
            inputs=[self._base, self._diagonal, extra, self._values],
            device=self.device,
        )

    def solve(self, b: wp.array, x: wp.array, *, penalised: bool = False) -> None:
        """``x`` <- the solution of ``A x = b`` (``A_oo``, or ``A_oo + H`` with ``penalised``), started from the
        better of ``x`` and zero. Queues the launches; never waits: on CUDA outside a capture the solve is a graph
        of its own (captured once per set of arrays), since ``wp.capture_while`` run eagerly polls its condition."""
        if not self.device.is_cuda or self.device.is_capturing:
            self._queue(b, x, penalised)
            return
        key = (b.ptr, x.ptr, penalised)
        graph = self._graphs.get(key)
        if graph is None:
            with wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
                self._queue(b, x, penalised)
            graph = self._graphs[key] = capture.graph
        wp.capture_launch(graph)

    def _queue(self, b: wp.array, x: wp.array, penalised: bool) -> None:
        A = self._A_penalised if penalised else self._A
        w, w_flat, slots, cg_iter, device = self._work, self._work_flat, self._slots, self._cg_iter, self.device
        lower, upper = self._factors
        k = self._kernels
        slots.zero_()
        wp.launch(_start, dim=self.free_count, inputs=[A, b, x, w, slots, cg_iter, self._condition], device=device)
        self._tiled(k.lower_start, [lower, w, w_flat, slots])
        self._tiled(k.upper, [upper, w, w_flat, slots, cg_iter, self._tol_sq, self._maxiter])

        def iterations():
            for _ in range(UNROLL):
                self._tiled(k.direction, [A, w, slots, cg_iter, self._condition, self._tol_sq, self._maxiter])
                self._tiled(k.lower, [lower, w, w_flat, slots, cg_iter, self._tol_sq, self._maxiter])
                self._tiled(k.upper, [upper, w, w_flat, slots, cg_iter, self._tol_sq, self._maxiter])

        wp.capture_while(self._condition, iterations)
        wp.launch(_finish, dim=self.free_count, inputs=[w, slots, cg_iter, self._tol_sq, x, self.failed], device=device)

    def _tiled(self, kernel, inputs) -> None:
        blocks = -(-self.free_count // self._kernels.rows)
        wp.launch_tiled(kernel, dim=blocks, inputs=inputs, block_dim=self._kernels.block_dim, device=self.device)
