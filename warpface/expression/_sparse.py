"""Vertex-major CSR packing of sparse (vertex, column, value) entries, shared by muscles and wrinkles."""

from __future__ import annotations

import numpy as np

__all__ = ["vertex_csr"]


def vertex_csr(vertex_count: int, rows: list, columns: list, values: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sort entries given as per-column lists into vertex-major CSR.

    Args:
        vertex_count: number of rows V.
        rows, columns, values: equally long lists; item ``i`` holds the vertex indices (E_i,), the
            column index (E_i,) and the values (E_i, ...) of one column (a muscle or a wrinkle).

    Returns:
        ``(offsets (V + 1,) int32, column (E,) int32, value (E, ...))`` with the entries of vertex
        ``v`` at ``offsets[v]:offsets[v + 1]``, in column order within a vertex.
    """
    if not rows:
        return np.zeros(vertex_count + 1, dtype=np.int32), np.zeros(0, dtype=np.int32), np.zeros(0)
    row = np.concatenate(rows).astype(np.int64)
    column = np.concatenate(columns).astype(np.int32)
    value = np.concatenate(values)
    order = np.argsort(row, kind="stable")
    offsets = np.zeros(vertex_count + 1, dtype=np.int32)
    np.cumsum(np.bincount(row, minlength=vertex_count), out=offsets[1:])
    return offsets, column[order], value[order]
