"""Matrix rows of the device CG step: one lane's part of a row times a vector.

Both CG loops (the launched kernels of :mod:`warpface.fem.kernels_cg` and the persistent kernel of
:mod:`warpface.fem.kernels_persistent`) share a free node's matrix row among ``lanes`` threads and
compute the same row products; this module builds them once per float type and lane count. Each
function returns the calling lane's partial sum (a ``vec3``): the kernel sums the lanes of a row
its own way (shared memory or warp shuffles), so the arithmetic of a lane is the same in both loops.

A lane walks its entries ``start + lane, start + lane + lanes, ...``: the first ``unroll`` in
straight-line code (clamped index, masked result, so all their loads are in flight together; a
thread walking a row would load 15–96 entries one after another), the rest in an ordinary loop.
Indices that do not depend on the iteration (``fetch_a``, ``fetch_g``) are loaded by separate
functions, so a kernel can load them ahead of a barrier or of loads that do.

``A`` and ``P`` are BSR with 3x3 blocks. ``G`` and ``Gᵀ`` are scalar CSR matrices grouped by block
row: the entries of scalar rows ``3i .. 3i+2`` are ``offsets[i] .. offsets[i+1]`` and ``keys[e] =
3 * column + row % 3``; they read vectors through flat scalar views (``u[3 node + axis]``: one scalar
load instead of a whole vec3).
"""

import functools
import math
import types

import warp as wp

__all__ = ["cg_row_functions"]

# Straight-line row entries per lane: block rows of A_oo hold ~15 blocks (up to ~30), rows of P three
# times that, a block row of an FSAI factor up to 3 x 32 scalars.
_SPAN_A, _SPAN_P, _SPAN_G, _MAX_UNROLL = 32, 64, 96, 8


def _row_fetch(index_type, unroll: int, lanes: int):
    """``fetch(offsets, indices, i, lane)`` → ``(start, end, indices)``: the bounds of row ``i`` and the indices
    (columns or keys) of this lane's ``unroll`` straight-line entries, clamped to the row (rows are never empty)."""

    @wp.func
    def fetch(offsets: wp.array(dtype=wp.int32), indices: wp.array(dtype=wp.int32), i: int, lane: int):
        start, end = offsets[i], offsets[i + 1]
        found = index_type()
        for s in range(wp.static(unroll)):
            found[s] = indices[wp.min(start + lane + s * lanes, end - 1)]
        return start, end, found

    return fetch


@functools.lru_cache(maxsize=None)
def cg_row_functions(dtype, lanes: int) -> types.SimpleNamespace:
    """Row functions for vectors of ``wp.vec3`` of ``dtype`` and ``lanes`` threads per row (module docstring).

    Returns a namespace with ``vec``, ``mat`` and the ``wp.func`` s:

    - ``fetch_a(offsets, columns, i, lane)`` → ``(start, end, columns)`` of block row ``i`` of a BSR matrix;
    - ``fetch_g(offsets, keys, i, lane)`` → ``(start, end, keys)`` of block row ``i`` of a grouped factor;
    - ``residual_part(i, lane, P…, A…, d, v, a, driven, guess)`` → this lane's parts of
      ``(P [d; v; a; driven])_i`` and ``(A guess)_i`` (``P``'s columns ``[0, N)`` multiply ``d``,
      ``[N, 2N)`` ``v``, ``[2N, 3N)`` ``a``, the rest ``driven``);
    - ``direction_part(start, end, columns, lane, a_columns, values, z, p_old, beta)`` → part of
      ``(A (z + β p_old))_i``;
    - ``factor_part(start, end, keys, lane, g_keys, values, u, w, alpha)`` → part of ``(G (u − α w))_i``
      (``u``, ``w`` flat scalar views; ``G y`` is ``u = w = y``, ``α = 0``).
    """
    if lanes < 1:
        raise ValueError(f"lanes must be positive, got {lanes}")
    vec = wp.types.vector(length=3, dtype=dtype)
    mat = wp.types.matrix(shape=(3, 3), dtype=dtype)
    unroll_a, unroll_p, unroll_g = (min(math.ceil(span / lanes), _MAX_UNROLL) for span in (_SPAN_A, _SPAN_P, _SPAN_G))
    index_a = wp.types.vector(length=unroll_a, dtype=wp.int32)
    index_g = wp.types.vector(length=unroll_g, dtype=wp.int32)

    @wp.func
    def unit(axis: int, value: dtype):
        # value * e_axis without indexing a vector by a runtime value (that spills it to local memory)
        zero = dtype(0.0)
        return vec(wp.where(axis == 0, value, zero), wp.where(axis == 1, value, zero), wp.where(axis == 2, value, zero))

    fetch_a, fetch_g = _row_fetch(index_a, unroll_a, lanes), _row_fetch(index_g, unroll_g, lanes)

    @wp.func
    def factor_part(
        start: int,
        end: int,
        found: index_g,
        lane: int,
        keys: wp.array(dtype=wp.int32),
        values: wp.array(dtype=dtype),
        u: wp.array(dtype=dtype),
        w: wp.array(dtype=dtype),
        alpha: dtype,
    ):
        acc = vec()
        for s in range(wp.static(unroll_g)):
            e = start + lane + s * lanes
            col = found[s] // 3
            g = values[wp.min(e, end - 1)]
            acc += wp.where(e < end, unit(found[s] - 3 * col, g * (u[col] - alpha * w[col])), vec())
        for e in range(start + lane + unroll_g * lanes, end, lanes):
            key = keys[e]
            col = key // 3
            acc += unit(key - 3 * col, values[e] * (u[col] - alpha * w[col]))
        return acc

    @wp.func
    def direction_part(
        start: int,
        end: int,
        found: index_a,
        lane: int,
        columns: wp.array(dtype=wp.int32),
        values: wp.array(dtype=mat),
        z: wp.array(dtype=vec),
        p_old: wp.array(dtype=vec),
        beta: dtype,
    ):
        acc = vec()
        for s in range(wp.static(unroll_a)):
            e = start + lane + s * lanes
            j = found[s]
            acc += wp.where(e < end, values[wp.min(e, end - 1)] * (z[j] + beta * p_old[j]), vec())
        for e in range(start + lane + unroll_a * lanes, end, lanes):
            j = columns[e]
            acc += values[e] * (z[j] + beta * p_old[j])
        return acc

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
    def residual_part(
        i: int,
        lane: int,
        p_offsets: wp.array(dtype=wp.int32),
        p_columns: wp.array(dtype=wp.int32),
        p_values: wp.array(dtype=mat),
        a_offsets: wp.array(dtype=wp.int32),
        a_columns: wp.array(dtype=wp.int32),
        a_values: wp.array(dtype=mat),
        d: wp.array(dtype=vec),
        v: wp.array(dtype=vec),
        a: wp.array(dtype=vec),
        driven: wp.array(dtype=vec),
        guess: wp.array(dtype=vec),
    ):
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
        return acc, correction

    return types.SimpleNamespace(
        vec=vec,
        mat=mat,
        fetch_a=fetch_a,
        fetch_g=fetch_g,
        factor_part=factor_part,
        direction_part=direction_part,
        residual_part=residual_part,
    )
