"""Pinhole intrinsics and robust back-projection against analytic depth images."""

import numpy as np
import pytest

from warpface.tracking import KINECT_V1_INTRINSICS as K
from warpface.tracking import CameraIntrinsics, KinectNoise, backproject


def rays(k: CameraIntrinsics, u, v):
    return np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u, dtype=float)], axis=-1)


def plane_depth(normal, offset, k=K):
    """Depth image of the plane n·X = offset (OpenCV pixel centres at integers)."""
    u, v = np.meshgrid(np.arange(k.width), np.arange(k.height))
    return offset / (rays(k, u, v) @ normal)


def sphere_depth(center, radius, k=K):
    u, v = np.meshgrid(np.arange(k.width), np.arange(k.height))
    d = rays(k, u, v)
    # |t d − c|² = r² → smallest t; Z = t since d_z = 1.
    a = np.sum(d * d, -1)
    b = -2 * d @ center
    c = center @ center - radius**2
    disc = b * b - 4 * a * c
    t = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
    return np.where(disc > 0, t, 0.0)


def test_intrinsics_round_trip_and_pyrender_shift():
    pts = np.array([[0.1, -0.05, 0.6], [-0.02, 0.03, 0.9]])
    np.testing.assert_allclose(K.unproject(K.project(pts), pts[:, 2]), pts, atol=1e-15)
    assert K.to_pyrender() == (525.0, 525.0, 320.0, 240.0)
    assert CameraIntrinsics.from_dict(K.to_dict()) == K
    with pytest.raises(ValueError, match="missing fy"):
        CameraIntrinsics.from_dict({"fx": 1, "cx": 1, "cy": 1, "width": 2, "height": 2})
    with pytest.raises(ValueError, match="focal"):
        CameraIntrinsics(0.0, 1.0, 0.0, 0.0, 4, 4)


@pytest.mark.parametrize("model", ["plane", "quadric"])
def test_exact_on_a_slanted_plane(model):
    n = np.array([0.35, -0.25, -1.0])
    n /= np.linalg.norm(n)
    offset = -0.6 * abs(n[2])
    depth = plane_depth(n, offset)
    rng = np.random.default_rng(0)
    px = rng.uniform([30, 30], [610, 450], size=(60, 2))
    got, inliers = backproject(px, depth, K, model=model, device="cpu")
    r = rays(K, px[:, 0], px[:, 1])
    want = r * (offset / (r @ n))[:, None]
    np.testing.assert_allclose(got, want, atol=5e-7)  # float32 kernel, exact model
    assert np.all(inliers == 81)


def test_quadric_removes_curvature_bias_on_a_sphere():
    center, radius = np.array([0.0, 0.0, 0.68]), 0.08  # a nose-sized bump at 0.6 m
    depth = sphere_depth(center, radius)
    u, v = np.meshgrid(np.arange(300, 341, 8), np.arange(220, 261, 8))
    px = np.stack([u.ravel() + 0.3, v.ravel() - 0.2], axis=1)
    r = rays(K, px[:, 0], px[:, 1])
    b = -2 * r @ center
    t = (-b - np.sqrt(b * b - 4 * np.sum(r * r, -1) * (center @ center - radius**2))) / (2 * np.sum(r * r, -1))
    want = r * t[:, None]
    plane, _ = backproject(px, depth, K, model="plane", window=11, device="cpu")
    quad, _ = backproject(px, depth, K, model="quadric", window=11, device="cpu")
    err_plane = np.linalg.norm(plane - want, axis=1).max()
    err_quad = np.linalg.norm(quad - want, axis=1).max()
    assert err_quad < 2e-5 and err_quad < 0.25 * err_plane


def test_noise_holes_and_flying_pixels_are_rejected():
    n = np.array([0.2, 0.1, -1.0])
    n /= np.linalg.norm(n)
    offset = -0.6 * abs(n[2])
    clean = plane_depth(n, offset)
    rng = np.random.default_rng(5)
    noisy = KinectNoise(dropout=0.2).apply(clean, rng)
    flying = rng.random(clean.shape) < 0.03
    noisy[flying] = rng.uniform(0.3, 3.0, flying.sum())  # flying pixels / background
    px = rng.uniform([40, 40], [600, 440], size=(200, 2))
    got, inliers = backproject(px, noisy, K, device="cpu")
    r = rays(K, px[:, 0], px[:, 1])
    want = r * (offset / (r @ n))[:, None]
    err = np.linalg.norm(got - want, axis=1)
    assert np.all(np.isfinite(err)) and err.mean() < 0.4e-3 and err.max() < 1.5e-3
    # The nearest depth pixel, for comparison, carries the noise and every outlier.
    near = np.round(px).astype(int)
    z = noisy[near[:, 1], near[:, 0]]
    ok = z > 0
    nearest_err = np.linalg.norm(r[ok] * z[ok, None] - want[ok], axis=1)
    assert nearest_err.mean() > 5 * err.mean()


def test_occluding_edge_is_rejected_not_guessed():
    depth = np.full((K.height, K.width), 0.62)
    depth[:, 320:] = 0.58  # a nearer surface covering the right half
    px = np.array([[318.6, 200.0], [300.0, 200.0], [340.0, 200.0], [322.0, 240.0]])
    got, inliers = backproject(px, depth, K, device="cpu")
    assert np.isnan(got[0]).all() and inliers[0] == 0  # window split almost evenly across the edge
    assert got[3, 2] == pytest.approx(0.58, abs=1e-6)  # 2 px inside the near surface: its own surface
    assert got[1, 2] == pytest.approx(0.62, abs=1e-6) and got[2, 2] == pytest.approx(0.58, abs=1e-6)


def test_missing_landmarks_and_bad_input():
    depth = np.full((K.height, K.width), 0.6, dtype=np.float32)
    depth[100:140, 100:140] = 0.0  # a hole
    got, inliers = backproject([[np.nan, 3.0], [-50.0, 10.0], [120.0, 120.0], [320.0, 240.0]], depth, K, device="cpu")
    assert np.isnan(got[:3]).all() and inliers[:3].tolist() == [0, 0, 0]
    np.testing.assert_allclose(got[3], [0.5 / 525 * 0.6, 0.5 / 525 * 0.6, 0.6], atol=1e-7)
    with pytest.raises(ValueError, match="intrinsics are 640×480"):
        backproject(np.zeros((1, 2)), np.zeros((10, 10)), K, device="cpu")
    with pytest.raises(ValueError, match="odd"):
        backproject(np.zeros((1, 2)), depth, K, window=8, device="cpu")
    with pytest.raises(ValueError, match="model"):
        backproject(np.zeros((1, 2)), depth, K, model="cubic", device="cpu")


def test_repeated_depth_values_select_the_right_surface():
    """Quantised depths repeat: the medians (seed and MAD) must pick the right order statistic among
    ties. A flat face at 0.6 m with a background at 0.9 m on one side of each landmark: the seed is
    the majority surface of the innermost ring, whichever it is."""
    rng = np.random.default_rng(3)
    depth = np.full((K.height, K.width), 0.6)
    depth[:, 320:] = 0.9  # background right of column 320
    depth[rng.random(depth.shape) < 0.1] = 0.0  # holes
    pixels = np.array([[318.0, 100.0], [321.0, 200.0], [150.0, 300.0], [500.0, 50.0]])
    points, _ = backproject(pixels, depth, K, min_inlier_fraction=0.0)
    # 318: ring 1 is columns 317–319 — all face; 321: columns 320–322 — all background.
    np.testing.assert_allclose(points[:, 2], [0.6, 0.9, 0.6, 0.9], atol=1e-6)
    # Three quantisation levels, many ties each: the fit stays within the levels' spread.
    levels = rng.choice([0.599, 0.600, 0.601], size=depth.shape)
    points, inliers = backproject(pixels[2:], levels, K)
    assert np.all(inliers > 0) and np.all(np.abs(points[:, 2] - 0.6) < 1e-3)


def test_kth_smallest_with_ties_matches_numpy():
    """The in-kernel selection behind the medians, on rows full of repeated values, every rank."""
    import warp as wp

    from warpface.tracking.depth import kth_smallest

    @wp.kernel
    def select_rows(
        values: wp.array2d(dtype=float),
        lengths: wp.array(dtype=wp.int32),
        ranks: wp.array(dtype=wp.int32),
        out: wp.array(dtype=float),
    ):
        i = wp.tid()
        out[i] = kth_smallest(values, i, lengths[i], ranks[i])

    rng = np.random.default_rng(5)
    rows, width = 400, 81
    values = rng.integers(0, 4, size=(rows, width)).astype(np.float32) * 0.001 + 0.6  # four distinct depths
    values[::3] = rng.normal(size=(len(values[::3]), width)).astype(np.float32)  # and rows without ties
    lengths = rng.integers(1, width + 1, size=rows).astype(np.int32)
    ranks = (rng.random(rows) * lengths).astype(np.int32)
    out = wp.empty(rows, dtype=float, device="cpu")
    wp.launch(
        select_rows,
        dim=rows,
        inputs=[
            wp.array(values, dtype=float, device="cpu"),
            wp.array(lengths, device="cpu"),
            wp.array(ranks, device="cpu"),
        ],
        outputs=[out],
        device="cpu",
    )
    expected = [np.sort(values[i, : lengths[i]])[ranks[i]] for i in range(rows)]
    np.testing.assert_array_equal(out.numpy(), expected)


def test_a_reused_image_buffer_and_new_pixels_are_read_every_call():
    """The CPU path keeps the last image's wrapper and writes pixels into a recorded buffer: a camera
    that refills the same buffer, and new landmark positions, must still be seen on every call."""
    n = np.array([0.2, -0.1, -1.0])
    n /= np.linalg.norm(n)
    frame = plane_depth(n, -0.6 * abs(n[2])).astype(np.float32)  # float32, contiguous: used in place
    px = np.random.default_rng(1).uniform([40, 40], [600, 440], size=(20, 2))
    for offset in (-0.6, -0.7, -0.55):
        frame[:] = plane_depth(n, offset * abs(n[2]))
        for pixels in (px, px[::-1] + 3.0):
            got, _ = backproject(pixels, frame, K, device="cpu")
            r = rays(K, pixels[:, 0], pixels[:, 1])
            np.testing.assert_allclose(got, r * (offset * abs(n[2]) / (r @ n))[:, None], atol=5e-6)
