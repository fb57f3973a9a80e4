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

A grid barrier is only safe when every block of the launch is resident on the GPU at once: the
solver launches at most as many blocks as the device holds (from the kernel's register count;
each block then walks row groups ``block, block + blocks, ...``), and a barrier that waits far
longer than any step could (a block not resident) gives up and raises the ``barrier[1]`` flag
instead of hanging; the solver reports it. On the CPU the kernel runs as a single block of one
thread that walks every row (the barriers are then no-ops).

Models of a batch go in chunks of ``models``: a thread works on its row for each model of its chunk
in turn, so the row's indices (and a factor shared by every model) are loaded once per chunk, and
the chunk's blocks share one barrier; each model keeps its own scalars and stops with its own
convergence.

Row sums of the lanes of a matrix row use warp shuffles (``lanes`` divides 32), dot products a
block reduction in shared memory; on the CPU (one lane, one thread) both are the identity.
"""

import functools
import math
import types

import warp as wp

from .kernels_cg import PQ, RR, RZ, SLOT_SPREAD, START, cg_finished, slot_total

__all__ = ["BARRIER_POLLS", "MAX_CHUNK", "RESIDENT_THREADS", "grid_capacity", "persistent_pcg_kernel"]

# Straight-line row entries per lane, as in kernels_cg: block rows of A_oo hold ~15 blocks (up to
# ~30), a block row of an FSAI factor up to 3 x 32 scalars.
_SPAN_A, _SPAN_P, _SPAN_G, _MAX_UNROLL = 32, 64, 96, 8

RESIDENT_THREADS = 512
"""Threads per multiprocessor the persistent kernel is compiled to fit (``__launch_bounds__``)."""

MAX_CHUNK = 16
"""Most models per chunk (a thread's loop over them is unrolled: at most ``wp.config.max_unroll``)."""

BARRIER_POLLS = 1 << 22
"""Polls of the barrier counter (~1 s) before a block gives up waiting and raises the abort flag."""

_GRID_SYNC = """
#if defined(__CUDA_ARCH__)
    __syncthreads();
    if (threadIdx.x == 0) {
        int* counter = (int*)barrier.data;
        volatile int* watched = counter;
        __threadfence();
        atomicAdd(counter, 1);
        long long polls = 0;
        while (watched[0] < target && watched[1] == 0) {
            if (++polls > (long long)BARRIER_LIMIT) {
                atomicExch(counter + 1, 1);
            }
        }
        __threadfence();
    }
    __syncthreads();
#endif
""".replace("BARRIER_LIMIT", str(BARRIER_POLLS))


@wp.func_native(_GRID_SYNC)
def grid_sync(barrier: wp.array(dtype=wp.int32), target: int):
    """Wait until ``barrier[0]`` (advanced by one per arriving block) reaches ``target``; all writes
    before the barrier are visible to every block after it. Gives up (sets ``barrier[1]``) after
    :data:`BARRIER_POLLS` polls. CUDA only; a no-op on the CPU."""
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
    """Blocks of ``block_dim`` threads of ``kernel`` that ``device`` (default: Warp's preferred device) holds
    at once (registers and threads per multiprocessor; 1 on the CPU)."""
    device = wp.get_device(device)
    if not device.is_cuda:
        return 1
    registers = wp.get_cuda_kernel_properties(kernel, device, block_dim)["register_count"]
    warps = -(-block_dim // 32)
    per_warp = -(-max(registers, 1) * 32 // 256) * 256  # allocated per warp in units of 256 registers
    per_sm = min(32, 2048 // block_dim, 65536 // (warps * per_warp))
    return max(per_sm, 0) * device.sm_count


@functools.lru_cache(maxsize=None)
def persistent_pcg_kernel(dtype, lanes: int = 1, rows: int = 1, resident_threads: int = RESIDENT_THREADS,
                          models: int = 1, shared_factor: bool = False) -> types.SimpleNamespace:
    """The persistent CG step for ``dtype`` and block shape (module docstring), for one model or a batch.

    ``cg_step`` solves the step of models ``first_model .. model_end − 1`` of a batch of B models that
    share the mesh (one sparsity pattern), in chunks of ``models`` models (the last chunk may hold fewer):
    launch it with ``wp.launch_tiled(dim=C * blocks, block_dim=rows * lanes)`` for ``C`` chunks; the first
    ``blocks`` blocks work on the first chunk, the next ``blocks`` on the second, and so on. A thread works
    on one row for every model of its chunk (the row's indices, and with ``shared_factor`` the factor's
    values, loaded once); each model has its own ``α``, ``β``, dot products and convergence, and the
    chunk's blocks meet at one barrier and iterate until the last of its models has converged (a converged
    model does no more work). ``C * blocks`` must be at most :func:`grid_capacity` (every block resident),
    ``blocks`` at most the row groups ``ceil(F / rows)``; on the CPU build it with ``lanes = rows = 1``
    and launch one block per chunk. Per-model arrays have the model as their first index: the state
    ``d, v, a`` (B, N), ``trajectory`` (chunk, B, D), work vectors (B, F) or (B, 2, F) (flat scalar views
    (B, 3F), (B, 2, 3F)), ``slots`` (B, 4, maxiter + 1, SLOT_SPREAD) cleared, ``cg_iter`` (B, 2) and
    ``barrier`` (B, 3: arrivals, gave up, departures; a chunk uses the row of its first model), which must
    start at zero (the last block of a chunk to leave clears its arrivals and departures again). Matrix and
    factor values are (B, nnz), or (1, nnz) when one is shared by all models (``shared_factor``: the
    factors are, and their values come with the indices). A single model is a batch of one.

    Per model it does the work of ``residual``, ``lower_start``, ``upper`` and the iteration loop of
    :func:`~warpface.fem.kernels_cg.pcg_kernels` (same arithmetic, same results whatever the chunk) and
    leaves ``cg_iter[b, 0] = cg_iter[b, 1]`` = its iterations and ``ring[1] = ring[0]`` for the update
    kernel. The kernel is compiled to keep at least ``resident_threads`` threads per multiprocessor
    resident (``__launch_bounds__``: fewer registers per thread, more blocks at once).
    """
    if 32 % lanes:
        raise ValueError(f"lanes must divide 32, got {lanes}")
    if not 1 <= models <= MAX_CHUNK:
        raise ValueError(f"models per chunk must be 1 .. {MAX_CHUNK}, got {models}")
    vec = wp.types.vector(length=3, dtype=dtype)
    mat = wp.types.matrix(shape=(3, 3), dtype=dtype)
    spread = SLOT_SPREAD
    lane_sum = lane_sum64 if dtype == wp.float64 else lane_sum32
    unroll_a, unroll_p, unroll_g = (min(math.ceil(span / lanes), _MAX_UNROLL) for span in (_SPAN_A, _SPAN_P, _SPAN_G))
    index_a = wp.types.vector(length=unroll_a, dtype=wp.int32)
    index_g = wp.types.vector(length=unroll_g, dtype=wp.int32)
    values_g = wp.types.vector(length=unroll_g, dtype=dtype)
    per_model = wp.types.vector(length=models, dtype=wp.float64)  # one dot product of each model of the chunk
    per_model_scalar = wp.types.vector(length=models, dtype=dtype)
    per_model_int = wp.types.vector(length=models, dtype=wp.int32)
    per_model_rows = wp.types.matrix(shape=(models, 3), dtype=dtype)  # one row result of each model

    @wp.func
    def row_total(part: vec):
        return vec(lane_sum(part[0], lanes), lane_sum(part[1], lanes), lane_sum(part[2], lanes))

    @wp.func
    def unit(axis: int, value: dtype):
        zero = dtype(0.0)
        return vec(wp.where(axis == 0, value, zero), wp.where(axis == 1, value, zero), wp.where(axis == 2, value, zero))

    @wp.func
    def fetch_a(offsets: wp.array(dtype=wp.int32), columns: wp.array(dtype=wp.int32), i: int, lane: int):
        # row bounds and the columns of this lane's straight-line entries, loaded ahead of their use
        start, end = offsets[i], offsets[i + 1]
        found = index_a()
        for s in range(wp.static(unroll_a)):
            found[s] = columns[wp.min(start + lane + s * lanes, end - 1)]
        return start, end, found

    @wp.func
    def fetch_g(offsets: wp.array(dtype=wp.int32), keys: wp.array(dtype=wp.int32), values: wp.array2d(dtype=dtype),
                i: int, lane: int):
        # as fetch_a; a factor shared by every model also gives its straight-line values here
        start, end = offsets[i], offsets[i + 1]
        found = index_g()
        shared = values_g()
        for s in range(wp.static(unroll_g)):
            e = wp.min(start + lane + s * lanes, end - 1)
            found[s] = keys[e]
            if wp.static(shared_factor):
                shared[s] = values[0, e]
        return start, end, found, shared

    @wp.func
    def factor_rows(start: int, end: int, found: index_g, shared: values_g, lane: int, keys: wp.array(dtype=wp.int32),
                    values_all: wp.array2d(dtype=dtype), first: int, last: int, u_all: wp.array3d(dtype=dtype),
                    u_slot: per_model_int, w_all: wp.array3d(dtype=dtype), w_slot: int, alpha: per_model_scalar):
        # factor_row for each model b = first + m of the chunk (clamped to last): u_all[b, u_slot[m]] and
        # w_all[b, w_slot]; the row's keys (and a shared factor's values) loaded once for all of them
        acc = per_model_rows()
        for s in range(wp.static(unroll_g)):
            e = start + lane + s * lanes
            col = found[s] // 3
            axis = found[s] - 3 * col
            inside = e < end
            clamped = wp.min(e, end - 1)
            for m in range(wp.static(models)):
                b = wp.min(first + m, last)
                g = dtype(0.0)
                if wp.static(shared_factor):
                    g = shared[s]
                else:
                    g = values_all[wp.min(b, values_all.shape[0] - 1), clamped]
                acc[m] += wp.where(inside, unit(axis, g * (u_all[b, u_slot[m], col] - alpha[m] * w_all[b, w_slot, col])),
                                   vec())
        for e in range(start + lane + unroll_g * lanes, end, lanes):
            key = keys[e]
            col = key // 3
            for m in range(wp.static(models)):
                b = wp.min(first + m, last)
                g = values_all[wp.min(b, values_all.shape[0] - 1), e]
                acc[m] += unit(key - 3 * col, g * (u_all[b, u_slot[m], col] - alpha[m] * w_all[b, w_slot, col]))
        totals = per_model_rows()
        for m in range(wp.static(models)):
            totals[m] = row_total(acc[m])
        return totals

    @wp.func
    def direction_rows(start: int, end: int, found: index_a, lane: int, columns: wp.array(dtype=wp.int32),
                       values_all: wp.array2d(dtype=mat), first: int, last: int, z_all: wp.array2d(dtype=vec),
                       p_all: wp.array3d(dtype=vec), old: int, beta: per_model_scalar):
        # direction_row for each model b = first + m of the chunk (clamped to last), p_old = p_all[b, old]
        acc = per_model_rows()
        for s in range(wp.static(unroll_a)):
            e = start + lane + s * lanes
            j = found[s]
            inside = e < end
            clamped = wp.min(e, end - 1)
            for m in range(wp.static(models)):
                b = wp.min(first + m, last)
                acc[m] += wp.where(inside, values_all[wp.min(b, values_all.shape[0] - 1), clamped]
                                   * (z_all[b, j] + beta[m] * p_all[b, old, j]), vec())
        for e in range(start + lane + unroll_a * lanes, end, lanes):
            j = columns[e]
            for m in range(wp.static(models)):
                b = wp.min(first + m, last)
                acc[m] += values_all[wp.min(b, values_all.shape[0] - 1), e] * (z_all[b, j] + beta[m] * p_all[b, old, j])
        totals = per_model_rows()
        for m in range(wp.static(models)):
            totals[m] = row_total(acc[m])
        return totals

    @wp.func
    def state_entry(e: int, columns: wp.array(dtype=wp.int32), values: wp.array(dtype=mat), d: wp.array(dtype=vec),
                    v: wp.array(dtype=vec), a: wp.array(dtype=vec), driven: wp.array(dtype=vec)):
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
    def residual_row(i: int, lane: int, p_offsets: wp.array(dtype=wp.int32), p_columns: wp.array(dtype=wp.int32),
                     p_values: wp.array(dtype=mat), a_offsets: wp.array(dtype=wp.int32),
                     a_columns: wp.array(dtype=wp.int32), a_values: wp.array(dtype=mat), d: wp.array(dtype=vec),
                     v: wp.array(dtype=vec), a: wp.array(dtype=vec), driven: wp.array(dtype=vec),
                     guess: wp.array(dtype=vec)):
        # (P [d; v; a; driven])_i and (A guess)_i, summed over the lanes (kernels_cg.residual)
        p_start, p_end = p_offsets[i], p_offsets[i + 1]
        a_start, a_end = a_offsets[i], a_offsets[i + 1]
        acc = vec()
        for s in range(wp.static(unroll_p)):
            e = p_start + lane + s * lanes
            acc += wp.where(e < p_end, state_entry(wp.min(e, p_end - 1), p_columns, p_values, d, v, a, driven), vec())
        for e in range(p_start + lane + unroll_p * lanes, p_end, lanes):
            acc += state_entry(e, p_columns, p_values, d, v, a, driven)
        correction = vec()
        for s in range(wp.static(unroll_a)):
            e = wp.min(a_start + lane + s * lanes, a_end - 1)
            correction += wp.where(a_start + lane + s * lanes < a_end, a_values[e] * guess[a_columns[e]], vec())
        for e in range(a_start + lane + unroll_a * lanes, a_end, lanes):
            correction += a_values[e] * guess[a_columns[e]]
        predicted = row_total(acc)
        return predicted, predicted - row_total(correction)

    @wp.func
    def total(slots_all: wp.array4d(dtype=wp.float64), b: int, which: int, k: int):
        s = wp.float64(0.0)
        for j in range(wp.static(spread)):
            s += slots_all[b, which, k, j]
        return s

    # at least resident_threads (default RESIDENT_THREADS) threads per multiprocessor: caps the registers (128 a thread for 512), so that a
    # grid of one row group per block stays resident (H200, 6.7k nodes, 16x16: 130 registers and 132 resident
    # blocks for 247 row groups without the bound)
    @wp.kernel(enable_backward=False, module="unique", grid_stride=False,
               launch_bounds=(rows * lanes, max(1, resident_threads // (rows * lanes))))
    def cg_step(
        p_offsets: wp.array(dtype=wp.int32),
        p_columns: wp.array(dtype=wp.int32),
        p_values_all: wp.array2d(dtype=mat),
        a_offsets: wp.array(dtype=wp.int32),
        a_columns: wp.array(dtype=wp.int32),
        a_values_all: wp.array2d(dtype=mat),
        g_offsets: wp.array(dtype=wp.int32),
        g_keys: wp.array(dtype=wp.int32),
        g_values_all: wp.array2d(dtype=dtype),
        t_offsets: wp.array(dtype=wp.int32),
        t_keys: wp.array(dtype=wp.int32),
        t_values_all: wp.array2d(dtype=dtype),
        d_all: wp.array2d(dtype=vec),
        v_all: wp.array2d(dtype=vec),
        a_all: wp.array2d(dtype=vec),
        trajectory: wp.array3d(dtype=vec),
        guess_all: wp.array2d(dtype=vec),
        ring: wp.array(dtype=wp.int32),
        r_all: wp.array3d(dtype=vec),
        r_flat_all: wp.array3d(dtype=dtype),
        x_all: wp.array2d(dtype=vec),
        y_all: wp.array2d(dtype=vec),
        y_flat_all: wp.array3d(dtype=dtype),
        z_all: wp.array2d(dtype=vec),
        p_all: wp.array3d(dtype=vec),
        q_all: wp.array2d(dtype=vec),
        q_flat_all: wp.array3d(dtype=dtype),
        slots_all: wp.array4d(dtype=wp.float64),
        cg_iter_all: wp.array2d(dtype=wp.int32),
        barrier_all: wp.array2d(dtype=wp.int32),
        tol_sq: wp.float64,
        maxiter: int,
        blocks: int,
        first_model: int,
        model_end: int,
    ):
        """Residuals, start and every CG iteration, phases separated by :func:`grid_sync` (module docstring).
        Each phase's row indices for the block's first row group are loaded before the barrier ahead of it;
        per row, the models of the chunk one after the other (``m``, model ``first + m``)."""
        launched_block, thread = wp.tid()
        chunk = launched_block // blocks
        block = launched_block - chunk * blocks
        first = first_model + chunk * models
        last = model_end - 1
        barrier = barrier_all[first]
        live = per_model_int()  # models still iterating (0 past the batch's end)
        done = per_model_int()  # iterations of the models that have finished
        for m in range(wp.static(models)):
            live[m] = wp.where(first + m < model_end, 1, 0)
        local = thread // lanes
        lane = thread - local * lanes
        count = x_all.shape[1]
        groups = (count + rows - 1) // rows
        first_row = wp.min(block * rows + local, count - 1)
        arrivals = int(0)

        # residuals of the predictor (r[1]) and of the extrapolated start (r[0]), as kernels_cg.residual
        slot = ring[0]
        predicted_sq = per_model()
        extrapolated_sq = per_model()
        for g in range(block, groups, blocks):
            row = g * rows + local
            i = wp.min(row, count - 1)
            for m in range(wp.static(models)):
                if live[m] != 0:
                    b = first + m
                    predicted, extrapolated = residual_row(
                        i, lane, p_offsets, p_columns, p_values_all[wp.min(b, p_values_all.shape[0] - 1)], a_offsets,
                        a_columns, a_values_all[wp.min(b, a_values_all.shape[0] - 1)], d_all[b], v_all[b], a_all[b],
                        trajectory[slot][b], guess_all[b])
                    if row < count and lane == 0:
                        r_all[b, 0, i] = extrapolated
                        r_all[b, 1, i] = predicted
                        x_all[b, i] = guess_all[b, i]
                        predicted_sq[m] += wp.float64(wp.dot(predicted, predicted))
                        extrapolated_sq[m] += wp.float64(wp.dot(extrapolated, extrapolated))
        for m in range(wp.static(models)):
            if live[m] != 0:
                predicted_sq[m] = block_sum64(predicted_sq[m])
                extrapolated_sq[m] = block_sum64(extrapolated_sq[m])
                if thread == 0:
                    wp.atomic_add(slots_all, first + m, START, 0, block % spread, predicted_sq[m])
                    wp.atomic_add(slots_all, first + m, START, 1, block % spread, extrapolated_sq[m])
        if thread == 0 and launched_block == 0:
            ring[1] = slot
        g_start, g_end, g_found, g_shared = fetch_g(g_offsets, g_keys, g_values_all, first_row, lane)
        arrivals += 1
        grid_sync(barrier, arrivals * blocks)

        # start from the better of the two points (as lower_start): y = G r0
        use = per_model_int()
        for m in range(wp.static(models)):
            if live[m] != 0:
                if not (total(slots_all, first + m, START, 1) <= total(slots_all, first + m, START, 0)):
                    use[m] = 1
        g = block
        while g < groups:
            row = g * rows + local
            i = wp.min(row, count - 1)
            y_rows = factor_rows(g_start, g_end, g_found, g_shared, lane, g_keys, g_values_all, first, last, r_flat_all,
                                 use, r_flat_all, 0, per_model_scalar())
            for m in range(wp.static(models)):
                if live[m] != 0 and row < count and lane == 0:
                    b = first + m
                    y_all[b, i] = y_rows[m]
                    if use[m] == 1:
                        r_all[b, 0, i] = r_all[b, 1, i]
                        x_all[b, i] = vec()
            g += blocks
            g_start, g_end, g_found, g_shared = fetch_g(g_offsets, g_keys, g_values_all,
                                                        wp.min(g * rows + local, count - 1), lane)
        t_start, t_end, t_found, t_shared = fetch_g(t_offsets, t_keys, t_values_all, first_row, lane)
        arrivals += 1
        grid_sync(barrier, arrivals * blocks)

        k = int(0)
        searching = bool(True)
        while searching:
            # upper: z = Gᵀ y, r·z and r·r of iteration k from r[k % 2]
            rz = per_model()
            rr = per_model()
            g = block
            while g < groups:
                row = g * rows + local
                i = wp.min(row, count - 1)
                z_rows = factor_rows(t_start, t_end, t_found, t_shared, lane, t_keys, t_values_all, first, last,
                                     y_flat_all, per_model_int(), y_flat_all, 0, per_model_scalar())
                for m in range(wp.static(models)):
                    if live[m] != 0 and row < count and lane == 0:
                        b = first + m
                        ri = r_all[b, k % 2, i]
                        zi = z_rows[m]
                        z_all[b, i] = zi
                        rz[m] += wp.float64(wp.dot(ri, zi))
                        rr[m] += wp.float64(wp.dot(ri, ri))
                g += blocks
                t_start, t_end, t_found, t_shared = fetch_g(t_offsets, t_keys, t_values_all,
                                                            wp.min(g * rows + local, count - 1), lane)
            for m in range(wp.static(models)):
                if live[m] != 0:
                    rz[m] = block_sum64(rz[m])
                    rr[m] = block_sum64(rr[m])
                    if thread == 0:
                        wp.atomic_add(slots_all, first + m, RZ, k, block % spread, rz[m])
                        wp.atomic_add(slots_all, first + m, RR, k, block % spread, rr[m])
            a_start, a_end, a_found = fetch_a(a_offsets, a_columns, first_row, lane)
            arrivals += 1
            grid_sync(barrier, arrivals * blocks)
            searching = False
            for m in range(wp.static(models)):
                if live[m] != 0:
                    b = first + m
                    if (k >= maxiter or not (total(slots_all, b, RR, k) > tol_sq * total(slots_all, b, START, 0))
                            or barrier[1] != 0):
                        live[m] = 0
                        done[m] = k
                    else:
                        searching = True
            if searching:
                # direction: p[k % 2] = z + β p[(k+1) % 2], q = A p, p·q
                new = k % 2
                beta = per_model_scalar()
                for m in range(wp.static(models)):
                    if k > 0 and live[m] != 0:
                        beta[m] = dtype(total(slots_all, first + m, RZ, k) / total(slots_all, first + m, RZ, k - 1))
                pq = per_model()
                g = block
                while g < groups:
                    row = g * rows + local
                    i = wp.min(row, count - 1)
                    q_rows = direction_rows(a_start, a_end, a_found, lane, a_columns, a_values_all, first, last, z_all,
                                            p_all, 1 - new, beta)
                    for m in range(wp.static(models)):
                        if live[m] != 0 and row < count and lane == 0:
                            b = first + m
                            pi = z_all[b, i] + beta[m] * p_all[b, 1 - new, i]
                            qi = q_rows[m]
                            p_all[b, new, i] = pi
                            q_all[b, i] = qi
                            pq[m] += wp.float64(wp.dot(pi, qi))
                    g += blocks
                    a_start, a_end, a_found = fetch_a(a_offsets, a_columns, wp.min(g * rows + local, count - 1), lane)
                for m in range(wp.static(models)):
                    if live[m] != 0:
                        pq[m] = block_sum64(pq[m])
                        if thread == 0:
                            wp.atomic_add(slots_all, first + m, PQ, k, block % spread, pq[m])
                g_start, g_end, g_found, g_shared = fetch_g(g_offsets, g_keys, g_values_all, first_row, lane)
                arrivals += 1
                grid_sync(barrier, arrivals * blocks)

                # lower: x += α p, r[(k+1) % 2] = r[k % 2] − α q, y = G r_new
                alpha = per_model_scalar()
                current = per_model_int()  # r[k % 2] of every model
                for m in range(wp.static(models)):
                    current[m] = new
                    if live[m] != 0:
                        alpha[m] = dtype(total(slots_all, first + m, RZ, k) / total(slots_all, first + m, PQ, k))
                g = block
                while g < groups:
                    row = g * rows + local
                    i = wp.min(row, count - 1)
                    y_rows = factor_rows(g_start, g_end, g_found, g_shared, lane, g_keys, g_values_all, first, last,
                                         r_flat_all, current, q_flat_all, 0, alpha)
                    for m in range(wp.static(models)):
                        if live[m] != 0 and row < count and lane == 0:
                            b = first + m
                            x_all[b, i] = x_all[b, i] + alpha[m] * p_all[b, new, i]
                            r_all[b, 1 - new, i] = r_all[b, new, i] - alpha[m] * q_all[b, i]
                            y_all[b, i] = y_rows[m]
                    g += blocks
                    g_start, g_end, g_found, g_shared = fetch_g(g_offsets, g_keys, g_values_all,
                                                                wp.min(g * rows + local, count - 1), lane)
                t_start, t_end, t_found, t_shared = fetch_g(t_offsets, t_keys, t_values_all, first_row, lane)
                arrivals += 1
                grid_sync(barrier, arrivals * blocks)
                k += 1
        if thread == 0:
            if block == 0:
                for m in range(wp.static(models)):
                    if first + m < model_end:
                        b = first + m
                        iterations = done[m]
                        if barrier[1] != 0:  # a block gave up at a barrier: book the step as not converged
                            iterations = maxiter
                            slots_all[b, RR, maxiter, 0] = wp.float64(wp.nan)
                        cg_iter_all[b, 0] = iterations
                        cg_iter_all[b, 1] = iterations
            # every block has passed its last barrier: the last one out clears the counters for the next step
            if wp.atomic_add(barrier, 2, 1) == blocks - 1:
                barrier[0] = 0
                barrier[2] = 0

    return types.SimpleNamespace(vec=vec, block_dim=rows * lanes, rows=rows, models=models, cg_step=cg_step)
