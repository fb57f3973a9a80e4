"""Fiducial detection on synthetic images with known sub-pixel positions."""

import cv2
import numpy as np
import pytest

from warpface.tracking import ArucoMarkers, DotTracker
from warpface.tracking.detect import detect_blobs


def paint_dots(centers, *, size=(480, 640), radius=4.0, background=(200, 150, 120), color=(20, 20, 20), gradient=True):
    """Anti-aliased discs by exact area coverage (4×4 supersampling) on a shaded background."""
    h, w = size
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    shade = (0.8 + 0.2 * xx / w)[..., None] if gradient else 1.0
    image = np.ones((h, w, 3)) * np.asarray(background, float) * shade
    offsets = (np.arange(4) + 0.5) / 4 - 0.5
    for cx, cy in centers:
        x0, x1 = int(cx - radius - 2), int(cx + radius + 3)
        y0, y1 = int(cy - radius - 2), int(cy + radius + 3)
        px, py = xx[y0:y1, x0:x1], yy[y0:y1, x0:x1]
        cover = np.zeros_like(px)
        for ox in offsets:
            for oy in offsets:
                cover += (np.hypot(px + ox - cx, py + oy - cy) <= radius) / 16.0
        patch = image[y0:y1, x0:x1]
        image[y0:y1, x0:x1] = patch * (1 - cover[..., None]) + np.asarray(color, float) * cover[..., None]
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def test_blob_centroids_are_subpixel_accurate():
    rng = np.random.default_rng(0)
    centers = np.stack([rng.uniform(40, 600, 30), rng.uniform(40, 440, 30)], axis=1)
    centers = centers[np.min(np.linalg.norm(centers[:, None] - centers[None], axis=2) + np.eye(30) * 1e3, 1) > 20]
    blobs = detect_blobs(paint_dots(centers))
    assert len(blobs.centers) == len(centers)
    d = np.linalg.norm(centers[:, None] - blobs.centers[None], axis=2)
    assert d.min(axis=1).max() < 0.05
    # Coloured dots by chromaticity (shading does not matter), dark ones ignored.
    image = paint_dots(centers[:5], color=(40, 200, 60))
    image = np.where((paint_dots(centers[5:10]) < 100).all(-1, keepdims=True), paint_dots(centers[5:10]), image)
    green = detect_blobs(image, color=(40, 200, 60), threshold=128)
    d = np.linalg.norm(centers[:5, None] - green.centers[None], axis=2)
    assert len(green.centers) == 5 and d.min(axis=1).max() < 0.1


def test_shape_gates_reject_lines_and_large_regions():
    image = paint_dots([(100.0, 100.0)])
    cv2.line(image, (200, 50), (400, 60), (10, 10, 10), 3)  # hair, an eyebrow edge
    cv2.rectangle(image, (300, 300), (360, 360), (10, 10, 10), -1)  # a big dark region (mouth)
    blobs = detect_blobs(image)
    assert len(blobs.centers) == 1 and np.allclose(blobs.centers[0], [100, 100], atol=0.05)
    with pytest.raises(ValueError, match="uint8"):
        detect_blobs(image.astype(np.float32))
    with pytest.raises(ValueError, match="color"):
        detect_blobs(image, color="blue")


def test_dot_tracker_keeps_identities_and_rejects_outliers():
    rng = np.random.default_rng(1)
    gx, gy = np.meshgrid(np.linspace(150, 490, 6), np.linspace(120, 360, 5))
    start = np.stack([gx.ravel(), gy.ravel()], axis=1) + rng.normal(scale=2, size=(30, 2))
    lower = start[:, 1] > 250
    tracker = DotTracker(start, gate_px=12, outlier_px=6)
    for k in range(1, 9):
        # A smooth motion: everything drifts, the lower part opens downwards ("jaw").
        truth = start + [1.5 * k, 0.5 * k] + np.where(lower[:, None], [0.0, 3.0 * k], 0.0)
        hidden = {3: 7, 4: 7, 5: 12, 6: 20}.get(k)  # occluded dots
        shown = truth if hidden is None else np.delete(truth, hidden, axis=0)
        if k == 6:  # dot 20 hidden, and a highlight appears within its gate: an outlier
            shown = np.vstack([shown, truth[20] + [9.0, 0.0]])
        rejected = tracker.rejected_outliers
        pixels, conf = tracker.detect(paint_dots(shown))
        found = conf > 0
        np.testing.assert_allclose(pixels[found], truth[found], atol=0.05)  # never a wrong identity
        if hidden is not None:
            assert not found[hidden] and np.isnan(pixels[hidden]).all()
            assert found.sum() == 29
        else:
            assert found.all()  # re-acquired after the gap
        assert tracker.rejected_outliers - rejected == (1 if k == 6 else 0)
    with pytest.raises(ValueError, match="initial_pixels"):
        DotTracker(np.zeros((0, 2)))


def render_marker(image, dictionary, marker_id, corners):
    """Warp an ArUco marker (with a white quiet zone) onto four image corners."""
    side = 60
    marker = cv2.aruco.generateImageMarker(dictionary, marker_id, side, borderBits=1)
    padded = np.full((side + 30, side + 30), 255, np.uint8)
    padded[15 : 15 + side, 15 : 15 + side] = marker
    src = np.array([[15, 15], [15 + side, 15], [15 + side, 15 + side], [15, 15 + side]], np.float32) - 0.5
    h = cv2.getPerspectiveTransform(src, np.asarray(corners, np.float32))
    warped = cv2.warpPerspective(padded, h, (image.shape[1], image.shape[0]), flags=cv2.INTER_LINEAR, borderValue=0)
    mask = cv2.warpPerspective(np.ones_like(padded), h, (image.shape[1], image.shape[0]), flags=cv2.INTER_NEAREST)
    image[mask > 0] = warped[mask > 0][:, None]
    return h


def test_aruco_marker_centres():
    detector = ArucoMarkers([3, 7, 11], names=["brow", "chin", "cheek"])
    image = np.full((480, 640, 3), 90, np.uint8)
    quads = {
        3: [[100, 100], [170, 105], [168, 172], [98, 168]],
        7: [[300, 250], [370, 240], [380, 310], [305, 318]],
        99: [[450, 100], [520, 100], [520, 170], [450, 170]],
    }  # an id we do not track
    centres = {}
    for marker, quad in quads.items():
        h = render_marker(image, detector.dictionary, marker if marker != 99 else 20, quad)
        c = h @ np.array([15 + 30 - 0.5, 15 + 30 - 0.5, 1.0])  # the marker's centre, mapped
        centres[marker] = c[:2] / c[2]
    pixels, conf = detector.detect(image)
    assert detector.landmark_names == ("brow", "chin", "cheek")
    assert conf.tolist() == [1.0, 1.0, 0.0] and np.isnan(pixels[2]).all()
    np.testing.assert_allclose(pixels[0], centres[3], atol=0.15)
    np.testing.assert_allclose(pixels[1], centres[7], atol=0.15)
    with pytest.raises(ValueError, match="repeated"):
        ArucoMarkers([1, 1])
    with pytest.raises(ValueError, match="outside DICT_4X4_50"):
        ArucoMarkers([50])
    with pytest.raises(ValueError, match="dictionary"):
        ArucoMarkers([1], dictionary="DICT_NOPE")
