"""Shared surface math (warpface.geometry): the generic closest-point function in float32 and float64
against an independent float64 NumPy reference, the mesh index on far and degenerate input, the
NumPy triangle helpers against Heron's formula and the Warp vertex-normal kernel, and the edge list
against a count of every triangle's edges by hand."""

import numpy as np
import pytest
import warp as wp
from helpers import grid_surface

from warpface import FaceMesh
from warpface.geometry import (
    TriangleMeshIndex,
    area_weighted_vertex_normals,
    closest_point_on_triangle,
    closest_points,
    smooth_ramp,
    smoothstep,
    triangle_areas,
    triangle_corners,
    triangle_normals,
)
from warpface.geometry.triangles import triangle_crosses, triangle_edges, vertex_shells, vertex_triangles


@wp.kernel
def _closest_f32(p: wp.array(dtype=wp.vec3), tri: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = closest_point_on_triangle(p[i], tri[3 * i], tri[3 * i + 1], tri[3 * i + 2])


@wp.kernel
def _closest_f64(p: wp.array(dtype=wp.vec3d), tri: wp.array(dtype=wp.vec3d), out: wp.array(dtype=wp.vec3d)):
    i = wp.tid()
    out[i] = closest_point_on_triangle(p[i], tri[3 * i], tri[3 * i + 1], tri[3 * i + 2])


def reference_distance(p, a, b, c):
    """Point–triangle distance by a different method: the plane projection's 2×2 normal equations when
    it falls inside, otherwise the best of the three clamped edge projections (float64)."""
    ab, ac, ap = b - a, c - a, p - a
    gram = np.array([[ab @ ab, ab @ ac], [ab @ ac, ac @ ac]])
    best = np.inf
    if np.linalg.det(gram) > 1e-14 * gram[0, 0] * gram[1, 1]:
        v, w = np.linalg.solve(gram, [ap @ ab, ap @ ac])
        if v >= 0 and w >= 0 and v + w <= 1:
            best = np.linalg.norm(ap - v * ab - w * ac)
    for s, e in ((a, b), (a, c), (b, c)):
        se = e - s
        t = 0.0 if se @ se == 0 else np.clip((p - s) @ se / (se @ se), 0.0, 1.0)
        best = min(best, np.linalg.norm(p - s - t * se))
    return best


def random_cases(rng, count):
    tris = rng.normal(size=(count, 3, 3))
    tris[::7, 2] = tris[::7, 0] + 0.5 * (tris[::7, 1] - tris[::7, 0])  # collinear (zero area)
    tris[::11, 1] = tris[::11, 0]  # a zero-length edge
    tris[::13, 1] = tris[::13, 2] = tris[::13, 0]  # a point
    points = rng.normal(size=(count, 3)) * 2.0
    return points, tris


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_closest_point_on_triangle_generic_matches_reference(rng, precision):
    points, tris = random_cases(rng, 300)
    vec, kernel, tol = (wp.vec3, _closest_f32, 2e-5) if precision == "float32" else (wp.vec3d, _closest_f64, 1e-12)
    out = wp.empty(len(points), dtype=vec, device="cpu")
    wp.launch(
        kernel,
        dim=len(points),
        inputs=[wp.array(points, dtype=vec, device="cpu"), wp.array(tris.reshape(-1, 3), dtype=vec, device="cpu")],
        outputs=[out],
        device="cpu",
    )
    bary = out.numpy().astype(np.float64)
    assert out.dtype == vec
    assert np.all(np.isfinite(bary)) and bary.min() >= -tol and np.abs(bary.sum(axis=1) - 1).max() <= 10 * tol
    closest = np.einsum("ij,ijk->ik", bary, tris)
    got = np.linalg.norm(points - closest, axis=1)
    want = np.array([reference_distance(p, *t) for p, t in zip(points, tris)])
    np.testing.assert_allclose(got, want, atol=tol * 10, rtol=0)


def test_float64_keeps_precision_beyond_float32():
    """A point 1e-9 m above a triangle 1 m from the origin: float64 resolves the distance, float32 cannot."""
    tri = np.array([[1.0, 0.0, 0.0], [1.1, 0.0, 0.0], [1.0, 0.1, 0.0]])
    p = np.array([[1.02, 0.02, 1e-9]])
    out = wp.empty(1, dtype=wp.vec3d, device="cpu")
    wp.launch(
        _closest_f64,
        dim=1,
        inputs=[wp.array(p, dtype=wp.vec3d, device="cpu"), wp.array(tri, dtype=wp.vec3d, device="cpu")],
        outputs=[out],
        device="cpu",
    )
    closest = out.numpy()[0] @ tri
    assert abs(np.linalg.norm(p[0] - closest) - 1e-9) < 1e-15


def test_closest_points_far_and_out_of_range_queries():
    v = np.eye(3)
    t = np.array([[0, 1, 2]])
    tri, bary, dist = closest_points(np.array([[9e5, 0.0, 0.0], [0.0, -9e5, 3e5]]), v, t, device="cpu")
    assert tri.tolist() == [0, 0] and np.all(np.isfinite(bary)) and np.all(np.isfinite(dist))
    np.testing.assert_allclose(dist, [reference_distance(q, *v) for q in ([9e5, 0, 0], [0, -9e5, 3e5])], rtol=1e-5)
    with pytest.raises(ValueError, match="query"):
        closest_points(np.array([[1e16, 0.0, 0.0]]), v, t, device="cpu")
    with pytest.raises(ValueError, match="vertices"):
        closest_points(np.zeros((1, 3)), v * 1e20, t, device="cpu")
    with pytest.raises(ValueError, match="triangles"):
        closest_points(np.zeros((1, 3)), v, np.array([[0, 1, -5]]), device="cpu")


def test_mesh_index_all_degenerate_triangles_never_invalid(rng):
    """A mesh of only zero-area triangles still gives a valid triangle and finite weights."""
    v = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
    t = np.array([[0, 1, 2], [1, 2, 3]])
    index = TriangleMeshIndex(v, t, device="cpu")
    q = rng.normal(size=(50, 3)) * 3
    tri, bary, dist = index.query(q)
    assert set(tri.tolist()) <= {0, 1} and np.all(np.isfinite(bary)) and np.all(np.isfinite(dist))
    want = [min(reference_distance(p, *v[t[0]]), reference_distance(p, *v[t[1]])) for p in q]
    np.testing.assert_allclose(dist, want, atol=1e-5)


def test_triangle_helpers_match_heron_and_the_normal_kernel(rng):

    points, triangles = grid_surface(12)
    corners = triangle_corners(points, triangles)
    crosses = triangle_crosses(corners)
    a, b, c = (np.linalg.norm(corners[:, i] - corners[:, j], axis=1) for i, j in ((0, 1), (1, 2), (2, 0)))
    s = 0.5 * (a + b + c)
    heron = np.sqrt(np.maximum(s * (s - a) * (s - b) * (s - c), 0.0))
    np.testing.assert_allclose(triangle_areas(corners), heron, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(triangle_areas(crosses=crosses), triangle_areas(corners))
    normals = triangle_normals(crosses=crosses)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, rtol=1e-12)
    for i, j in ((0, 1), (1, 2)):
        assert np.abs(np.einsum("ij,ij->i", normals, corners[:, j] - corners[:, i])).max() < 1e-12
    assert np.all(normals[:, 2] > 0)  # the grid faces +z in corner order
    np.testing.assert_array_equal(triangle_normals(np.zeros((1, 3, 3))), np.zeros((1, 3)))
    vertex = area_weighted_vertex_normals(points, triangles)
    kernel = FaceMesh(points, triangles).vertex_normals(device="cpu")
    np.testing.assert_allclose(vertex, kernel, atol=2e-6)
    isolated = area_weighted_vertex_normals(np.vstack([points, [[9.0, 9.0, 9.0]]]), triangles)
    assert np.array_equal(isolated[-1], np.zeros(3))


@pytest.mark.parametrize("seed", range(4))
def test_triangle_edges_lists_every_edge_once_with_its_triangle_count(seed):
    rng = np.random.default_rng(seed)
    count = int(rng.integers(3, 40))
    triangles = np.array([rng.choice(count, 3, replace=False) for _ in range(int(rng.integers(1, 60)))])
    tally: dict[tuple[int, int], int] = {}
    for triangle in triangles.tolist():
        for a, b in ((triangle[0], triangle[1]), (triangle[1], triangle[2]), (triangle[2], triangle[0])):
            key = (min(a, b), max(a, b))
            tally[key] = tally.get(key, 0) + 1
    edges, counts = triangle_edges(triangles.astype(np.int32))
    assert edges.dtype == np.int64
    assert [tuple(edge) for edge in edges.tolist()] == sorted(tally)
    assert counts.tolist() == [tally[key] for key in sorted(tally)]


def test_face_mesh_open_edges_are_the_grid_s_border():
    points, triangles = grid_surface(5)
    mesh = FaceMesh(points, triangles)
    border = mesh.open_edges
    assert len(border) == 4 * (5 - 1)
    assert len(mesh.edges) == len(border) + (len(triangles) * 3 - len(border)) // 2
    np.testing.assert_array_equal(mesh.boundary_vertices, np.unique(border))


def test_vertex_triangles_lists_each_vertex_s_triangles_in_order():
    points, triangles = grid_surface(6)
    offsets, ids = vertex_triangles(triangles, len(points) + 2)  # two vertices on no triangle
    assert offsets[0] == 0 and offsets[-1] == 3 * len(triangles) and len(offsets) == len(points) + 3
    for vertex in range(len(points) + 2):
        expected = [t for t, triangle in enumerate(triangles.tolist()) if vertex in triangle]
        assert ids[offsets[vertex] : offsets[vertex + 1]].tolist() == expected


def test_vertex_shells_join_exactly_the_vertices_a_path_of_edges_joins():
    rng = np.random.default_rng(4)
    for _ in range(20):
        count = int(rng.integers(3, 40))
        triangles = np.array([rng.choice(count, 3, replace=False) for _ in range(int(rng.integers(1, 12)))])
        shells = vertex_shells(triangles, count + 1)  # one vertex on no triangle
        root = list(range(count + 1))  # union-find by hand

        def find(v, root=root):
            while root[v] != v:
                v = root[v]
            return v

        for a, b, c in triangles.tolist():
            for u, v in ((a, b), (b, c)):
                root[find(u)] = find(v)
        for u in range(count + 1):
            for v in range(count + 1):
                assert (shells[u] == shells[v]) == (find(u) == find(v))


@wp.kernel
def _smoothstep_f32(e0: float, e1: float, x: wp.array(dtype=float), out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = smoothstep(e0, e1, x[i])


@pytest.mark.parametrize("edges", [(-0.3, 0.7), (0.5, -0.25)])
def test_the_array_ramp_is_the_warp_smoothstep(edges):
    """``smooth_ramp`` over a NumPy array matches the ``@wp.func`` smoothstep (float32) and is 0 / 1 at and past its
    edges, monotone between (rising or falling with the edges' order)."""
    x = np.linspace(-1.0, 1.0, 401)
    out = wp.zeros(len(x), dtype=float, device="cpu")
    wp.launch(
        _smoothstep_f32,
        dim=len(x),
        inputs=[edges[0], edges[1], wp.array(x, dtype=float, device="cpu"), out],
        device="cpu",
    )
    ramp = smooth_ramp(edges[0], edges[1], x)
    np.testing.assert_allclose(ramp, out.numpy(), atol=1e-6)
    low, high = min(edges), max(edges)
    assert np.all(ramp[x <= low] == (0.0 if edges[0] < edges[1] else 1.0))
    assert np.all(ramp[x >= high] == (1.0 if edges[0] < edges[1] else 0.0))
    steps = np.diff(ramp) * np.sign(edges[1] - edges[0])
    assert np.all(steps >= 0.0)
