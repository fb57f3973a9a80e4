"""Fiducial detection in colour images: ArUco markers and painted dots with frame-to-frame tracking.

Both detectors share one interface — ``landmark_names`` and ``detect(color) -> (pixels (N, 2),
confidence (N,))`` with NaN pixels for landmarks not found — so
:class:`~warpface.tracking.sources.RGBDLandmarks` can lift either to 3-D. Pixel coordinates follow
OpenCV's convention (pixel centres at integer coordinates; see :mod:`warpface.tracking.depth`).

* :class:`ArucoMarkers` — ``cv2.aruco.ArucoDetector`` with sub-pixel corner refinement; the
  landmark is the marker centre, the intersection of its diagonals (the projective centre of the
  square, unlike the corner mean).
* :func:`detect_blobs` — dark or coloured dots: a contrast map (dark: local background from a
  morphological closing minus the image; coloured: closeness to a target colour), connected
  components, shape gates (area, axis ratio, fill), and a contrast-weighted sub-pixel centroid.
* :class:`DotTracker` — dots are anonymous, so identities come from the previous frame: the
  prediction (last position plus damped velocity) is associated to detections by minimum-cost
  assignment within a gate; a match whose motion disagrees with its neighbours' by more than
  ``outlier_px`` is rejected as an outlier (a highlight, a stray blob), and the landmark is
  reported missing for that frame.

OpenCV is imported lazily.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .._validate import as_bounded, as_count, as_finite_array, as_positive
from .streams import validate_landmark_names

__all__ = ["Blobs", "detect_blobs", "DotTracker", "ArucoMarkers", "MAX_DOT_DIAMETER"]

MAX_DOT_DIAMETER = 1000
"""Largest accepted dot diameter [px] (it sizes the background filter of dark dots)."""


def _checked_blob_options(
    *,
    color="dark",
    threshold: float = 70.0,
    min_area: int = 6,
    max_area: int = 2000,
    min_axis_ratio: float = 0.35,
    max_diameter: int = 25,
) -> dict:
    """The blob gates of :func:`detect_blobs` with their defaults (the one place they are set), checked; each bad
    one named in a ValueError (an unknown one in a TypeError)."""
    if isinstance(color, str):
        if color != "dark":
            raise ValueError(f"color must be 'dark' or an RGB triple, got {color!r}")
    else:
        rgb = as_finite_array(color, "color", shape=(3,))
        if rgb.min() < 0 or rgb.max() > 255:
            raise ValueError(f"color: RGB values must be in [0, 255], got {rgb.tolist()}")
        color = tuple(float(c) for c in rgb)
    return dict(
        color=color,
        threshold=as_bounded(threshold, "threshold", 0.0, 255.0),
        min_area=as_count(min_area, "min_area", minimum=1),
        max_area=as_count(max_area, "max_area", minimum=1),
        min_axis_ratio=as_bounded(min_axis_ratio, "min_axis_ratio", 0.0, 1.0),
        max_diameter=as_count(max_diameter, "max_diameter", minimum=1, maximum=MAX_DOT_DIAMETER),
    )


@dataclass(frozen=True)
class Blobs:
    """Blob candidates in one image."""

    centers: np.ndarray
    """Contrast-weighted centroids [px], shape (K, 2), float64, OpenCV convention (over the blob and a
    one-pixel rim, so partially covered edge pixels count with their partial contrast)."""
    areas: np.ndarray
    """Pixel counts, shape (K,), int64."""
    axis_ratio: np.ndarray
    """Minor/major axis ratio from second moments, shape (K,), in (0, 1]; 1 = round."""
    contrast: np.ndarray
    """Mean contrast of the blob's pixels, shape (K,), float64, 0–255 scale."""


def _image_array(image) -> np.ndarray:
    """``image`` as an array; a ragged nesting is a ValueError naming the image."""
    try:
        return np.asarray(image)
    except (TypeError, ValueError):
        raise ValueError("image must be (H, W, 3) uint8 RGB, got a ragged nesting") from None


def _contrast_map(image: np.ndarray, color, max_diameter: int) -> np.ndarray:
    """Per-pixel evidence of a dot, 0–255 (uint8 for dark dots, float32 for coloured ones): darkness
    below the local background, or closeness to the target colour."""
    import cv2

    rgb = _image_array(image)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8 or rgb.size == 0:
        raise ValueError(f"image must be (H, W, 3) uint8 RGB, got {rgb.shape} {rgb.dtype}")
    if isinstance(color, str):
        if color != "dark":
            raise ValueError(f"color must be 'dark' or an RGB triple, got {color!r}")
        gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        # A closing wider than any dot fills the dots with the surrounding skin; a rectangular
        # element is separable, so this costs O(pixels) whatever the dot size.
        size = int(max_diameter) + 2
        kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (size, size))
        background = cv2.morphologyEx(gray, cv2.MORPH_CLOSE, kernel)
        # A closing never darkens a pixel, so the uint8 difference is exact (no saturation).
        return cv2.subtract(background, gray)
    target = np.asarray(color, dtype=np.float32).reshape(-1)
    if target.shape != (3,):
        raise ValueError(f"color must be 'dark' or an RGB triple, got {color!r}")
    # Chromaticity distance ignores shading; brightness gates out near-black pixels.
    pix = rgb.astype(np.float32)
    total = pix.sum(axis=2, keepdims=True)
    chroma = pix / np.maximum(total, 1.0)
    t_chroma = target / max(float(target.sum()), 1.0)
    dist = np.linalg.norm(chroma - t_chroma, axis=2)
    score = np.clip(1.0 - dist / 0.25, 0.0, 1.0) * 255.0
    return np.where(total[..., 0] > 60.0, score, 0.0).astype(np.float32)


def detect_blobs(image: np.ndarray, **options) -> Blobs:
    """Find dot-like blobs.

    Args:
        image: RGB image, shape (H, W, 3), uint8.
        options: the blob gates, keywords (the defaults in brackets):

            * ``color`` [``"dark"``]: ``"dark"`` for dark dots on lighter skin, or an RGB triple for coloured dots;
            * ``threshold`` [70]: contrast (0–255) a pixel needs to belong to a dot;
            * ``min_area``, ``max_area`` [6, 2000]: accepted blob sizes [px];
            * ``min_axis_ratio`` [0.35]: rejects elongated blobs (edges, hair, eyelids); 1 = only perfect circles;
            * ``max_diameter`` [25]: largest dot diameter [px], 1 … :data:`MAX_DOT_DIAMETER` (sets the
              background filter for dark dots).

    Returns:
        :class:`Blobs` passing the gates, in no particular order.
    """
    return _detect_blobs(image, **_checked_blob_options(**options))


def _detect_blobs(image, *, color, threshold, min_area, max_area, min_axis_ratio, max_diameter) -> Blobs:
    """:func:`detect_blobs` with options already checked."""
    import cv2

    contrast = _contrast_map(image, color, max_diameter)
    mask = (contrast >= threshold).astype(np.uint8)
    # Labels without OpenCV's statistics (which cost 6× the labelling); the few needed come below.
    count, labels = cv2.connectedComponents(mask, connectivity=8)
    if count <= 1:
        empty = np.zeros(0)
        return Blobs(np.zeros((0, 2)), empty.astype(np.int64), empty, empty)
    # Centroids over each blob grown by one pixel: its partially covered rim pixels (below the
    # threshold) still carry their share of contrast, which removes the threshold's edge bias. The
    # 3×3 maximum of the labels is that growth: 8-connected blobs never touch, so inside a blob it
    # is the blob's own label (a rim pixel between two blobs joins the higher label).
    exact = np.uint16 if count <= np.iinfo(np.uint16).max else np.float64
    grown = cv2.dilate(labels.astype(exact), np.ones((3, 3), np.uint8))
    width = grown.shape[1]
    flat = np.flatnonzero(grown.ravel() > 0)  # through a boolean mask: 4× faster than on the labels
    lab = grown.ravel()[flat].astype(np.int64)
    rows, cols = np.divmod(flat, width)
    w = np.maximum(contrast.ravel()[flat].astype(np.float64), 0.0)
    x = cols.astype(np.float64)
    y = rows.astype(np.float64)
    sw = np.bincount(lab, w, count)
    sx = np.bincount(lab, w * x, count)
    sy = np.bincount(lab, w * y, count)
    sxx = np.bincount(lab, w * x * x, count)
    syy = np.bincount(lab, w * y * y, count)
    sxy = np.bincount(lab, w * x * y, count)
    # Area and bounding box of the blob itself (rim excluded): its pixels sorted by label, each
    # label's run reduced (every label 1…count−1 has at least one pixel).
    inside = labels.ravel()[flat] > 0
    own = lab[inside]
    order = np.argsort(own, kind="stable")
    area = np.bincount(own, minlength=count)[1:]
    starts = np.concatenate([[0], np.cumsum(area)[:-1]])
    own_cols, own_rows = cols[inside][order], rows[inside][order]
    bw = np.maximum.reduceat(own_cols, starts) - np.minimum.reduceat(own_cols, starts) + 1
    bh = np.maximum.reduceat(own_rows, starts) - np.minimum.reduceat(own_rows, starts) + 1
    ids = np.arange(1, count)
    sw_ = sw[ids]
    cx, cy = sx[ids] / sw_, sy[ids] / sw_
    vxx = sxx[ids] / sw_ - cx * cx
    vyy = syy[ids] / sw_ - cy * cy
    vxy = sxy[ids] / sw_ - cx * cy
    half_tr = 0.5 * (vxx + vyy)
    disc = np.sqrt(np.maximum(0.25 * (vxx - vyy) ** 2 + vxy * vxy, 0.0))
    ratio = np.sqrt(np.maximum(half_tr - disc, 0.0) / np.maximum(half_tr + disc, 1e-12))
    fill = area / np.maximum(bw * bh, 1)  # a disc fills π/4 ≈ 0.79 of its box
    keep = (area >= min_area) & (area <= max_area) & (ratio >= min_axis_ratio) & (fill >= 0.5)
    return Blobs(
        centers=np.stack([cx, cy], axis=1)[keep],
        areas=area[keep],
        axis_ratio=ratio[keep],
        contrast=(sw_ / area)[keep],  # mean over the blob's own pixels, rim included in the sum
    )


MAX_TRACKING_PX = 1.0e5
"""Largest accepted pixel coordinate or pixel distance in :class:`DotTracker`."""


class DotTracker:
    """Track N painted dots from frame to frame.

    Args:
        initial_pixels: where each dot is in the first frame [px], shape (N, 2) (e.g. from a
            calibration click, a stored layout, or a synthetic camera's projection).
        names: landmark names, length N; ``dot_000``… when omitted.
        blob_options: the blob gates (``color``, ``threshold``, ``min_area``, ``max_area``, ``min_axis_ratio``,
            ``max_diameter``), keywords of :func:`detect_blobs`.
        gate_px: largest distance [px] between a prediction and its detection.
        outlier_px: largest disagreement [px] between a dot's motion and the median motion of its
            ``neighbours`` nearest dots before the match is rejected.
        neighbours: how many neighbours vote in the outlier test.
        velocity_damping: fraction of the last velocity used in the prediction (0 = none).
        area_change: largest factor by which a dot's blob area may change between its running
            average and one frame before the match is dropped (partial occlusion).

    Raises:
        ValueError: bad shapes or non-finite initial pixels.
    """

    def __init__(
        self,
        initial_pixels,
        *,
        names: Sequence[str] | None = None,
        gate_px: float = 15.0,
        outlier_px: float = 8.0,
        neighbours: int = 4,
        velocity_damping: float = 0.5,
        area_change: float = 1.6,
        **blob_options,
    ):
        start = as_finite_array(initial_pixels, "initial_pixels", shape=(None, 2), max_abs=MAX_TRACKING_PX)
        if start.shape[0] == 0:
            raise ValueError("initial_pixels: expected shape (N, 2) with N ≥ 1, got (0, 2)")
        n = start.shape[0]
        default = tuple(f"dot_{i:03d}" for i in range(n))
        self.landmark_names = default if names is None else validate_landmark_names(names, n, "names")
        self.blob_options = _checked_blob_options(**blob_options)
        self.gate_px = as_positive(gate_px, "gate_px", maximum=MAX_TRACKING_PX)
        self.outlier_px = as_positive(outlier_px, "outlier_px", maximum=MAX_TRACKING_PX)
        self.neighbours = as_count(neighbours, "neighbours", minimum=1, maximum=1000)
        self.velocity_damping = as_bounded(velocity_damping, "velocity_damping", 0.0, 1.0)
        self.area_change = as_bounded(area_change, "area_change", 1.0, 1e6)
        self.reset(start)

    def reset(self, pixels) -> None:
        """Restart tracking from known dot positions [px], shape (N, 2)."""
        count = len(self.landmark_names)
        self.position = as_finite_array(pixels, "pixels", shape=(count, 2), max_abs=MAX_TRACKING_PX).copy()
        """Last known position of each dot [px], shape (N, 2)."""
        self.velocity = np.zeros_like(self.position)
        """Last per-frame motion of each dot [px/frame], shape (N, 2)."""
        self.rejected_outliers = 0
        """Matches rejected by the outlier test so far."""
        self.area = np.full(self.position.shape[0], np.nan)
        """Running blob area of each dot [px²] (NaN until first seen)."""

    def detect(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Find the dots in ``image``: pixels (N, 2) with NaN for dots not found, confidence (N,)."""
        image = _image_array(image)
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8 or image.size == 0:
            raise ValueError(f"image must be (H, W, 3) uint8 RGB, got {image.shape} {image.dtype}")
        # Only the neighbourhood of the tracked dots can hold them: crop to it.
        margin = self.gate_px + self.blob_options["max_diameter"] + 2
        predicted = self.position + self.velocity_damping * self.velocity
        h, w = image.shape[:2]
        x0 = int(np.clip(np.floor(predicted[:, 0].min() - margin), 0, w))
        x1 = int(np.clip(np.ceil(predicted[:, 0].max() + margin) + 1, 0, w))
        y0 = int(np.clip(np.floor(predicted[:, 1].min() - margin), 0, h))
        y1 = int(np.clip(np.ceil(predicted[:, 1].max() + margin) + 1, 0, h))
        if x1 - x0 < 3 or y1 - y0 < 3:
            return self.update(np.zeros((0, 2)))
        blobs = _detect_blobs(image[y0:y1, x0:x1], **self.blob_options)  # options checked in __init__
        return self._associate(blobs.centers + [x0, y0], blobs.areas)

    def update(self, detections: np.ndarray, areas: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Associate detected centres (K, 2) with the tracked dots; see :meth:`detect`.

        1. Each dot's own prediction is matched to the detections (minimum total distance, within
           ``gate_px``).
        2. Matches whose motion differs from the median motion of their nearest matched
           neighbours by more than ``outlier_px`` are rejected.
        3. Dots still unmatched are predicted from their neighbours' median motion and matched
           within ``outlier_px`` of that — this re-acquires dots lost in earlier frames or moving
           faster than their own prediction.
        4. With ``areas`` (K,), a match whose blob area changed by more than a factor ``area_change``
           from the dot's running area is dropped: a dot sliding behind an occluding contour is
           truncated, and its centroid no longer marks its centre.
        """
        det = as_finite_array(detections, "detections", max_abs=MAX_TRACKING_PX)
        if det.size % 2:
            raise ValueError(f"detections: expected shape (K, 2), got {det.shape}")
        det = det.reshape(-1, 2)
        if areas is not None:
            areas = as_finite_array(areas, "areas").reshape(-1)
            if areas.shape != (det.shape[0],) or (areas <= 0).any():
                raise ValueError(f"areas: expected {det.shape[0]} positive blob areas, got shape {areas.shape}")
        return self._associate(det, areas)

    def _associate(self, det: np.ndarray, areas: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`update` with checked detections (K, 2) and areas (K,) or None."""
        n = self.position.shape[0]
        match = np.full(n, -1, dtype=np.int64)  # detection index per dot
        if det.shape[0]:
            predicted = self.position + self.velocity_damping * self.velocity
            rows, cols = _assign(predicted, det, self.gate_px)
            match[rows] = cols
            rows = np.flatnonzero(match >= 0)
            if rows.size > self.neighbours:
                motion = det[match[rows]] - self.position[rows]
                expected = self._neighbour_motion(rows, motion, rows)
                outlier = np.linalg.norm(motion - expected, axis=1) > self.outlier_px
                self.rejected_outliers += int(outlier.sum())
                match[rows[outlier]] = -1
            rows = np.flatnonzero(match >= 0)
            lost = np.flatnonzero(match < 0)
            taken = np.zeros(det.shape[0], dtype=bool)
            taken[match[rows]] = True
            free = np.flatnonzero(~taken)
            if lost.size and free.size and rows.size >= min(self.neighbours, 3):
                motion = det[match[rows]] - self.position[rows]
                guess = self.position[lost] + self._neighbour_motion(rows, motion, lost)
                r2, c2 = _assign(guess, det[free], self.outlier_px)
                match[lost[r2]] = free[c2]

        if areas is not None and det.shape[0]:
            area = np.asarray(areas, dtype=np.float64).reshape(-1)
            rows = np.flatnonzero(match >= 0)
            seen = np.isfinite(self.area[rows])
            ratio = area[match[rows]] / np.where(seen, self.area[rows], 1.0)
            shrunk = seen & ((ratio < 1.0 / self.area_change) | (ratio > self.area_change))
            match[rows[shrunk]] = -1
            keep = rows[~shrunk]
            prev = self.area[keep]
            self.area[keep] = np.where(np.isfinite(prev), 0.7 * prev + 0.3 * area[match[keep]], area[match[keep]])

        found = match >= 0
        pixels = np.full((n, 2), np.nan)
        pixels[found] = det[match[found]]
        confidence = found.astype(np.float32)
        self.velocity[found] = pixels[found] - self.position[found]
        self.velocity[~found] = 0.0
        self.position[found] = pixels[found]
        return pixels, confidence

    def _neighbour_motion(self, known: np.ndarray, motion: np.ndarray, query: np.ndarray) -> np.ndarray:
        """Median motion of the ``neighbours`` nearest dots in ``known`` (excluding itself) for each
        dot in ``query``, shape (len(query), 2)."""
        is_known = np.zeros(self.position.shape[0], dtype=bool)
        is_known[known] = True
        k = max(1, min(self.neighbours, known.size - 1 if is_known[query].any() else known.size))
        # All pairwise distances: for ~100 dots cheaper than building and querying a k-d tree.
        dx = self.position[query, 0, None] - self.position[None, known, 0]
        dy = self.position[query, 1, None] - self.position[None, known, 1]
        squared = dx * dx + dy * dy
        squared[query[:, None] == known[None, :]] = np.inf  # not the dot itself
        nearest = np.argpartition(squared, k - 1, axis=1)[:, :k]  # the k nearest, in no order
        # The median over the k neighbours (np.median's definition, without its overhead per call).
        ranked = np.sort(motion[nearest], axis=1)
        return 0.5 * (ranked[:, (k - 1) // 2] + ranked[:, k // 2])


def _assign(predicted: np.ndarray, detections: np.ndarray, gate: float) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-cost one-to-one matching of predictions to detections, pairs within ``gate`` only."""
    from scipy.optimize import linear_sum_assignment

    dx = predicted[:, 0, None] - detections[None, :, 0]
    dy = predicted[:, 1, None] - detections[None, :, 1]
    cost = np.sqrt(dx * dx + dy * dy)  # a fifth of np.linalg.norm's time over the last axis
    rows, cols = linear_sum_assignment(np.where(cost <= gate, cost, 1e6))
    ok = cost[rows, cols] <= gate
    return rows[ok], cols[ok]


class ArucoMarkers:
    """ArUco markers as landmarks: one landmark per expected marker id, at the marker centre.

    Args:
        marker_ids: the ids to report, in landmark order.
        dictionary: name of a predefined ``cv2.aruco`` dictionary (``"DICT_4X4_50"``…).
        names: landmark names; ``aruco_<id>`` when omitted.
        refine: use sub-pixel corner refinement.

    Raises:
        ValueError: unknown dictionary, repeated ids, or ids outside the dictionary.
    """

    def __init__(
        self,
        marker_ids: Sequence[int],
        *,
        dictionary: str = "DICT_4X4_50",
        names: Sequence[str] | None = None,
        refine: bool = True,
    ):
        import cv2

        if isinstance(marker_ids, (str, bytes)) or not hasattr(marker_ids, "__iter__"):
            raise ValueError(f"marker_ids: expected a sequence of integer ids, got {marker_ids!r}")
        ids = [as_count(i, "marker_ids") for i in marker_ids]
        if len(set(ids)) != len(ids):
            raise ValueError(f"marker_ids: repeated id in {ids}")
        if not isinstance(dictionary, str):
            raise TypeError(f"dictionary: expected a cv2.aruco dictionary name, got {type(dictionary).__name__}")
        if not dictionary.startswith("DICT_") or not hasattr(cv2.aruco, dictionary):
            raise ValueError(f"dictionary: cv2.aruco has no {dictionary[:40]!r}")
        self.dictionary_name = dictionary
        self.dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
        size = self.dictionary.bytesList.shape[0]
        bad = [i for i in ids if not 0 <= i < size]
        if bad:
            raise ValueError(f"marker_ids: {bad} outside {dictionary} (0…{size - 1})")
        self.marker_ids = tuple(ids)
        default = tuple(f"aruco_{i}" for i in ids)
        self.landmark_names = default if names is None else validate_landmark_names(names, len(ids), "names")
        params = cv2.aruco.DetectorParameters()
        if refine:
            params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        self._detector = cv2.aruco.ArucoDetector(self.dictionary, params)
        self._row = {marker: k for k, marker in enumerate(ids)}

    def detect_corners(self, image: np.ndarray) -> dict[int, np.ndarray]:
        """Corners [px] of each expected marker found, ``{id: (4, 2)}`` in ArUco's corner order."""
        import cv2

        rgb = _image_array(image)
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8 or rgb.size == 0:
            raise ValueError(f"image must be (H, W, 3) uint8 RGB, got {rgb.shape} {rgb.dtype}")
        corners, ids, _ = self._detector.detectMarkers(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))
        found: dict[int, np.ndarray] = {}
        if ids is None:
            return found
        for quad, marker in zip(corners, ids.reshape(-1)):
            marker = int(marker)
            if marker in self._row and marker not in found:  # first detection wins on duplicates
                found[marker] = np.asarray(quad, dtype=np.float64).reshape(4, 2)
        return found

    def detect(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Marker centres [px], shape (N, 2), NaN where not found; confidence (N,) 1 or 0."""
        pixels = np.full((len(self.marker_ids), 2), np.nan)
        confidence = np.zeros(len(self.marker_ids), dtype=np.float32)
        for marker, quad in self.detect_corners(image).items():
            center = _diagonal_intersection(quad)
            if center is not None:
                pixels[self._row[marker]] = center
                confidence[self._row[marker]] = 1.0
        return pixels, confidence


def _diagonal_intersection(quad: np.ndarray) -> np.ndarray | None:
    """Intersection of the diagonals 0–2 and 1–3 of a quadrilateral (None if parallel)."""
    p, r = quad[0], quad[2] - quad[0]
    q, s = quad[1], quad[3] - quad[1]
    denom = r[0] * s[1] - r[1] * s[0]
    if abs(denom) < 1e-12:
        return None
    t = ((q - p)[0] * s[1] - (q - p)[1] * s[0]) / denom
    return p + t * r
