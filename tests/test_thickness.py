"""ThicknessMap: pixel-exact sampling, bilinear interpolation, blur, range, file input, errors."""

from __future__ import annotations

import numpy as np
import pytest

import warpface as wf

PLANAR = wf.PlanarProjection([0, 0, 0], [1, 0, 0], [0, 1, 0])
IMAGE = np.array([[0, 51, 102, 153], [204, 255, 0, 51]], dtype=np.uint8)  # (H=2, W=4)


def points_at(uv):
    uv = np.asarray(uv, dtype=float)
    return np.c_[uv, np.zeros(len(uv))]


def test_pixel_centres_give_pixel_values_and_midpoints_interpolate():
    tmap = wf.ThicknessMap(IMAGE, PLANAR, (0, 4), (0, 2), black=1.0, white=6.0)
    rows, cols = np.meshgrid(np.arange(2), np.arange(4), indexing="ij")
    centres = np.c_[cols.ravel() + 0.5, 2 - (rows.ravel() + 0.5)]  # row 0 is the top (largest v)
    expected = 1.0 + 5.0 * IMAGE.ravel() / 255.0
    np.testing.assert_allclose(tmap.sample(points_at(centres), device="cpu"), expected, atol=1e-5)
    between = tmap.sample(points_at([[1.0, 1.5], [1.5, 1.0]]), device="cpu")
    np.testing.assert_allclose(between, [1 + 5 * (0 + 51) / 2 / 255, 1 + 5 * (51 + 255) / 2 / 255], atol=1e-4)
    np.testing.assert_allclose(tmap.sample(points_at([[-3.0, 1.5]]), device="cpu"), [1.0], atol=1e-6)  # clamped edge


def test_blur_smooths_and_keeps_the_mean(tmp_path):
    rng = np.random.default_rng(0)
    noisy = rng.integers(0, 256, (64, 64)).astype(np.uint8)
    import cv2

    path = tmp_path / "map.png"
    cv2.imwrite(str(path), noisy)
    grid = np.stack(np.meshgrid(np.linspace(0.5, 63.5, 64), np.linspace(0.5, 63.5, 64)), -1).reshape(-1, 2)
    sharp = wf.ThicknessMap(path, PLANAR, (0, 64), (0, 64), 0.0, 20.0).sample(points_at(grid), device="cpu")
    smooth = wf.ThicknessMap(path, PLANAR, (0, 64), (0, 64), 0.0, 20.0, blur_sigma=3.0).sample(
        points_at(grid), device="cpu"
    )
    assert smooth.std() < 0.25 * sharp.std()
    assert smooth.mean() == pytest.approx(sharp.mean(), rel=0.02)
    assert sharp.min() >= 0.0 and sharp.max() <= 20.0


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(image=np.zeros((2, 2, 2))), "grayscale"),
        (dict(u_range=(1, 1)), "u_range"),
        (dict(white=-1.0), "white"),
        (dict(image=np.full((2, 2), 2.0)), r"\[0, 1\]"),
        (dict(image="/nonexistent/map.png"), "cannot read"),
    ],
)
def test_bad_maps(kwargs, message):
    args = dict(image=IMAGE, projection=PLANAR, u_range=(0, 4), v_range=(0, 2))
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        wf.ThicknessMap(**args)


def test_sampling_more_points_than_one_remap_row_holds():
    """cv2.remap refuses maps of 32,767 or more on a side: a dense head's vertices are sampled in rows."""
    tmap = wf.ThicknessMap(IMAGE, PLANAR, (0, 4), (0, 2), black=1.0, white=6.0)
    uv = np.random.default_rng(3).uniform((0.5, 0.5), (3.5, 1.5), (40_000, 2))
    column, row = uv[:, 0] - 0.5, 2.0 - uv[:, 1] - 0.5  # pixel coordinates of the bilinear lookup
    c0, r0 = np.floor(column).astype(int), np.floor(row).astype(int)
    fc, fr = column - c0, row - r0
    pixel = IMAGE.astype(np.float64) / 255.0
    expected = (
        pixel[r0, c0] * (1 - fc) * (1 - fr)
        + pixel[r0, c0 + 1] * fc * (1 - fr)
        + pixel[r0 + 1, c0] * (1 - fc) * fr
        + pixel[r0 + 1, c0 + 1] * fc * fr
    )
    np.testing.assert_allclose(tmap.sample(points_at(uv), device="cpu"), 1.0 + 5.0 * expected, atol=2e-3)
