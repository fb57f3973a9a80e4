"""Embedding surface points in a tet mesh: Warp location and interpolation vs NumPy brute force."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from warpface.fem import box_tet_mesh, shell_tet_mesh
from warpface.fem.embedding import embed_points


def brute_force_barycentrics(mesh, x):
    """Barycentric coordinates of every point in every tet, shape (P, M, 4), by dense float64 solves."""
    p = mesh.points[mesh.tets]  # (M, 4, 3)
    edges = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=2)  # (M, 3, 3)
    rhs = x[:, None, :] - p[None, :, 0]  # (P, M, 3)
    l123 = np.linalg.solve(np.broadcast_to(edges, (len(x),) + edges.shape), rhs[..., None])[..., 0]
    return np.concatenate([1.0 - l123.sum(axis=2, keepdims=True), l123], axis=2)


def sampled_distance(mesh, x, samples: int = 3000, seed: int = 7):
    """Upper bound on the distance from each point to the tet mesh: min over dense samples of every tet
    (Dirichlet-random interior points plus the faces' vertices and edge midpoints)."""
    rng = np.random.default_rng(seed)
    w = rng.dirichlet(np.full(4, 0.3), samples)  # concentration < 1: many samples near faces and edges
    w = np.r_[w, np.eye(4), 0.5 * (np.eye(4)[:, None] + np.eye(4)[None]).reshape(-1, 4)]
    pts = np.einsum("sk,mkd->msd", w, mesh.points[mesh.tets]).reshape(-1, 3)
    from scipy.spatial import cKDTree

    return cKDTree(pts).query(x)[0]


@pytest.fixture(scope="module")
def box():
    return box_tet_mesh((0.04, 0.03, 0.02), (4, 3, 2))


def test_inside_points_match_brute_force(box):
    rng = np.random.default_rng(1)
    x = rng.uniform([0, 0, 0], [0.04, 0.03, 0.02], (400, 3))
    emb = embed_points(box, x, device="cpu")
    assert emb.outside_count == 0 and np.all(emb.distances == 0.0)
    bary = brute_force_barycentrics(box, x)
    containing = bary.min(axis=2) >= -1e-12
    assert containing[np.arange(len(x)), emb.tets].all()
    np.testing.assert_allclose(emb.weights, bary[np.arange(len(x)), emb.tets], atol=1e-12)
    assert np.all(emb.weights >= 0.0)
    np.testing.assert_allclose(emb.weights.sum(axis=1), 1.0, atol=1e-14)
    np.testing.assert_array_equal(emb.nodes, box.tets[emb.tets])
    np.testing.assert_allclose(np.einsum("vk,vkd->vd", emb.weights, box.points[emb.nodes]), x, atol=1e-15)


def test_outside_points_bind_to_the_nearest_tet(box):
    rng = np.random.default_rng(2)
    # points up to 3 mm outside the box on every side
    x = rng.uniform([-0.003, -0.003, -0.003], [0.043, 0.033, 0.023], (300, 3))
    emb = embed_points(box, x, max_distance=0.01, device="cpu")
    outside = ~((x >= 0) & (x <= [0.04, 0.03, 0.02])).all(axis=1)
    assert emb.outside_count == outside.sum() > 50
    closest = np.einsum("vk,vkd->vd", emb.weights, box.points[emb.nodes])
    # the exact distance to a box is known in closed form
    exact = np.linalg.norm(x - np.clip(x, 0.0, [0.04, 0.03, 0.02]), axis=1)
    np.testing.assert_allclose(emb.distances, exact, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(closest - x, axis=1), exact, atol=1e-12)
    assert np.all(emb.weights >= 0.0)


def test_nearest_tet_on_a_curved_shell_vs_sampling():
    mesh = shell_tet_mesh(8, 8, 2, thickness=0.01)
    rng = np.random.default_rng(3)
    surface = mesh.points[mesh.surface_nodes]
    x = surface[rng.choice(len(surface), 200)] + rng.normal(0.0, 0.001, (200, 3))
    emb = embed_points(mesh, x, max_distance=0.02, device="cpu")
    bound = sampled_distance(mesh, x)
    # our point lies in its tet, so its distance is >= the true distance; not exceeding the sampled
    # upper bound makes it the minimum
    assert np.all(emb.distances <= bound + 1e-12)
    closest = np.einsum("vk,vkd->vd", emb.weights, mesh.points[emb.nodes])
    np.testing.assert_allclose(np.linalg.norm(closest - x, axis=1), emb.distances, atol=1e-12)
    inside = emb.distances == 0.0
    bary = brute_force_barycentrics(mesh, x[inside])
    assert (bary.min(axis=2).max(axis=1) >= -1e-12).all()
    outside_bary = brute_force_barycentrics(mesh, x[~inside])
    assert (outside_bary.min(axis=2).max(axis=1) < 0.0).all()  # truly outside every tet


def test_far_point_is_rejected(box):
    with pytest.raises(ValueError, match=r"point 1 at .* farther than max_distance"):
        embed_points(box, [[0.01, 0.01, 0.01], [0.2, 0.0, 0.0]], max_distance=0.005, device="cpu")
    with pytest.raises(ValueError, match="not finite"):
        embed_points(box, [[np.nan, 0.0, 0.0]], device="cpu")
    with pytest.raises(ValueError, match=r"shape \(V, 3\)"):
        embed_points(box, np.zeros((3, 2)), device="cpu")
    with pytest.raises(TypeError, match="max_distance"):
        embed_points(box, [[0.01, 0.01, 0.01]], max_distance="far", device="cpu")


def test_apply_reproduces_linear_fields_single_and_batched(box):
    rng = np.random.default_rng(4)
    x = rng.uniform([-0.002, 0, 0], [0.042, 0.03, 0.02], (250, 3))
    emb = embed_points(box, x, device="cpu")
    A = rng.normal(size=(3, 3, 3))
    b = rng.normal(size=(3, 3))
    fields = np.einsum("fij,nj->fni", A, box.points) + b[:, None, :]
    closest = np.einsum("vk,vkd->vd", emb.weights, box.points[emb.nodes])
    expected = np.einsum("fij,vj->fvi", A, closest) + b[:, None, :]
    np.testing.assert_allclose(emb.apply(fields, device="cpu"), expected, atol=1e-13)
    np.testing.assert_allclose(emb.apply(fields[1], device="cpu"), expected[1], atol=1e-13)
    on_device = emb.apply(wp.array(fields, dtype=wp.vec3d, device="cpu"))
    assert isinstance(on_device, wp.array) and on_device.shape == (3, 250)
    np.testing.assert_allclose(on_device.numpy(), expected, atol=1e-13)
    single = emb.apply(wp.array(fields[2], dtype=wp.vec3d, device="cpu"))
    assert single.shape == (250,)
    np.testing.assert_allclose(single.numpy(), expected[2], atol=1e-13)


def test_apply_checks_input(box):
    emb = embed_points(box, [[0.01, 0.01, 0.01]], device="cpu")
    with pytest.raises(ValueError, match="shape"):
        emb.apply(np.zeros((box.node_count + 1, 3)))
    bad = np.zeros((box.node_count, 3))
    bad[5, 1] = np.inf
    with pytest.raises(ValueError, match=r"index \(5, 1\) is not finite"):
        emb.apply(bad)
    with pytest.raises(ValueError, match="vec3d"):
        emb.apply(wp.zeros(box.node_count, dtype=wp.vec3, device="cpu"))


def test_nodes_for_and_subset(box):
    rng = np.random.default_rng(5)
    nodes = rng.choice(box.node_count, 20, replace=False)
    x = box.points[nodes] + rng.normal(0.0, 1e-5, (20, 3))  # just next to nodes
    x = np.clip(x, 0.0, [0.04, 0.03, 0.02])
    emb = embed_points(box, x, device="cpu")
    np.testing.assert_array_equal(emb.nodes_for(np.arange(20)), nodes)
    sub = emb.subset([3, 7])
    np.testing.assert_array_equal(sub.tets, emb.tets[[3, 7]])
    np.testing.assert_array_equal(sub.weights, emb.weights[[3, 7]])
    u = rng.normal(size=(box.node_count, 3))
    np.testing.assert_allclose(sub.apply(u, device="cpu"), emb.apply(u, device="cpu")[[3, 7]], atol=0)
    with pytest.raises(ValueError, match="out of range"):
        emb.nodes_for([20])


def test_on_nodes_matches_full_apply(box):
    rng = np.random.default_rng(6)
    emb = embed_points(box, rng.uniform([0, 0, 0], [0.04, 0.03, 0.02], (30, 3)), device="cpu")
    used = np.unique(emb.nodes)
    shuffled = rng.permutation(np.r_[used, np.setdiff1d(np.arange(box.node_count), used)[:5]])
    compact = emb.on_nodes(shuffled)
    u = rng.normal(size=(2, box.node_count, 3))
    np.testing.assert_allclose(compact.apply(u[:, shuffled], device="cpu"), emb.apply(u, device="cpu"), atol=1e-15)
    with pytest.raises(ValueError, match="used by the embedding but not given"):
        emb.on_nodes(used[1:])
    with pytest.raises(ValueError, match="duplicates"):
        emb.on_nodes(np.r_[used, used[:1]])
