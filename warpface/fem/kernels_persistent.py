"""The whole CG loop of the device Newmark step as one persistent kernel with grid-wide barriers.

:mod:`warpface.fem.kernels_cg` runs an iteration as three launches in a ``wp.capture_while``
loop; on a GPU each launch (and the loop's condition node) costs a few microseconds of latency
on top of the work, which at 6.7k nodes is most of an iteration. Here one launch runs every
iteration: the same three phases (``direction``, ``lower``, ``upper``; their arithmetic is that
of :mod:`warpface.fem.kernels_cg`) and the start (``y = G r0``, ``z = Gᵀ y``), separated by
grid-wide barriers instead of kernel boundaries. The iteration counter is a register, the dot
products are summed per block (warp shuffles) and added to the same float64 slots, and every
block reads the same slot sums after a barrier, so all blocks agree on ``α``, ``β`` and on when
CG has finished.

The kernel steps a batch of models on one mesh (:class:`~warpface.fem.solver_batch.BatchedCGSolver`;
a single model is a batch of one): each model has its own group of blocks, barrier, dot-product slots
and convergence, so the models of one launch never wait for each other.

A grid barrier is only safe when every block of the launch is resident on the GPU at once: the
solver launches at most as many blocks as the device holds (the driver's occupancy query,
:func:`grid_capacity`; each block then walks row groups ``block, block + blocks, ...``), and a barrier that waits far
longer than any step could (a block not resident) gives up and raises the ``barrier[1]`` flag
instead of hanging; the solver reports it. On the CPU the kernel runs as a single block of one
thread that walks every row (the barriers are then no-ops).

Row sums of the lanes of a matrix row use warp shuffles (``lanes`` divides 32), dot products a
block reduction in shared memory; on the CPU (one lane, one thread) both are the identity.
"""

import ctypes
import functools
import types

import warp as wp

from .kernels_cg import (
    PQ,
    RR,
    RZ,
    SLOT_SPREAD,
    START,
    WORK_P,
    WORK_Q,
    WORK_R,
    WORK_X,
    WORK_Y,
    WORK_Z,
    cg_finished,
    slot_total,
)
from .kernels_cg_rows import cg_matrix_types, cg_row_functions, model_rows

__all__ = [
    "BARRIER_POLLS",
    "RESIDENT_THREADS",
    "grid_capacity",
    "grid_sync",
    "grid_sync_acquire",
    "persistent_pcg_kernel",
    "resident_blocks_per_multiprocessor",
]

RESIDENT_THREADS = 512
"""Threads per multiprocessor the persistent kernel is compiled to fit (``__launch_bounds__``)."""

BARRIER_POLLS = 1 << 22
"""Polls of the barrier counter (~1 s) before a block gives up waiting and raises the abort flag."""


def _grid_sync_source(arrive: str, leave: str) -> str:
    """CUDA source of a grid barrier on ``barrier[0]`` whose thread 0 announces its block with ``arrive``, polls
    (relaxed loads) until every block has arrived or the abort flag ``barrier[1]`` is up, then runs ``leave``."""
    return f"""
#if defined(__CUDA_ARCH__)
    __syncthreads();
    if (threadIdx.x == 0) {{
        int* counter = (int*)barrier.data;
        volatile int* watched = counter;
        {arrive}
        long long polls = 0;
        while (watched[0] < target && watched[1] == 0) {{
            if (++polls > {BARRIER_POLLS}LL) {{
                atomicExch(counter + 1, 1);
            }}
        }}
        {leave}
    }}
    __syncthreads();
#endif
"""


@wp.func_native(_grid_sync_source("__threadfence(); atomicAdd(counter, 1);", "__threadfence();"))
def grid_sync(barrier: wp.array(dtype=wp.int32), target: int):
    """Wait until ``barrier[0]`` (advanced by one per arriving block) reaches ``target``; all writes
    before the barrier are visible to every block after it. Gives up (sets ``barrier[1]``) after
    :data:`BARRIER_POLLS` polls. CUDA only; a no-op on the CPU. A ``__threadfence`` before the arrival and after
    the poll: the barrier of a batch."""
    ...


@wp.func_native(
    _grid_sync_source(
        'asm volatile("red.release.gpu.global.add.s32 [%0], 1;" :: "l"(counter) : "memory");',
        'int seen; asm volatile("ld.acquire.gpu.global.s32 %0, [%1];" : "=r"(seen) : "l"(counter) : "memory");',
    )
)
def grid_sync_acquire(barrier: wp.array(dtype=wp.int32), target: int):
    """:func:`grid_sync` with a release add for the arrival and one acquire load of the counter after the poll
    (PTX memory model, GPU scope) in place of the two full fences: the single model's barrier (faster for one
    model, not for a batch, which keeps the fences; measurements: ``benchmarks/README.md``)."""
    ...


_LANE_SUM = """
#if defined(__CUDA_ARCH__)
    for (int offset = lanes / 2; offset > 0; offset /= 2) {
        value += __shfl_xor_sync(0xffffffffu, value, offset);
    }
#endif
    return value;
"""


@wp.func_native(_LANE_SUM)
def lane_sum64(value: wp.float64, lanes: int) -> wp.float64:
    """Sum of ``value`` over the ``lanes`` consecutive threads of a warp that share a row (CUDA)."""
    ...


@wp.func_native(_LANE_SUM)
def lane_sum32(value: wp.float32, lanes: int) -> wp.float32:
    """float32 :func:`lane_sum64`."""
    ...


_BLOCK_SUM = """
#if defined(__CUDA_ARCH__)
    __shared__ double warp_parts[32];
    for (int offset = 16; offset > 0; offset /= 2) {
        value += __shfl_xor_sync(0xffffffffu, value, offset);
    }
    __syncthreads();
    if ((threadIdx.x & 31) == 0) {
        warp_parts[threadIdx.x / 32] = value;
    }
    __syncthreads();
    if (threadIdx.x == 0) {
        value = 0.0;
        for (int w = 0; w < (int)((blockDim.x + 31) / 32); ++w) {
            value += warp_parts[w];
        }
    }
#endif
    return value;
"""


@wp.func_native(_BLOCK_SUM)
def block_sum64(value: wp.float64) -> wp.float64:
    """Sum of ``value`` over the thread block, valid in thread 0 (CUDA; the identity on the CPU)."""
    ...


def grid_capacity(kernel, block_dim: int, *, device=None) -> int:
    """Blocks of ``block_dim`` threads of ``kernel`` that ``device`` (default: Warp's preferred device) holds at once:
    the CUDA driver's occupancy query (``cuOccupancyMaxActiveBlocksPerMultiprocessor``, which counts registers,
    shared memory and the block limits) times the multiprocessors. 1 on the CPU (one block at a time, no
    barrier to wait at); 0 when the query is not available or the kernel cannot be resident at all, which is
    when a grid barrier would not be safe and the solvers use the launched loop instead."""
    device = wp.get_device(device)
    if not device.is_cuda:
        return 1
    return resident_blocks_per_multiprocessor(kernel, block_dim, device=device) * device.sm_count


def resident_blocks_per_multiprocessor(kernel, block_dim: int, *, device) -> int:
    """``cuOccupancyMaxActiveBlocksPerMultiprocessor`` of ``kernel`` compiled for ``block_dim`` threads on the CUDA
    ``device`` (loads the kernel), or 0 when the driver or the query is not available."""
    driver = _cuda_driver()
    if driver is None:
        return 0
    try:
        hooks = kernel.module.load(device, block_dim).get_kernel_hooks(kernel)
        count = ctypes.c_int(0)
        with wp.ScopedDevice(device):  # the kernel's context current for the driver call
            result = driver.cuOccupancyMaxActiveBlocksPerMultiprocessor(
                ctypes.byref(count),
                ctypes.c_void_p(hooks.forward),
                ctypes.c_int(block_dim),
                ctypes.c_size_t(hooks.forward_smem_bytes),
            )
    except (AttributeError, OSError, RuntimeError, TypeError):
        return 0
    return max(count.value, 0) if result == 0 else 0


@functools.lru_cache(maxsize=1)
def _cuda_driver():
    """The CUDA driver library (ctypes), or None where it cannot be loaded."""
    for name in ("libcuda.so.1", "libcuda.so", "nvcuda.dll"):
        try:
            return ctypes.CDLL(name)
        except OSError:
            continue
    return None


@functools.lru_cache(maxsize=None)
def persistent_pcg_kernel(
    dtype, lanes: int = 1, rows: int = 1, resident_threads: int = RESIDENT_THREADS, single: bool = False
) -> types.SimpleNamespace:
    """The persistent CG step for ``dtype`` and block shape (module docstring), for one model or a batch.

    ``cg_step`` solves the step of models ``first_model .. first_model + M − 1`` of a batch of B models
    that share the mesh (one sparsity pattern): launch it with ``wp.launch_tiled(dim=M * blocks,
    block_dim=rows * lanes)``; the first ``blocks`` blocks work on the first of those models, the next
    ``blocks`` on the second, and so on, each model's blocks meeting at their own barrier and stopping
    at their own convergence. ``M * blocks`` must be at most :func:`grid_capacity` (every block resident),
    ``blocks`` at most the row groups ``ceil(F / rows)``; on the CPU build it with ``lanes = rows = 1``
    and launch one block per model. Per-model arrays have the model as their first index: the state
    ``d, v, a`` (B, N), ``trajectory`` (chunk, B, D), ``guess`` (B, F), the external nodal force ``force``
    (B, N), or (1, N) for one shared by all, or (1, 0) for none (read at ``free_nodes`` (F,), the free rows'
    nodes), the work vectors in ``work``
    (B, :data:`~warpface.fem.kernels_cg.WORK_ROWS`, F) and its flat scalar view ``work_flat``
    (B, WORK_ROWS, 3F), ``slots`` (B, 4, maxiter + 1, SLOT_SPREAD) cleared, ``cg_iter`` (B, 2) and
    ``barrier`` (B, 3: arrivals, gave up, departures), which must start at zero (the last block of a model
    to leave clears its arrivals and departures again). The matrices ``P``, ``A`` and the factors ``G``, ``Gᵀ`` are
    ``BatchBlockRows`` / ``BatchFactorRows`` (:func:`~warpface.fem.kernels_cg_rows.cg_matrix_types`) whose values
    are (B, nnz), or (1, nnz) when one is shared by all models. A single model is a batch of one.

    Per model it does the work of ``residual``, ``lower_start``, ``upper`` and the iteration loop of
    :func:`~warpface.fem.kernels_cg.pcg_kernels` (same arithmetic, same results) and leaves
    ``cg_iter[b, 0] = cg_iter[b, 1]`` = the iterations done and ``ring[1] = ring[0]`` for the update kernel.
    The kernel is compiled to keep at least ``resident_threads`` threads per multiprocessor resident
    (``__launch_bounds__``: fewer registers per thread, more blocks at once). ``single`` compiles it for a batch
    of exactly one model (launched with ``first_model = 0``): the model index is then a constant, and the
    per-model views need no registers of their own, and its barriers are :func:`grid_sync_acquire`.
    """
    if 32 % lanes:
        raise ValueError(f"lanes must divide 32, got {lanes}")
    matrices = cg_matrix_types(dtype)
    vec, BlockRows, FactorRows = matrices.vec, matrices.BlockRows, matrices.FactorRows
    BatchBlockRows, BatchFactorRows = matrices.BatchBlockRows, matrices.BatchFactorRows
    fetch_a, fetch_g, residual_part, direction_part, factor_part = cg_row_functions(dtype, lanes)
    spread = SLOT_SPREAD
    lane_sum = lane_sum64 if dtype == wp.float64 else lane_sum32
    barrier_sync = grid_sync_acquire if single else grid_sync

    @wp.func
    def row_total(part: vec):
        return vec(lane_sum(part[0], lanes), lane_sum(part[1], lanes), lane_sum(part[2], lanes))

    @wp.func
    def group_row(g: int, local: int, count: int):
        # (row, clamped row to read) of the thread's row in row group g
        row = g * rows + local
        return row, wp.min(row, count - 1)

    @wp.func
    def arrive(barrier: wp.array(dtype=wp.int32), arrivals: int, blocks: int):
        # wait at the model's next barrier; returns the barriers passed
        barrier_sync(barrier, (arrivals + 1) * blocks)
        return arrivals + 1

    # at least resident_threads threads per multiprocessor: caps the registers (128 a thread for 512), so that a
    # grid of one row group per block of a face-sized mesh stays resident
    @wp.kernel(
        enable_backward=False,
        module="unique",
        grid_stride=False,
        launch_bounds=(rows * lanes, max(1, resident_threads // (rows * lanes))),
    )
    def cg_step(
        P_all: BatchBlockRows,
        A_all: BatchBlockRows,
        G_all: BatchFactorRows,
        GT_all: BatchFactorRows,
        d_all: wp.array2d(dtype=vec),
        v_all: wp.array2d(dtype=vec),
        a_all: wp.array2d(dtype=vec),
        trajectory: wp.array3d(dtype=vec),
        guess_all: wp.array2d(dtype=vec),
        force_all: wp.array2d(dtype=vec),
        free_nodes: wp.array(dtype=wp.int32),
        ring: wp.array(dtype=wp.int32),
        work_all: wp.array3d(dtype=vec),
        work_flat_all: wp.array3d(dtype=dtype),
        slots_all: wp.array4d(dtype=wp.float64),
        cg_iter_all: wp.array2d(dtype=wp.int32),
        barrier_all: wp.array2d(dtype=wp.int32),
        tol_sq: wp.float64,
        maxiter: int,
        blocks: int,
        first_model: int,
    ):
        """Residuals, start and every CG iteration, phases separated by :func:`grid_sync` (module docstring).
        Each phase's row indices for the block's first row group are loaded before the barrier ahead of it."""
        launched_block, thread = wp.tid()
        if wp.static(single):  # model 0 known when compiled: its views are the arrays' own addresses
            block = launched_block
            b = 0
        else:
            model = launched_block // blocks
            block = launched_block - model * blocks
            b = first_model + model
        # this model's views
        P, A = model_rows(P_all, b, BlockRows()), model_rows(A_all, b, BlockRows())
        G, GT = model_rows(G_all, b, FactorRows()), model_rows(GT_all, b, FactorRows())
        d, v, a, guess = d_all[b], v_all[b], a_all[b], guess_all[b]
        force = force_all[wp.min(b, force_all.shape[0] - 1)]
        w, wf = work_all[b], work_flat_all[b]  # rows WORK_R (2), WORK_P (2), WORK_X, WORK_Y, WORK_Z, WORK_Q
        slots, cg_iter, barrier = slots_all[b], cg_iter_all[b], barrier_all[b]
        local = thread // lanes
        lane = thread - local * lanes
        count = w.shape[1]
        groups = (count + rows - 1) // rows
        _, first = group_row(block, local, count)
        arrivals = int(0)

        # residuals of the predictor (r[1]) and of the extrapolated start (r[0]), as kernels_cg.residual
        slot = ring[0]
        driven = trajectory[slot][b]
        predicted_sq = wp.float64(0.0)
        extrapolated_sq = wp.float64(0.0)
        for g in range(block, groups, blocks):
            row, i = group_row(g, local, count)
            acc, correction = residual_part(i, lane, P, A, d, v, a, driven, guess, force, free_nodes)
            predicted = row_total(acc)
            extrapolated = predicted - row_total(correction)
            if row < count and lane == 0:
                w[WORK_R, i] = extrapolated
                w[WORK_R + 1, i] = predicted
                w[WORK_X, i] = guess[i]
                predicted_sq += wp.float64(wp.dot(predicted, predicted))
                extrapolated_sq += wp.float64(wp.dot(extrapolated, extrapolated))
        predicted_sq = block_sum64(predicted_sq)
        extrapolated_sq = block_sum64(extrapolated_sq)
        if thread == 0:
            wp.atomic_add(slots, START, 0, block % spread, predicted_sq)
            wp.atomic_add(slots, START, 1, block % spread, extrapolated_sq)
            if launched_block == 0:
                ring[1] = slot
        g_start, g_end, g_found = fetch_g(G, first, lane)
        arrivals = arrive(barrier, arrivals, blocks)

        # start from the better of the two points (as lower_start): y = G r0
        use = int(0)
        if not (slot_total(slots, START, 1) <= slot_total(slots, START, 0)):
            use = 1
        r_use = wf[WORK_R + use]
        g = block
        while g < groups:
            row, i = group_row(g, local, count)
            yi = row_total(factor_part(g_start, g_end, g_found, lane, G, r_use, r_use, dtype(0.0)))
            if row < count and lane == 0:
                w[WORK_Y, i] = yi
                if use == 1:
                    w[WORK_R, i] = w[WORK_R + 1, i]
                    w[WORK_X, i] = vec()
            g += blocks
            g_start, g_end, g_found = fetch_g(G, wp.min(g * rows + local, count - 1), lane)
        t_start, t_end, t_found = fetch_g(GT, first, lane)
        arrivals = arrive(barrier, arrivals, blocks)

        k = int(0)
        searching = bool(True)
        while searching:
            # upper: z = Gᵀ y, r·z and r·r of iteration k from r[k % 2]
            rz = wp.float64(0.0)
            rr = wp.float64(0.0)
            y_flat = wf[WORK_Y]
            g = block
            while g < groups:
                row, i = group_row(g, local, count)
                zi = row_total(factor_part(t_start, t_end, t_found, lane, GT, y_flat, y_flat, dtype(0.0)))
                if row < count and lane == 0:
                    ri = w[WORK_R + k % 2, i]
                    w[WORK_Z, i] = zi
                    rz += wp.float64(wp.dot(ri, zi))
                    rr += wp.float64(wp.dot(ri, ri))
                g += blocks
                t_start, t_end, t_found = fetch_g(GT, wp.min(g * rows + local, count - 1), lane)
            rz = block_sum64(rz)
            rr = block_sum64(rr)
            if thread == 0:
                wp.atomic_add(slots, RZ, k, block % spread, rz)
                wp.atomic_add(slots, RR, k, block % spread, rr)
            a_start, a_end, a_found = fetch_a(A, first, lane)
            arrivals = arrive(barrier, arrivals, blocks)
            if cg_finished(slots, k, tol_sq, maxiter) or barrier[1] != 0:
                searching = False
            else:
                # direction: p[k % 2] = z + β p[(k+1) % 2], q = A p, p·q
                beta = dtype(0.0)
                if k > 0:
                    beta = dtype(slot_total(slots, RZ, k) / slot_total(slots, RZ, k - 1))
                new = k % 2
                p_old = w[WORK_P + 1 - new]
                z = w[WORK_Z]
                pq = wp.float64(0.0)
                g = block
                while g < groups:
                    row, i = group_row(g, local, count)
                    qi = row_total(direction_part(a_start, a_end, a_found, lane, A, z, p_old, beta))
                    if row < count and lane == 0:
                        pi = z[i] + beta * p_old[i]
                        w[WORK_P + new, i] = pi
                        w[WORK_Q, i] = qi
                        pq += wp.float64(wp.dot(pi, qi))
                    g += blocks
                    a_start, a_end, a_found = fetch_a(A, wp.min(g * rows + local, count - 1), lane)
                pq = block_sum64(pq)
                if thread == 0:
                    wp.atomic_add(slots, PQ, k, block % spread, pq)
                g_start, g_end, g_found = fetch_g(G, first, lane)
                arrivals = arrive(barrier, arrivals, blocks)

                # lower: x += α p, r[(k+1) % 2] = r[k % 2] − α q, y = G r_new
                alpha = dtype(slot_total(slots, RZ, k) / slot_total(slots, PQ, k))
                r_cur = wf[WORK_R + new]
                q_flat = wf[WORK_Q]
                g = block
                while g < groups:
                    row, i = group_row(g, local, count)
                    yi = row_total(factor_part(g_start, g_end, g_found, lane, G, r_cur, q_flat, alpha))
                    if row < count and lane == 0:
                        w[WORK_X, i] = w[WORK_X, i] + alpha * w[WORK_P + new, i]
                        w[WORK_R + 1 - new, i] = w[WORK_R + new, i] - alpha * w[WORK_Q, i]
                        w[WORK_Y, i] = yi
                    g += blocks
                    g_start, g_end, g_found = fetch_g(G, wp.min(g * rows + local, count - 1), lane)
                t_start, t_end, t_found = fetch_g(GT, first, lane)
                arrivals = arrive(barrier, arrivals, blocks)
                k += 1
        if thread == 0:
            if block == 0:
                if barrier[1] != 0:  # a block gave up at a barrier: book the step as not converged
                    k = maxiter
                    slots[RR, k, 0] = wp.float64(wp.nan)
                cg_iter[0] = k
                cg_iter[1] = k
            # every block has passed its last barrier: the last one out clears the counters for the next step
            if wp.atomic_add(barrier, 2, 1) == blocks - 1:
                barrier[0] = 0
                barrier[2] = 0

    return types.SimpleNamespace(vec=vec, block_dim=rows * lanes, rows=rows, cg_step=cg_step)
