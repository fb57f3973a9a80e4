"""A synthetic RGB-D camera with exact ground truth: render a (deforming) painted mesh with pyrender.

:class:`SyntheticRGBDCamera` takes plain ``(points per frame, triangles)`` in a model frame (+y up,
+z toward the viewer, metres), paints fiducials (dark dots and/or ArUco markers) into a texture at
known surface points, renders colour and linear depth at the requested intrinsics (640×480 Kinect
v1-like by default) and optionally corrupts the depth like a Kinect (:class:`KinectNoise`). Because
fiducials are fixed in the surface's texture, they move with the mesh, and their exact 3-D
positions follow from their barycentric coordinates in every frame
(:meth:`SyntheticRGBDCamera.landmark_positions`).

Texture coordinates are a front (x, y) projection of the first frame, isotropically scaled, so a
dot painted round in texture space is round on the face as seen from the camera.

Rendering needs ``pyrender`` and an offscreen OpenGL: ``PYOPENGL_PLATFORM`` defaults to
``osmesa`` here when unset. The OpenCV/pyrender half-pixel offset is handled by
:meth:`~warpface.tracking.intrinsics.CameraIntrinsics.to_pyrender`.

Also here: :func:`procedural_face` and :func:`procedural_jaw_open` (a face-like test surface that
needs no data), and :func:`place_fiducials` (well-spaced, camera-facing surface points).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np
import warp as wp

from .._validate import (
    as_bounded,
    as_count,
    as_device,
    as_finite_array,
    as_points,
    as_positive,
    as_vec3,
    expect_instance,
)
from ..mesh import FaceMesh
from .frames import RGBDFrame, SourceBase
from .intrinsics import KINECT_V1_INTRINSICS, CameraIntrinsics

__all__ = [
    "KinectNoise",
    "default_model_to_camera",
    "SyntheticRGBDCamera",
    "procedural_face",
    "procedural_jaw_open",
    "place_fiducials",
]


# --------------------------------------------------------------------------------------------
# Depth noise
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class KinectNoise:
    """Kinect-v1-like depth corruption.

    Axial noise ``σ(Z) = sigma0 + sigma2 (Z − z_ref)²`` (Nguyen, Izadi & Lovell 2012, fitted on
    a Kinect v1: 1.2 mm + 1.9 mm·(Z − 0.4 m)²/m²), then disparity quantisation: the sensor
    measures disparity ``d = b f / Z`` in steps of ``disparity_step`` pixels, so depth steps grow
    as ``Z² · step / (b f)`` (≈ 1 mm at 0.6 m). A fraction ``dropout`` of pixels is lost (0).
    """

    sigma0: float = 0.0012
    """Axial noise at ``z_ref`` [m]."""
    sigma2: float = 0.0019
    """Growth of the axial noise [1/m]: σ += sigma2 · (Z − z_ref)²."""
    z_ref: float = 0.4
    """Reference distance of the noise model [m]."""
    baseline_focal: float = 0.075 * 580.0
    """Projector–camera baseline × IR focal length [m·px]."""
    disparity_step: float = 1.0 / 8.0
    """Disparity resolution [px] (Kinect v1: 1/8 px)."""
    dropout: float = 0.0
    """Fraction of valid pixels randomly set to 0 (holes)."""

    def __post_init__(self) -> None:
        for field in ("sigma0", "sigma2", "z_ref"):
            object.__setattr__(
                self, field, as_positive(getattr(self, field), f"KinectNoise: {field}", allow_zero=True, maximum=1e3)
            )
        for field in ("baseline_focal", "disparity_step"):
            object.__setattr__(self, field, as_positive(getattr(self, field), f"KinectNoise: {field}", maximum=1e6))
        object.__setattr__(self, "dropout", as_bounded(self.dropout, "KinectNoise: dropout", 0.0, 1.0))

    def apply(self, depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Corrupted copy of a depth image [m] (0 = no surface), float64."""
        expect_instance(rng, np.random.Generator, "rng")
        z = np.asarray(depth, dtype=np.float64)
        valid = z > 0
        sigma = self.sigma0 + self.sigma2 * (z - self.z_ref) ** 2
        noisy = np.where(valid, z + rng.standard_normal(z.shape) * sigma, 0.0)
        noisy = np.where(noisy > 0, noisy, 0.0)
        if self.disparity_step > 0:
            disparity = self.baseline_focal / np.where(noisy > 0, noisy, np.inf)
            steps = np.round(disparity / self.disparity_step)
            noisy = np.where(steps > 0, self.baseline_focal / np.maximum(steps, 1) / self.disparity_step, 0.0)
            noisy = np.where(valid, noisy, 0.0)
        if self.dropout > 0:
            noisy = np.where(rng.random(z.shape) < self.dropout, 0.0, noisy)
        return noisy


# --------------------------------------------------------------------------------------------
# Mesh helpers
# --------------------------------------------------------------------------------------------


def procedural_face(
    resolution: int = 64, *, width: float = 0.16, height: float = 0.21
) -> tuple[np.ndarray, np.ndarray]:
    """A face-like open surface needing no data: a rounded dome with a nose and brow ridge.

    Returns ``(points (R², 3) [m], triangles (2 (R−1)², 3) int32)`` in the model frame (+y up,
    +z toward the viewer), centred on x = y = 0, triangles oriented toward +z.
    """
    resolution = as_count(resolution, "resolution", minimum=3, maximum=4096)
    width = as_positive(width, "width")
    height = as_positive(height, "height")
    xs = np.linspace(-0.5 * width, 0.5 * width, resolution)
    ys = np.linspace(-0.5 * height, 0.5 * height, resolution)
    x, y = np.meshgrid(xs, ys)
    r2 = (x / (0.62 * width)) ** 2 + (y / (0.62 * height)) ** 2
    z = 0.055 * (1.0 - r2)  # dome
    z += 0.022 * np.exp(-((x / 0.011) ** 2 + ((y + 0.005) / 0.03) ** 2))  # nose
    z += 0.006 * np.exp(-(((y - 0.035) / 0.012) ** 2)) * np.exp(-(((np.abs(x) - 0.03) / 0.025) ** 2))  # brows
    points = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(resolution - 1), np.arange(resolution - 1))
    v00 = (j * resolution + i).reshape(-1)
    v10, v01, v11 = v00 + 1, v00 + resolution, v00 + resolution + 1
    triangles = np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)]).astype(np.int32)
    return points, triangles


def procedural_jaw_open(points: np.ndarray, amount: float) -> np.ndarray:
    """Open the jaw of :func:`procedural_face` by ``amount`` [m]: the lower face moves down and
    back, blending smoothly in over the mouth region. Returns a new (V, 3) array."""
    p = as_points(points, "points").copy()
    amount = float(as_finite_array(amount, "amount", shape=(), max_abs=1.0))
    t = np.clip((-0.02 - p[:, 1]) / 0.05, 0.0, 1.0)
    s = t * t * (3.0 - 2.0 * t)
    p[:, 1] -= amount * s
    p[:, 2] -= 0.35 * amount * s
    return p


@wp.func
def _blocked(mesh: wp.uint64, point: wp.vec3, normal: wp.vec3, eye: wp.vec3, offset: float):
    """1 where the segment from the surface point (lifted by ``offset`` along its normal) to the eye hits the mesh."""
    start = point + offset * normal
    to_eye = eye - start
    length = wp.length(to_eye)
    hit = wp.mesh_query_ray(mesh, start, to_eye / length, length)
    return wp.where(hit.result, 1, 0)


def _occluded(
    points: np.ndarray, triangles: np.ndarray, normals: np.ndarray, eye: np.ndarray, *, device=None
) -> np.ndarray:
    """Vertices whose line of sight to ``eye`` is blocked by the mesh itself, shape (V,), bool."""
    center = points.mean(axis=0)
    device = as_device(device)
    pts = wp.array((points - center).astype(np.float32), dtype=wp.vec3, device=device)
    mesh = wp.Mesh(points=pts, indices=wp.array(np.asarray(triangles, dtype=np.int32).reshape(-1), device=device))
    lifted_by = 1e-4 * float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    eye_point = wp.vec3(*(np.asarray(eye, dtype=np.float64) - center))
    wp_normals = wp.array(normals.astype(np.float32), dtype=wp.vec3, device=device)
    blocked = wp.map(_blocked, wp.uint64(mesh.id), pts, wp_normals, eye_point, lifted_by, device=device)
    return blocked.numpy().astype(bool)


def default_model_to_camera(rest_points: np.ndarray, distance: float = 0.6) -> np.ndarray:
    """Model → camera (OpenCV) transform, 4×4: the face looks into the camera, centred in x and y,
    its front-most point ``distance`` [m] away."""
    p = as_points(rest_points, "rest_points", min_count=1)
    distance = as_positive(distance, "distance")
    lo, hi = p.min(axis=0), p.max(axis=0)
    center = 0.5 * (lo + hi)
    return np.array(
        [
            [1.0, 0.0, 0.0, -center[0]],
            [0.0, -1.0, 0.0, center[1]],
            [0.0, 0.0, -1.0, distance + hi[2]],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def place_fiducials(
    points: np.ndarray,
    triangles: np.ndarray,
    count: int,
    *,
    spacing: float = 0.015,
    min_facing: float = 0.6,
    boundary_margin: float = 0.01,
    camera_position=None,
    device=None,
) -> np.ndarray:
    """Well-spaced fiducial vertices that the camera sees (farthest-point sampling).

    Candidates face the camera (unit normal · unit direction to the camera ≥ ``min_facing``), lie at
    least ``boundary_margin`` [m] from the mesh boundary (holes for eyes and mouth included) and,
    when ``camera_position`` is given, are not hidden behind another part of the mesh. Returns up
    to ``count`` vertex indices (int64), at least ``spacing`` [m] apart.

    Args:
        points, triangles: the mesh [m], model frame.
        camera_position: the camera centre in the model frame [m]; default: far along +z
            (an orthographic view from the front, no occlusion test).
        device: Warp device for the occlusion ray casts.

    Raises:
        ValueError: no vertex qualifies.
    """
    p = as_points(points, "fiducial surface: points")
    surface = FaceMesh(p, triangles, name="fiducial surface", degenerate="ignore")
    count = as_count(count, "count", minimum=1, maximum=len(p))
    spacing = as_positive(spacing, "spacing", allow_zero=True)
    min_facing = as_bounded(min_facing, "min_facing", -1.0, 1.0)
    boundary_margin = as_positive(boundary_margin, "boundary_margin", allow_zero=True)
    if camera_position is not None:
        camera_position = as_vec3(camera_position, "camera_position")
    normals = surface.vertex_normals(device=device).astype(np.float64)
    if camera_position is None:
        view = np.broadcast_to(np.array([0.0, 0.0, 1.0]), p.shape)
    else:
        view = np.asarray(camera_position, dtype=np.float64) - p
        view = view / np.linalg.norm(view, axis=1, keepdims=True)
    ok = np.sum(normals * view, axis=1) >= min_facing
    border = np.zeros(len(p), dtype=bool)
    border[surface.boundary_vertices] = True
    if border.any():
        bpts = p[border]
        for start in range(0, p.shape[0], 2048):
            chunk = p[start : start + 2048]
            d = np.sqrt(((chunk[:, None, :] - bpts[None, :, :]) ** 2).sum(-1)).min(axis=1)
            ok[start : start + 2048] &= d >= boundary_margin
    if camera_position is not None:
        ok &= ~_occluded(p, triangles, normals, np.asarray(camera_position, dtype=np.float64), device=device)
    candidates = np.flatnonzero(ok)
    if candidates.size == 0:
        raise ValueError("place_fiducials: no vertex faces the camera away from the boundary")
    cand = p[candidates]
    center = cand.mean(axis=0)
    chosen = [int(np.argmin(np.linalg.norm(cand - center, axis=1)))]
    dist = np.linalg.norm(cand - cand[chosen[0]], axis=1)
    while len(chosen) < count:
        nxt = int(np.argmax(dist))
        if dist[nxt] < spacing:
            break
        chosen.append(nxt)
        dist = np.minimum(dist, np.linalg.norm(cand - cand[nxt], axis=1))
    return candidates[np.array(chosen)]


# --------------------------------------------------------------------------------------------
# The camera
# --------------------------------------------------------------------------------------------


def _import_pyrender():
    os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    try:
        import pyrender
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("SyntheticRGBDCamera needs pyrender (and an offscreen OpenGL such as OSMesa)") from exc
    return pyrender


class SyntheticRGBDCamera(SourceBase):
    """Render a deforming, fiducial-painted mesh to colour + depth with exact ground truth.

    Args:
        points: mesh points per frame [m], shape (F, V, 3) — or (V, 3) for one static frame —
            in the model frame (+y up, +z toward the viewer).
        triangles: shape (T, 3), integer, oriented toward +z.
        fiducials: where the fiducials are: vertex indices, shape (K,), or ``(triangle (K,),
            barycentric (K, 3))``.
        style: ``"dot"`` or ``"aruco"`` for all fiducials, or one per fiducial.
        names: landmark names, length K (``fid_000``… when omitted).
        intrinsics: the camera (OpenCV convention); Kinect v1-like 640×480 by default.
        distance: distance [m] from the camera to the mesh's front-most point (first frame).
        model_to_camera: 4×4 rigid transform from the model frame to the camera frame (OpenCV:
            x right, y down, z forward); overrides ``distance`` (default: the face looks at the
            camera, centred, front at ``distance``).
        fps: frame rate [1/s] of the timestamps ``i / fps``.
        depth_noise: a :class:`KinectNoise`, or ``None`` for exact depth.
        depth_scale: metres per unit of the uint16 depth output (1e-4: 0.1 mm, 6.5 m range).
        seed: noise seed (frames are reproducible).
        dot_radius: dot radius [m]; aruco_size: marker side [m] including its black border.
        aruco_dictionary: ``cv2.aruco`` dictionary; aruco_ids: marker id per ArUco fiducial
            (0, 1, 2… in fiducial order when omitted).
        skin_rgb, dot_rgb: colours (0–255).
        texture_size: texture resolution [texels] along its longer side.
        lighting: ``"lit"`` (a light at the camera plus ambient) or ``"flat"`` (unlit albedo).

    Raises:
        ValueError: bad shapes, fiducials out of range, unknown style.
    """

    def __init__(
        self,
        points,
        triangles,
        fiducials,
        *,
        style: str | Sequence[str] = "dot",
        names: Sequence[str] | None = None,
        intrinsics: CameraIntrinsics = KINECT_V1_INTRINSICS,
        distance: float = 0.6,
        model_to_camera: np.ndarray | None = None,
        fps: float = 30.0,
        depth_noise: KinectNoise | None = None,
        depth_scale: float = 1e-4,
        seed: int = 0,
        dot_radius: float = 0.003,
        aruco_size: float = 0.02,
        aruco_dictionary: str = "DICT_4X4_50",
        aruco_ids: Sequence[int] | None = None,
        skin_rgb=(222, 170, 140),
        dot_rgb=(25, 25, 25),
        texture_size: int = 2048,
        lighting: str = "lit",
    ):
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim == 2:
            pts = pts[None]
        if pts.ndim != 3 or pts.shape[2] != 3 or pts.shape[0] == 0:
            raise ValueError(f"points: expected shape (F, V, 3) or (V, 3), got {np.shape(points)}")
        if not np.all(np.isfinite(pts)):
            raise ValueError("points: non-finite coordinates")
        tri = np.asarray(triangles)
        if tri.ndim != 2 or tri.shape[1] != 3 or tri.min() < 0 or tri.max() >= pts.shape[1]:
            raise ValueError(f"triangles: expected (T, 3) indices into {pts.shape[1]} points")
        self.points = pts
        """Mesh points per frame [m], shape (F, V, 3), model frame."""
        self.triangles = tri.astype(np.int32)
        self.fiducial_triangle, self.fiducial_barycentric = self._resolve_fiducials(fiducials)
        k = self.fiducial_triangle.shape[0]
        styles = [style] * k if isinstance(style, str) else list(style)
        if len(styles) != k or any(s not in ("dot", "aruco") for s in styles):
            raise ValueError(f"style: 'dot', 'aruco', or one of those per fiducial ({k}), got {style!r}")
        self.styles = tuple(styles)
        self.landmark_names = tuple(names) if names is not None else tuple(f"fid_{i:03d}" for i in range(k))
        if len(self.landmark_names) != k:
            raise ValueError(f"names: {len(self.landmark_names)} names for {k} fiducials")
        n_aruco = sum(s == "aruco" for s in styles)
        self.aruco_ids = tuple(int(i) for i in aruco_ids) if aruco_ids is not None else tuple(range(n_aruco))
        if len(self.aruco_ids) != n_aruco:
            raise ValueError(f"aruco_ids: {len(self.aruco_ids)} ids for {n_aruco} ArUco fiducials")
        self.aruco_dictionary = aruco_dictionary
        self.intrinsics = intrinsics
        self.fps = float(fps)
        self.depth_noise = depth_noise
        self.depth_scale = float(depth_scale)
        self.seed = int(seed)
        self.dot_radius = float(dot_radius)
        self.aruco_size = float(aruco_size)
        self.skin_rgb = tuple(int(c) for c in skin_rgb)
        self.dot_rgb = tuple(int(c) for c in dot_rgb)
        if lighting not in ("lit", "flat"):
            raise ValueError(f"lighting must be 'lit' or 'flat', got {lighting!r}")
        self.lighting = lighting

        rest = pts[0]
        if model_to_camera is None:
            model_to_camera = default_model_to_camera(rest, distance)
        self.model_to_camera = np.asarray(model_to_camera, dtype=np.float64).reshape(4, 4)
        """Model → camera (OpenCV) rigid transform, 4×4."""
        inverse = np.linalg.inv(self.model_to_camera)
        self.camera_position = inverse[:3, 3].copy()
        """The camera centre in the model frame [m], shape (3,)."""

        # Texture coordinates: isotropic front projection of the first frame.
        lo, hi = rest[:, :2].min(axis=0), rest[:, :2].max(axis=0)
        extent = float(max(hi - lo)) * 1.02
        self._uv_origin, self._uv_extent = lo - 0.01 * extent, extent
        self.texcoords = ((rest[:, :2] - self._uv_origin) / extent).astype(np.float32)
        """Per-vertex texture coordinates, shape (V, 2), float32."""
        size = int(texture_size)
        self.texture = self._paint_texture(size)
        """The painted albedo texture, shape (S, S, 3), uint8 (row 0 = top = high v)."""
        self._renderer = None
        self._topology = None  # a FaceMesh of the topology: its Warp kernel gives the render normals
        self._scene = None
        self._mesh_node = None
        self._material = None

    # -- setup ---------------------------------------------------------------------------------

    def _resolve_fiducials(self, fiducials) -> tuple[np.ndarray, np.ndarray]:
        if isinstance(fiducials, tuple) and len(fiducials) == 2:
            tri = np.asarray(fiducials[0], dtype=np.int64).reshape(-1)
            bary = np.asarray(fiducials[1], dtype=np.float64).reshape(-1, 3)
            if bary.shape[0] != tri.shape[0]:
                raise ValueError(f"fiducials: {tri.shape[0]} triangles but {bary.shape[0]} barycentric rows")
            if tri.size and (tri.min() < 0 or tri.max() >= self.triangles.shape[0]):
                raise ValueError("fiducials: triangle index out of range")
            if not np.all(np.isfinite(bary)) or (bary < -1e-9).any() or np.abs(bary.sum(1) - 1).max(initial=0) > 1e-6:
                raise ValueError("fiducials: barycentric rows must be ≥ 0 and sum to 1")
            return tri, bary
        verts = np.asarray(fiducials, dtype=np.int64).reshape(-1)
        if verts.size == 0:
            raise ValueError("fiducials: none given")
        if verts.min() < 0 or verts.max() >= self.points.shape[1]:
            raise ValueError(f"fiducials: vertex index out of range [0, {self.points.shape[1]})")
        # An incident triangle per vertex, with the one-hot barycentric of that corner.
        tri = np.full(verts.shape[0], -1, dtype=np.int64)
        bary = np.zeros((verts.shape[0], 3))
        for corner in range(3):
            owner = np.full(self.points.shape[1], -1, dtype=np.int64)
            owner[self.triangles[::-1, corner]] = np.arange(self.triangles.shape[0])[::-1]
            hit = (tri < 0) & (owner[verts] >= 0)
            tri[hit] = owner[verts[hit]]
            bary[hit, corner] = 1.0
        if (tri < 0).any():
            raise ValueError(f"fiducials: vertex {int(verts[tri < 0][0])} belongs to no triangle")
        return tri, bary

    def _fiducial_uv(self) -> np.ndarray:
        corners = self.texcoords[self.triangles[self.fiducial_triangle]].astype(np.float64)  # (K, 3, 2)
        return np.einsum("kj,kjd->kd", self.fiducial_barycentric, corners)

    def _paint_texture(self, size: int) -> np.ndarray:
        image = np.empty((size, size, 3), dtype=np.float32)
        image[:] = self.skin_rgb
        uv = self._fiducial_uv()
        # Texel (col, row) centre sits at u = (col + ½)/S, v = 1 − (row + ½)/S (pyrender flips rows).
        centers = np.stack([uv[:, 0] * size - 0.5, (1.0 - uv[:, 1]) * size - 0.5], axis=1)
        per_metre = size / self._uv_extent
        dot = np.asarray(self.dot_rgb, dtype=np.float32)
        aruco_iter = iter(self.aruco_ids)
        for (cx, cy), style in zip(centers, self.styles):
            if style == "dot":
                r = self.dot_radius * per_metre
                x0, x1 = int(max(cx - r - 2, 0)), int(min(cx + r + 3, size))
                y0, y1 = int(max(cy - r - 2, 0)), int(min(cy + r + 3, size))
                xx, yy = np.meshgrid(np.arange(x0, x1), np.arange(y0, y1))
                cover = np.clip(r - np.hypot(xx - cx, yy - cy) + 0.5, 0.0, 1.0)[..., None]
                patch = image[y0:y1, x0:x1]
                image[y0:y1, x0:x1] = patch * (1.0 - cover) + dot * cover
            else:
                self._paint_marker(image, cx, cy, next(aruco_iter), self.aruco_size * per_metre)
        return np.clip(np.round(image), 0, 255).astype(np.uint8)

    def _paint_marker(self, image: np.ndarray, cx: float, cy: float, marker_id: int, side: float) -> None:
        import cv2

        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.aruco_dictionary))
        cells = dictionary.markerSize + 2
        bits = cv2.aruco.generateImageMarker(dictionary, marker_id, cells, borderBits=1)  # one pixel per cell
        size = image.shape[0]
        quiet = side * (cells + 2) / cells  # white margin of one cell all round
        x0, x1 = int(max(round(cx - 0.5 * quiet), 0)), int(min(round(cx + 0.5 * quiet), size))
        y0, y1 = int(max(round(cy - 0.5 * quiet), 0)), int(min(round(cy + 0.5 * quiet), size))
        image[y0:y1, x0:x1] = 255.0
        xx, yy = np.meshgrid(np.arange(x0, x1), np.arange(y0, y1))
        # Cell of each texel centre, relative to the marker's top-left corner.
        col = np.floor((xx - (cx - 0.5 * side)) / side * cells).astype(int)
        row = np.floor((yy - (cy - 0.5 * side)) / side * cells).astype(int)
        inside = (col >= 0) & (col < cells) & (row >= 0) & (row < cells)
        values = np.where(inside, bits[np.clip(row, 0, cells - 1), np.clip(col, 0, cells - 1)], 255)
        image[y0:y1, x0:x1] = values[..., None].astype(np.float32)

    # -- ground truth --------------------------------------------------------------------------

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def camera_points(self, index: int) -> np.ndarray:
        """Mesh points of frame ``index`` in the camera frame [m], shape (V, 3)."""
        p = self.points[index]
        return p @ self.model_to_camera[:3, :3].T + self.model_to_camera[:3, 3]

    def landmark_positions(self, index: int) -> np.ndarray:
        """Exact fiducial centres of frame ``index`` in the camera frame [m], shape (K, 3)."""
        corners = self.camera_points(index)[self.triangles[self.fiducial_triangle]]  # (K, 3, 3)
        return np.einsum("kj,kjd->kd", self.fiducial_barycentric, corners)

    def landmark_pixels(self, index: int) -> np.ndarray:
        """Projections of the exact fiducial centres [px], shape (K, 2), OpenCV convention."""
        return self.intrinsics.project(self.landmark_positions(index))

    def aruco_detector(self, **kwargs):
        """An :class:`~warpface.tracking.detect.ArucoMarkers` for this camera's ArUco fiducials,
        with landmark order = the ArUco fiducials in fiducial order."""
        from .detect import ArucoMarkers

        names = [n for n, s in zip(self.landmark_names, self.styles) if s == "aruco"]
        return ArucoMarkers(self.aruco_ids, dictionary=self.aruco_dictionary, names=names, **kwargs)

    def dot_tracker(self, **kwargs):
        """A :class:`~warpface.tracking.detect.DotTracker` started at frame 0's exact dot pixels."""
        from .detect import DotTracker

        dots = np.array([s == "dot" for s in self.styles])
        names = [n for n, d in zip(self.landmark_names, dots) if d]
        return DotTracker(self.landmark_pixels(0)[dots], names=names, **kwargs)

    # -- rendering -----------------------------------------------------------------------------

    def _setup(self):
        pyrender = _import_pyrender()
        intr = self.intrinsics
        fx, fy, cx, cy = intr.to_pyrender()
        ambient = 0.35 if self.lighting == "lit" else 1.0
        self._scene = pyrender.Scene(bg_color=[0.0, 0.0, 0.0, 1.0], ambient_light=[ambient] * 3)
        self._scene.add(pyrender.IntrinsicsCamera(fx=fx, fy=fy, cx=cx, cy=cy, znear=0.05, zfar=10.0), pose=np.eye(4))
        if self.lighting == "lit":
            self._scene.add(pyrender.DirectionalLight(color=np.ones(3), intensity=2.5), pose=np.eye(4))
        sampler = pyrender.Sampler(magFilter=9729, minFilter=9987)  # GL_LINEAR, GL_LINEAR_MIPMAP_LINEAR
        texture = pyrender.Texture(source=self.texture, source_channels="RGB", sampler=sampler)
        self._material = pyrender.MetallicRoughnessMaterial(
            baseColorTexture=texture, metallicFactor=0.0, roughnessFactor=1.0, doubleSided=False
        )
        self._renderer = pyrender.OffscreenRenderer(intr.width, intr.height)

    def render(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Exact colour (H, W, 3) uint8 RGB and depth (H, W) float32 [m] of frame ``index``."""
        pyrender = _import_pyrender()
        if self._renderer is None:
            self._setup()
        cam = self.camera_points(index)
        to_gl = np.array([1.0, -1.0, -1.0])  # OpenCV camera axes → OpenGL camera axes
        positions = (cam * to_gl).astype(np.float32)
        if self._topology is None:
            self._topology = FaceMesh(cam, self.triangles, name="synthetic camera mesh", degenerate="ignore")
        normals = self._topology.vertex_normals(cam, device="cpu") * to_gl.astype(np.float32)
        primitive = pyrender.Primitive(
            positions=positions,
            normals=normals,
            texcoord_0=self.texcoords,
            indices=self.triangles,
            material=self._material,
        )
        if self._mesh_node is not None:
            self._scene.remove_node(self._mesh_node)
        self._mesh_node = self._scene.add(pyrender.Mesh([primitive]))
        flags = pyrender.RenderFlags.FLAT if self.lighting == "flat" else pyrender.RenderFlags.NONE
        color, depth = self._renderer.render(self._scene, flags=flags)
        return np.ascontiguousarray(color[..., :3]), np.asarray(depth, dtype=np.float32)

    def frame(self, index: int) -> RGBDFrame:
        """Frame ``index`` as an :class:`RGBDFrame`, with depth noise (seeded by ``seed`` and index)."""
        color, depth = self.render(index)
        if self.depth_noise is not None:
            depth = self.depth_noise.apply(depth, np.random.default_rng([self.seed, index]))
        raw = np.round(np.asarray(depth, dtype=np.float64) / self.depth_scale)
        raw = np.clip(raw, 0, np.iinfo(np.uint16).max).astype(np.uint16)
        return RGBDFrame(index / self.fps, color, raw, self.depth_scale, index)

    def frames(self) -> Iterator[RGBDFrame]:
        """All frames in order."""
        for i in range(len(self)):
            yield self.frame(i)

    def fiducial_layout(self) -> dict:
        """JSON-ready description of the fiducials (names, styles, frame-0 pixels) for
        :meth:`RGBDFolder.write <warpface.tracking.sources.RGBDFolder.write>`."""
        return {
            "names": list(self.landmark_names),
            "styles": list(self.styles),
            "aruco_ids": list(self.aruco_ids),
            "aruco_dictionary": self.aruco_dictionary,
            "initial_pixels": self.landmark_pixels(0).tolist(),
        }

    def close(self) -> None:
        """Release the OpenGL context. Safe to call twice."""
        if self._renderer is not None:
            self._renderer.delete()
            self._renderer = None
            self._scene = None
            self._mesh_node = None
