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
shared by ``lanes`` threads of a block of ``rows x lanes`` threads, every thread loads its first
few entries of the row in straight-line code (all loads in flight at once; a thread per row would
walk 15–96 entries one after another), and the lanes of a row are summed in shared memory.
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
while writing their own new ones.

The kernels are built by :func:`pcg_kernels` per float type (matrices and vectors of that type;
dot products, ``α`` and ``β`` always float64) and block shape.
"""

import functools
import math
import types

import warp as wp

__all__ = ["PQ", "RR", "RZ", "SLOT_SPREAD", "START", "cg_finished", "pcg_kernels", "slot_total"]

SLOT_SPREAD = wp.constant(16)
"""Partial-sum slots per dot product and iteration, chosen by ``block % SLOT_SPREAD``."""

RZ, PQ, RR, START = wp.constant(0), wp.constant(1), wp.constant(2), wp.constant(3)
"""First index of ``slots``: which dot product (``START``: ``[0]`` predictor, ``[1]`` extrapolated start)."""

# Row entries covered by the straight-line (unrolled) part of a row loop; longer rows finish
# in an ordinary loop. Block rows of A_oo hold about 15 blocks (up to ~30); rows of P three
# times that; a block row of an FSAI factor up to 3 x 32 scalars.
_SPAN_A, _SPAN_P, _SPAN_G, _MAX_UNROLL = 32, 64, 96, 8


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
    (``offsets`` shape (F + 1,), ``columns``, ``values``). ``G`` and ``Gᵀ`` are scalar CSR
    matrices grouped by block row: the entries of scalar rows ``3i .. 3i+2`` are ``offsets[i] ..
    offsets[i+1]``, and ``keys[e] = 3 * column + row % 3``. No (block) row may be empty; the
    rows of all four hold at least their diagonal.
    """
    vec = wp.types.vector(length=3, dtype=dtype)
    mat = wp.types.matrix(shape=(3, 3), dtype=dtype)
    spread = SLOT_SPREAD
    unroll_a, unroll_p, unroll_g = (min(math.ceil(span / lanes), _MAX_UNROLL) for span in (_SPAN_A, _SPAN_P, _SPAN_G))

    index_a = wp.types.vector(length=unroll_a, dtype=wp.int32)
    index_g = wp.types.vector(length=unroll_g, dtype=wp.int32)

    @wp.func
    def fetch_a(columns: wp.array(dtype=wp.int32), start: int, end: int, lane: int):
        # the columns of this lane's straight-line entries (clamped to the row: rows are never empty)
        cols = index_a()
        for s in range(wp.static(unroll_a)):
            cols[s] = columns[wp.min(start + lane + s * lanes, end - 1)]
        return cols

    @wp.func
    def fetch_g(keys: wp.array(dtype=wp.int32), start: int, end: int, lane: int):
        found = index_g()
        for s in range(wp.static(unroll_g)):
            found[s] = keys[wp.min(start + lane + s * lanes, end - 1)]
        return found

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

    @wp.func
    def unit(axis: int, value: dtype):
        # value * e_axis without indexing a vector by a runtime value (that spills it to local memory)
        zero = dtype(0.0)
        return vec(wp.where(axis == 0, value, zero), wp.where(axis == 1, value, zero), wp.where(axis == 2, value, zero))

    @wp.func
    def state_entry(
        e: int,
        columns: wp.array(dtype=wp.int32),
        values: wp.array(dtype=mat),
        d: wp.array(dtype=vec),
        v: wp.array(dtype=vec),
        a: wp.array(dtype=vec),
        driven: wp.array(dtype=vec),
    ):
        c = columns[e]
        n = d.shape[0]
        u = vec()
        if c < n:
            u = d[c]
        elif c < 2 * n:
            u = v[c - n]
        elif c < 3 * n:
            u = a[c - 2 * n]
        else:
            u = driven[c - 3 * n]
        return values[e] * u

    @wp.func
    def product_entry(e: int, columns: wp.array(dtype=wp.int32), values: wp.array(dtype=mat), u: wp.array(dtype=vec)):
        return values[e] * u[columns[e]]

    @wp.func
    def direction_entry(
        e: int,
        columns: wp.array(dtype=wp.int32),
        values: wp.array(dtype=mat),
        z: wp.array(dtype=vec),
        p_old: wp.array(dtype=vec),
        beta: dtype,
        first: bool,
    ):
        j = columns[e]
        pj = z[j]
        if not first:
            pj += beta * p_old[j]
        return values[e] * pj

    # G and Gᵀ entries address scalar dofs: they read the vectors through flat scalar views
    # (``r_flat[3 node + axis]``), which loads one scalar instead of a whole vec3.

    @wp.func
    def lower_entry(
        e: int, keys: wp.array(dtype=wp.int32), values: wp.array(dtype=dtype), r: wp.array(dtype=dtype),
        q: wp.array(dtype=dtype), alpha: dtype,
    ):
        key = keys[e]
        col = key // 3
        return unit(key - 3 * col, values[e] * (r[col] - alpha * q[col]))

    @wp.func
    def upper_entry(e: int, keys: wp.array(dtype=wp.int32), values: wp.array(dtype=dtype), y: wp.array(dtype=dtype)):
        key = keys[e]
        col = key // 3
        return unit(key - 3 * col, values[e] * y[col])

    # Each row loop below: `unroll` straight-line entries per lane (clamped index, masked
    # result, so all their loads can be in flight together), then an ordinary loop for the rest.

    @wp.kernel(enable_backward=False, module="unique")
    def residual(
        p_offsets: wp.array(dtype=wp.int32),
        p_columns: wp.array(dtype=wp.int32),
        p_values: wp.array(dtype=mat),
        a_offsets: wp.array(dtype=wp.int32),
        a_columns: wp.array(dtype=wp.int32),
        a_values: wp.array(dtype=mat),
        d: wp.array(dtype=vec),
        v: wp.array(dtype=vec),
        a: wp.array(dtype=vec),
        trajectory: wp.array2d(dtype=vec),
        guess: wp.array(dtype=vec),
        ring: wp.array(dtype=wp.int32),
        r: wp.array2d(dtype=vec),
        x: wp.array(dtype=vec),
        slots: wp.array3d(dtype=wp.float64),
        cg_iter: wp.array(dtype=wp.int32),
        condition: wp.array(dtype=wp.int32),
    ):
        """Residuals of the two starting points: ``r[1] = P [d; v; a; t]``, ``r[0] = r[1] − A guess``.

        ``r[1]`` is the residual of the Newmark predictor ``d + dt v + dt²/2 a`` (``P`` from the
        solver; its columns ``[0, N)`` multiply ``d``, ``[N, 2N)`` ``v``, ``[2N, 3N)`` ``a`` and
        ``[3N, 3N + D)`` the driven displacements ``trajectory[ring[0]]`` at the end of the step);
        ``r[0]`` that of the predictor plus ``guess`` (the extrapolation of the solver). Sets
        ``x = guess`` and slots ``START`` ``[0]``, ``[1]`` to ``|r[1]|²``, ``|r[0]|²``. Also starts the
        CG counters and copies ``ring[0]`` to ``ring[1]`` for the update kernel.
        """
        block, thread = wp.tid()
        row, lane, local, i = place(block, thread, guess.shape[0])
        p_start, p_end = p_offsets[i], p_offsets[i + 1]
        a_start, a_end = a_offsets[i], a_offsets[i + 1]
        slot = ring[0]
        driven = trajectory[slot]
        acc = vec()
        for s in range(wp.static(unroll_p)):
            e = p_start + lane + s * lanes
            acc += wp.where(e < p_end, state_entry(wp.min(e, p_end - 1), p_columns, p_values, d, v, a, driven), vec())
        for e in range(p_start + lane + unroll_p * lanes, p_end, lanes):
            acc += state_entry(e, p_columns, p_values, d, v, a, driven)
        correction = vec()
        for s in range(wp.static(unroll_a)):
            e = a_start + lane + s * lanes
            correction += wp.where(e < a_end, product_entry(wp.min(e, a_end - 1), a_columns, a_values, guess), vec())
        for e in range(a_start + lane + unroll_a * lanes, a_end, lanes):
            correction += product_entry(e, a_columns, a_values, guess)
        start_x = guess[i]
        predicted = row_sum(acc, local, lane)
        extrapolated = predicted - row_sum(correction, local, lane)
        mine = row < guess.shape[0] and lane == 0
        if mine:
            r[0, i] = extrapolated
            r[1, i] = predicted
            x[i] = start_x
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
        offsets: wp.array(dtype=wp.int32),
        columns: wp.array(dtype=wp.int32),
        values: wp.array(dtype=mat),
        z: wp.array(dtype=vec),
        p: wp.array2d(dtype=vec),
        q: wp.array(dtype=vec),
        slots: wp.array3d(dtype=wp.float64),
        cg_iter: wp.array(dtype=wp.int32),
        condition: wp.array(dtype=wp.int32),
        tol_sq: wp.float64,
        maxiter: int,
    ):
        """Phase 1: ``p[k % 2] = z + β p[(k+1) % 2]``, ``q = A p``, slots ``PQ`` += ``p·q``."""
        block, thread = wp.tid()
        row, lane, local, i = place(block, thread, z.shape[0])
        start, end = offsets[i], offsets[i + 1]
        k = cg_iter[0]
        cols = fetch_a(columns, start, end, lane)
        rz = slot_total(slots, RZ, k)
        rz_old = slot_total(slots, RZ, wp.max(k - 1, 0))
        if block == 0 and thread == 0:
            cg_iter[1] = k
        if cg_finished(slots, k, tol_sq, maxiter):
            if block == 0 and thread == 0:
                condition[0] = 0
            return
        first = k == 0
        beta = dtype(0.0)
        if not first:
            beta = dtype(rz / rz_old)
        new = k % 2
        p_old = p[1 - new]
        acc = vec()
        for s in range(wp.static(unroll_a)):
            e = start + lane + s * lanes
            j = cols[s]
            pj = z[j]
            if not first:
                pj += beta * p_old[j]
            acc += wp.where(e < end, values[wp.min(e, end - 1)] * pj, vec())
        for e in range(start + lane + unroll_a * lanes, end, lanes):
            acc += direction_entry(e, columns, values, z, p_old, beta, first)
        pi = z[i]
        if not first:
            pi += beta * p_old[i]
        qi = row_sum(acc, local, lane)
        mine = row < z.shape[0] and lane == 0
        pq = wp.float64(0.0)
        if mine:
            p[new, i] = pi
            q[i] = qi
            pq = wp.float64(wp.dot(pi, qi))
        pq = block_sum(pq)
        if thread == 0:
            wp.atomic_add(slots, PQ, k, block % spread, pq)

    @wp.kernel(enable_backward=False, module="unique")
    def lower(
        offsets: wp.array(dtype=wp.int32),
        keys: wp.array(dtype=wp.int32),
        values: wp.array(dtype=dtype),
        p: wp.array2d(dtype=vec),
        q: wp.array(dtype=vec),
        q_flat: wp.array(dtype=dtype),
        r: wp.array2d(dtype=vec),
        r_flat: wp.array2d(dtype=dtype),
        x: wp.array(dtype=vec),
        y: wp.array(dtype=vec),
        slots: wp.array3d(dtype=wp.float64),
        cg_iter: wp.array(dtype=wp.int32),
        tol_sq: wp.float64,
        maxiter: int,
    ):
        """Phase 2: ``x += α p``, ``r[(k+1) % 2] = r[k % 2] − α q`` and ``y = G r_new``."""
        block, thread = wp.tid()
        row, lane, local, i = place(block, thread, q.shape[0])
        start, end = offsets[i], offsets[i + 1]
        k = cg_iter[0]
        found = fetch_g(keys, start, end, lane)
        rz = slot_total(slots, RZ, k)
        pq = slot_total(slots, PQ, k)
        if cg_finished(slots, k, tol_sq, maxiter):
            return
        alpha = dtype(rz / pq)
        cur = k % 2
        r_cur = r_flat[cur]
        x_new = x[i] + alpha * p[cur, i]
        r_new = r[cur, i] - alpha * q[i]
        acc = vec()
        for s in range(wp.static(unroll_g)):
            e = start + lane + s * lanes
            col = found[s] // 3
            g = values[wp.min(e, end - 1)]
            acc += wp.where(e < end, unit(found[s] - 3 * col, g * (r_cur[col] - alpha * q_flat[col])), vec())
        for e in range(start + lane + unroll_g * lanes, end, lanes):
            acc += lower_entry(e, keys, values, r_cur, q_flat, alpha)
        yi = row_sum(acc, local, lane)
        if row < q.shape[0] and lane == 0:
            x[i] = x_new
            r[1 - cur, i] = r_new
            y[i] = yi

    @wp.kernel(enable_backward=False, module="unique")
    def lower_start(
        offsets: wp.array(dtype=wp.int32),
        keys: wp.array(dtype=wp.int32),
        values: wp.array(dtype=dtype),
        r: wp.array2d(dtype=vec),
        r_flat: wp.array2d(dtype=dtype),
        x: wp.array(dtype=vec),
        slots: wp.array3d(dtype=wp.float64),
        y: wp.array(dtype=vec),
    ):
        """Start from the better of the two points of ``residual``; ``y = G r[0]``.

        If the extrapolated start has the larger residual (the motion was not smooth), ``r[0]``
        and ``x`` are reset to the predictor's (``r[1]``, zero correction).
        """
        block, thread = wp.tid()
        row, lane, local, i = place(block, thread, x.shape[0])
        start, end = offsets[i], offsets[i + 1]
        use = 0
        if not (slot_total(slots, START, 1) <= slot_total(slots, START, 0)):
            use = 1
        r_use = r_flat[use]
        acc = vec()
        for s in range(wp.static(unroll_g)):
            e = start + lane + s * lanes
            acc += wp.where(e < end, lower_entry(wp.min(e, end - 1), keys, values, r_use, r_use, dtype(0.0)), vec())
        for e in range(start + lane + unroll_g * lanes, end, lanes):
            acc += lower_entry(e, keys, values, r_use, r_use, dtype(0.0))
        yi = row_sum(acc, local, lane)
        if row < x.shape[0] and lane == 0:
            y[i] = yi
            if use == 1:
                r[0, i] = r[1, i]
                x[i] = vec()

    @wp.kernel(enable_backward=False, module="unique")
    def upper(
        offsets: wp.array(dtype=wp.int32),
        keys: wp.array(dtype=wp.int32),
        values: wp.array(dtype=dtype),
        y_flat: wp.array(dtype=dtype),
        r: wp.array2d(dtype=vec),
        z: wp.array(dtype=vec),
        slots: wp.array3d(dtype=wp.float64),
        cg_iter: wp.array(dtype=wp.int32),
        tol_sq: wp.float64,
        maxiter: int,
    ):
        """Phase 3: ``z = Gᵀ y``; slots ``RZ``, ``RR`` of iteration k+1 += ``r·z``, ``r·r``; ``k += 1``.

        With ``cg_iter[1] == -1`` (set by ``residual``) it starts CG: ``z = M⁻¹ r[0]``.
        """
        block, thread = wp.tid()
        row, lane, local, i = place(block, thread, z.shape[0])
        start, end = offsets[i], offsets[i + 1]
        k = cg_iter[1]
        found = fetch_g(keys, start, end, lane)
        if cg_finished(slots, wp.max(k, 0), tol_sq, maxiter) and k >= 0:
            return
        ri = r[(k + 1) % 2, i]
        acc = vec()
        for s in range(wp.static(unroll_g)):
            e = start + lane + s * lanes
            col = found[s] // 3
            acc += wp.where(e < end, unit(found[s] - 3 * col, values[wp.min(e, end - 1)] * y_flat[col]), vec())
        for e in range(start + lane + unroll_g * lanes, end, lanes):
            acc += upper_entry(e, keys, values, y_flat)
        zi = row_sum(acc, local, lane)
        rz = wp.float64(0.0)
        rr = wp.float64(0.0)
        if row < z.shape[0] and lane == 0:
            z[i] = zi
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
        vec=vec, mat=mat, block_dim=rows * lanes, rows=rows,
        residual=residual, direction=direction, lower=lower, lower_start=lower_start, upper=upper,
    )
