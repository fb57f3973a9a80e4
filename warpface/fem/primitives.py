"""Procedural tet meshes: structured boxes (verification) and curved tissue shells (benchmarks).

Both are hexahedral grids split into six tets per cell along the cell's main diagonal
(the Kuhn/Freudenthal split), which is conforming across neighbouring cells because every
cell is split the same way. Vectorised NumPy; no Python loop over cells.
"""

from __future__ import annotations

import itertools

import numpy as np

from .._validate import as_count, as_finite_array, shape_of
from .tetmesh import TetMesh, tet_signed_volumes

MAX_CELLS = 1000
"""Largest cell count along one axis of the primitive meshes; their product is limited to MAX_CELLS²."""

__all__ = ["box_tet_mesh", "shell_tet_mesh", "grid_tets"]

# Kuhn split of the unit cube: corner k has coordinates (k & 1, (k >> 1) & 1, (k >> 2) & 1);
# one tet per axis permutation, walking from corner 0 to corner 7 one axis at a time.
_KUHN = np.array(
    [[0, 1 << p[0], (1 << p[0]) | (1 << p[1]), 7] for p in itertools.permutations(range(3))],
    dtype=np.int64,
)


def grid_tets(shape: tuple[int, int, int]) -> np.ndarray:
    """Tets of a structured grid of ``shape = (nx, ny, nz)`` cells, nodes numbered ``i + (nx+1)(j + (ny+1) k)``.

    Returns:
        Node indices, shape (6 * nx * ny * nz, 4), int64, orientation not fixed.
    """
    nx, ny, nz = (int(s) for s in shape)
    if min(nx, ny, nz) < 1:
        raise ValueError(f"grid_tets: need at least one cell per axis, got {shape}")
    i, j, k = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    base = (i + (nx + 1) * (j + (ny + 1) * k)).ravel()
    corner = np.arange(8)
    offset = (corner & 1) + (nx + 1) * (((corner >> 1) & 1) + (ny + 1) * ((corner >> 2) & 1))
    return (base[:, None, None] + offset[_KUHN][None]).reshape(-1, 4)


def _oriented(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    flip = tet_signed_volumes(points, tets) < 0.0
    tets = tets.copy()
    tets[flip] = tets[flip][:, [0, 1, 3, 2]]
    return tets


def box_tet_mesh(size, cells) -> TetMesh:
    """Axis-aligned box ``[0, size_x] x [0, size_y] x [0, size_z]`` [m] of ``cells = (nx, ny, nz)`` hex cells.

    Node ``(i, j, k)`` has index ``i + (nx+1)(j + (ny+1) k)`` and position ``(i hx, j hy, k hz)``.
    """
    size = as_finite_array(size, "box_tet_mesh: size", shape=(3,))
    if not np.all(size > 0):
        raise ValueError(f"box_tet_mesh: size must be three positive lengths, got {size.tolist()}")
    if (
        isinstance(cells, (str, bytes, dict))
        or not isinstance(cells, (list, tuple, np.ndarray))
        or shape_of(cells) != (3,)
    ):
        raise ValueError(f"box_tet_mesh: cells must be three counts (nx, ny, nz), got {type(cells).__name__}")
    nx, ny, nz = (as_count(c, "box_tet_mesh: cells", minimum=1, maximum=MAX_CELLS) for c in cells)
    if nx * ny * nz > MAX_CELLS**2:
        raise ValueError(f"box_tet_mesh: {nx}·{ny}·{nz} cells is more than the largest accepted {MAX_CELLS**2}")
    x, y, z = (np.linspace(0.0, s, c + 1) for s, c in zip(size, (nx, ny, nz), strict=True))
    gx, gy, gz = np.meshgrid(x, y, z, indexing="ij")
    points = np.stack([gx.transpose(2, 1, 0).ravel(), gy.transpose(2, 1, 0).ravel(), gz.transpose(2, 1, 0).ravel()], 1)
    return TetMesh(points, _oriented(points, grid_tets((nx, ny, nz))))


def shell_tet_mesh(
    cells_u: int = 40,
    cells_v: int = 40,
    layers: int = 3,
    *,
    radii=(0.075, 0.105, 0.09),
    thickness: float = 0.012,
    span_u: float = 2.4,
    span_v: float = 2.0,
) -> TetMesh:
    """A curved tissue shell shaped like the front of a face: an ellipsoidal cap with thickness.

    The outer surface is the part of the ellipsoid with semi-axes ``radii`` [m] (x width,
    y height, z depth) within ``span_u`` [rad] of azimuth and ``span_v`` [rad] of elevation,
    facing +z; the shell extends ``thickness`` [m] inwards along the ellipsoid normal.
    ``(cells_u + 1) (cells_v + 1) (layers + 1)`` nodes; the default has 6,724 nodes, the
    scale of Kato's 6,434-node face (SPEC §2.1).
    """
    cells_u, cells_v, layers = (
        as_count(c, f"shell_tet_mesh: {n}", minimum=1, maximum=MAX_CELLS)
        for c, n in ((cells_u, "cells_u"), (cells_v, "cells_v"), (layers, "layers"))
    )
    if cells_u * cells_v * layers > MAX_CELLS**2:
        raise ValueError(
            f"shell_tet_mesh: {cells_u}·{cells_v}·{layers} cells is more than the largest accepted {MAX_CELLS**2}"
        )
    if not 0.0 < thickness < min(radii):
        raise ValueError(f"shell_tet_mesh: thickness must be in (0, {min(radii)}), got {thickness}")
    a, b, c = (float(r) for r in radii)
    u = np.linspace(-span_u / 2, span_u / 2, cells_u + 1)
    v = np.linspace(-span_v / 2, span_v / 2, cells_v + 1)
    w = np.linspace(0.0, 1.0, layers + 1)
    gu, gv, gw = np.meshgrid(u, v, w, indexing="ij")
    gu, gv, gw = (g.transpose(2, 1, 0).ravel() for g in (gu, gv, gw))
    # outer point on the ellipsoid, azimuth u around y, elevation v
    outer = np.stack([a * np.cos(gv) * np.sin(gu), b * np.sin(gv), c * np.cos(gv) * np.cos(gu)], axis=1)
    normal = outer / np.array([a * a, b * b, c * c])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    points = outer - (thickness * (1.0 - gw))[:, None] * normal
    tets = grid_tets((cells_u, cells_v, layers))
    return TetMesh(points, _oriented(points, tets))
