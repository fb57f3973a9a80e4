"""Embedding a render surface in a tet mesh: containing tet and barycentric weights per vertex.

The FEM of SPEC §2 runs on a coarse tet mesh of the tissue; the face is drawn with a finer surface.
Each surface vertex ``x`` is bound to the tet that contains it, with barycentric weights ``w``
(``x = Σ_k w_k p_k`` over the tet's four nodes ``p_k``), so any nodal field ``u`` — displacements,
velocities — moves the surface as ``u(x) = Σ_k w_k u_k`` (exact for fields linear inside a tet,
which is what linear tets represent). Vertices just outside the tet mesh (a mesher approximates
the boundary within an envelope) bind to the nearest tet, at their closest point in it.

Location is a Warp kernel over a BVH of tet bounding boxes (``wp.Bvh``, ``wp.bvh_query_aabb``);
interpolation is a Warp kernel over vertices (and frames), so both run unchanged on CPU and CUDA.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import warp as wp

from .._validate import as_device, expect_instance
from ..geometry.bounds import padded_element_bvh
from ..geometry.funcs import closest_point_on_triangle
from .tetmesh import MAX_COORDINATE, TET_EDGE_NODES, TetMesh

__all__ = ["Embedding", "embed_points"]

# A point whose smallest barycentric coordinate is at least this is inside its tet (round-off).
_INSIDE_TOLERANCE = 1e-10


# ---------------------------------------------------------------------------------------------- kernels


@wp.kernel
def _tet_inverse(points: wp.array(dtype=wp.vec3d), tets: wp.array(dtype=wp.vec4i), inverse: wp.array(dtype=wp.mat33d)):
    """Per tet: the inverse of its edge matrix ``[p1 - p0, p2 - p0, p3 - p0]``."""
    t = wp.tid()
    tet = tets[t]
    p0 = points[tet[0]]
    inverse[t] = wp.inverse(wp.matrix_from_cols(points[tet[1]] - p0, points[tet[2]] - p0, points[tet[3]] - p0))


@wp.func
def _barycentric(x: wp.vec3d, p0: wp.vec3d, inverse: wp.mat33d) -> wp.vec4d:
    l = inverse * (x - p0)
    return wp.vec4d(wp.float64(1.0) - l[0] - l[1] - l[2], l[0], l[1], l[2])


@wp.func
def _min4(v: wp.vec4d) -> wp.float64:
    return wp.min(wp.min(v[0], v[1]), wp.min(v[2], v[3]))


@wp.func
def _on_face(x: wp.vec3d, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d) -> wp.vec3d:
    """The point of face ``abc`` closest to ``x`` (float64: embedding distances are checked to 1e-12 m)."""
    w = closest_point_on_triangle(x, a, b, c)
    return w[0] * a + w[1] * b + w[2] * c


@wp.func
def _closest_in_tet(x: wp.vec3d, p0: wp.vec3d, p1: wp.vec3d, p2: wp.vec3d, p3: wp.vec3d) -> wp.vec3d:
    """Closest point to an exterior point ``x`` on the boundary of a tet (its four faces)."""
    best = _on_face(x, p1, p2, p3)
    best_d = wp.length_sq(best - x)
    c = _on_face(x, p0, p2, p3)
    d = wp.length_sq(c - x)
    if d < best_d:
        best = c
        best_d = d
    c = _on_face(x, p0, p1, p3)
    d = wp.length_sq(c - x)
    if d < best_d:
        best = c
        best_d = d
    c = _on_face(x, p0, p1, p2)
    d = wp.length_sq(c - x)
    if d < best_d:
        best = c
    return best


@wp.func
def _clamped(w: wp.vec4d) -> wp.vec4d:
    """Barycentric weights with round-off negatives zeroed, renormalised to sum 1."""
    zero = wp.float64(0.0)
    c = wp.vec4d(wp.max(w[0], zero), wp.max(w[1], zero), wp.max(w[2], zero), wp.max(w[3], zero))
    return c / (c[0] + c[1] + c[2] + c[3])


@wp.kernel
def _locate(
    bvh: wp.uint64,
    points: wp.array(dtype=wp.vec3d),
    tets: wp.array(dtype=wp.vec4i),
    inverse: wp.array(dtype=wp.mat33d),
    queries: wp.array(dtype=wp.vec3d),
    pad: float,
    max_distance: float,
    found_tet: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=wp.vec4d),
    distance: wp.array(dtype=wp.float64),
):
    """Containing tet of each query point, else the nearest tet within ``max_distance`` (or -1)."""
    k = wp.tid()
    x = queries[k]
    xf = wp.vec3(float(x[0]), float(x[1]), float(x[2]))
    # 1. containing tet: the candidate whose smallest barycentric coordinate is largest
    best = int(-1)
    best_min = wp.float64(-1.0e300)
    best_w = wp.vec4d()
    query = wp.bvh_query_aabb(bvh, xf - wp.vec3(pad, pad, pad), xf + wp.vec3(pad, pad, pad))
    t = int(0)
    while wp.bvh_query_next(query, t):
        w = _barycentric(x, points[tets[t][0]], inverse[t])
        m = _min4(w)
        if m > best_min:
            best_min = m
            best = t
            best_w = w
    if best >= 0 and best_min >= wp.float64(-_INSIDE_TOLERANCE):
        found_tet[k] = best
        weights[k] = _clamped(best_w)
        distance[k] = wp.float64(0.0)
        return
    # 2. outside every tet: the nearest tet, at the closest point of its boundary
    reach = max_distance + pad
    best = int(-1)
    best_d = wp.float64(max_distance)
    query = wp.bvh_query_aabb(bvh, xf - wp.vec3(reach, reach, reach), xf + wp.vec3(reach, reach, reach))
    while wp.bvh_query_next(query, t):
        tet = tets[t]
        c = _closest_in_tet(x, points[tet[0]], points[tet[1]], points[tet[2]], points[tet[3]])
        d = wp.length(c - x)
        if d <= best_d:
            best_d = d
            best = t
            best_w = _barycentric(c, points[tet[0]], inverse[t])
    found_tet[k] = best
    if best >= 0:
        weights[k] = _clamped(best_w)
        distance[k] = best_d
    else:
        weights[k] = wp.vec4d()
        distance[k] = wp.float64(-1.0)


@wp.kernel
def _interpolate(
    node_values: wp.array2d(dtype=wp.vec3d),
    nodes: wp.array(dtype=wp.vec4i),
    weights: wp.array(dtype=wp.vec4d),
    out: wp.array2d(dtype=wp.vec3d),
):
    """``out[f, v] = Σ_k weights[v][k] · node_values[f, nodes[v][k]]`` for every frame f and point v."""
    f, v = wp.tid()
    n = nodes[v]
    w = weights[v]
    out[f, v] = (
        w[0] * node_values[f, n[0]]
        + w[1] * node_values[f, n[1]]
        + w[2] * node_values[f, n[2]]
        + w[3] * node_values[f, n[3]]
    )


# ---------------------------------------------------------------------------------------------- API


@dataclass(frozen=True, eq=False)
class Embedding:
    """Surface points bound to a tet mesh by barycentric weights.

    Build with :func:`embed_points`. Arrays are read-only NumPy; device copies are made on use.
    """

    node_count: int
    """Nodes N of the tet mesh the points are embedded in."""
    tets: np.ndarray
    """Index of the tet holding each point, shape (V,), int32."""
    nodes: np.ndarray
    """The four nodes of that tet per point, shape (V, 4), int32."""
    weights: np.ndarray
    """Barycentric weights per point, shape (V, 4), float64, each >= 0, rows summing to 1."""
    distances: np.ndarray
    """Distance from each point to its tet [m], shape (V,), float64: 0 inside, > 0 for points bound
    to the nearest tet from outside."""
    _device_arrays: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def point_count(self) -> int:
        """Number of embedded points V."""
        return int(len(self.tets))

    @property
    def outside_count(self) -> int:
        """Points that lie outside the tet mesh (bound to their nearest tet)."""
        return int(np.count_nonzero(self.distances > 0.0))

    def apply(self, node_values, *, device=None):
        """Interpolate a nodal vector field (displacements, velocities ...) at the embedded points.

        Args:
            node_values: Shape (N, 3) or (F, N, 3) for F frames, NumPy (any float dtype), or a Warp
                array of ``vec3d`` with shape (N,) or (F, N).
            device: Warp device for NumPy input (``None``: Warp's preferred device); Warp input
                runs on its own device.

        Returns:
            Shape (V, 3) or (F, V, 3) float64 NumPy for NumPy input; a Warp ``vec3d`` array of shape
            (V,) or (F, V) on the input's device for Warp input (no host transfer).

        Raises:
            ValueError: wrong shape or non-finite values (NumPy input).
        """
        if isinstance(node_values, wp.array):
            return self._apply_warp(node_values)
        values = np.asarray(node_values, dtype=np.float64)
        single = values.ndim == 2
        if values.ndim not in (2, 3) or values.shape[-2:] != (self.node_count, 3):
            raise ValueError(
                f"Embedding.apply: node values must have shape ({self.node_count}, 3) or (F, {self.node_count}, 3), "
                f"got {values.shape}"
            )
        if not np.isfinite(values).all():
            bad = np.argwhere(~np.isfinite(values))[0]
            raise ValueError(f"Embedding.apply: node value at index {tuple(int(i) for i in bad)} is not finite")
        device = as_device(device)
        frames = values.reshape(-1, self.node_count, 3)
        src = wp.array(np.ascontiguousarray(frames), dtype=wp.vec3d, device=device)
        out = self._launch(src, device)
        result = out.numpy()
        return result[0] if single else result

    def _apply_warp(self, values: wp.array) -> wp.array:
        if values.dtype != wp.vec3d or values.ndim not in (1, 2) or values.shape[-1] != self.node_count:
            raise ValueError(
                f"Embedding.apply: Warp input must be vec3d of shape ({self.node_count},) or (F, {self.node_count}), "
                f"got {values.dtype.__name__} {values.shape}"
            )
        frames = values if values.ndim == 2 else values.reshape((1, self.node_count))
        out = self._launch(frames, values.device)
        return out if values.ndim == 2 else out.reshape((self.point_count,))

    def _launch(self, frames: wp.array, device) -> wp.array:
        key = str(device)
        if key not in self._device_arrays:
            self._device_arrays[key] = (
                wp.array(self.nodes, dtype=wp.vec4i, device=device),
                wp.array(self.weights, dtype=wp.vec4d, device=device),
            )
        nodes, weights = self._device_arrays[key]
        out = wp.empty((frames.shape[0], self.point_count), dtype=wp.vec3d, device=device)
        wp.launch(_interpolate, dim=out.shape, inputs=[frames, nodes, weights], outputs=[out], device=device)
        return out

    def nodes_for(self, vertex_indices) -> np.ndarray:
        """The tet node that stands for each given point: the node of its tet with the largest weight.

        Use it to turn constraints on surface vertices (tracked landmarks, fixed regions) into
        constraints on FEM nodes.

        Args:
            vertex_indices: Point indices, any integer array-like of shape (K,).

        Returns:
            Node indices, shape (K,), int32 (several points may map to one node).

        Raises:
            ValueError: an index is out of range.
        """
        index = self._check_indices(vertex_indices)
        rows = np.arange(len(index))
        return self.nodes[index][rows, np.argmax(self.weights[index], axis=1)].astype(np.int32)

    def subset(self, vertex_indices) -> Embedding:
        """The embedding of only the given points, in the given order (e.g. landmark vertices)."""
        index = self._check_indices(vertex_indices)
        return _frozen_embedding(
            self.node_count, self.tets[index], self.nodes[index], self.weights[index], self.distances[index]
        )

    def on_nodes(self, nodes) -> Embedding:
        """The same embedding for node values given only on ``nodes`` (e.g. nodes recorded by a simulation).

        Args:
            nodes: Node indices, shape (K,), containing every node this embedding uses (see
                ``np.unique(embedding.nodes)``).

        Returns:
            An embedding whose :meth:`apply` takes values of shape (K, 3) or (F, K, 3), ordered like ``nodes``.

        Raises:
            ValueError: ``nodes`` has duplicates or indices out of range, or misses a node in use.
        """
        nodes = np.asarray(nodes)
        if nodes.ndim != 1 or not np.issubdtype(nodes.dtype, np.integer):
            raise ValueError(f"on_nodes: nodes must be a 1-D integer array, got {nodes.dtype} shape {nodes.shape}")
        if nodes.size and (nodes.min() < 0 or nodes.max() >= self.node_count):
            raise ValueError(f"on_nodes: node index out of range [0, {self.node_count})")
        if len(np.unique(nodes)) != len(nodes):
            raise ValueError("on_nodes: nodes has duplicates")
        position = np.full(self.node_count, -1, dtype=np.int64)
        position[nodes] = np.arange(len(nodes))
        local = position[self.nodes]
        if np.any(local < 0):
            raise ValueError(f"on_nodes: node {self.nodes[local < 0][0]} is used by the embedding but not given")
        return _frozen_embedding(len(nodes), self.tets, local, self.weights, self.distances)

    def _check_indices(self, vertex_indices) -> np.ndarray:
        index = np.asarray(vertex_indices)
        if index.ndim != 1 or not (np.issubdtype(index.dtype, np.integer) or index.size == 0):
            raise ValueError(f"vertex indices must be a 1-D integer array, got {index.dtype} shape {index.shape}")
        index = index.astype(np.int64)
        bad = np.flatnonzero((index < 0) | (index >= self.point_count))
        if bad.size:
            raise ValueError(f"vertex index {index[bad[0]]} out of range [0, {self.point_count})")
        return index


def _frozen_embedding(node_count, tets, nodes, weights, distances) -> Embedding:
    arrays = [
        np.ascontiguousarray(tets, dtype=np.int32),
        np.ascontiguousarray(nodes, dtype=np.int32),
        np.ascontiguousarray(weights, dtype=np.float64),
        np.ascontiguousarray(distances, dtype=np.float64),
    ]
    for a in arrays:
        a.setflags(write=False)
    return Embedding(int(node_count), *arrays)


def _median_edge_length(tetmesh: TetMesh) -> float:
    p = tetmesh.points[tetmesh.tets]
    d = p[:, TET_EDGE_NODES[:, 0]] - p[:, TET_EDGE_NODES[:, 1]]
    return float(np.median(np.linalg.norm(d, axis=2)))


def embed_points(tetmesh: TetMesh, points, *, max_distance: float | None = None, device=None) -> Embedding:
    """Bind points (a render surface's vertices) to a tet mesh.

    Args:
        tetmesh: The tissue mesh.
        points: Positions [m], shape (V, 3), or anything with a ``points`` attribute (a
            :class:`~warpface.FaceMesh`).
        max_distance: How far outside the tet mesh a point may lie and still be bound to its
            nearest tet [m]. Default: half the median tet edge length (a mesher's boundary strays
            from the surface by a fraction of an edge).
        device: Warp device; ``None`` uses Warp's preferred device.

    Returns:
        The :class:`Embedding`.

    Raises:
        ValueError: points are not finite or of the wrong shape, or a point is farther than
            ``max_distance`` from every tet (naming it and its position).
    """
    expect_instance(tetmesh, TetMesh, "tetmesh")
    try:
        points = np.asarray(getattr(points, "points", points), dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("embed_points: points must be numbers of shape (V, 3)") from None
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"embed_points: points must have shape (V, 3), got {points.shape}")
    bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
    if bad.size:
        raise ValueError(f"embed_points: point {bad[0]} is not finite: {points[bad[0]].tolist()}")
    far = np.flatnonzero(np.abs(points).max(axis=1) > MAX_COORDINATE) if len(points) else np.zeros(0, dtype=np.int64)
    if far.size:
        raise ValueError(
            f"embed_points: point {far[0]} lies beyond {MAX_COORDINATE:g} m from the origin: {points[far[0]].tolist()}"
        )
    if max_distance is None:
        max_distance = 0.5 * _median_edge_length(tetmesh)
    try:
        max_distance = float(max_distance)
    except (TypeError, ValueError):
        raise TypeError(f"embed_points: max_distance must be a number [m], got {type(max_distance).__name__}") from None
    if not (np.isfinite(max_distance) and max_distance >= 0.0):
        raise ValueError(f"embed_points: max_distance must be finite and >= 0 [m], got {max_distance}")

    device = as_device(device)
    extent = float(np.ptp(np.concatenate([tetmesh.points, points]), axis=0).max()) or 1.0
    pad = 1e-6 * extent  # float32 bounds must never exclude a tet that touches the point
    nodes_wp = wp.array(tetmesh.points, dtype=wp.vec3d, device=device)
    tets_wp = wp.array(tetmesh.tets, dtype=wp.vec4i, device=device)
    inverse = wp.empty(tetmesh.tet_count, dtype=wp.mat33d, device=device)
    wp.launch(_tet_inverse, dim=tetmesh.tet_count, inputs=[nodes_wp, tets_wp], outputs=[inverse], device=device)
    bvh, _, _ = padded_element_bvh(nodes_wp, tetmesh.tets, pad)
    n = len(points)
    found = wp.empty(n, dtype=wp.int32, device=device)
    weights = wp.empty(n, dtype=wp.vec4d, device=device)
    distance = wp.empty(n, dtype=wp.float64, device=device)
    if n:
        wp.launch(
            _locate,
            dim=n,
            inputs=[
                bvh.id,
                nodes_wp,
                tets_wp,
                inverse,
                wp.array(points, dtype=wp.vec3d, device=device),
                pad,
                max_distance,
            ],
            outputs=[found, weights, distance],
            device=device,
        )
    tets = found.numpy()
    missing = np.flatnonzero(tets < 0)
    if missing.size:
        v = missing[0]
        raise ValueError(
            f"embed_points: point {v} at {np.round(points[v], 6).tolist()} m is farther than max_distance "
            f"{max_distance:.3g} m from every tet ({missing.size} such points); the surface does not match the "
            "tet mesh, or pass a larger max_distance"
        )
    return _frozen_embedding(tetmesh.node_count, tets, tetmesh.tets[tets], weights.numpy(), distance.numpy())
