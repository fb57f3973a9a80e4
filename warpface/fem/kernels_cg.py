"""Warp kernels of the device Newmark step's preconditioned conjugate gradient (PCG).

The solver of :mod:`warpface.fem.solver_cg` runs CG on ``A_oo δ = r0`` with a preconditioner
in factored form ``M⁻¹ = Gᵀ G`` (FSAI, or the Cholesky factors of Jacobi / 3x3 block Jacobi).
One iteration is three grid-wide phases, the fewest the data dependencies allow:

1. ``direction`` — ``p = z + β p_old`` and ``q = A p`` (``p`` of the neighbours is formed on
   the fly), partial ``p·q``;
2. ``lower`` — ``α = r·z / p·q``, ``x += α p``, ``r_new = r − α q`` and ``y = G r_new``
   (computed as ``G (r − α q)`` from the old ``r`` of the neighbours);
3. ``upper`` — ``z = Gᵀ y`` and the partial ``r·z`` and ``r·r`` of the next iteration.

A step is short of arithmetic (a few hundred thousand multiply-adds per phase) and long on
dependent memory loads, so the kernels are shaped for latency: each free node's matrix row is
shared by ``lanes`` threads of a block of ``rows x lanes`` threads, each computing its part of the
row (:mod:`warpface.fem.kernels_cg_rows`, shared with the persistent loop), and the lanes of a row
are summed in shared memory.
Loads that do not depend on the iteration counter come before the loads that do. Each block
adds its part of a dot product to one of ``SLOT_SPREAD`` float64 slots with one atomic (spreading
the atomics avoids thousands queueing on one address); ``slots[which, k, :]`` sums to ``r·z``
(``RZ``), ``p·q`` (``PQ``) or ``r·r`` (``RR``) of iteration ``k``. The slots are cleared once per
step, not per iteration.

The iteration counter lives on the device: ``cg_iter[0]`` is read by phases 1–2 and advanced
by phase 3, which reads its own copy ``cg_iter[1]`` (written by phase 1), so no kernel writes a
value that other blocks of the same launch read. Each phase first checks whether CG is finished
(``r·r <= tol² |r_predictor|²``, NaN, or ``maxiter`` reached) and then does nothing; phase 1 also
clears the ``wp.capture_while`` condition, so a captured graph loops only while needed. ``r`` and
``p`` are double-buffered by iteration parity because blocks read their neighbours' old values
while writing their own new ones. The vectors are the rows of one work array ``w`` (:data:`WORK_ROWS` x F,
rows ``WORK_R`` …, the persistent kernel's layout) and its flat scalar view ``w_flat``.

The kernels are built by :func:`pcg_kernels` per float type (matrices and vectors of that type;
dot products, ``α`` and ``β`` always float64) and block shape.
"""

import functools
import types

import warp as wp

from .kernels_cg_rows import cg_matrix_types, cg_row_functions

__all__ = [
    "PQ",
    "RR",
    "RZ",
    "SLOT_SPREAD",
    "START",
    "WORK_P",
    "WORK_Q",
    "WORK_R",
    "WORK_ROWS",
    "WORK_X",
    "WORK_Y",
    "WORK_Z",
    "cg_finished",
    "pcg_kernels",
    "slot_total",
]

SLOT_SPREAD = wp.constant(16)
"""Partial-sum slots per dot product and iteration, chosen by ``block % SLOT_SPREAD``."""

RZ, PQ, RR, START = wp.constant(0), wp.constant(1), wp.constant(2), wp.constant(3)
"""First index of ``slots``: which dot product (``START``: ``[0]`` predictor, ``[1]`` extrapolated start)."""

WORK_ROWS = 8
"""Rows of a model's work array: the residual (2, alternating), the direction (2), the solution x, y = G r,
z = Gᵀ y and q = A p, each (F,) vec3 (one array: one base address and stride live in the kernel, not nine)."""
WORK_R, WORK_P, WORK_X, WORK_Y, WORK_Z, WORK_Q = (wp.constant(row) for row in (0, 2, 4, 5, 6, 7))
"""First row of each work vector in the work array."""


@wp.func
def slot_total(slots: wp.array3d(dtype=wp.float64), which: int, k: int):
    """Dot product ``which`` (``RZ``, ``PQ``, ``RR``, ``START``) of iteration ``k``: the sum of its slots."""
    s = wp.float64(0.0)
    for j in range(wp.static(SLOT_SPREAD)):
        s += slots[which, k, j]
    return s


@wp.func
def cg_finished(slots: wp.array3d(dtype=wp.float64), k: int, tol_sq: wp.float64, maxiter: int):
    """CG stops at iteration ``k``: converged (``r·r <= tol² |r_predictor|²``), NaN, or ``k >= maxiter``."""
    return k >= maxiter or not (slot_total(slots, RR, k) > tol_sq * slot_total(slots, START, 0))


@functools.lru_cache(maxsize=None)
def pcg_kernels(dtype, lanes: int = 1, rows: int = 1) -> types.SimpleNamespace:
    """The PCG kernels for ``dtype`` (``wp.float32`` or ``wp.float64``), see the module docstring.

    Launch them with ``wp.launch_tiled(dim=ceil(F / rows), block_dim=rows * lanes)``; on the CPU
    a block has one thread, so build them with ``lanes = rows = 1`` there.

    Vectors are per free node, ``wp.vec3`` of ``dtype``; ``A`` and ``P`` are BSR with 3x3 blocks
    (``BlockRows``: ``offsets`` shape (F + 1,), block column ``indices``, ``values``). ``G`` and ``Gᵀ`` are
    scalar CSR matrices grouped by block row (``FactorRows``): the entries of scalar rows ``3i .. 3i+2`` are
    ``offsets[i] .. offsets[i+1]``, and ``indices[e] = 3 * column + row % 3``. No (block) row may be empty;
    the rows of all four hold at least their diagonal. Build the matrix arguments with
    :func:`~warpface.fem.kernels_cg_rows.cg_matrix`.
    """
    matrices = cg_matrix_types(dtype)
    vec, BlockRows, FactorRows = matrices.vec, matrices.BlockRows, matrices.FactorRows
    fetch_a, fetch_g, residual_part, direction_part, factor_part = cg_row_functions(dtype, lanes)
    spread = SLOT_SPREAD

    @wp.func
    def place(block: int, thread: int, count: int):
        # (row, lane, row within the block, clamped row to read) of this thread
        local = thread // lanes
        row = block * rows + local
        return row, thread - local * lanes, local, wp.min(row, count - 1)

    @wp.func
    def row_sum(part: vec, local: int, lane: int):
        # sum of the lanes' parts of this thread's row
        sums = wp.tile_zeros(shape=(rows, lanes), dtype=vec, storage="shared")
        wp.tile_scatter_add(sums, local, lane, part, True, False)
        return wp.tile_extract(wp.tile_sum(sums, axis=1), local)

    @wp.func
    def block_sum(x: wp.float64):
        return wp.tile_extract(wp.tile_sum(wp.tile(x)), 0)

    @wp.kernel(enable_backward=False, module="unique")
    def residual(
        P: BlockRows,
        A: BlockRows,
        d: wp.array(dtype=vec),
        v: wp.array(dtype=vec),
        a: wp.array(dtype=vec),
        trajectory: wp.array2d(dtype=vec),
        guess: wp.array(dtype=vec),
        force: wp.array(dtype=vec),
        free_nodes: wp.array(dtype=wp.int32),
        ring: wp.array(dtype=wp.int32),
        w: wp.array2d(dtype=vec),
        slots: wp.array3d(dtype=wp.float64),
        cg_iter: wp.array(dtype=wp.int32),
        condition: wp.array(dtype=wp.int32),
    ):
        """Residuals of the two starting points: ``r[1] = P [d; v; a; t] + f``, ``r[0] = r[1] − A guess``.

        ``r[1]`` is the residual of the Newmark predictor ``d + dt v + dt²/2 a`` (``P`` from the
        solver; its columns ``[0, N)`` multiply ``d``, ``[N, 2N)`` ``v``, ``[2N, 3N)`` ``a`` and
        ``[3N, 3N + D)`` the driven displacements ``trajectory[ring[0]]`` at the end of the step);
        ``r[0]`` that of the predictor plus ``guess`` (the extrapolation of the solver); ``f`` is the external
        nodal force ``force[free_nodes[row]]`` (N,), none when ``force`` is empty. Sets
        ``x = guess`` and slots ``START`` ``[0]``, ``[1]`` to ``|r[1]|²``, ``|r[0]|²``. Also starts the
        CG counters and copies ``ring[0]`` to ``ring[1]`` for the update kernel.
        """
        block, thread = wp.tid()
        row, lane, local, i = place(block, thread, w.shape[1])
        slot = ring[0]
        acc, correction = residual_part(i, lane, P, A, d, v, a, trajectory[slot], guess, force, free_nodes)
        start_x = guess[i]
        predicted = row_sum(acc, local, lane)
        extrapolated = predicted - row_sum(correction, local, lane)
        mine = row < w.shape[1] and lane == 0
        if mine:
            w[WORK_R, i] = extrapolated
            w[WORK_R + 1, i] = predicted
            w[WORK_X, i] = start_x
        predicted_sq = block_sum(wp.where(mine, wp.float64(wp.dot(predicted, predicted)), wp.float64(0.0)))
        extrapolated_sq = block_sum(wp.where(mine, wp.float64(wp.dot(extrapolated, extrapolated)), wp.float64(0.0)))
        if thread == 0:
            wp.atomic_add(slots, START, 0, block % spread, predicted_sq)
            wp.atomic_add(slots, START, 1, block % spread, extrapolated_sq)
            if block == 0:
                ring[1] = slot
                cg_iter[0] = 0
                cg_iter[1] = -1
                condition[0] = 1

    @wp.kernel(enable_backward=False, module="unique")
    def direction(
        A: BlockRows,
        w: wp.array2d(dtype=vec),
        slots: wp.array3d(dtype=wp.float64),
        cg_iter: wp.array(dtype=wp.int32),
        condition: wp.array(dtype=wp.int32),
        tol_sq: wp.float64,
        maxiter: int,
    ):
        """Phase 1: ``p[k % 2] = z + β p[(k+1) % 2]``, ``q = A p``, slots ``PQ`` += ``p·q``."""
        block, thread = wp.tid()
        row, lane, local, i = place(block, thread, w.shape[1])
        k = cg_iter[0]
        start, end, cols = fetch_a(A, i, lane)
        rz = slot_total(slots, RZ, k)
        rz_old = slot_total(slots, RZ, wp.max(k - 1, 0))
        if block == 0 and thread == 0:
            cg_iter[1] = k
        if cg_finished(slots, k, tol_sq, maxiter):
            if block == 0 and thread == 0:
                condition[0] = 0
            return
        beta = dtype(0.0)
        if k > 0:
            beta = dtype(rz / rz_old)
        new = k % 2
        z = w[WORK_Z]
        p_old = w[WORK_P + 1 - new]  # at k = 0 the previous step's (finite) direction, times β = 0
        pi = z[i] + beta * p_old[i]
        qi = row_sum(direction_part(start, end, cols, lane, A, z, p_old, beta), local, lane)
        mine = row < w.shape[1] and lane == 0
        pq = wp.float64(0.0)
        if mine:
            w[WORK_P + new, i] = pi
            w[WORK_Q, i] = qi
            pq = wp.float64(wp.dot(pi, qi))
        pq = block_sum(pq)
        if thread == 0:
            wp.atomic_add(slots, PQ, k, block % spread, pq)

    @wp.kernel(enable_backward=False, module="unique")
    def lower(
        G: FactorRows,
        w: wp.array2d(dtype=vec),
        w_flat: wp.array2d(dtype=dtype),
        slots: wp.array3d(dtype=wp.float64),
        cg_iter: wp.array(dtype=wp.int32),
        tol_sq: wp.float64,
        maxiter: int,
    ):
        """Phase 2: ``x += α p``, ``r[(k+1) % 2] = r[k % 2] − α q`` and ``y = G r_new``."""
        block, thread = wp.tid()
        row, lane, local, i = place(block, thread, w.shape[1])
        k = cg_iter[0]
        start, end, found = fetch_g(G, i, lane)
        rz = slot_total(slots, RZ, k)
        pq = slot_total(slots, PQ, k)
        if cg_finished(slots, k, tol_sq, maxiter):
            return
        alpha = dtype(rz / pq)
        cur = k % 2
        x_new = w[WORK_X, i] + alpha * w[WORK_P + cur, i]
        r_new = w[WORK_R + cur, i] - alpha * w[WORK_Q, i]
        yi = row_sum(factor_part(start, end, found, lane, G, w_flat[WORK_R + cur], w_flat[WORK_Q], alpha), local, lane)
        if row < w.shape[1] and lane == 0:
            w[WORK_X, i] = x_new
            w[WORK_R + 1 - cur, i] = r_new
            w[WORK_Y, i] = yi

    @wp.kernel(enable_backward=False, module="unique")
    def lower_start(
        G: FactorRows,
        w: wp.array2d(dtype=vec),
        w_flat: wp.array2d(dtype=dtype),
        slots: wp.array3d(dtype=wp.float64),
    ):
        """Start from the better of the two points of ``residual``; ``y = G r[0]``.

        If the extrapolated start has the larger residual (the motion was not smooth), ``r[0]``
        and ``x`` are reset to the predictor's (``r[1]``, zero correction).
        """
        block, thread = wp.tid()
        row, lane, local, i = place(block, thread, w.shape[1])
        start, end, found = fetch_g(G, i, lane)
        use = 0
        if not (slot_total(slots, START, 1) <= slot_total(slots, START, 0)):
            use = 1
        r_use = w_flat[WORK_R + use]
        yi = row_sum(factor_part(start, end, found, lane, G, r_use, r_use, dtype(0.0)), local, lane)
        if row < w.shape[1] and lane == 0:
            w[WORK_Y, i] = yi
            if use == 1:
                w[WORK_R, i] = w[WORK_R + 1, i]
                w[WORK_X, i] = vec()

    @wp.kernel(enable_backward=False, module="unique")
    def upper(
        GT: FactorRows,
        w: wp.array2d(dtype=vec),
        w_flat: wp.array2d(dtype=dtype),
        slots: wp.array3d(dtype=wp.float64),
        cg_iter: wp.array(dtype=wp.int32),
        tol_sq: wp.float64,
        maxiter: int,
    ):
        """Phase 3: ``z = Gᵀ y``; slots ``RZ``, ``RR`` of iteration k+1 += ``r·z``, ``r·r``; ``k += 1``.

        With ``cg_iter[1] == -1`` (set by ``residual``) it starts CG: ``z = M⁻¹ r[0]``.
        """
        block, thread = wp.tid()
        row, lane, local, i = place(block, thread, w.shape[1])
        k = cg_iter[1]
        start, end, found = fetch_g(GT, i, lane)
        if cg_finished(slots, wp.max(k, 0), tol_sq, maxiter) and k >= 0:
            return
        ri = w[WORK_R + (k + 1) % 2, i]
        y_flat = w_flat[WORK_Y]
        zi = row_sum(factor_part(start, end, found, lane, GT, y_flat, y_flat, dtype(0.0)), local, lane)
        rz = wp.float64(0.0)
        rr = wp.float64(0.0)
        if row < w.shape[1] and lane == 0:
            w[WORK_Z, i] = zi
            rz = wp.float64(wp.dot(ri, zi))
            rr = wp.float64(wp.dot(ri, ri))
        rz = block_sum(rz)
        rr = block_sum(rr)
        if thread == 0:
            wp.atomic_add(slots, RZ, k + 1, block % spread, rz)
            wp.atomic_add(slots, RR, k + 1, block % spread, rr)
            if block == 0:
                cg_iter[0] = k + 1

    return types.SimpleNamespace(
        vec=vec,
        block_dim=rows * lanes,
        rows=rows,
        residual=residual,
        direction=direction,
        lower=lower,
        lower_start=lower_start,
        upper=upper,
    )
