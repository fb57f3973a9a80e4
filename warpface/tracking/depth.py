"""Pinhole intrinsics and robust back-projection of image landmarks with a depth image.

Pixel convention: **OpenCV's** throughout warpface. Pixel ``(col, row)`` has its centre at the
continuous image coordinate ``(u, v) = (col, row)``; a camera-frame point ``(X, Y, Z)`` (x right,
y down, z forward, metres) projects to ``u = fx X / Z + cx``, ``v = fy Y / Z + cy``. RealSense and
Orbbec SDKs report intrinsics in this convention, and ArUco corners and image moments use it.

OpenGL — and so pyrender — puts pixel ``col`` at window coordinate ``[col, col + 1)``, centre
``col + 0.5``, and its ``IntrinsicsCamera`` maps a point to window coordinate ``fx X / Z + cx``.
Rendering with OpenCV intrinsics therefore needs ``cx + 0.5`` and ``cy + 0.5`` on the pyrender side
(:meth:`CameraIntrinsics.to_pyrender`); forgetting it shifts every landmark by half a pixel
(≈ 0.6 mm at 0.6 m for a 525 px focal length). pyrender's depth is linear Z, 0 where nothing was hit.

:func:`backproject` lifts sub-pixel landmarks to 3-D with a robust local fit rather than the
nearest depth pixel: over a small window it ignores holes (0), rejects outliers with median/MAD
gates, and fits a plane in *inverse depth* — exact for a planar patch, since ``1/Z`` is affine in
``(u, v)`` on a plane — evaluated at the landmark's sub-pixel position.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

__all__ = ["CameraIntrinsics", "backproject", "KINECT_V1_INTRINSICS"]


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics in OpenCV's pixel convention (pixel centres at integer coordinates)."""

    fx: float
    """Focal length along x [px]."""
    fy: float
    """Focal length along y [px]."""
    cx: float
    """Principal point x [px], OpenCV convention."""
    cy: float
    """Principal point y [px], OpenCV convention."""
    width: int
    """Image width [px]."""
    height: int
    """Image height [px]."""

    def __post_init__(self):
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if not np.isfinite(value):
                raise ValueError(f"intrinsics: {name} must be finite, got {value}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"intrinsics: focal lengths must be > 0, got fx={self.fx}, fy={self.fy}")
        if int(self.width) != self.width or int(self.height) != self.height or self.width <= 0 or self.height <= 0:
            raise ValueError(f"intrinsics: width/height must be positive integers, got {self.width}×{self.height}")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @property
    def matrix(self) -> np.ndarray:
        """The 3×3 camera matrix K, float64."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def to_dict(self) -> dict:
        """JSON-ready dict with keys fx, fy, cx, cy, width, height."""
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy, "width": self.width, "height": self.height}

    @classmethod
    def from_dict(cls, data: dict, *, where: str = "intrinsics") -> "CameraIntrinsics":
        """Build from a dict with keys fx, fy, cx, cy, width, height; ValueError naming a missing key."""
        if not isinstance(data, dict):
            raise ValueError(f"{where}: expected an object with fx, fy, cx, cy, width, height")
        missing = [k for k in ("fx", "fy", "cx", "cy", "width", "height") if k not in data]
        if missing:
            raise ValueError(f"{where}: missing {', '.join(missing)}")
        try:
            return cls(float(data["fx"]), float(data["fy"]), float(data["cx"]), float(data["cy"]),
                       int(data["width"]), int(data["height"]))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{where}: {exc}") from None

    def project(self, points) -> np.ndarray:
        """Pixel coordinates of camera-frame points [m], shape (N, 3) → (N, 2), float64."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.stack([self.fx * p[:, 0] / p[:, 2] + self.cx, self.fy * p[:, 1] / p[:, 2] + self.cy], axis=1)

    def unproject(self, pixels, depth) -> np.ndarray:
        """Camera-frame points [m] of pixels (N, 2) at depths Z (N,) [m], shape (N, 3), float64."""
        uv = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        z = np.asarray(depth, dtype=np.float64).reshape(-1)
        return np.stack([(uv[:, 0] - self.cx) * z / self.fx, (uv[:, 1] - self.cy) * z / self.fy, z], axis=1)

    def to_pyrender(self) -> tuple[float, float, float, float]:
        """``(fx, fy, cx, cy)`` for ``pyrender.IntrinsicsCamera``: principal point shifted by +½ px."""
        return self.fx, self.fy, self.cx + 0.5, self.cy + 0.5


KINECT_V1_INTRINSICS = CameraIntrinsics(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480)
"""A Kinect-v1-like 640×480 camera (the thesis's sensor): 525 px focal length, centred."""


@wp.func
def _plane_depth(a: float, b: float, c: float, du: float, dv: float) -> float:
    """Depth of the inverse-depth plane ``1/Z = a + b du + c dv`` (0 where it is not in front)."""
    w = a + b * du + c * dv
    if w <= 0.0:
        return 0.0
    return 1.0 / w


@wp.func
def _count_residual_le(
    depth: wp.array2d(dtype=float),
    r0: int, r1: int, c0: int, c1: int,
    u: float, v: float, a: float, b: float, c: float,
    signed: int, threshold: float,
) -> int:
    """Count valid window pixels with residual ≤ threshold (signed: Z − plane; else |Z − plane|)."""
    count = int(0)
    for row in range(r0, r1):
        for col in range(c0, c1):
            z = depth[row, col]
            if z > 0.0:
                r = z - _plane_depth(a, b, c, float(col) - u, float(row) - v)
                if signed == 0:
                    r = wp.abs(r)
                if r <= threshold:
                    count += 1
    return count


@wp.func
def _median_residual(
    depth: wp.array2d(dtype=float),
    r0: int, r1: int, c0: int, c1: int,
    u: float, v: float, a: float, b: float, c: float,
    signed: int, lo: float, hi: float, n: int,
) -> float:
    """Median of the (signed or absolute) residuals of the n valid pixels, by bisection on [lo, hi]."""
    half = (n + 1) // 2
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if _count_residual_le(depth, r0, r1, c0, c1, u, v, a, b, c, signed, mid) >= half:
            hi = mid
        else:
            lo = mid
    return hi


@wp.kernel
def _backproject_kernel(
    depth: wp.array2d(dtype=float),
    pixels: wp.array(dtype=wp.vec2),
    half: int,
    min_valid: int,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    outlier_floor: float,
    noise_floor: float,
    iterations: int,
    out_points: wp.array(dtype=wp.vec3),
    out_inliers: wp.array(dtype=wp.int32),
):
    """Robust inverse-depth plane fit over a (2·half+1)² window per landmark; see :func:`backproject`."""
    i = wp.tid()
    u = pixels[i][0]
    v = pixels[i][1]
    out_points[i] = wp.vec3(0.0, 0.0, 0.0)
    out_inliers[i] = 0
    if not (wp.isfinite(u) and wp.isfinite(v)):
        return
    height = depth.shape[0]
    width = depth.shape[1]
    uc = int(wp.round(u))
    vc = int(wp.round(v))
    c0 = wp.max(uc - half, 0)
    c1 = wp.min(uc + half + 1, width)
    r0 = wp.max(vc - half, 0)
    r1 = wp.min(vc + half + 1, height)
    if c0 >= c1 or r0 >= r1:
        return

    n = int(0)
    zmin = float(1.0e30)
    zmax = float(0.0)
    for row in range(r0, r1):
        for col in range(c0, c1):
            z = depth[row, col]
            if z > 0.0:
                n += 1
                zmin = wp.min(zmin, z)
                zmax = wp.max(zmax, z)
    if n < min_valid:
        return

    # Robust start: a fronto-parallel plane at the median depth, gate = 3 σ̂ (σ̂ = 1.4826 MAD).
    a = float(0.0)
    b = float(0.0)
    c = float(0.0)
    z_med = _median_residual(depth, r0, r1, c0, c1, u, v, a, b, c, 1, zmin, zmax, n)
    a = 1.0 / z_med
    mad = _median_residual(depth, r0, r1, c0, c1, u, v, a, b, c, 0, 0.0, zmax - zmin, n)
    gate = wp.max(3.0 * 1.4826 * mad, outlier_floor)

    inliers = int(0)
    for _it in range(iterations):
        A = wp.mat33(0.0)
        rhs = wp.vec3(0.0)
        count = int(0)
        for row in range(r0, r1):
            for col in range(c0, c1):
                z = depth[row, col]
                if z > 0.0:
                    du = float(col) - u
                    dv = float(row) - v
                    if wp.abs(z - _plane_depth(a, b, c, du, dv)) <= gate:
                        x = wp.vec3(1.0, du, dv)
                        A += wp.outer(x, x)
                        rhs += x * (1.0 / z)
                        count += 1
        if count < min_valid or wp.determinant(A) <= 1.0e-6 * float(count) * float(count) * float(count):
            return
        sol = wp.inverse(A) * rhs
        if sol[0] <= 0.0:
            return
        a = sol[0]
        b = sol[1]
        c = sol[2]
        inliers = count
        # Re-gate on the residuals of this fit: 2.5 σ̂, never tighter than the sensor's noise floor.
        lim = float(0.0)
        for row in range(r0, r1):
            for col in range(c0, c1):
                z = depth[row, col]
                if z > 0.0:
                    lim = wp.max(lim, wp.abs(z - _plane_depth(a, b, c, float(col) - u, float(row) - v)))
        mad_r = _median_residual(depth, r0, r1, c0, c1, u, v, a, b, c, 0, 0.0, lim, n)
        gate = wp.max(2.5 * 1.4826 * mad_r, 2.5 * noise_floor)

    z0 = 1.0 / a
    out_points[i] = wp.vec3((u - cx) * z0 / fx, (v - cy) * z0 / fy, z0)
    out_inliers[i] = inliers


def backproject(
    pixels,
    depth,
    intrinsics: CameraIntrinsics,
    *,
    window: int = 9,
    min_valid: int = 12,
    outlier_floor: float = 0.004,
    noise_floor: float = 0.0005,
    iterations: int = 3,
    device=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame 3-D positions of sub-pixel landmarks from a depth image.

    Per landmark, a ``window × window`` neighbourhood is examined: holes (depth 0) are skipped,
    pixels further than ``max(3 σ̂, outlier_floor)`` from the median depth are rejected (σ̂ from the
    median absolute deviation), and a plane ``1/Z = a + b du + c dv`` is fitted by least squares and
    re-fitted ``iterations`` times on pixels within ``max(2.5 σ̂_r, 2.5 noise_floor)`` of it. The
    depth is the plane evaluated at the landmark; X and Y follow from the pinhole model.

    Args:
        pixels: landmark positions [px], shape (N, 2), OpenCV convention; NaN rows are skipped.
        depth: depth image [m], shape (H, W) matching ``intrinsics``; 0 marks a hole.
        intrinsics: the depth image's intrinsics (depth registered to the colour camera when the
            landmarks were found in colour).
        window: odd window size [px], ≥ 3.
        min_valid: fewest inlier pixels for a valid fit.
        outlier_floor: smallest first-pass gate [m] (flying pixels and background beyond it go).
        noise_floor: smallest residual scale [m] assumed for the sensor.
        iterations: number of reweighted fits.
        device: Warp device.

    Returns:
        ``(points, inliers)``: positions [m], shape (N, 3), float64, NaN where no valid fit
        (landmark missing, off-image, or too few valid depth pixels); inlier counts, shape (N,), int32.

    Raises:
        ValueError: bad shapes, even/too small window, or a depth image whose size does not match
            ``intrinsics``.
    """
    uv = np.asarray(pixels, dtype=np.float64)
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise ValueError(f"pixels: expected shape (N, 2), got {uv.shape}")
    z = np.asarray(depth)
    if z.ndim != 2:
        raise ValueError(f"depth: expected a 2-D image, got shape {z.shape}")
    if z.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(
            f"depth: image is {z.shape[1]}×{z.shape[0]} but intrinsics are {intrinsics.width}×{intrinsics.height}"
        )
    if window < 3 or window % 2 == 0:
        raise ValueError(f"window: must be an odd integer ≥ 3, got {window}")
    if min_valid < 3:
        raise ValueError(f"min_valid: must be ≥ 3 for a plane fit, got {min_valid}")
    count = uv.shape[0]
    if count == 0:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int32)
    z32 = np.where(np.isfinite(z) & (z > 0), z, 0).astype(np.float32)
    device = wp.get_device(device)
    points = wp.empty(count, dtype=wp.vec3, device=device)
    inliers = wp.empty(count, dtype=wp.int32, device=device)
    wp.launch(
        _backproject_kernel,
        dim=count,
        inputs=[
            wp.array(z32, dtype=float, device=device),
            wp.array(uv.astype(np.float32), dtype=wp.vec2, device=device),
            window // 2,
            int(min_valid),
            float(intrinsics.fx),
            float(intrinsics.fy),
            float(intrinsics.cx),
            float(intrinsics.cy),
            float(outlier_floor),
            float(noise_floor),
            int(max(iterations, 1)),
        ],
        outputs=[points, inliers],
        device=device,
    )
    out = points.numpy().astype(np.float64)
    n_in = inliers.numpy()
    out[n_in == 0] = np.nan
    return out, n_in
