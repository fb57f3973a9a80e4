"""Pinhole camera intrinsics.

Pixel convention: **OpenCV's** throughout warpface. Pixel ``(col, row)`` has its centre at the
continuous image coordinate ``(u, v) = (col, row)``; a camera-frame point ``(X, Y, Z)`` (x right,
y down, z forward, metres) projects to ``u = fx X / Z + cx``, ``v = fy Y / Z + cy``. RealSense and
Orbbec SDKs report intrinsics in this convention, and ArUco corners and image moments use it.

OpenGL — and so pyrender — puts pixel ``col`` at window coordinate ``[col, col + 1)``, centre
``col + 0.5``, and its ``IntrinsicsCamera`` maps a point to window coordinate ``fx X / Z + cx``.
Rendering with OpenCV intrinsics therefore needs ``cx + 0.5`` and ``cy + 0.5`` on the pyrender side
(:meth:`CameraIntrinsics.to_pyrender`); forgetting it shifts every landmark by half a pixel
(≈ 0.6 mm at 0.6 m for a 525 px focal length). pyrender's depth is linear Z, 0 where nothing was hit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_finite_array

__all__ = ["CameraIntrinsics", "KINECT_V1_INTRINSICS", "MAX_PIXELS", "MAX_DEPTH"]

MAX_PIXELS = 65536
"""Largest accepted image width or height [px]."""

MAX_DEPTH = 1.0e4
"""Depths at or beyond this [m] are holes (no depth sensor measures them; they would overflow the fit)."""


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
            value = as_finite_array(getattr(self, name), f"intrinsics: {name}", shape=(), max_abs=MAX_PIXELS * 1e3)
            object.__setattr__(self, name, float(value))
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"intrinsics: focal lengths must be > 0, got fx={self.fx}, fy={self.fy}")
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, (bool, np.bool_)):
                raise TypeError(f"intrinsics: {name} must be a positive integer, got {type(value).__name__}")
            number = float(as_finite_array(value, f"intrinsics: {name}", shape=()))
            if number != int(number) or not 1 <= number <= MAX_PIXELS:
                raise ValueError(
                    f"intrinsics: {name} must be a whole number of pixels in [1, {MAX_PIXELS}], got {value!r}"
                )
            object.__setattr__(self, name, int(number))

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
            return cls(*(data[key] for key in ("fx", "fy", "cx", "cy", "width", "height")))
        except (TypeError, ValueError, OverflowError) as exc:
            raise ValueError(f"{where}: {str(exc).removeprefix('intrinsics: ')}") from None

    def project(self, points) -> np.ndarray:
        """Pixel coordinates of camera-frame points [m], shape (N, 3) → (N, 2), float64."""
        p = as_finite_array(points, "points", max_abs=MAX_DEPTH)
        if p.size % 3 or (p.ndim and p.shape[-1] != 3):
            raise ValueError(f"points: expected shape (N, 3), got {p.shape}")
        p = p.reshape(-1, 3)
        behind = np.flatnonzero(p[:, 2] <= 0.0)
        if len(behind):
            raise ValueError(
                f"points: point {int(behind[0])} is not in front of the camera (z = {p[behind[0], 2]:.6g} m)"
            )
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.stack([self.fx * p[:, 0] / p[:, 2] + self.cx, self.fy * p[:, 1] / p[:, 2] + self.cy], axis=1)

    def unproject(self, pixels, depth) -> np.ndarray:
        """Camera-frame points [m] of pixels (N, 2) at depths Z (N,) [m], shape (N, 3), float64."""
        uv = as_finite_array(pixels, "pixels", max_abs=1e7)
        z = as_finite_array(depth, "depth", max_abs=MAX_DEPTH).reshape(-1)
        if uv.size % 2 or (uv.ndim and uv.shape[-1] != 2) or uv.size // 2 != z.size:
            raise ValueError(f"pixels, depth: expected shapes (N, 2) and (N,), got {uv.shape} and {np.shape(depth)}")
        uv = uv.reshape(-1, 2)
        return np.stack([(uv[:, 0] - self.cx) * z / self.fx, (uv[:, 1] - self.cy) * z / self.fy, z], axis=1)

    def to_pyrender(self) -> tuple[float, float, float, float]:
        """``(fx, fy, cx, cy)`` for ``pyrender.IntrinsicsCamera``: principal point shifted by +½ px."""
        return self.fx, self.fy, self.cx + 0.5, self.cy + 0.5


KINECT_V1_INTRINSICS = CameraIntrinsics(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480)
"""A Kinect-v1-like 640×480 camera (the thesis's sensor): 525 px focal length, centred."""
