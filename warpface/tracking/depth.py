"""Robust back-projection of image landmarks with a depth image (pixel convention: :mod:`.intrinsics`).

:func:`backproject` lifts sub-pixel landmarks to 3-D with a robust local fit rather than the
nearest depth pixel: over a small window it ignores holes (0), rejects outliers with median/MAD
gates, and fits a plane in *inverse depth* — exact for a planar patch, since ``1/Z`` is affine in
``(u, v)`` on a plane — evaluated at the landmark's sub-pixel position.
"""

from __future__ import annotations

import threading

import numpy as np
import warp as wp

from .._validate import as_count, as_device, as_finite_array, as_positive
from .intrinsics import KINECT_V1_INTRINSICS, MAX_DEPTH, MAX_PIXELS, CameraIntrinsics

__all__ = [
    "CameraIntrinsics",
    "backproject",
    "kth_smallest",
    "KINECT_V1_INTRINSICS",
    "MAX_PIXELS",
    "MAX_DEPTH",
    "MAX_DEPTH_WINDOW",
]

MAX_DEPTH_WINDOW = 101
"""Largest back-projection window [px] (the fit visits window² pixels per landmark)."""

_vec6f = wp.types.vector(length=6, dtype=wp.float32)
_vec6d = wp.types.vector(length=6, dtype=wp.float64)
_mat66d = wp.types.matrix(shape=(6, 6), dtype=wp.float64)


_vec10d = wp.types.vector(length=10, dtype=wp.float64)
_vec5d = wp.types.vector(length=5, dtype=wp.float64)


@wp.func
def _normal_matrix(low: _vec10d, high: _vec5d) -> _mat66d:
    """The normal matrix Σ t³ m mᵀ of the basis m = (1, x, y, x², xy, y²) from its moments: entry
    (i, j) is the moment of the monomial m_i m_j (x^a y^b, a + b ≤ 4)."""
    return _mat66d(
        low[0],
        low[1],
        low[2],
        low[3],
        low[4],
        low[5],
        low[1],
        low[3],
        low[4],
        low[6],
        low[7],
        low[8],
        low[2],
        low[4],
        low[5],
        low[7],
        low[8],
        low[9],
        low[3],
        low[6],
        low[7],
        high[0],
        high[1],
        high[2],
        low[4],
        low[7],
        low[8],
        high[1],
        high[2],
        high[3],
        low[5],
        low[8],
        low[9],
        high[2],
        high[3],
        high[4],
    )


@wp.func
def _is_depth(z: float) -> bool:
    """A measured depth: not a hole (0), negative, NaN, infinite or beyond :data:`MAX_DEPTH`."""
    return z > 0.0 and z < wp.static(MAX_DEPTH)


@wp.func
def _basis(du: float, dv: float, scale: float) -> _vec6f:
    """Monomials of the local surface model in window-normalised offsets (so the fit is well scaled)."""
    x = du * scale
    y = dv * scale
    return _vec6f(1.0, x, y, x * x, x * y, y * y)


@wp.func
def _model_depth(coef: _vec6f, du: float, dv: float, scale: float) -> float:
    """Depth of the inverse-depth model ``1/Z = Σ coef_k m_k(du, dv)`` (0 where not in front)."""
    w = wp.dot(coef, _basis(du, dv, scale))
    if w <= 0.0:
        return 0.0
    return 1.0 / w


@wp.func
def _solve_spd(A: _mat66d, b: _vec6d, n: int) -> _vec6d:
    """Solve the leading n×n block of a symmetric positive-definite system by Cholesky.

    Returns the zero vector if the block is not (numerically) positive definite.
    """
    L = _mat66d()
    x = _vec6d()
    ok = int(1)
    for j in range(n):
        d = A[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if d <= wp.float64(1.0e-12) * A[j, j] or d <= wp.float64(0.0):
            ok = 0
        else:
            L[j, j] = wp.sqrt(d)
            for i in range(j + 1, n):
                e = A[i, j]
                for k in range(j):
                    e -= L[i, k] * L[j, k]
                L[i, j] = e / L[j, j]
    if ok == 0:
        return _vec6d()
    y = _vec6d()
    for i in range(n):
        e = b[i]
        for k in range(i):
            e -= L[i, k] * y[k]
        y[i] = e / L[i, i]
    for ii in range(n):
        i = n - 1 - ii
        e = y[i]
        for k in range(i + 1, n):
            e -= L[k, i] * x[k]
        x[i] = e / L[i, i]
    return x


@wp.func
def _move_to_front(values: wp.array2d(dtype=float), row: int, lo: int, hi: int, pivot: float, equal: int) -> int:
    """Move the values of ``values[row, lo:hi]`` below ``pivot`` (equal to it with ``equal``) to the
    front of that range; returns the end of that front part. Branch-free (Lomuto with selects): the
    comparisons on noisy depths are unpredictable, and mispredicted branches cost more than the
    two stores per element."""
    i = int(lo)
    for j in range(lo, hi):
        v = values[row, j]
        t = values[row, i]
        front = v < pivot
        if equal != 0:
            front = v == pivot
        values[row, j] = wp.where(front, t, v)
        values[row, i] = wp.where(front, v, t)
        i += wp.where(front, 1, 0)
    return i


@wp.func
def kth_smallest(values: wp.array2d(dtype=float), row: int, n: int, k: int) -> float:
    """The k-th smallest (0-based) of ``values[row, :n]`` by quickselect (middle pivot, three-way
    split so that repeated values — quantised depths — cost no more than distinct ones); reorders
    that row in place. Expected O(n)."""
    lo = int(0)
    hi = int(n)  # the k-th smallest lies in [lo, hi)
    result = float(0.0)
    found = int(0)
    while found == 0 and hi - lo > 1:
        pivot = values[row, (lo + hi) // 2]
        below = _move_to_front(values, row, lo, hi, pivot, 0)
        if k < below:
            hi = below
        else:
            equal = _move_to_front(values, row, below, hi, pivot, 1)
            if k < equal:
                result = pivot
                found = 1
            else:
                lo = equal
    if found == 0:
        result = values[row, lo]
    return result


@wp.struct
class _Window:
    """Pixel rows [r0, r1) × columns [c0, c1) of a depth image."""

    r0: int
    r1: int
    c0: int
    c1: int


@wp.func
def _window_around(uc: int, vc: int, half: int, depth: wp.array2d(dtype=float)) -> _Window:
    """The (2 half + 1)² pixels centred on column ``uc``, row ``vc``, clipped to the image (maybe empty)."""
    window = _Window()
    window.r0 = wp.max(vc - half, 0)
    window.r1 = wp.min(vc + half + 1, depth.shape[0])
    window.c0 = wp.max(uc - half, 0)
    window.c1 = wp.min(uc + half + 1, depth.shape[1])
    return window


@wp.func
def _median_residual(
    depth: wp.array2d(dtype=float),
    window: _Window,
    u: float,
    v: float,
    coef: _vec6f,
    scale: float,
    signed: int,
    scratch: wp.array2d(dtype=float),
    slot: int,
) -> float:
    """Median (the ⌈n/2⌉-th smallest) of the valid pixels' residuals in ``window``:
    Z − model (signed) or |Z − model|; a zero model makes the signed residual the depth
    itself. The residuals are gathered once in row ``slot`` of ``scratch`` and selected there, so
    the model is evaluated once per pixel. The window must hold at least one valid pixel."""
    n = int(0)
    for row in range(window.r0, window.r1):
        for col in range(window.c0, window.c1):
            z = depth[row, col]
            if _is_depth(z):
                r = z - _model_depth(coef, float(col) - u, float(row) - v, scale)
                if signed == 0:
                    r = wp.abs(r)
                scratch[slot, n] = r
                n += 1
    return kth_smallest(scratch, slot, n, (n + 1) // 2 - 1)


@wp.func
def _valid_range(depth: wp.array2d(dtype=float), window: _Window) -> wp.vec3:
    """(count, min, max) of the valid depths in a window."""
    n = float(0.0)
    zmin = float(1.0e30)
    zmax = float(0.0)
    for row in range(window.r0, window.r1):
        for col in range(window.c0, window.c1):
            z = depth[row, col]
            if _is_depth(z):
                n += 1.0
                zmin = wp.min(zmin, z)
                zmax = wp.max(zmax, z)
    return wp.vec3(n, zmin, zmax)


# Planes of the per-landmark scratch rows (row ``_PLANES * landmark + plane``): the window's valid pixels
# gathered once, in row-major order, so the three fits and two medians loop over a compact list and
# compute each pixel's distance weight, inverse depth and model residual once instead of per pass.
_SELECT, _Z, _DU, _DV, _DIST, _WEIGHT, _INV_Z, _RESIDUAL = range(8)
_PLANES = 8


@wp.func
def _gather_window(
    depth: wp.array2d(dtype=float),
    window: _Window,
    u: float,
    v: float,
    reach_px: float,
    scratch: wp.array2d(dtype=float),
    base: int,
) -> int:
    """Store the window's valid pixels (depth, offsets, distance, tricube weight, inverse depth) in
    the planes of rows ``base + plane`` of ``scratch``; returns their count."""
    n = int(0)
    for row in range(window.r0, window.r1):
        for col in range(window.c0, window.c1):
            z = depth[row, col]
            if _is_depth(z):
                du = float(col) - u
                dv = float(row) - v
                dist = wp.sqrt(du * du + dv * dv)
                # Tricube weights (as in LOESS): the centre, where the landmark is, counts most.
                q = wp.min(dist / reach_px, 1.0)
                t = 1.0 - q * q * q
                scratch[base + _Z, n] = z
                scratch[base + _DU, n] = du
                scratch[base + _DV, n] = dv
                scratch[base + _DIST, n] = dist
                scratch[base + _WEIGHT, n] = t * t * t
                scratch[base + _INV_Z, n] = 1.0 / z
                n += 1
    return n


@wp.kernel
def _backproject_kernel(
    depth: wp.array2d(dtype=float),
    pixels: wp.array(dtype=wp.vec2),
    half: int,
    quadric: int,
    min_valid: int,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    outlier_floor: float,
    max_slope: float,
    noise_floor: float,
    iterations: int,
    min_inlier_fraction: float,
    scratch: wp.array2d(dtype=float),
    out_points: wp.array(dtype=wp.vec3),
    out_inliers: wp.array(dtype=wp.int32),
):
    """Robust local inverse-depth surface fit per landmark; see :func:`backproject`."""
    i = wp.tid()
    u = pixels[i][0]
    v = pixels[i][1]
    out_points[i] = wp.vec3(0.0, 0.0, 0.0)
    out_inliers[i] = 0
    if not (wp.isfinite(u) and wp.isfinite(v)):
        return
    uc = int(wp.round(u))
    vc = int(wp.round(v))
    window = _window_around(uc, vc, half, depth)
    if window.c0 >= window.c1 or window.r0 >= window.r1:
        return
    base = i * wp.static(_PLANES)
    select = base + wp.static(_SELECT)
    reach_px = float(half) * 1.4143 + 1.0
    n = _gather_window(depth, window, u, v, reach_px, scratch, base)
    if n < min_valid:
        return
    scale = 1.0 / float(half)
    zero = _vec6f()

    # Seed on the landmark's own surface: the median depth of the innermost ring that has data.
    z_seed = float(0.0)
    found = int(0)
    for ring in range(1, half + 1):
        if found == 0:
            inner = _window_around(uc, vc, ring, depth)
            if int(_valid_range(depth, inner)[0]) >= 3:
                z_seed = _median_residual(depth, inner, u, v, zero, scale, 1, scratch, select)
                found = 1
    if found == 0:
        return

    # First pass: a cone around the seed depth — a surface up to max_slope steep stays inside,
    # an occluding or occluded surface a few millimetres away does not.
    focal = 0.5 * (fx + fy)
    coef = zero
    inliers = int(0)
    gate = float(0.0)
    for it in range(iterations + 1):
        moments_low = _vec10d()  # Σ t³ x^a y^b for a + b ≤ 3: 1, x, y, x², xy, y², x³, x²y, xy², y³
        moments_high = _vec5d()  # a + b = 4: x⁴, x³y, x²y², xy³, y⁴
        rhs = _vec6d()
        count = int(0)
        if it > 0:
            # Re-gate on this fit's residuals: 2.5 σ̂ (σ̂ = 1.4826 MAD), never below the sensor's noise.
            for k in range(n):
                residual = wp.abs(
                    scratch[base + _Z, k] - _model_depth(coef, scratch[base + _DU, k], scratch[base + _DV, k], scale)
                )
                scratch[base + _RESIDUAL, k] = residual
                scratch[select, k] = residual
            mad = kth_smallest(scratch, select, n, (n + 1) // 2 - 1)
            gate = wp.max(2.5 * 1.4826 * mad, 2.5 * noise_floor)
        for k in range(n):
            keep = int(0)
            if it == 0:
                reach = outlier_floor + max_slope * scratch[base + _DIST, k] * z_seed / focal
                if wp.abs(scratch[base + _Z, k] - z_seed) <= reach:
                    keep = 1
            elif scratch[base + _RESIDUAL, k] <= gate:
                keep = 1
            if keep == 1:
                # Normal equations accumulate in float64 (the quadric terms span decades),
                # as the 15 distinct weighted moments x^a y^b (a + b ≤ 4) of the 6×6 matrix.
                wt = wp.float64(scratch[base + _WEIGHT, k])
                x = wp.float64(scratch[base + _DU, k] * scale)
                y = wp.float64(scratch[base + _DV, k] * scale)
                xx = x * x
                xy = x * y
                yy = y * y
                low = wt * _vec10d(wp.float64(1.0), x, y, xx, xy, yy, xx * x, xx * y, x * yy, yy * y)
                moments_low += low
                moments_high += wt * _vec5d(xx * xx, xx * xy, xx * yy, xy * yy, yy * yy)
                rhs += wp.float64(scratch[base + _INV_Z, k]) * _vec6d(low[0], low[1], low[2], low[3], low[4], low[5])
                count += 1
        # The first fit is a plane (robust on little data); later ones the requested model.
        terms = int(3)
        if it > 0 and quadric == 1 and count >= 12:
            terms = int(6)
        if count < min_valid:
            return
        sol = _solve_spd(_normal_matrix(moments_low, moments_high), rhs, terms)
        if sol[0] <= wp.float64(0.0):
            return
        coef = _vec6f(sol)
        inliers = count

    # Two surfaces in the window (an occluding edge) leave many pixels out: the landmark may sit on
    # either, so give up rather than guess.
    if float(inliers) < min_inlier_fraction * float(n):
        return
    z0 = 1.0 / float(coef[0])
    out_points[i] = wp.vec3((u - cx) * z0 / fx, (v - cy) * z0 / fy, z0)
    out_inliers[i] = inliers


_recorded = threading.local()  # per thread: a recorded launch owns its output buffers


def _recorded_launch(device, count: int, window: int, settings: tuple) -> tuple:
    """``(launch, points, inliers, pixel_view, pixel_buffer)``: the back-projection kernel recorded once per device,
    landmark count and settings (packing its 17 arguments anew costs time every frame); the
    depth image and the pixels (parameters 0 and 1) are set per call — on the CPU the pixels through
    ``pixel_view``, a NumPy view (N, 2) of the recorded pixel buffer (None on other devices)."""
    cache = getattr(_recorded, "launches", None)
    if cache is None:
        cache = _recorded.launches = {}
    key = (str(device), count, window, settings)
    if key not in cache:
        if len(cache) >= 8:
            cache.clear()
        points = wp.empty(count, dtype=wp.vec3, device=device)
        inliers = wp.empty(count, dtype=wp.int32, device=device)
        scratch = wp.empty((_PLANES * count, window * window), dtype=float, device=device)  # _PLANES rows per landmark
        placeholder_depth = wp.zeros((1, 1), dtype=float, device=device)
        pixel_buffer = wp.zeros(count, dtype=wp.vec2, device=device)
        launch = wp.launch(
            _backproject_kernel,
            dim=count,
            inputs=[placeholder_depth, pixel_buffer, *settings, scratch],
            outputs=[points, inliers],
            device=device,
            record_cmd=True,
        )
        # On the CPU the pixels are written into this buffer through a NumPy view (no array per call).
        pixel_view = pixel_buffer.numpy().reshape(count, 2) if wp.get_device(device).is_cpu else None
        cache[key] = (launch, points, inliers, pixel_view, pixel_buffer)  # (the buffer: kept alive with its view)
    return cache[key]


def backproject(
    pixels,
    depth,
    intrinsics: CameraIntrinsics,
    *,
    window: int = 9,
    model: str = "quadric",
    min_valid: int = 12,
    outlier_floor: float = 0.003,
    max_slope: float = 3.0,
    noise_floor: float = 0.0005,
    iterations: int = 2,
    min_inlier_fraction: float = 0.7,
    device=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame 3-D positions of sub-pixel landmarks from a depth image.

    Per landmark, over a ``window × window`` neighbourhood (holes, depth 0, skipped):

    1. **Seed** on the landmark's own surface: the median depth of the smallest ring around the
       landmark that holds ≥ 3 valid pixels.
    2. **Cone gate**: keep pixels within ``outlier_floor + max_slope · ρ · Z / f`` of the seed depth
       (ρ = pixel distance from the landmark), i.e. any surface up to ``max_slope`` steep — not an
       occluding or occluded surface, flying pixels or background.
    3. **Fit** the inverse depth ``1/Z`` as a plane in (du, dv) by least squares (exact for a planar
       patch), then ``iterations`` refits — a full quadric with ``model="quadric"``, which removes
       the curvature bias a plane has on a curved face — each on the pixels within
       ``max(2.5 σ̂, 2.5 noise_floor)`` of the previous fit (σ̂ = 1.4826 × median absolute residual).
    4. **Reject** the landmark if the final fit keeps fewer than ``min_inlier_fraction`` of the valid
       pixels (the window straddles an occluding edge; the landmark may lie on either surface).

    The depth is the model evaluated at the landmark's sub-pixel position; X and Y follow from the
    pinhole model. This replaces the nearest depth pixel, whose noise (σ ≈ 1.3 mm at 0.6 m for a
    Kinect) and holes go straight into the landmark.

    Args:
        pixels: landmark positions [px], shape (N, 2), OpenCV convention; NaN rows are skipped.
        depth: depth image [m], shape (H, W) matching ``intrinsics``; 0 marks a hole.
        intrinsics: the depth image's intrinsics (depth registered to the colour camera when the
            landmarks were found in colour).
        window: odd window size [px], 3 … :data:`MAX_DEPTH_WINDOW`.
        model: ``"quadric"`` (default) or ``"plane"``.
        min_valid: fewest inlier pixels for a valid fit.
        outlier_floor: half-width of the first gate at the landmark itself [m].
        max_slope: steepest surface slope (dZ per lateral distance) the first gate admits.
        noise_floor: smallest residual scale [m] assumed for the sensor.
        iterations: number of refits after the first plane.
        min_inlier_fraction: see step 4.
        device: Warp device.

    Returns:
        ``(points, inliers)``: positions [m], shape (N, 3), float64, NaN where there is no valid fit
        (landmark missing, off the image, too few valid depth pixels, or an occluding edge);
        inlier counts, shape (N,), int32, 0 where invalid.

    Raises:
        ValueError: bad shapes, an even or too small window, an unknown model, or a depth image
            whose size does not match ``intrinsics``.
    """
    if not isinstance(intrinsics, CameraIntrinsics):
        raise TypeError(f"intrinsics: expected a CameraIntrinsics, got {type(intrinsics).__name__}")
    try:
        uv = np.array(pixels, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("pixels: expected an (N, 2) array of numbers") from None
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise ValueError(f"pixels: expected shape (N, 2), got {uv.shape}")
    uv[~np.all(np.isfinite(uv), axis=1)] = np.nan  # an infinite pixel is as missing as a NaN one
    uv[np.any(np.abs(uv) > MAX_PIXELS, axis=1)] = np.nan  # far off any image
    try:
        with np.errstate(over="ignore"):  # beyond float32's range becomes inf: a hole, like NaN, 0 and < 0
            z = np.ascontiguousarray(depth, dtype=np.float32)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"depth: cannot convert to a numeric image ({exc})") from None
    if z.ndim != 2:
        raise ValueError(f"depth: expected a 2-D image, got shape {z.shape}")
    if z.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(
            f"depth: image is {z.shape[1]}×{z.shape[0]} but intrinsics are {intrinsics.width}×{intrinsics.height}"
        )
    window = as_count(window, "window", minimum=3, maximum=MAX_DEPTH_WINDOW)
    if window % 2 == 0:
        raise ValueError(f"window: must be an odd integer ≥ 3, got {window}")
    if model not in ("plane", "quadric"):
        raise ValueError(f"model: 'plane' or 'quadric', got {model!r}")
    min_valid = as_count(min_valid, "min_valid", minimum=6)
    iterations = as_count(iterations, "iterations", minimum=0, maximum=100)
    outlier_floor = as_positive(outlier_floor, "outlier_floor", allow_zero=True)
    max_slope = as_positive(max_slope, "max_slope", allow_zero=True)
    noise_floor = as_positive(noise_floor, "noise_floor", allow_zero=True)
    min_inlier_fraction = float(as_finite_array(min_inlier_fraction, "min_inlier_fraction", shape=()))
    if not 0.0 <= min_inlier_fraction <= 1.0:
        raise ValueError(f"min_inlier_fraction: must be in [0, 1], got {min_inlier_fraction}")
    count = uv.shape[0]
    if count == 0:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int32)
    device = as_device(device)
    settings = (
        window // 2,
        1 if model == "quadric" else 0,
        int(min_valid),
        float(intrinsics.fx),
        float(intrinsics.fy),
        float(intrinsics.cx),
        float(intrinsics.cy),
        float(outlier_floor),
        float(max_slope),
        float(noise_floor),
        int(max(iterations, 1)),
        float(min_inlier_fraction),
    )
    launch, points, inliers, pixel_view, _ = _recorded_launch(device, count, window, settings)
    if device.is_cpu:
        # The caller's image, no copy; its wrapper is kept while the same buffer comes back (a live camera's
        # frame buffer), so that buffer cannot be freed and its address reused by another image meanwhile.
        key = (z.ctypes.data, z.shape)
        if getattr(_recorded, "image_key", None) != key:
            _recorded.image = wp.array(z, dtype=float, device=device, copy=False)
            _recorded.image_key = key
        launch.set_param_at_index(0, _recorded.image)
        pixel_view[:] = uv  # into the recorded launch's own pixel buffer (parameter 1)
        launch.launch()
    else:
        image = wp.array(z, dtype=float, device=device)
        landmarks = wp.array(uv.astype(np.float32), dtype=wp.vec2, device=device)
        launch.set_param_at_index(0, image)
        launch.set_param_at_index(1, landmarks)
        launch.launch()  # (the inputs stay referenced until the results are read back below)
    out = points.numpy().astype(np.float64)
    n_in = inliers.numpy()
    invalid = (n_in == 0) | ~np.all(np.isfinite(out), axis=1)
    out[invalid] = np.nan
    n_in = np.where(invalid, 0, n_in).astype(np.int32)
    return out, n_in
