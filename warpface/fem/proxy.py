"""A cleaned proxy of a face surface to build the tissue volume from.

A render surface such as ICT-FaceKit's follows every crease of a face: nostrils are cavities a
centimetre deep, lid and lip margins curl into the head, the lips overlap at the mouth corners
and cross each other. An inward offset of such a surface (:func:`~warpface.fem.shell.offset_shell`)
crosses itself wherever the thickness exceeds the gap between two parts of the surface. The tissue
*volume* need not follow those creases: it is built from a proxy surface and the render surface
is embedded in it afterwards (:func:`~warpface.fem.embedding.embed_points` with a ``max_distance``
of at least :attr:`TissueProxy.max_deviation`; a vertex of a removed part binds to its nearest tet).

:func:`tissue_proxy` makes the proxy in five steps:

1. **Remove what is not skin seen from outside.** Seen from a point inside the head (default:
   behind the face's middle), a triangle is dropped when it faces away from the ray through it
   (lid and lip margins curling inward), when that ray meets the surface again further out (it is
   hidden: nostril interiors, the lips' inner faces), when the surface lies within ``crease_gap``
   in front of it along its normal (the walls of a narrow crease or cavity), or when it crosses
   another triangle. The largest edge-connected piece is kept, cleaned of non-manifold "bow tie"
   vertices.
2. **Cap cavities.** A boundary loop that the removal opened inside the surface (a nostril), and
   any loop picked by ``close_near`` (the eyes), is closed by a cap of concentric rings whose
   vertices are relaxed to a membrane (harmonic fairing, the loop held fixed), so the proxy spans
   the opening instead of following the cavity. Other loops that grew from the surface's own
   boundary (the mouth, the rim) stay open.
3. **Trim the margins.** Triangles within ``margin`` of the remaining boundary are dropped, which
   widens the mouth slit where the lips touch and takes the last of the curl off open lid
   margins; the zigzag loops the cuts leave are then smoothed as curves (with two rings of
   vertices inside).
4. **Limit the thickness** to ``gap_fraction`` of the distance a ray travels inward from each
   vertex before it leaves the proxy again (the thin alar walls), so opposite offsets never meet;
   to ``boundary_thickness`` on the open loops, whose side walls would otherwise cross at the
   pointed corners of the mouth; and its slope along the surface to ``max_slope``, so the inner
   surface stays near parallel to the outer one.
5. **Check** the proxy: an oriented manifold with boundary, free of self-intersections.

The hit tests are Warp kernels over a ``wp.Mesh`` BVH (``mesh_query_ray``); the rest is set-up
NumPy and SciPy (connected components, a KD-tree, sparse fairing) run once. The proxy is still a
fine surface: :func:`~warpface.fem.volume.mesh_tissue` coarsens it, and its ``fair_folds`` option
relaxes the coarse surface locally where the offset still folds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from .._validate import as_device
from ..geometry.surface_checks import as_surface, boundary_loops, check_surface, directed_edges, find_self_intersections
from ..geometry.triangles import area_weighted_vertex_normals, triangle_edges
from .shell import fair_locally, thickness_per_vertex

__all__ = ["TissueProxy", "default_center", "tissue_proxy"]


# ---------------------------------------------------------------------------------------------- kernels


@wp.kernel
def _view_tests(
    mesh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    triangles: wp.array(dtype=wp.vec3i),
    center: wp.vec3,
    eps: float,
    reach: float,
    facing: wp.array(dtype=float),
    hidden: wp.array(dtype=wp.int32),
    clearance: wp.array(dtype=float),
):
    """Per triangle: cosine between its normal and the ray from ``center`` through its centroid,
    whether that ray meets the surface again beyond the centroid, and how far the surface lies in
    front of the triangle along its normal (``reach`` when nothing is in front)."""
    t = wp.tid()
    tri = triangles[t]
    a = points[tri[0]]
    b = points[tri[1]]
    c = points[tri[2]]
    normal = wp.normalize(wp.cross(b - a, c - a))
    centroid = (a + b + c) / 3.0
    ray = wp.normalize(centroid - center)
    facing[t] = wp.dot(normal, ray)
    hidden[t] = 0
    if wp.mesh_query_ray_anyhit(mesh, centroid + eps * ray, ray, reach):
        hidden[t] = 1
    clearance[t] = reach
    hit = wp.mesh_query_ray(mesh, centroid + eps * normal, normal, reach)
    if hit.result:
        clearance[t] = hit.t + eps


@wp.kernel
def _inward_gap(
    mesh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    eps: float,
    reach: float,
    gap: wp.array(dtype=float),
):
    """Distance from each vertex along its inward normal to the next crossing of the surface."""
    v = wp.tid()
    inward = -normals[v]
    gap[v] = reach
    hit = wp.mesh_query_ray(mesh, points[v] + eps * inward, inward, reach)
    if hit.result:
        gap[v] = hit.t + eps


@wp.kernel
def _distance_to_surface(
    mesh: wp.uint64, queries: wp.array(dtype=wp.vec3), reach: float, distance: wp.array(dtype=float)
):
    k = wp.tid()
    q = queries[k]
    distance[k] = reach
    hit = wp.mesh_query_point_no_sign(mesh, q, reach)
    if hit.result:
        distance[k] = wp.length(q - wp.mesh_eval_position(mesh, hit.face, hit.u, hit.v))


class _RayMesh:
    """A float32 ``wp.Mesh`` of a triangle surface for ray and closest-point queries."""

    def __init__(self, points: np.ndarray, triangles: np.ndarray, device):
        self.device = as_device(device)
        self.points = self._vectors(points)
        tris = np.ascontiguousarray(triangles, dtype=np.int32)
        self.triangles = wp.array(tris, dtype=wp.vec3i, device=self.device)
        self.mesh = wp.Mesh(points=self.points, indices=wp.array(tris.ravel(), dtype=wp.int32, device=self.device))
        self.extent = float(np.ptp(points, axis=0).max()) or 1.0
        self.eps = 1e-6 * self.extent  # ray start off the surface: above float32 round-off at this size
        self.reach = 4.0 * self.extent  # farther than any point of the surface from any other

    def _query(self, kernel, count: int, inputs: list, outputs: list) -> None:
        """Launch ``kernel`` over ``count`` items; its inputs are the mesh, ``inputs`` and the query reach."""
        wp.launch(kernel, dim=count, inputs=[self.mesh.id, *inputs, self.reach], outputs=outputs, device=self.device)

    def _vectors(self, values: np.ndarray) -> wp.array:
        return wp.array(np.asarray(values, dtype=np.float32), dtype=wp.vec3, device=self.device)

    def view_tests(self, center: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = self.triangles.shape[0]
        facing = wp.empty(n, dtype=float, device=self.device)
        hidden = wp.empty(n, dtype=wp.int32, device=self.device)
        clearance = wp.empty(n, dtype=float, device=self.device)
        center = wp.vec3(*np.asarray(center, dtype=np.float32))
        self._query(_view_tests, n, [self.points, self.triangles, center, self.eps], [facing, hidden, clearance])
        return facing.numpy().astype(np.float64), hidden.numpy().astype(bool), clearance.numpy().astype(np.float64)

    def inward_gap(self, normals: np.ndarray) -> np.ndarray:
        gap = wp.empty(self.points.shape[0], dtype=float, device=self.device)
        self._query(_inward_gap, self.points.shape[0], [self.points, self._vectors(normals), self.eps], [gap])
        return gap.numpy().astype(np.float64)

    def distance(self, queries: np.ndarray) -> np.ndarray:
        distance = wp.empty(len(queries), dtype=float, device=self.device)
        self._query(_distance_to_surface, len(queries), [self._vectors(queries)], [distance])
        return distance.numpy().astype(np.float64)


# ---------------------------------------------------------------------------------------------- topology


def _edge_keys(edges: np.ndarray, vertex_count: int) -> np.ndarray:
    """One int64 key per undirected edge ``(a, b)``, shape (E,)."""
    e = np.sort(edges, axis=1)
    return e[:, 0] * vertex_count + e[:, 1]


def _triangle_labels(triangles: np.ndarray, vertex_count: int) -> np.ndarray:
    """Edge-connected component label of each triangle, shape (T,)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    keys = _edge_keys(directed_edges(triangles), vertex_count)
    owner = np.repeat(np.arange(len(triangles)), 3)
    order = np.argsort(keys, kind="stable")
    keys, owner = keys[order], owner[order]
    shared = keys[1:] == keys[:-1]
    a, b = owner[:-1][shared], owner[1:][shared]
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(len(triangles), len(triangles)))
    return connected_components(graph, directed=False)[1]


def _manifold_piece(points: np.ndarray, triangles: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """``keep`` reduced to its largest edge-connected piece, without bow-tie vertices (where two
    boundary loops touch, the triangles around the vertex go)."""
    keep = keep.copy()
    while keep.any():
        kept = np.flatnonzero(keep)
        labels = _triangle_labels(triangles[kept], len(points))
        keep[:] = False
        keep[kept[labels == np.argmax(np.bincount(labels))]] = True
        tris = triangles[keep]
        directed = directed_edges(tris)
        keys = _edge_keys(directed, len(points))
        _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
        boundary = directed[counts[inverse.ravel()] == 1]
        loops_at = np.bincount(boundary[:, 0], minlength=len(points))
        drop = keep & (loops_at[triangles] > 1).any(axis=1)
        if not drop.any():
            return keep
        keep &= ~drop
    raise ValueError("tissue proxy: removing the hidden and inward-facing parts left no surface")


def _compact(points: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Drop unused vertices: ``(points, triangles, used)`` with ``used`` the old index of each kept vertex."""
    used = np.unique(triangles)
    remap = np.full(len(points), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return points[used], remap[triangles], used


def _cavity_loops(points: np.ndarray, triangles: np.ndarray, keep: np.ndarray, loops: list, used: np.ndarray) -> list:
    """The loops of the kept surface (local indices) that the removal opened inside the input surface.

    A loop is a cavity's rim unless it runs along the input's boundary or borders a removed piece
    that reaches it (then it is an eye, the mouth or the rim, grown)."""
    n = len(points)
    keys_all = _edge_keys(directed_edges(triangles), n)
    uniq, counts = np.unique(keys_all, return_counts=True)
    input_open = uniq[counts == 1]
    removed = np.flatnonzero(~keep)
    if len(removed) == 0:
        return []
    labels = _triangle_labels(triangles[removed], n)
    removed_keys = _edge_keys(directed_edges(triangles[removed]), n)
    removed_owner = labels[np.repeat(np.arange(len(removed)), 3)]
    reaches_open = np.zeros(labels.max() + 1, dtype=bool)
    reaches_open[removed_owner[np.isin(removed_keys, input_open)]] = True
    order = np.argsort(removed_keys)
    sorted_keys = removed_keys[order]
    cavities = []
    for loop in loops:
        global_loop = used[loop]
        keys = _edge_keys(np.stack([global_loop, np.roll(global_loop, -1)], axis=1), n)
        if np.isin(keys, input_open).any():
            continue
        at = np.clip(np.searchsorted(sorted_keys, keys), 0, len(sorted_keys) - 1)
        found = sorted_keys[at] == keys
        if not reaches_open[removed_owner[order[at[found]]]].any():
            cavities.append(loop)
    return cavities


def _cap(points: np.ndarray, loop: np.ndarray, rings: int) -> tuple[np.ndarray, np.ndarray]:
    """Rings shrinking from ``loop`` to its centroid: new points (rings*len(loop) - len(loop) + 1, 3)
    and triangles (indices: ``loop`` vertices, then new points from ``len(points)``), wound so the
    cap continues the surface whose boundary runs along ``loop``."""
    m = len(loop)
    centroid = points[loop].mean(axis=0)
    steps = np.arange(1, rings)[:, None, None] / rings
    new = np.concatenate(
        [(points[loop][None] + steps * (centroid - points[loop])[None]).reshape(-1, 3), centroid[None]]
    )
    base = len(points)
    triangles = []
    outer = loop
    for ring in range(rings - 1):
        inner = base + ring * m + np.arange(m)
        nxt_outer, nxt_inner = np.roll(outer, -1), np.roll(inner, -1)
        triangles += [np.stack([nxt_outer, outer, inner], axis=1), np.stack([nxt_outer, inner, nxt_inner], axis=1)]
        outer = inner
    triangles.append(np.stack([np.roll(outer, -1), outer, np.full(m, base + (rings - 1) * m)], axis=1))
    return new, np.concatenate(triangles)


def _lipschitz(points: np.ndarray, triangles: np.ndarray, values: np.ndarray, slope: float) -> np.ndarray:
    """The largest field below ``values`` that changes by at most ``slope`` per unit length along edges.

    A thickness that drops faster than the surface runs tilts the inner surface steeply over short
    triangles; limiting its slope (min-plus relaxation over the edges) keeps the inner surface
    roughly parallel to the outer."""
    edges = triangle_edges(triangles)[0]
    bound = slope * np.linalg.norm(points[edges[:, 0]] - points[edges[:, 1]], axis=1)
    values = values.copy()
    for _ in range(len(points)):
        relaxed = values.copy()
        np.minimum.at(relaxed, edges[:, 0], values[edges[:, 1]] + bound)
        np.minimum.at(relaxed, edges[:, 1], values[edges[:, 0]] + bound)
        if np.array_equal(relaxed, values):
            break
        values = relaxed
    return values


def _relax(points: np.ndarray, triangles: np.ndarray, free: np.ndarray, iterations: int) -> np.ndarray:
    """Jacobi iterations of the uniform Laplacian on the ``free`` vertices (the others held): a membrane."""
    from scipy.sparse import coo_matrix

    n = len(points)
    edges = triangle_edges(triangles)[0]
    rows, cols = np.r_[edges[:, 0], edges[:, 1]], np.r_[edges[:, 1], edges[:, 0]]
    adjacency = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)).tocsr()[free]
    degree = np.asarray(adjacency.sum(axis=1))
    points = points.copy()
    for _ in range(int(iterations)):
        points[free] = (adjacency @ points) / degree
    return points


# ---------------------------------------------------------------------------------------------- proxy


@dataclass(frozen=True)
class TissueProxy:
    """Result of :func:`tissue_proxy`: the surface to thicken and what was done to get it."""

    points: np.ndarray
    """Vertex positions [m], shape (P, 3), float64."""
    triangles: np.ndarray
    """Triangles, shape (F, 3), int64, wound like the input (normals out of the tissue)."""
    thickness: np.ndarray
    """Tissue thickness per proxy vertex [m], shape (P,), float64, all > 0."""
    source: np.ndarray
    """Input vertex of each proxy vertex, shape (P,), int64; -1 for a vertex of a cavity cap."""
    removed_triangles: int
    """Input triangles not in the proxy (removed or trimmed)."""
    capped_loops: int
    """Openings closed by a cap (cavities and ``close_near`` loops)."""
    thinned_vertices: int
    """Vertices whose thickness was limited (inward gap, boundary thickness, slope)."""
    input_intersections: int
    """Pairs of crossing triangles in the input surface."""
    max_deviation: float
    """Largest distance of an input vertex from the proxy surface [m]: the embedding's ``max_distance``
    must be at least this (plus the mesher's envelope)."""

    def __str__(self) -> str:
        return (
            f"{len(self.points)}-vertex proxy: {self.removed_triangles} input triangles removed, "
            f"{self.capped_loops} cavities capped, thickness limited at {self.thinned_vertices} vertices "
            f"({1e3 * self.thickness.min():.2f}..{1e3 * self.thickness.max():.2f} mm), "
            f"{self.input_intersections} crossing pairs in the input, input within "
            f"{1e3 * self.max_deviation:.2f} mm of the proxy"
        )


def default_center(points: np.ndarray, forward=(0.0, 0.0, 1.0)) -> np.ndarray:
    """A point inside a face's head: the middle of the bounding box across ``forward``, level with the
    rearmost point along it [m], shape (3,)."""
    points = np.asarray(points, dtype=np.float64)
    forward = np.asarray(forward, dtype=np.float64)
    forward = forward / np.linalg.norm(forward)
    middle = 0.5 * (points.min(axis=0) + points.max(axis=0))
    depth = points @ forward
    return middle + (depth.min() - middle @ forward) * forward


def tissue_proxy(
    surface,
    thickness,
    *,
    center=None,
    forward=(0.0, 0.0, 1.0),
    close_near=None,
    min_facing: float = 0.1,
    crease_gap: float = 0.003,
    margin: float = 0.002,
    gap_fraction: float = 0.45,
    max_slope: float = 0.5,
    boundary_thickness: float | None = 0.002,
    cap_rings: int = 4,
    boundary_passes: int = 10,
    device=None,
) -> TissueProxy:
    """A proxy of a face surface whose inward offset is a valid tissue shell (see the module docstring).

    Args:
        surface: :class:`~warpface.FaceMesh` or ``(points (V, 3), triangles (T, 3))`` [m], an
            oriented open manifold whose normals point out of the tissue (it may cross itself).
        thickness: Tissue thickness per input vertex [m]: a scalar or shape (V,), all > 0.
        center: A point inside the head [m] from which the skin is "seen"; default
            :func:`default_center` (the middle of the face, level with its rearmost point).
        forward: The direction the face looks (+z in warpface); used only for the default center.
        close_near: Points [m], shape (K, 3): the boundary loop nearest to each is capped like a
            cavity (e.g. the eyes' centres: lids resting on a capped opening, as on the eyeball,
            instead of a hole whose pointed corners the offset cannot follow). The outer rim
            (the longest loop) cannot be closed.
        min_facing: A triangle is kept only when the cosine between its normal and the ray from
            ``center`` through it is at least this (0.1: up to about 84 degrees off the ray).
        crease_gap: A triangle with the surface closer than this in front of it (along its
            normal) is a wall of a crease or cavity and is removed [m]; 0 disables the test.
        margin: Triangles within this distance of the remaining boundary are trimmed [m]; 0 keeps them.
        gap_fraction: Thickness is limited to this fraction of the inward gap at each vertex, ...
        boundary_thickness: ... to this on the proxy's open boundary loops [m] (short side walls,
            which cannot cross at the pointed corners of the mouth slit); ``None``: no limit ...
        max_slope: ... and then to change by at most this much per unit length along the surface
            (the thickness tapers from the limited vertices).
        cap_rings: Rings of vertices in each cavity cap.
        boundary_passes: Laplacian passes over the boundary loops (as curves) and the two edge
            rings inside them, which straightens the zigzag the cuts leave.
        device: Warp device for the ray and distance queries; ``None`` uses Warp's preferred device.

    Returns:
        The :class:`TissueProxy`.

    Raises:
        ValueError: a bad surface (see :func:`~warpface.geometry.surface_checks.check_surface`), thickness or
            option; nothing left after the removal; or a proxy that still crosses itself (naming where).
    """
    points, triangles = as_surface(surface)
    check_surface(points, triangles, closed=False, name="face surface")
    h = thickness_per_vertex(thickness, points)
    if not -1.0 <= min_facing < 1.0:
        raise ValueError(f"min_facing must be in [-1, 1), got {min_facing}")
    for name, value in (("crease_gap", crease_gap), ("margin", margin)):
        if not (np.isfinite(value) and value >= 0.0):
            raise ValueError(f"{name} must be finite and >= 0 [m], got {value}")
    if not 0.0 < gap_fraction <= 0.5:
        raise ValueError(f"gap_fraction must be in (0, 0.5] (opposite offsets must not meet), got {gap_fraction}")
    if not (np.isfinite(max_slope) and max_slope > 0.0):
        raise ValueError(f"max_slope must be finite and > 0, got {max_slope}")
    if boundary_thickness is not None and not (np.isfinite(boundary_thickness) and boundary_thickness > 0.0):
        raise ValueError(f"boundary_thickness must be None or finite and > 0 [m], got {boundary_thickness}")
    if int(boundary_passes) < 0:
        raise ValueError(f"boundary_passes must be >= 0, got {boundary_passes}")
    if int(cap_rings) < 1:
        raise ValueError(f"cap_rings must be >= 1, got {cap_rings}")
    center = default_center(points, forward) if center is None else np.asarray(center, dtype=np.float64)
    if center.shape != (3,) or not np.isfinite(center).all():
        raise ValueError(f"center must be a finite point (3,), got {center!r}")
    close_near = np.zeros((0, 3)) if close_near is None else np.asarray(close_near, dtype=np.float64).reshape(-1, 3)
    if not np.isfinite(close_near).all():
        raise ValueError("close_near points must be finite")
    device = as_device(device)

    # 1. remove what the skin seen from the centre does not show
    crossings, pairs = find_self_intersections(points, triangles, max_pairs=len(triangles), device=device)
    facing, hidden, clearance = _RayMesh(points, triangles, device).view_tests(center)
    keep = (facing >= min_facing) & ~hidden & (clearance > crease_gap)
    keep[pairs.ravel()] = False
    keep = _manifold_piece(points, triangles, keep)
    kept_points, kept_triangles, used = _compact(points, triangles[keep])
    loops = boundary_loops(check_surface(kept_points, kept_triangles, closed=False, name="tissue proxy"))

    # 2. cap the cavities the removal opened, relaxed to a membrane spanning each opening
    cavities = _cavity_loops(points, triangles, keep, loops, used)
    for point in close_near:
        # the loop passing nearest to the point (an eye's centre picks that eye's loop)
        nearest = int(np.argmin([np.linalg.norm(kept_points[loop] - point, axis=1).min() for loop in loops]))
        if nearest == 0:
            raise ValueError(
                f"close_near point {np.round(point, 5).tolist()} is nearest to the outer rim loop, "
                "which cannot be closed"
            )
        if not any(loop is loops[nearest] for loop in cavities):
            cavities.append(loops[nearest])
    source = used.copy()
    h_kept = h[used]
    new_points, new_triangles, new_h = [], [], []
    count = len(kept_points)
    for loop in cavities:
        cap_points, cap_triangles = _cap(kept_points, loop, int(cap_rings))
        new_triangles.append(
            np.where(cap_triangles >= len(kept_points), cap_triangles - len(kept_points) + count, cap_triangles)
        )
        new_points.append(cap_points)
        new_h.append(np.full(len(cap_points), h_kept[loop].mean()))
        count += len(cap_points)
    if cavities:
        first_new = len(kept_points)
        kept_points = np.concatenate([kept_points, *new_points])
        kept_triangles = np.concatenate([kept_triangles, *new_triangles])
        h_kept = np.concatenate([h_kept, *new_h])
        source = np.concatenate([source, np.full(count - first_new, -1, dtype=np.int64)])
        kept_points = _relax(kept_points, kept_triangles, np.arange(first_new, count), 100 * int(cap_rings) ** 2)

    # 3. trim the margins of the remaining boundary loops
    if margin > 0.0:
        from scipy.spatial import cKDTree

        boundary = np.unique(check_surface(kept_points, kept_triangles, closed=False, name="tissue proxy"))
        distance, _ = cKDTree(kept_points[boundary]).query(kept_points)
        trimmed = _manifold_piece(kept_points, kept_triangles, ~(distance[kept_triangles] < margin).any(axis=1))
        kept_points, kept_triangles, used = _compact(kept_points, kept_triangles[trimmed])
        source, h_kept = source[used], h_kept[used]
    # the cuts leave zigzag loops, which a coarsening keeps (it holds boundaries) as needle triangles
    boundary = np.unique(check_surface(kept_points, kept_triangles, closed=False, name="tissue proxy"))
    kept_points, _ = fair_locally(
        kept_points, kept_triangles, h_kept, boundary, rings=2, passes=int(boundary_passes), thinning=1.0
    )

    # 4. thickness no more than a fraction of the inward gap: opposite offsets never meet
    proxy_mesh = _RayMesh(kept_points, kept_triangles, device)
    gap = proxy_mesh.inward_gap(area_weighted_vertex_normals(kept_points, kept_triangles))
    limited = np.minimum(h_kept, gap_fraction * gap)
    if boundary_thickness is not None:
        limited[boundary] = np.minimum(limited[boundary], float(boundary_thickness))
    limited = _lipschitz(kept_points, kept_triangles, limited, max_slope)
    thinned = int(np.count_nonzero(limited < h_kept))

    # 5. a clean surface, and how far the input strays from it
    count, pairs = find_self_intersections(kept_points, kept_triangles, device=device)
    if count:
        i = int(pairs[0, 0])
        raise ValueError(
            f"tissue proxy intersects itself at {count} triangle pairs, first near "
            f"{np.round(kept_points[kept_triangles[i]].mean(axis=0), 5).tolist()} m: raise min_facing or crease_gap"
        )
    removed = len(triangles) - int(np.count_nonzero(source[kept_triangles].min(axis=1) >= 0))
    return TissueProxy(
        points=kept_points,
        triangles=kept_triangles,
        thickness=limited,
        source=source,
        removed_triangles=removed,
        capped_loops=len(cavities),
        thinned_vertices=thinned,
        input_intersections=int(crossings),
        max_deviation=float(proxy_mesh.distance(points).max()),
    )
