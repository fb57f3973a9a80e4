"""Where the targets sit on the face, and their validation at the boundary.

A target point is either a vertex or a surface point (triangle + barycentric coordinates); both are
rows of one sparse observation matrix ``P`` (N × V) so that the observed model positions are
``P · x3``. Only the vertices ``P`` touches are ever evaluated.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .._validate import MAX_COORDINATE

__all__ = ["Observation", "observation", "frame_targets", "point_weights"]


class Observation:
    """The observed points of a rig: ``P`` restricted to the vertices it touches.

    Attributes:
        count: number of target points N.
        vertices: the touched vertices, sorted, (n,) int64.
        matrix: ``P`` over the touched vertices, sparse (N, n) CSR.
        dense: True when the target is the whole mesh, vertex by vertex.
    """

    def __init__(
        self, vertex_count: int, rows: np.ndarray, columns: np.ndarray, values: np.ndarray, count: int, dense: bool
    ):
        self.vertices, local = np.unique(columns, return_inverse=True)
        self.matrix = sp.csr_matrix((values, (rows, local)), shape=(count, len(self.vertices)))
        self.count = count
        self.dense = dense
        self.vertex_count = vertex_count
        # Vertex targets select rows (no sparse product); dense targets in vertex order are the identity.
        is_selection = np.allclose(values, 1.0) and len(rows) == count
        self._selection = local[np.argsort(rows)] if is_selection else None
        self._identity = (
            is_selection and len(self.vertices) == count and np.array_equal(self._selection, np.arange(count))
        )

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Observed positions (N, 3) from the mesh's per-vertex positions (V, 3)."""
        return self.apply_frames(np.asarray(points)[None, self.vertices])[0]

    def apply_frames(self, values: np.ndarray) -> np.ndarray:
        """``P`` applied to per-vertex values at :attr:`vertices`: (F, n, ...) → (F, N, ...)."""
        if self._selection is not None:
            return values if self._identity else values[:, self._selection]
        moved = np.moveaxis(values, 1, 0)
        flat = self.matrix @ moved.reshape(moved.shape[0], -1)
        return np.moveaxis(np.asarray(flat).reshape((self.count,) + moved.shape[1:]), 0, 1)


def _integer_indices(values, name: str, upper: int) -> np.ndarray:
    array = np.asarray(values)
    if array.ndim != 1:
        raise ValueError(f"{name}: expected a 1-D array of indices, got shape {array.shape}")
    if array.dtype.kind == "f":
        if not np.all(np.isfinite(array)) or np.any(array != np.round(array)):
            raise ValueError(f"{name}: indices must be integers")
    elif array.dtype.kind == "b":
        raise ValueError(f"{name}: expected integer indices, got a boolean array (np.flatnonzero(mask) gives indices)")
    elif array.dtype.kind not in "iu":
        raise TypeError(f"{name}: indices must be integers, got dtype {array.dtype}")
    array = array.astype(np.int64)
    bad = np.flatnonzero((array < 0) | (array >= upper))
    if len(bad):
        raise ValueError(f"{name}: index {int(array[bad[0]])} at position {int(bad[0])} is out of range [0, {upper})")
    return array


def observation(mesh, vertices=None, triangles=None, barycentrics=None) -> Observation:
    """Build the observation of ``mesh`` for vertex targets, surface-point targets, or the dense shape.

    Args:
        vertices: (N,) vertex indices; or ``None``.
        triangles: (N,) triangle indices of surface points (with ``barycentrics``); or ``None``.
        barycentrics: (N, 3) barycentric coordinates, finite, each row summing to 1.
        Neither: the target is dense, (V, 3) in vertex order.

    Raises:
        ValueError: naming the bad argument (indices out of range, wrong shapes, non-finite values).
        TypeError: naming it when it is not numbers (or, for indices, not integers).
    """
    vertex_count = mesh.vertex_count
    if vertices is not None and (triangles is not None or barycentrics is not None):
        raise ValueError("vertices: give either vertices or triangles + barycentrics, not both")
    if vertices is not None:
        index = _integer_indices(vertices, "vertices", vertex_count)
        if len(index) == 0:
            raise ValueError("vertices: no target points")
        return Observation(vertex_count, np.arange(len(index)), index, np.ones(len(index)), len(index), False)
    if triangles is not None or barycentrics is not None:
        if triangles is None or barycentrics is None:
            raise ValueError("triangles: surface points need both triangles (N,) and barycentrics (N, 3)")
        tri = _integer_indices(triangles, "triangles", mesh.triangle_count)
        try:
            bary = np.asarray(barycentrics, dtype=np.float64)
        except (TypeError, ValueError):
            raise TypeError(
                "barycentrics: expected numbers, got values that do not convert to a numeric array"
            ) from None
        if bary.shape != (len(tri), 3):
            raise ValueError(f"barycentrics: expected shape ({len(tri)}, 3), got {bary.shape}")
        if not np.all(np.isfinite(bary)):
            raise ValueError(f"barycentrics: non-finite value in row {int(np.argwhere(~np.isfinite(bary))[0, 0])}")
        off = np.flatnonzero(np.abs(bary.sum(axis=1) - 1.0) > 1e-6)
        if len(off):
            raise ValueError(f"barycentrics: row {int(off[0])} sums to {bary[off[0]].sum():.6g}, expected 1")
        if len(tri) == 0:
            raise ValueError("triangles: no target points")
        corners = mesh.triangles[tri].astype(np.int64)
        return Observation(
            vertex_count, np.repeat(np.arange(len(tri)), 3), corners.ravel(), bary.ravel(), len(tri), False
        )
    every = np.arange(vertex_count)
    return Observation(vertex_count, every, every, np.ones(vertex_count), vertex_count, True)


def frame_targets(target, obs: Observation, *, batched: bool) -> np.ndarray:
    """``target`` as float64 (F, N, 3) (NaN allowed: missing points); ValueError naming what is wrong."""
    try:
        array = np.asarray(target, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError("target: expected numbers, got values that do not convert to a numeric array") from None
    expected = "(frames, N, 3)" if batched else "(N, 3)"
    if array.ndim != (3 if batched else 2) or array.shape[-1] != 3:
        raise ValueError(f"target: expected shape {expected}, got {array.shape}")
    if array.shape[-2] != obs.count:
        if obs.dense:
            raise ValueError(
                f"target: {array.shape[-2]} points but the rig's mesh has {obs.vertex_count} vertices "
                "(a dense target needs the rig's topology; give vertices= for sparse points)"
            )
        raise ValueError(f"target: {array.shape[-2]} points but {obs.count} target locations were given")
    if np.any(np.isinf(array)):
        raise ValueError("target: infinite coordinate (use NaN for a missing point)")
    with np.errstate(invalid="ignore"):
        far = np.abs(array) > MAX_COORDINATE
    if np.any(far):
        raise ValueError(
            f"target: coordinate {array[far][0]:.6g} is outside ±{MAX_COORDINATE:g} (use NaN for a missing point)"
        )
    return array if batched else array[None]


def point_weights(weights, count: int) -> np.ndarray:
    """Per-point weights (N,) ≥ 0 and finite; ``None`` → ones."""
    if weights is None:
        return np.ones(count)
    try:
        array = np.asarray(weights, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError("weights: expected numbers, got values that do not convert to a numeric array") from None
    if array.ndim == 0:
        array = np.full(count, float(array))
    if array.shape != (count,):
        raise ValueError(f"weights: expected shape ({count},), got {array.shape}")
    bad = np.flatnonzero(~np.isfinite(array))
    if len(bad):
        raise ValueError(f"weights: non-finite weight {array[bad[0]]} at point {int(bad[0])}")
    bad = np.flatnonzero(array < 0.0)
    if len(bad):
        raise ValueError(f"weights: negative weight {array[bad[0]]} at point {int(bad[0])}")
    return array
