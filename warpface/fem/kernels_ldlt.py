"""Kernels of the block LDLᵀ solver (:mod:`warpface.fem.ldlt`): a residual product and one refinement round.

The factor is stored by rows of 3x3 node blocks, ``L = I + N`` with ``N`` strictly lower in the
factor's node order; each row's blocks form *runs* of consecutive block columns (a supernode's
columns, or a whole profile row for an envelope ordering), so a run costs one column index and the
loops stream blocks and solution entries contiguously. The blocks are float32: the triangular
sweeps are bound by the bytes they stream, and the float64 result comes from refinement around
them (:class:`~warpface.fem.ldlt.BlockLDLT`).

Both kernels run on one CPU thread (``dim=1``): the sweeps' rows depend on each other, and the
residual scatters. Inner loops are ``while`` loops: Warp's ``range`` iterator checks the sign of
its step every iteration, which costs more than a 3x3 product; the forward sweep's loop is
unrolled four times with separate sums, the backward one four times.
"""

from __future__ import annotations

import warp as wp

__all__ = ["block_residual", "ldlt_refine"]

# -O3 instead of Warp's CPU default -O2: the sweeps take 5.0–5.2 ms instead of 6.0–6.4 on the 6.7k-node ANP shell
wp.set_module_options({"optimization_level": 3})


@wp.kernel
def block_residual(
    row_start: wp.array(dtype=wp.int32),
    columns: wp.array(dtype=wp.int32),
    lower: wp.array(dtype=wp.mat33d),
    diagonal: wp.array(dtype=wp.mat33d),
    rhs: wp.array(dtype=wp.vec3d),
    x: wp.array(dtype=wp.vec3d),
    residual: wp.array(dtype=wp.vec3d),
):
    """``residual = rhs − A x`` for a symmetric matrix of 3x3 float64 blocks given by its strictly lower
    blocks (by rows, ``row_start`` of shape (n + 1,)) and diagonal blocks (shape (n,)); run with ``dim=1``.

    Each stored block serves its row and, transposed, its column, so the product streams half of ``A``.
    """
    n = residual.shape[0]
    for i in range(n):
        residual[i] = rhs[i]
    for i in range(n):
        xi = x[i]
        acc = residual[i] - diagonal[i] * xi
        e = row_start[i]
        end = row_start[i + 1]
        while e < end:
            j = columns[e]
            block = lower[e]
            acc = acc - block * x[j]
            residual[j] = residual[j] - wp.transpose(block) * xi
            e += 1
        residual[i] = acc


@wp.func
def _run(run_start: wp.array(dtype=wp.int32), run_column: wp.array(dtype=wp.int32), r: int):
    """Run ``r`` of the factor: its blocks ``[e, e_end)`` and the block column ``j`` of its first block."""
    return run_start[r], run_start[r + 1], run_column[r]


@wp.kernel
def ldlt_refine(
    order: wp.array(dtype=wp.int32),
    row_runs: wp.array(dtype=wp.int32),
    run_column: wp.array(dtype=wp.int32),
    run_start: wp.array(dtype=wp.int32),
    blocks: wp.array(dtype=wp.mat33f),
    diagonal_inverse: wp.array(dtype=wp.mat33f),
    pivot_inverse: wp.array(dtype=wp.vec3f),
    residual: wp.array(dtype=wp.vec3d),
    work: wp.array(dtype=wp.vec3f),
    x: wp.array(dtype=wp.vec3d),
    correction_max: wp.array(dtype=wp.float64),
):
    """One refinement round ``x += (L D Lᵀ)⁻¹ residual`` with a float32 factor; run with ``dim=1``.

    Args:
        order: Node of each factor row, shape (n,): factor row ``k`` is node ``order[k]``.
        row_runs: First run of each factor row, shape (n + 1,).
        run_column: First block column of each run, shape (runs,).
        run_start: First block of each run, shape (runs + 1,).
        blocks: Off-diagonal blocks of ``L`` by rows, shape (blocks,).
        diagonal_inverse: Inverse of each row's unit-lower-triangular diagonal block of ``L``, shape (n,).
        pivot_inverse: ``1 / D`` per row, shape (n,).
        residual: Right-hand side, by node, shape (n,), float64.
        work: Scratch, shape (n,).
        x: Solution by node, shape (n,), float64; the correction is added in place.
        correction_max: Out, shape (1,): the largest component of the correction [units of x].

    The residual is scaled by its largest component before it is rounded to float32, so the sweeps
    never meet float32 underflow or overflow whatever the units.
    """
    n = work.shape[0]
    scale = wp.float64(0.0)
    for i in range(n):
        scale = wp.max(scale, wp.max(wp.abs(residual[i])))
    if scale == wp.float64(0.0):
        correction_max[0] = wp.float64(0.0)
        return
    inverse_scale = wp.float64(1.0) / scale
    # forward: L y = P r (gather along each row)
    for i in range(n):
        acc = wp.vec3f(residual[order[i]] * inverse_scale)
        r = row_runs[i]
        r_end = row_runs[i + 1]
        while r < r_end:
            e, e_end, j = _run(run_start, run_column, r)
            acc1 = wp.vec3f(0.0)
            acc2 = wp.vec3f(0.0)
            acc3 = wp.vec3f(0.0)
            while e + 3 < e_end:
                acc = acc - blocks[e] * work[j]
                acc1 = acc1 - blocks[e + 1] * work[j + 1]
                acc2 = acc2 - blocks[e + 2] * work[j + 2]
                acc3 = acc3 - blocks[e + 3] * work[j + 3]
                e += 4
                j += 4
            while e < e_end:
                acc = acc - blocks[e] * work[j]
                e += 1
                j += 1
            acc = acc + (acc1 + acc2) + acc3
            r += 1
        work[i] = diagonal_inverse[i] * acc
    for i in range(n):
        work[i] = wp.cw_mul(work[i], pivot_inverse[i])
    # backward: Lᵀ z = D⁻¹ y (row i is final once the rows after it are done; it then scatters)
    for t in range(n):
        i = n - 1 - t
        zi = wp.transpose(diagonal_inverse[i]) * work[i]
        work[i] = zi
        r = row_runs[i]
        r_end = row_runs[i + 1]
        while r < r_end:
            e, e_end, j = _run(run_start, run_column, r)
            while e + 3 < e_end:
                work[j] = work[j] - wp.transpose(blocks[e]) * zi
                work[j + 1] = work[j + 1] - wp.transpose(blocks[e + 1]) * zi
                work[j + 2] = work[j + 2] - wp.transpose(blocks[e + 2]) * zi
                work[j + 3] = work[j + 3] - wp.transpose(blocks[e + 3]) * zi
                e += 4
                j += 4
            while e < e_end:
                work[j] = work[j] - wp.transpose(blocks[e]) * zi
                e += 1
                j += 1
            r += 1
    largest = wp.float64(0.0)
    for i in range(n):
        correction = wp.vec3d(work[i]) * scale
        node = order[i]
        x[node] = x[node] + correction
        largest = wp.max(largest, wp.max(wp.abs(correction)))
    correction_max[0] = largest
