"""Warp kernels of the batched device Newmark step: B material models on one mesh, one launch per phase.

Every per-node array is ``(B, rows)`` (model-major), so consecutive threads of a launch of shape
``(B, rows)`` touch consecutive nodes of one model: coalesced loads on a GPU. The matrices share one
sparsity pattern (``offsets``, ``columns``) and hold their values per model (``values[model, entry]``);
per-model scalars are arrays of shape (B,).

One time step (see :class:`warpface.fem.solver_batch.BatchedCGSolver`) is

1. :data:`batch_begin` (B threads) — clear the model's accumulators, mark it active;
2. :data:`batch_residual` — residual of the Newmark predictor ``r_p = P [d; v; a; d_driven]`` and of
   the extrapolated start ``r_p − A_oo g``, and their squared norms;
3. :data:`batch_start` — each model starts from the better of the two; ``z = M⁻¹ r``, ``p = z``;
4. :data:`batch_check` (B threads) — converged already? Counts the models still running into the
   loop condition;
5. per CG iteration, in a ``wp.capture_while`` loop while any model runs: :data:`batch_product`
   (``q = A p``, ``p·q``), :data:`batch_update` (``x += α p``, ``r −= α q``, ``z = M⁻¹ r``, ``r·z``,
   ``r·r``), :data:`batch_check` (``β``, convergence per model) and :data:`batch_direction`
   (``p = z + β p``). A model that has converged skips all work;
6. :data:`batch_newmark_update` — new displacement (predictor + correction, driven or fixed value),
   :func:`~warpface.fem.kernels_integrator.newmark_advance`, the record of the step, and the cubic
   extrapolation for the next step (as the single-model CG solver).

The preconditioner is either 3x3 block Jacobi (the inverse diagonal blocks, per model) or one
factorised ``M⁻¹ = Gᵀ G`` (:data:`batch_factor_product`, :data:`batch_factor_finish`): FSAI of one
model's matrix shared by all models (values (1, nnz)), or that support refitted per model (values
(B, nnz)); any SPD preconditioner keeps CG exact, a shared one only costs iterations where the
models differ. All arithmetic is float64.
"""

from __future__ import annotations

import warp as wp

from .kernels_integrator import newmark_advance

__all__ = [
    "SCALARS",
    "S_RZ",
    "S_RZ_NEW",
    "batch_begin",
    "batch_block_jacobi",
    "batch_check",
    "batch_direction",
    "batch_factor_finish",
    "batch_factor_product",
    "batch_newmark_update",
    "batch_product",
    "batch_residual",
    "batch_start",
    "batch_update",
]

ROW_CHUNK = wp.constant(8)
"""Matrix-row entries per straight-line group in the per-iteration products: a thread walks a row of
up to ~96 entries, and within a group all loads are issued before the first is used (latency bound)."""

SCALARS = 10
"""Per-model scalars (second index of ``scalars``): see the ``S_*`` constants."""
S_PRED, S_GUESS, S_RZ, S_RZ_NEW, S_PQ, S_RR, S_BETA, S_THRESHOLD, S_LAST_RR, S_ITER = (wp.constant(k) for k in range(10))


@wp.kernel(enable_backward=False)
def batch_block_jacobi(
    offsets: wp.array(dtype=wp.int32),
    columns: wp.array(dtype=wp.int32),
    values: wp.array2d(dtype=wp.mat33d),
    inverse: wp.array2d(dtype=wp.mat33d),
):
    """``inverse[b, i]`` = inverse of the diagonal block of row ``i`` of model ``b`` (NaN if singular)."""
    b, i = wp.tid()
    block = wp.mat33d(wp.float64(0.0))
    for e in range(offsets[i], offsets[i + 1]):
        if columns[e] == i:
            block = values[b, e]
    if wp.determinant(block) > wp.float64(0.0):
        inverse[b, i] = wp.inverse(block)
    else:
        inverse[b, i] = wp.mat33d(wp.nan)


@wp.kernel(enable_backward=False)
def batch_begin(
    scalars: wp.array2d(dtype=wp.float64),
    active: wp.array(dtype=wp.int32),
    ring: wp.array(dtype=wp.int32),
    step_count: wp.array(dtype=wp.int32),
    condition: wp.array(dtype=wp.int32),
):
    """Per model: clear its accumulators and iteration count, mark it active. Model 0 copies ``ring[0]``
    to ``ring[1]`` and ``step_count[0]`` to ``step_count[1]`` (later kernels of the step read the copies)
    and clears the loop condition."""
    b = wp.tid()
    for k in range(wp.static(SCALARS)):
        scalars[b, k] = wp.float64(0.0)
    active[b] = 1
    if b == 0:
        ring[1] = ring[0]
        step_count[1] = step_count[0]
        condition[0] = 0


@wp.kernel(enable_backward=False)
def batch_residual(
    p_offsets: wp.array(dtype=wp.int32),
    p_columns: wp.array(dtype=wp.int32),
    p_values: wp.array2d(dtype=wp.mat33d),
    a_offsets: wp.array(dtype=wp.int32),
    a_columns: wp.array(dtype=wp.int32),
    a_values: wp.array2d(dtype=wp.mat33d),
    d: wp.array2d(dtype=wp.vec3d),
    v: wp.array2d(dtype=wp.vec3d),
    a: wp.array2d(dtype=wp.vec3d),
    trajectory: wp.array3d(dtype=wp.vec3d),
    ring: wp.array(dtype=wp.int32),
    guess: wp.array2d(dtype=wp.vec3d),
    predicted: wp.array2d(dtype=wp.vec3d),
    r: wp.array2d(dtype=wp.vec3d),
    scalars: wp.array2d(dtype=wp.float64),
):
    """``predicted = P [d; v; a; trajectory[ring[1]]]`` and ``r = predicted − A guess`` per model; squared norms
    into ``scalars[:, S_PRED]`` and ``scalars[:, S_GUESS]``. ``P``'s columns ``[0, N)`` multiply ``d``,
    ``[N, 2N)`` ``v``, ``[2N, 3N)`` ``a``, ``[3N, 3N + D)`` the driven displacements."""
    b, i = wp.tid()
    n = d.shape[1]
    slot = ring[1]
    acc = wp.vec3d()
    for e in range(p_offsets[i], p_offsets[i + 1]):
        c = p_columns[e]
        u = wp.vec3d()
        if c < n:
            u = d[b, c]
        elif c < 2 * n:
            u = v[b, c - n]
        elif c < 3 * n:
            u = a[b, c - 2 * n]
        else:
            u = trajectory[slot, b, c - 3 * n]
        acc += p_values[b, e] * u
    correction = wp.vec3d()
    for e in range(a_offsets[i], a_offsets[i + 1]):
        correction += a_values[b, e] * guess[b, a_columns[e]]
    start = acc - correction
    predicted[b, i] = acc
    r[b, i] = start
    wp.atomic_add(scalars, b, S_PRED, wp.dot(acc, acc))
    wp.atomic_add(scalars, b, S_GUESS, wp.dot(start, start))


@wp.kernel(enable_backward=False)
def batch_start(
    guess: wp.array2d(dtype=wp.vec3d),
    predicted: wp.array2d(dtype=wp.vec3d),
    inverse: wp.array2d(dtype=wp.mat33d),
    r: wp.array2d(dtype=wp.vec3d),
    x: wp.array2d(dtype=wp.vec3d),
    z: wp.array2d(dtype=wp.vec3d),
    p: wp.array2d(dtype=wp.vec3d),
    scalars: wp.array2d(dtype=wp.float64),
    use_inverse: int,
):
    """Start each model from the better of predictor and extrapolation; with ``use_inverse`` also
    ``z = p = M⁻¹ r`` (block Jacobi) and ``r·z`` into ``S_RZ`` (else the factor kernels do that)."""
    b, i = wp.tid()
    ri = r[b, i]
    xi = guess[b, i]
    if not (scalars[b, S_GUESS] <= scalars[b, S_PRED]):
        ri = predicted[b, i]
        xi = wp.vec3d()
        r[b, i] = ri
    x[b, i] = xi
    if use_inverse == 1:
        zi = inverse[b, i] * ri
        z[b, i] = zi
        p[b, i] = zi
        wp.atomic_add(scalars, b, S_RZ, wp.dot(ri, zi))


@wp.kernel(enable_backward=False)
def batch_check(
    scalars: wp.array2d(dtype=wp.float64),
    active: wp.array(dtype=wp.int32),
    tol_sq: wp.float64,
    maxiter: int,
    first: int,
    condition: wp.array(dtype=wp.int32),
):
    """Per active model: after the start (``first`` = 1) set its threshold ``tol² |r_p|²`` and its start's
    ``r·r``; after an iteration count it, form ``β`` and shift ``r·z``. Stop the model when
    ``r·r <= threshold`` (or NaN) or at ``maxiter``; else add it to ``condition[0]``."""
    b = wp.tid()
    if active[b] == 0:
        return
    rr = wp.float64(0.0)
    if first == 1:
        scalars[b, S_THRESHOLD] = tol_sq * scalars[b, S_PRED]
        rr = wp.min(scalars[b, S_PRED], scalars[b, S_GUESS])
    else:
        scalars[b, S_ITER] = scalars[b, S_ITER] + wp.float64(1.0)
        rr = scalars[b, S_RR]
        scalars[b, S_BETA] = scalars[b, S_RZ_NEW] / scalars[b, S_RZ]
        scalars[b, S_RZ] = scalars[b, S_RZ_NEW]
        scalars[b, S_RZ_NEW] = wp.float64(0.0)
        scalars[b, S_PQ] = wp.float64(0.0)
        scalars[b, S_RR] = wp.float64(0.0)
    scalars[b, S_LAST_RR] = rr
    if not (rr > scalars[b, S_THRESHOLD]) or int(scalars[b, S_ITER]) >= maxiter:
        active[b] = 0
    else:
        wp.atomic_add(condition, 0, 1)


@wp.kernel(enable_backward=False)
def batch_product(
    offsets: wp.array(dtype=wp.int32),
    columns: wp.array(dtype=wp.int32),
    values: wp.array2d(dtype=wp.mat33d),
    p: wp.array2d(dtype=wp.vec3d),
    active: wp.array(dtype=wp.int32),
    q: wp.array2d(dtype=wp.vec3d),
    scalars: wp.array2d(dtype=wp.float64),
    condition: wp.array(dtype=wp.int32),
):
    """``q = A p`` and ``p·q`` into ``S_PQ`` for active models; thread (0, 0) clears the loop condition."""
    b, i = wp.tid()
    if b == 0 and i == 0:
        condition[0] = 0
    if active[b] == 0:
        return
    acc = wp.vec3d()
    e = offsets[i]
    end = offsets[i + 1]
    while e + ROW_CHUNK <= end:  # straight-line groups: their loads are in flight together
        for s in range(wp.static(ROW_CHUNK)):
            acc += values[b, e + s] * p[b, columns[e + s]]
        e += ROW_CHUNK
    while e < end:
        acc += values[b, e] * p[b, columns[e]]
        e += 1
    q[b, i] = acc
    wp.atomic_add(scalars, b, S_PQ, wp.dot(p[b, i], acc))


@wp.kernel(enable_backward=False)
def batch_update(
    p: wp.array2d(dtype=wp.vec3d),
    q: wp.array2d(dtype=wp.vec3d),
    inverse: wp.array2d(dtype=wp.mat33d),
    active: wp.array(dtype=wp.int32),
    x: wp.array2d(dtype=wp.vec3d),
    r: wp.array2d(dtype=wp.vec3d),
    z: wp.array2d(dtype=wp.vec3d),
    scalars: wp.array2d(dtype=wp.float64),
    use_inverse: int,
):
    """``α = r·z / p·q``, ``x += α p``, ``r −= α q``, ``r·r`` into ``S_RR``; with ``use_inverse``
    ``z = M⁻¹ r`` and ``r·z`` into ``S_RZ_NEW``."""
    b, i = wp.tid()
    if active[b] == 0:
        return
    alpha = scalars[b, S_RZ] / scalars[b, S_PQ]
    x[b, i] = x[b, i] + alpha * p[b, i]
    ri = r[b, i] - alpha * q[b, i]
    r[b, i] = ri
    if use_inverse == 1:
        zi = inverse[b, i] * ri
        z[b, i] = zi
        wp.atomic_add(scalars, b, S_RZ_NEW, wp.dot(ri, zi))
    wp.atomic_add(scalars, b, S_RR, wp.dot(ri, ri))


@wp.kernel(enable_backward=False)
def batch_direction(
    z: wp.array2d(dtype=wp.vec3d),
    active: wp.array(dtype=wp.int32),
    scalars: wp.array2d(dtype=wp.float64),
    p: wp.array2d(dtype=wp.vec3d),
):
    """``p = z + β p`` for active models."""
    b, i = wp.tid()
    if active[b] == 0:
        return
    p[b, i] = z[b, i] + scalars[b, S_BETA] * p[b, i]


@wp.kernel(enable_backward=False)
def batch_newmark_update(
    correction: wp.array2d(dtype=wp.vec3d),
    history: wp.array3d(dtype=wp.vec3d),
    guess: wp.array2d(dtype=wp.vec3d),
    free_index: wp.array(dtype=wp.int32),
    driven_slot: wp.array(dtype=wp.int32),
    trajectory: wp.array3d(dtype=wp.vec3d),
    ring: wp.array(dtype=wp.int32),
    mass_displacement: wp.float64,
    mass_velocity: wp.float64,
    mass_acceleration: wp.float64,
    velocity_old_acceleration: wp.float64,
    velocity_new_acceleration: wp.float64,
    dt: wp.float64,
    half_dt_squared: wp.float64,
    scalars: wp.array2d(dtype=wp.float64),
    chunk: int,
    d: wp.array2d(dtype=wp.vec3d),
    v: wp.array2d(dtype=wp.vec3d),
    a: wp.array2d(dtype=wp.vec3d),
    record: wp.array3d(dtype=wp.vec3d),
    status: wp.array2d(dtype=wp.int32),
    failure: wp.array2d(dtype=wp.float64),
    step_count: wp.array(dtype=wp.int32),
):
    """End of a batched step, per (model, node): new displacement, Newmark update in place, record, extrapolation.

    Thread ``(b, 0)`` books model ``b``'s CG status: ``status[b] = [failed steps, first failed step,
    max iterations, last iterations, total iterations]``, ``failure[b] = [residual, tolerance]`` of
    its first failed step (NaN counts as failed). Thread (0, 0) counts the step (``step_count[0]``) and
    advances ``ring[0]``.
    """
    b, i = wp.tid()
    slot = ring[1]
    di = d[b, i]
    vi = v[b, i]
    ai = a[b, i]
    dn = wp.vec3d()
    o = free_index[i]
    s = driven_slot[i]
    if o >= 0:
        dn = di + dt * vi + half_dt_squared * ai + correction[b, o]
    elif s >= 0:
        dn = trajectory[slot, b, s]
    an, vn = newmark_advance(dn, di, vi, ai, mass_displacement, mass_velocity, mass_acceleration,
                             velocity_old_acceleration, velocity_new_acceleration)
    d[b, i] = dn
    v[b, i] = vn
    a[b, i] = an
    record[slot, b, i] = dn
    if o >= 0:
        increment = dn - di
        previous = history[0, b, o]
        guess[b, o] = wp.float64(3.0) * (increment - previous) + history[1, b, o] - dt * vn - half_dt_squared * an
        history[1, b, o] = previous
        history[0, b, o] = increment
    if i == 0:
        iterations = int(scalars[b, S_ITER])
        status[b, 2] = wp.max(status[b, 2], iterations)
        status[b, 3] = iterations
        status[b, 4] = status[b, 4] + iterations
        if not (scalars[b, S_LAST_RR] <= scalars[b, S_THRESHOLD]):
            if status[b, 0] == 0:
                status[b, 1] = step_count[1]
                failure[b, 0] = wp.sqrt(scalars[b, S_LAST_RR])
                failure[b, 1] = wp.sqrt(scalars[b, S_THRESHOLD])
            status[b, 0] = status[b, 0] + 1
        if b == 0:
            step_count[0] = step_count[1] + 1
            ring[0] = (slot + 1) % chunk


# The factorised preconditioner M⁻¹ = Gᵀ G (FSAI: one factor for every model, or one per model):
# scalar CSR grouped by block row, ``keys[e] = 3 * column + row % 3`` (as the single-model CG kernels).


@wp.func
def _unit(axis: int, value: wp.float64):
    zero = wp.float64(0.0)
    return wp.vec3d(wp.where(axis == 0, value, zero), wp.where(axis == 1, value, zero), wp.where(axis == 2, value, zero))


@wp.func
def _factor_entry(keys: wp.array(dtype=wp.int32), values: wp.array2d(dtype=wp.float64), u_flat: wp.array2d(dtype=wp.float64),
                  row: int, b: int, e: int):
    """Entry ``e`` of a grouped factor row times ``u``: ``values[row, e] · u[column]`` on its row's axis."""
    key = keys[e]
    col = key // 3
    return _unit(key - 3 * col, values[row, e] * u_flat[b, col])


@wp.kernel(enable_backward=False)
def batch_factor_product(
    offsets: wp.array(dtype=wp.int32),
    keys: wp.array(dtype=wp.int32),
    values: wp.array2d(dtype=wp.float64),
    u_flat: wp.array2d(dtype=wp.float64),
    active: wp.array(dtype=wp.int32),
    out: wp.array2d(dtype=wp.vec3d),
):
    """``out[b] = G u[b]`` for active models (``u_flat``: the scalar view (B, 3F) of ``u``)."""
    b, i = wp.tid()
    if active[b] == 0:
        return
    row = wp.min(b, values.shape[0] - 1)  # one shared factor, or one per model
    acc = wp.vec3d()
    e = offsets[i]
    end = offsets[i + 1]
    while e + ROW_CHUNK <= end:
        for s in range(wp.static(ROW_CHUNK)):
            acc += _factor_entry(keys, values, u_flat, row, b, e + s)
        e += ROW_CHUNK
    while e < end:
        acc += _factor_entry(keys, values, u_flat, row, b, e)
        e += 1
    out[b, i] = acc


@wp.kernel(enable_backward=False)
def batch_factor_finish(
    offsets: wp.array(dtype=wp.int32),
    keys: wp.array(dtype=wp.int32),
    values: wp.array2d(dtype=wp.float64),
    y_flat: wp.array2d(dtype=wp.float64),
    r: wp.array2d(dtype=wp.vec3d),
    active: wp.array(dtype=wp.int32),
    which: int,
    set_direction: int,
    z: wp.array2d(dtype=wp.vec3d),
    p: wp.array2d(dtype=wp.vec3d),
    scalars: wp.array2d(dtype=wp.float64),
):
    """``z[b] = Gᵀ y[b]`` (``Gᵀ`` in the same grouped form), ``r·z`` into ``scalars[b, which]``; ``p = z`` if
    ``set_direction``."""
    b, i = wp.tid()
    if active[b] == 0:
        return
    row = wp.min(b, values.shape[0] - 1)  # one shared factor, or one per model
    acc = wp.vec3d()
    e = offsets[i]
    end = offsets[i + 1]
    while e + ROW_CHUNK <= end:
        for s in range(wp.static(ROW_CHUNK)):
            acc += _factor_entry(keys, values, y_flat, row, b, e + s)
        e += ROW_CHUNK
    while e < end:
        acc += _factor_entry(keys, values, y_flat, row, b, e)
        e += 1
    z[b, i] = acc
    if set_direction == 1:
        p[b, i] = acc
    wp.atomic_add(scalars, b, which, wp.dot(r[b, i], acc))
