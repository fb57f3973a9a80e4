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
row: the entries of scalar rows ``3i .. 3i+2`` are ``offsets[i] .. offsets[i+1]`` and their keys ``indices[e] =
3 * column + row % 3``; they read vectors through flat scalar views (``u[3 node + axis]``: one scalar
load instead of a whole vec3). Kernels and functions take each matrix as one argument, a ``wp.struct``
of its three arrays (:func:`cg_matrix_types`): the same arrays, passed by value, so no extra loads.
"""

import functools
import math
import types
import typing

import warp as wp

__all__ = ["cg_matrix", "cg_matrix_types", "cg_row_functions", "model_rows"]

# Straight-line row entries per lane: block rows of A_oo hold ~15 blocks (up to ~30), rows of P three
# times that, a block row of an FSAI factor up to 3 x 32 scalars.
_SPAN_A, _SPAN_P, _SPAN_G, _MAX_UNROLL = 32, 64, 96, 8


def _matrix_struct(values_type):
    # one matrix: its row offsets, the column (or key) of each entry and the entries' values
    @wp.struct
    class MatrixRows:
        offsets: wp.array(dtype=wp.int32)
        indices: wp.array(dtype=wp.int32)
        values: values_type

    return MatrixRows


@functools.lru_cache(maxsize=None)
def cg_matrix_types(dtype) -> types.SimpleNamespace:
    """The value types of the CG for ``dtype``, ``vec`` (its ``wp.vec3``) and ``mat`` (3x3), and the ``wp.struct``
    types of its matrices (module docstring), each holding ``offsets`` (block rows + 1,), ``indices`` and ``values``:

    - ``BlockRows``: a BSR matrix of 3x3 blocks, ``A`` or ``P`` (``indices``: the block columns);
    - ``FactorRows``: a scalar CSR factor grouped by block row, ``G`` or ``Gᵀ`` (``indices``: the keys
      ``3 * column + row % 3``);
    - ``BatchBlockRows``, ``BatchFactorRows``: the same with the values of every model of a batch, shape
      (B, nnz), or (1, nnz) when all share one.
    """
    mat = wp.types.matrix(shape=(3, 3), dtype=dtype)
    return types.SimpleNamespace(
        vec=wp.types.vector(length=3, dtype=dtype),
        mat=mat,
        BlockRows=_matrix_struct(wp.array(dtype=mat)),
        FactorRows=_matrix_struct(wp.array(dtype=dtype)),
        BatchBlockRows=_matrix_struct(wp.array2d(dtype=mat)),
        BatchFactorRows=_matrix_struct(wp.array2d(dtype=dtype)),
    )


def cg_matrix(struct_type, offsets: wp.array, indices: wp.array, values: wp.array):
    """An instance of ``struct_type`` (one of :func:`cg_matrix_types`) holding a matrix's three arrays."""
    matrix = struct_type()
    matrix.offsets, matrix.indices, matrix.values = offsets, indices, values
    return matrix


@wp.func
def model_rows(batch: typing.Any, b: int, matrix: typing.Any):
    """``matrix`` (a ``BlockRows`` or ``FactorRows``) set to model ``b``'s matrix of ``batch`` (a
    ``BatchBlockRows`` or ``BatchFactorRows``); a matrix given once (leading dimension 1) is every model's."""
    matrix.offsets = batch.offsets
    matrix.indices = batch.indices
    matrix.values = batch.values[wp.min(b, batch.values.shape[0] - 1)]
    return matrix


def _row_fetch(matrix_type, index_type, unroll: int, lanes: int):
    """``fetch(M, i, lane)`` → ``(start, end, indices)``: the bounds of row ``i`` of ``M`` (a ``matrix_type``) and
    the indices (columns or keys) of this lane's ``unroll`` straight-line entries, clamped to the row (rows are
    never empty)."""

    @wp.func
    def fetch(M: matrix_type, i: int, lane: int):
        start, end = M.offsets[i], M.offsets[i + 1]
        found = index_type()
        for s in range(wp.static(unroll)):
            found[s] = M.indices[wp.min(start + lane + s * lanes, end - 1)]
        return start, end, found

    return fetch


@functools.lru_cache(maxsize=None)
def cg_row_functions(dtype, lanes: int) -> tuple:
    """Row functions for vectors of ``wp.vec3`` of ``dtype`` and ``lanes`` threads per row (module docstring),
    on the matrices of :func:`cg_matrix_types`. Returns the ``wp.func`` s ``(fetch_a, fetch_g, residual_part,
    direction_part, factor_part)``:

    - ``fetch_a(A, i, lane)`` → ``(start, end, columns)`` of block row ``i`` of a BSR matrix;
    - ``fetch_g(G, i, lane)`` → ``(start, end, keys)`` of block row ``i`` of a grouped factor;
    - ``residual_part(i, lane, P, A, d, v, a, driven, guess, force, free_nodes)`` → this lane's parts of
      ``(P [d; v; a; driven])_i + f[free_nodes[i]]`` and ``(A guess)_i`` (``P``'s columns ``[0, N)`` multiply ``d``,
      ``[N, 2N)`` ``v``, ``[2N, 3N)`` ``a``, the rest ``driven``; the external nodal force ``force`` (N,), added by
      lane 0, is left out when empty);
    - ``direction_part(start, end, columns, lane, A, z, p_old, beta)`` → part of ``(A (z + β p_old))_i``;
    - ``factor_part(start, end, keys, lane, G, u, w, alpha)`` → part of ``(G (u − α w))_i``
      (``u``, ``w`` flat scalar views; ``G y`` is ``u = w = y``, ``α = 0``).
    """
    if lanes < 1:
        raise ValueError(f"lanes must be positive, got {lanes}")
    matrices = cg_matrix_types(dtype)
    vec, BlockRows, FactorRows = matrices.vec, matrices.BlockRows, matrices.FactorRows
    unroll_a, unroll_p, unroll_g = (min(math.ceil(span / lanes), _MAX_UNROLL) for span in (_SPAN_A, _SPAN_P, _SPAN_G))
    index_a = wp.types.vector(length=unroll_a, dtype=wp.int32)
    index_g = wp.types.vector(length=unroll_g, dtype=wp.int32)

    @wp.func
    def unit(axis: int, value: dtype):
        # value * e_axis without indexing a vector by a runtime value (that spills it to local memory)
        zero = dtype(0.0)
        return vec(wp.where(axis == 0, value, zero), wp.where(axis == 1, value, zero), wp.where(axis == 2, value, zero))

    fetch_a = _row_fetch(BlockRows, index_a, unroll_a, lanes)
    fetch_g = _row_fetch(FactorRows, index_g, unroll_g, lanes)

    @wp.func
    def factor_part(
        start: int,
        end: int,
        found: index_g,
        lane: int,
        G: FactorRows,
        u: wp.array(dtype=dtype),
        w: wp.array(dtype=dtype),
        alpha: dtype,
    ):
        acc = vec()
        for s in range(wp.static(unroll_g)):
            e = start + lane + s * lanes
            col = found[s] // 3
            g = G.values[wp.min(e, end - 1)]
            acc += wp.where(e < end, unit(found[s] - 3 * col, g * (u[col] - alpha * w[col])), vec())
        for e in range(start + lane + unroll_g * lanes, end, lanes):
            key = G.indices[e]
            col = key // 3
            acc += unit(key - 3 * col, G.values[e] * (u[col] - alpha * w[col]))
        return acc

    @wp.func
    def direction_part(
        start: int,
        end: int,
        found: index_a,
        lane: int,
        A: BlockRows,
        z: wp.array(dtype=vec),
        p_old: wp.array(dtype=vec),
        beta: dtype,
    ):
        acc = vec()
        for s in range(wp.static(unroll_a)):
            e = start + lane + s * lanes
            j = found[s]
            acc += wp.where(e < end, A.values[wp.min(e, end - 1)] * (z[j] + beta * p_old[j]), vec())
        for e in range(start + lane + unroll_a * lanes, end, lanes):
            j = A.indices[e]
            acc += A.values[e] * (z[j] + beta * p_old[j])
        return acc

    @wp.func
    def state_entry(
        e: int,
        P: BlockRows,
        d: wp.array(dtype=vec),
        v: wp.array(dtype=vec),
        a: wp.array(dtype=vec),
        driven: wp.array(dtype=vec),
    ):
        c = P.indices[e]
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
        return P.values[e] * u

    @wp.func
    def residual_part(
        i: int,
        lane: int,
        P: BlockRows,
        A: BlockRows,
        d: wp.array(dtype=vec),
        v: wp.array(dtype=vec),
        a: wp.array(dtype=vec),
        driven: wp.array(dtype=vec),
        guess: wp.array(dtype=vec),
        force: wp.array(dtype=vec),
        free_nodes: wp.array(dtype=wp.int32),
    ):
        p_start, p_end = P.offsets[i], P.offsets[i + 1]
        a_start, a_end = A.offsets[i], A.offsets[i + 1]
        acc = vec()
        if lane == 0 and force.shape[0] > 0:
            acc = force[free_nodes[i]]
        for s in range(wp.static(unroll_p)):
            e = p_start + lane + s * lanes
            acc += wp.where(e < p_end, state_entry(wp.min(e, p_end - 1), P, d, v, a, driven), vec())
        for e in range(p_start + lane + unroll_p * lanes, p_end, lanes):
            acc += state_entry(e, P, d, v, a, driven)
        correction = vec()
        for s in range(wp.static(unroll_a)):
            e = wp.min(a_start + lane + s * lanes, a_end - 1)
            correction += wp.where(a_start + lane + s * lanes < a_end, A.values[e] * guess[A.indices[e]], vec())
        for e in range(a_start + lane + unroll_a * lanes, a_end, lanes):
            correction += A.values[e] * guess[A.indices[e]]
        return acc, correction

    return fetch_a, fetch_g, residual_part, direction_part, factor_part
