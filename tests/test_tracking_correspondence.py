"""Sparse ↔ dense correspondence: closest points vs an independent float64 brute force, SPEC §3
normalisation, overhang, triangulation."""

import numpy as np
import pytest

from warpface.data import ict_face_region, shared_data_path
from warpface.geometry import closest_points
from warpface.mesh import load_obj
from warpface.tracking import FaceNormalization, compute_correspondence
from warpface.tracking.correspondence import triangulate_landmarks
from warpface.tracking.synthetic import procedural_face


def brute_force_distance(query, vertices, triangles):
    """Exact point–triangle distance in float64, by a different method than the kernel: solve the
    2×2 normal equations of the plane projection; inside the triangle that is the answer, outside
    the minimum over the three edge segments is. Returns (Q, T) distances."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    ab, ac = b - a, c - a
    d00 = np.einsum("ij,ij->i", ab, ab)
    d01 = np.einsum("ij,ij->i", ab, ac)
    d11 = np.einsum("ij,ij->i", ac, ac)
    den = d00 * d11 - d01 * d01
    nondegenerate = den > 1e-14 * np.maximum(d00 * d11, 1e-300)
    out = np.empty((query.shape[0], triangles.shape[0]))
    for i, p in enumerate(query):
        ap = p - a
        d20 = np.einsum("ij,ij->i", ap, ab)
        d21 = np.einsum("ij,ij->i", ap, ac)
        with np.errstate(divide="ignore", invalid="ignore"):
            v = (d11 * d20 - d01 * d21) / den
            w = (d00 * d21 - d01 * d20) / den
        inside = nondegenerate & (v >= 0) & (w >= 0) & (v + w <= 1)
        proj = a + v[:, None] * ab + w[:, None] * ac
        dist = np.where(inside, np.linalg.norm(p - proj, axis=1), np.inf)
        for s, e in ((a, b), (a, c), (b, c)):
            se = e - s
            length = np.einsum("ij,ij->i", se, se)
            t = np.clip(np.einsum("ij,ij->i", p - s, se) / np.where(length > 0, length, 1.0), 0.0, 1.0)
            dist = np.minimum(dist, np.linalg.norm(p - (s + t[:, None] * se), axis=1))
        out[i] = dist
    return out


def check_against_brute_force(query, vertices, triangles, tol):
    tri, bary, dist = closest_points(query, vertices, triangles, device="cpu")
    ref = brute_force_distance(query, vertices, triangles)
    best = ref.min(axis=1)
    assert tri.shape == (query.shape[0],) and bary.shape == (query.shape[0], 3) and dist.shape == (query.shape[0],)
    assert np.all(np.isfinite(bary)) and np.all(np.isfinite(dist))
    assert bary.min() >= -1e-6 and np.abs(bary.sum(axis=1) - 1.0).max() < 1e-5
    # The reported distance is the true minimum ...
    np.testing.assert_allclose(dist, best, atol=tol, rtol=0)
    # ... the returned triangle attains it ...
    np.testing.assert_allclose(ref[np.arange(len(tri)), tri], best, atol=tol, rtol=0)
    # ... and the barycentric point lies at that distance.
    point = np.einsum("qj,qjk->qk", bary.astype(np.float64), vertices[triangles[tri]])
    np.testing.assert_allclose(np.linalg.norm(query - point, axis=1), best, atol=tol, rtol=0)


def test_random_triangle_soup_matches_brute_force():
    rng = np.random.default_rng(7)
    vertices = rng.normal(size=(150, 3))
    triangles = rng.integers(0, 150, size=(400, 3))  # includes repeated-index (degenerate) triangles
    query = rng.normal(size=(400, 3)) * 1.5
    check_against_brute_force(query, vertices, triangles, tol=2e-6)


def test_surface_mesh_near_and_far_queries_match_brute_force():
    rng = np.random.default_rng(3)
    points, triangles = procedural_face(24)
    points = points + rng.normal(scale=0.002, size=points.shape)  # irregular triangles
    near = points[rng.integers(0, len(points), 300)] + rng.normal(scale=0.004, size=(300, 3))
    far = rng.uniform(-0.3, 0.3, size=(100, 3))
    # Placed 0.6 m from the origin, like a face in front of a camera: precision must not suffer.
    offset = np.array([0.05, -0.02, 0.6])
    check_against_brute_force(np.vstack([near, far]) + offset, points + offset, triangles, tol=2e-7)


def test_voronoi_regions_and_degenerate_triangles():
    vertices = np.array(
        [
            [0, 0, 0],
            [1, 0, 0],
            [0, 1, 0],  # right triangle
            [2, 0, 0],
            [3, 0, 0],
            [4, 0, 0],  # collinear
            [5, 0, 0],
            [5, 0, 0],
            [6, 0, 0],  # two coincident corners
            [8, 0, 0],
            [8, 0, 0],
            [8, 0, 0],
        ],
        dtype=float,
    )  # a point
    triangles = np.arange(12).reshape(4, 3)
    cases = {
        (0.2, 0.2, 0.5): (0, [0.6, 0.2, 0.2], 0.5),  # face region
        (-1.0, -1.0, 0.0): (0, [1, 0, 0], np.sqrt(2)),  # vertex A region
        (1.3, -0.5, 0.0): (0, [0, 1, 0], np.sqrt(0.34)),  # vertex B region
        (-1.0, 2.0, 0.0): (0, [0, 0, 1], np.sqrt(2)),  # vertex C region
        (-1.0, 0.5, 0.0): (0, [0.5, 0, 0.5], 1.0),  # edge AC region
        (0.5, -1.0, 0.0): (0, [0.5, 0.5, 0], 1.0),  # edge AB region
        (1.0, 1.0, 0.0): (0, [0, 0.5, 0.5], np.sqrt(0.5)),  # edge BC region
        (3.5, 1.0, 0.0): (1, None, 1.0),  # collinear triangle: its segment
        (5.5, 2.0, 0.0): (2, None, 2.0),  # coincident corners: still the segment 5–6
        (8.0, 0.0, 3.0): (3, [1 / 3, 1 / 3, 1 / 3], 3.0),  # point triangle (any bary is the point)
    }
    for q, (want_tri, want_bary, want_dist) in cases.items():
        tri, bary, dist = closest_points(np.array([q]), vertices, triangles, device="cpu")
        assert tri[0] == want_tri, q
        assert dist[0] == pytest.approx(want_dist, abs=1e-6), q
        if want_bary is not None and want_tri != 3:
            np.testing.assert_allclose(bary[0], want_bary, atol=1e-6)
        assert np.isfinite(bary).all() and abs(bary.sum() - 1) < 1e-6


def test_closest_points_bad_input():
    v = np.eye(3)
    t = np.array([[0, 1, 2]])
    with pytest.raises(ValueError, match="query"):
        closest_points(np.array([[np.nan, 0, 0]]), v, t, device="cpu")
    with pytest.raises(ValueError, match="triangle 0"):
        closest_points(np.zeros((1, 3)), v, np.array([[0, 1, 3]]), device="cpu")
    with pytest.raises(ValueError, match="shape"):
        closest_points(np.zeros((1, 2)), v, t, device="cpu")
    with pytest.raises(TypeError, match="integer"):
        closest_points(np.zeros((1, 3)), v, t.astype(float), device="cpu")
    tri, bary, dist = closest_points(np.zeros((0, 3)), v, t, device="cpu")
    assert tri.shape == (0,) and bary.shape == (0, 3) and dist.shape == (0,)


def test_normalisation_matches_proportions_and_inverts():
    rng = np.random.default_rng(0)
    sparse = rng.uniform([-0.07, -0.11, 0.0], [0.07, 0.09, 0.05], size=(200, 3))
    dense = rng.uniform([-0.1, -0.15, -0.02], [0.1, 0.13, 0.09], size=(500, 3))
    s = FaceNormalization.measure(sparse, eye_y=0.01)
    d = FaceNormalization.measure(dense, eye_y=0.02)
    assert s.width == pytest.approx(np.ptp(sparse[:, 0]))
    nd = d.normalize(dense, match=s)
    ns = s.normalize(sparse)
    # eq. 5.1–5.4: both faces one unit wide, the dense heights above/below the eye line become the sparse's.
    assert np.ptp(nd[:, 0]) == pytest.approx(1.0) and np.ptp(ns[:, 0]) == pytest.approx(1.0)
    assert nd[:, 1].max() == pytest.approx(ns[:, 1].max())
    assert nd[:, 1].min() == pytest.approx(ns[:, 1].min())
    assert nd[:, 2].max() == pytest.approx(0.0) and ns[:, 2].max() == pytest.approx(0.0)
    np.testing.assert_allclose(d.denormalize(nd, match=s), dense, atol=1e-12)
    np.testing.assert_allclose(s.denormalize(ns), sparse, atol=1e-12)
    with pytest.raises(ValueError, match="eye_y"):
        FaceNormalization.measure(sparse, eye_y=1.0)


def test_overhang_is_distance_beyond_the_contour():
    # Sparse: the unit square in z = 0; dense: a larger grid in z = 0.01.
    sparse = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    sparse_tri = np.array([[0, 1, 2], [0, 2, 3]])
    x, y = np.meshgrid(np.linspace(-0.5, 1.5, 21), np.linspace(-0.5, 1.5, 21))
    dense = np.stack([x.ravel(), y.ravel(), np.full(x.size, 0.01)], axis=1)
    corr = compute_correspondence(dense, sparse, sparse_tri, device="cpu")
    beyond = np.hypot(
        np.clip(-dense[:, 0], 0, None) + np.clip(dense[:, 0] - 1, 0, None),
        np.clip(-dense[:, 1], 0, None) + np.clip(dense[:, 1] - 1, 0, None),
    )
    np.testing.assert_allclose(corr.overhang, beyond, atol=1e-6)
    np.testing.assert_allclose(corr.distance, np.hypot(beyond, 0.01), atol=1e-6)


def test_triangulate_landmarks_orientation():
    points, _ = procedural_face(8)
    tri = triangulate_landmarks(points)
    e1 = points[tri[:, 1], :2] - points[tri[:, 0], :2]
    e2 = points[tri[:, 2], :2] - points[tri[:, 0], :2]
    assert np.all(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] > 0)
    assert set(np.unique(tri)) == set(range(len(points)))


def test_mediapipe_canonical_to_ict_face_against_brute_force():
    mp = shared_data_path("mediapipe", "canonical_face_model.obj")
    ict = ict_face_region("neutral")
    if mp is None or ict is None:
        pytest.skip("shared data (mediapipe, ict_facekit) not available")
    sparse, sparse_tri = load_obj(mp)
    dense, _ = load_obj(ict)
    # Eye lines: MediaPipe outer eye corners 33/263; ICT landmarks 36/45 (iBUG order).
    from warpface.data import ict_landmark_indices

    s = FaceNormalization.measure(sparse, eye_y=sparse[[33, 263], 1].mean())
    d = FaceNormalization.measure(dense, eye_y=dense[ict_landmark_indices()[[36, 45]], 1].mean())
    corr = compute_correspondence(
        dense, sparse, sparse_tri, sparse_normalization=s, dense_normalization=d, device="cpu"
    )
    assert corr.triangle.shape == (len(dense),) and np.isfinite(corr.distance).all()
    rng = np.random.default_rng(1)
    pick = rng.choice(len(dense), 300, replace=False)
    ns, nd = s.normalize(sparse), d.normalize(dense, match=s)
    ref = brute_force_distance(nd[pick], ns, sparse_tri).min(axis=1)
    np.testing.assert_allclose(corr.distance[pick] / d.width, ref, atol=2e-6)
