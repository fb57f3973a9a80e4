"""Subcutaneous thickness (SPEC §1.5): per-vertex ``h`` from a grayscale map, or given directly."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._validate import MAX_COORDINATE, MAX_VERTICES, as_bounded, as_count, as_finite_array, as_per_vertex, as_points
from .wrinkles import CylindricalProjection, PlanarProjection, Projection, project_points

__all__ = ["ThicknessMap", "validate_thickness", "MAX_BLUR_SIGMA"]


def validate_thickness(thickness, vertex_count: int) -> np.ndarray:
    """Per-vertex thickness [mesh units] as float64 (V,): a scalar is broadcast.

    Raises ValueError naming ``thickness`` for a wrong shape, non-finite or negative values, or values
    above :data:`~warpface._validate.MAX_COORDINATE` (1e6 mesh units; they would overflow float32).
    """
    vertex_count = as_count(vertex_count, "vertex_count", maximum=MAX_VERTICES)
    return as_per_vertex(thickness, vertex_count, "thickness", minimum=0.0, maximum=MAX_COORDINATE)


MAX_BLUR_SIGMA = 256.0
"""Largest accepted :attr:`ThicknessMap.blur_sigma` [pixels]: the blur's cost grows with its kernel
width (≈ 6σ), and beyond a few hundred pixels it is a constant image in all but name."""
REMAP_WIDTH = 4096
"""Lookups per row of the coordinate maps handed to ``cv2.remap``, whose maps must be under 32,767 on each side: a
mesh's points are laid out as rows of this many (a single row would fail from 32,767 vertices on)."""


@dataclass(frozen=True, eq=False)
class ThicknessMap:
    """A grayscale thickness image laid over a projection of the face.

    The image covers the (u, v) rectangle ``u_range × v_range`` [mesh units] of ``projection``:
    column 0 is ``u_range[0]``, row 0 is ``v_range[1]`` (images are stored top row first, and v
    points up). Pixel centres sit at half-integer positions. Luminance maps linearly from
    ``black`` (0) to ``white`` (255, or 1.0 for float images) in mesh units.

    Args:
        image: (H, W) grayscale array (uint8, uint16 or float in [0, 1]) or a path to an image file.
        projection: the projection whose (u, v) the image is drawn in.
        u_range, v_range: (min, max) extent of the image in (u, v) [mesh units].
        black, white: thickness at luminance 0 and full scale [mesh units], both ≥ 0.
        blur_sigma: Gaussian blur standard deviation [pixels] applied before sampling (0 = none).
    """

    image: np.ndarray
    projection: Projection
    u_range: tuple[float, float]
    v_range: tuple[float, float]
    black: float = 0.0
    white: float = 20.0
    blur_sigma: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "image", _load_gray(self.image))
        for name in ("u_range", "v_range"):
            lo, hi = as_finite_array(getattr(self, name), f"thickness map: {name}", shape=(2,))
            if not hi > lo:
                raise ValueError(f"thickness map: {name} must be increasing, got ({lo}, {hi})")
            object.__setattr__(self, name, (float(lo), float(hi)))
        if not isinstance(self.projection, (PlanarProjection, CylindricalProjection)):
            raise TypeError(
                "thickness map: projection must be PlanarProjection or CylindricalProjection, "
                f"got {type(self.projection).__name__}"
            )
        for name, upper in (("black", MAX_COORDINATE), ("white", MAX_COORDINATE), ("blur_sigma", MAX_BLUR_SIGMA)):
            value = float(as_finite_array(getattr(self, name), f"thickness map: {name}", shape=()))
            if value < 0.0:
                raise ValueError(f"thickness map: {name} must be ≥ 0, got {value}")
            object.__setattr__(self, name, as_bounded(value, f"thickness map: {name}", 0.0, upper))

    def luminance(self) -> np.ndarray:
        """The (optionally blurred) image as float32 luminance in [0, 1], shape (H, W)."""
        image = self.image
        if self.blur_sigma > 0.0:
            import cv2

            image = cv2.GaussianBlur(image, ksize=(0, 0), sigmaX=self.blur_sigma, borderType=cv2.BORDER_REPLICATE)
        return image

    def sample(self, points: np.ndarray, *, device=None) -> np.ndarray:
        """Thickness at each point [mesh units]: (V, 3) → (V,) float64, bilinear, edges clamped.

        Raises ValueError naming ``points`` unless they are finite, shape (V, 3), within ±1e6.
        """
        import cv2

        points = as_points(points, "thickness map: points")
        if len(points) == 0:
            return np.zeros(0, dtype=np.float64)
        uv = project_points(self.projection, points, device=device)
        height, width = self.image.shape
        (u0, u1), (v0, v1) = self.u_range, self.v_range
        column = (uv[:, 0] - u0) / (u1 - u0) * width - 0.5
        row = (v1 - uv[:, 1]) / (v1 - v0) * height - 0.5
        sampled = cv2.remap(
            self.luminance(),
            _as_block(column),
            _as_block(row),
            interpolation=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REPLICATE,
        ).ravel()[: len(points)]
        return self.black + (self.white - self.black) * sampled.astype(np.float64)


def _as_block(values: np.ndarray) -> np.ndarray:
    """(N,) → float32 (⌈N / width⌉, width) with ``width = min(N, REMAP_WIDTH)``, the tail padded with zeros."""
    width = min(len(values), REMAP_WIDTH)
    block = np.zeros(-(-len(values) // width) * width, dtype=np.float32)
    block[: len(values)] = values
    return block.reshape(-1, width)


def _load_gray(image) -> np.ndarray:
    """Any supported image input as float32 luminance in [0, 1], shape (H, W)."""
    if isinstance(image, (str, Path)):
        import cv2

        loaded = cv2.imread(str(image), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH)
        if loaded is None:
            raise ValueError(f"thickness map: cannot read image {image}")
        image = loaded
    array = np.asarray(image)
    if array.ndim == 3 and array.shape[2] in (3, 4):
        array = array[..., :3].mean(axis=2).astype(array.dtype)
    if array.ndim != 2 or array.shape[0] < 1 or array.shape[1] < 1:
        raise ValueError(f"thickness map: image must be (H, W) grayscale, got shape {array.shape}")
    if array.dtype == np.uint8:
        return array.astype(np.float32) / 255.0
    if array.dtype == np.uint16:
        return array.astype(np.float32) / 65535.0
    array = as_finite_array(array, "thickness map: image")
    if array.min() < 0.0 or array.max() > 1.0:
        raise ValueError("thickness map: float images must lie in [0, 1]")
    return array.astype(np.float32)
