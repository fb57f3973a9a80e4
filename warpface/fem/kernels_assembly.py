"""Warp kernels for linear-tet element matrices and their sparse assembly (SPEC §2).

Element matrices of a linear tet with shape-function gradients ``g_i`` (i = 0..3) and
volume ``V``: for any Voigt constitutive matrix of the isotropic-by-blocks form

    normal block  lam' * 1 1^T + 2 mu_n * I,   shear terms  mu_s   (engineering shear)

the 3x3 block coupling nodes ``i`` and ``j`` of ``V B^T D B`` is

    V [ lam' g_i g_j^T + 2 mu_n diag(g_i * g_j) + mu_s (g_i.g_j I + g_j g_i^T - 2 diag(g_i * g_j)) ].

Isotropic elasticity is ``(lam, mu, mu)``; its deviatoric part ``(-2 mu / 3, mu, mu)``;
Stokes damping ``(-2 eta / 3, eta, eta)``; the thesis's printed damping ``(-eta / 3, eta / 2, eta)``.
All kernels are float64: assembly runs once, and the oracles it is tested against are float64.
"""

from __future__ import annotations

import warp as wp

__all__ = [
    "mat13d",
    "tet_gradients",
    "voigt_block",
    "element_triplets",
    "volumetric_operator_triplets",
    "nodal_volumetric_stiffness_triplets",
    "remap_bsr_triplets",
]

mat13d = wp.types.matrix(shape=(1, 3), dtype=wp.float64)
"""1x3 float64 block: one row of the nodal volumetric-strain operator."""


@wp.func
def tet_gradients(p0: wp.vec3d, p1: wp.vec3d, p2: wp.vec3d, p3: wp.vec3d):
    """Shape-function gradients [1/m] (rows 0..2 of the result are nodes 1..3) and volume [m^3].

    Returns ``(G, V)`` where row ``k`` of ``G`` is the gradient of node ``k + 1``; node 0's
    gradient is minus the sum of the rows.
    """
    dm = wp.matrix_from_cols(p1 - p0, p2 - p0, p3 - p0)
    volume = wp.determinant(dm) / wp.float64(6.0)
    return wp.inverse(dm), volume


@wp.func
def node_gradient(g: wp.mat33d, i: int):
    """Gradient of local node ``i`` (0..3) from the ``G`` of :func:`tet_gradients`."""
    if i == 0:
        return -(wp.vec3d(g[0]) + wp.vec3d(g[1]) + wp.vec3d(g[2]))
    return wp.vec3d(g[i - 1])


@wp.func
def voigt_block(gi: wp.vec3d, gj: wp.vec3d, lam: wp.float64, mu_n: wp.float64, mu_s: wp.float64):
    """Unscaled 3x3 block ``B_i^T D B_j`` for the block-isotropic Voigt matrix (module docstring)."""
    gg = wp.cw_mul(gi, gj)
    diag = wp.diag(gg)
    return (
        lam * wp.outer(gi, gj)
        + (wp.float64(2.0) * mu_n) * diag
        + mu_s * (wp.dot(gi, gj) * wp.identity(n=3, dtype=wp.float64) + wp.outer(gj, gi) - wp.float64(2.0) * diag)
    )


@wp.kernel
def element_triplets(
    points: wp.array(dtype=wp.vec3d),
    tets: wp.array2d(dtype=wp.int32),
    stiffness_coeffs: wp.array(dtype=wp.vec3d),
    damping_coeffs: wp.array(dtype=wp.vec3d),
    density: wp.array(dtype=wp.float64),
    rows: wp.array(dtype=wp.int32),
    cols: wp.array(dtype=wp.int32),
    k_values: wp.array(dtype=wp.mat33d),
    m_values: wp.array(dtype=wp.mat33d),
    c_values: wp.array(dtype=wp.mat33d),
):
    """Sixteen 3x3 COO blocks of K, M and C per tet, at ``16 * tet + 4 * i + j``.

    ``stiffness_coeffs``/``damping_coeffs`` hold ``(lam', mu_n, mu_s)`` [Pa] / [Pa s] per tet;
    ``density`` [kg/m^3]. Consistent mass: ``rho V / 20 (1 + delta_ij) I``.
    """
    e, i, j = wp.tid()
    a = tets[e, i]
    b = tets[e, j]
    g, volume = tet_gradients(points[tets[e, 0]], points[tets[e, 1]], points[tets[e, 2]], points[tets[e, 3]])
    gi = node_gradient(g, i)
    gj = node_gradient(g, j)
    kc = stiffness_coeffs[e]
    cc = damping_coeffs[e]
    slot = 16 * e + 4 * i + j
    rows[slot] = a
    cols[slot] = b
    k_values[slot] = volume * voigt_block(gi, gj, kc[0], kc[1], kc[2])
    c_values[slot] = volume * voigt_block(gi, gj, cc[0], cc[1], cc[2])
    mass = density[e] * volume / wp.float64(20.0)
    if i == j:
        mass = mass * wp.float64(2.0)
    m_values[slot] = mass * wp.identity(n=3, dtype=wp.float64)


@wp.kernel
def volumetric_operator_triplets(
    points: wp.array(dtype=wp.vec3d),
    tets: wp.array2d(dtype=wp.int32),
    nodal_volumes: wp.array(dtype=wp.float64),
    rows: wp.array(dtype=wp.int32),
    cols: wp.array(dtype=wp.int32),
    values: wp.array(dtype=mat13d),
):
    """COO blocks of ``W``, the nodal-averaged volumetric strain ``theta = W d`` (ANP).

    ``theta_a = (1 / V_a) sum_{e ni a} (V_e / 4) div_e(d)`` with ``V_a`` the nodal volume, so
    tet ``e`` adds ``(V_e / 4 / V_a) g_j^T`` at row ``a`` (its local node ``i``), column ``j``.
    """
    e, i, j = wp.tid()
    a = tets[e, i]
    g, volume = tet_gradients(points[tets[e, 0]], points[tets[e, 1]], points[tets[e, 2]], points[tets[e, 3]])
    gj = node_gradient(g, j)
    w = volume / (wp.float64(4.0) * nodal_volumes[a])
    slot = 16 * e + 4 * i + j
    rows[slot] = a
    cols[slot] = tets[e, j]
    values[slot] = wp.matrix_from_rows(w * gj)


@wp.kernel
def nodal_volumetric_stiffness_triplets(
    w_offsets: wp.array(dtype=wp.int32),
    w_columns: wp.array(dtype=wp.int32),
    w_values: wp.array(dtype=mat13d),
    nodal_weight: wp.array(dtype=wp.float64),
    triplet_offsets: wp.array(dtype=wp.int32),
    rows: wp.array(dtype=wp.int32),
    cols: wp.array(dtype=wp.int32),
    values: wp.array(dtype=wp.mat33d),
):
    """COO blocks of ``W^T diag(kappa_a V_a) W``: all pairs of entries in row ``a`` of ``W``.

    ``nodal_weight[a] = kappa_a V_a`` [Pa m^3]; ``triplet_offsets[a]`` is the exclusive prefix sum
    of the squared row lengths of ``W``.
    """
    a = wp.tid()
    beg = w_offsets[a]
    n = w_offsets[a + 1] - beg
    out = triplet_offsets[a]
    weight = nodal_weight[a]
    for p in range(n):
        wp_row = w_values[beg + p]
        gp = wp.vec3d(wp_row[0, 0], wp_row[0, 1], wp_row[0, 2])
        for q in range(n):
            wq_row = w_values[beg + q]
            gq = wp.vec3d(wq_row[0, 0], wq_row[0, 1], wq_row[0, 2])
            slot = out + p * n + q
            rows[slot] = w_columns[beg + p]
            cols[slot] = w_columns[beg + q]
            values[slot] = weight * wp.outer(gp, gq)


@wp.kernel
def remap_bsr_triplets(
    offsets: wp.array(dtype=wp.int32),
    columns: wp.array(dtype=wp.int32),
    values: wp.array(dtype=wp.mat33d),
    row_map: wp.array(dtype=wp.int32),
    col_map: wp.array(dtype=wp.int32),
    col_shift: wp.int32,
    scale: wp.float64,
    out_offset: wp.int32,
    rows_out: wp.array(dtype=wp.int32),
    cols_out: wp.array(dtype=wp.int32),
    values_out: wp.array(dtype=wp.mat33d),
):
    """Copy the blocks of a compact BSR matrix into COO triplets with renumbered rows and columns.

    A block at (r, c) goes to ``(row_map[r], col_map[c] + col_shift)`` scaled by ``scale``, at
    ``out_offset + block``; a negative map entry drops it (row or column -1, ignored by
    ``bsr_set_from_triplets``).
    """
    r = wp.tid()
    new_row = row_map[r]
    for block in range(offsets[r], offsets[r + 1]):
        new_col = col_map[columns[block]]
        slot = out_offset + block
        if new_row >= 0 and new_col >= 0:
            rows_out[slot] = new_row
            cols_out[slot] = new_col + col_shift
            values_out[slot] = scale * values[block]
        else:
            rows_out[slot] = -1
            cols_out[slot] = -1
            values_out[slot] = wp.mat33d(wp.float64(0.0))
