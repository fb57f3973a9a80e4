"""Offscreen previews with pyrender: shaded images, side-by-side comparisons, heat maps and videos.

Rendering is offscreen, through EGL (a GPU driver or Mesa's ``libegl1``) or OSMesa, chosen by
:func:`warpface.offscreen.choose_platform` unless ``PYOPENGL_PLATFORM`` is already set. pyrender,
OpenGL, OpenCV and matplotlib are imported only when a preview is made.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from ._validate import (
    MAX_COORDINATE,
    as_bounded,
    as_count,
    as_finite_array,
    as_path,
    as_points,
    as_positive,
    as_vec3,
    shape_of,
)

__all__ = [
    "Camera",
    "PreviewRenderer",
    "render",
    "render_comparison",
    "render_heat_map",
    "heat_colors",
    "write_video",
    "save_image",
    "check_offscreen_rendering",
    "scale_label",
]

SKIN_COLOR = (0.86, 0.68, 0.58)


@dataclass(frozen=True)
class Camera:
    """A perspective camera looking at ``target`` from ``eye`` with +Y up.

    Attributes:
        eye, target: positions [mesh units], shape (3,).
        yfov_deg: vertical field of view [degrees].
    """

    eye: np.ndarray
    target: np.ndarray
    yfov_deg: float = 30.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "eye", as_vec3(self.eye, "camera eye"))
        object.__setattr__(self, "target", as_vec3(self.target, "camera target"))
        if not np.linalg.norm(self.eye - self.target) >= 1e-9:
            raise ValueError("camera: eye and target coincide (closer than 1e-9)")
        object.__setattr__(self, "yfov_deg", as_bounded(self.yfov_deg, "camera yfov_deg", 0.1, 179.0))

    @classmethod
    def framing(
        cls,
        points: np.ndarray,
        *,
        yaw_deg: float = 0.0,
        pitch_deg: float = 0.0,
        margin: float = 1.15,
        yfov_deg: float = 30.0,
        aspect: float = 4 / 3,
    ) -> "Camera":
        """A camera that fits the bounding box of ``points`` (V, 3), looking along −Z (rotated by yaw/pitch)."""
        points = as_points(points, "points", min_count=1)
        yaw_deg, pitch_deg = (
            as_bounded(a, n, -3600.0, 3600.0) for a, n in ((yaw_deg, "yaw_deg"), (pitch_deg, "pitch_deg"))
        )
        margin, aspect = as_bounded(margin, "margin", 1e-3, 1e3), as_bounded(aspect, "aspect", 1e-3, 1e3)
        yfov_deg = as_bounded(yfov_deg, "yfov_deg", 0.1, 179.0)
        lo, hi = points.min(axis=0), points.max(axis=0)
        centre = 0.5 * (lo + hi)
        half = 0.5 * (hi - lo)
        fov = np.radians(yfov_deg)
        distance = margin * max(half[1] / np.tan(fov / 2), half[0] / (np.tan(fov / 2) * aspect)) + half[2]
        yaw, pitch = np.radians(yaw_deg), np.radians(pitch_deg)
        direction = np.array([np.sin(yaw) * np.cos(pitch), np.sin(pitch), np.cos(yaw) * np.cos(pitch)])
        eye = centre + distance * direction
        if not np.all(np.abs(eye) <= MAX_COORDINATE):
            raise ValueError(
                f"camera framing: the points need a camera {distance:.3g} units away, beyond ±{MAX_COORDINATE:g} "
                "(check points, margin, yfov_deg and aspect)"
            )
        return cls(eye=eye, target=centre, yfov_deg=yfov_deg)

    @classmethod
    def for_face(cls, landmark_points: np.ndarray, *, yaw_deg: float = 0.0, pitch_deg: float = 0.0) -> "Camera":
        """A portrait camera from 68 landmark positions (L, 3): aimed a little above their centre (the
        landmarks stop at the brows) and far enough to frame forehead to chin, 22° field of view."""
        landmark_points = as_points(landmark_points, "landmark_points", min_count=2)
        yaw_deg, pitch_deg = (
            as_bounded(a, n, -3600.0, 3600.0) for a, n in ((yaw_deg, "yaw_deg"), (pitch_deg, "pitch_deg"))
        )
        lo, hi = landmark_points.min(axis=0), landmark_points.max(axis=0)
        height = float(hi[1] - lo[1])
        target = 0.5 * (lo + hi) + np.array([0.0, 0.25 * height, 0.0])
        yaw, pitch = np.radians(yaw_deg), np.radians(pitch_deg)
        direction = np.array([np.sin(yaw) * np.cos(pitch), np.sin(pitch), np.cos(yaw) * np.cos(pitch)])
        return cls(eye=target + 4.6 * height * direction, target=target, yfov_deg=22.0)

    def pose(self) -> np.ndarray:
        """Camera-to-world 4×4 matrix (OpenGL convention: the camera looks down its −Z)."""
        forward = self.target - self.eye
        forward = forward / np.linalg.norm(forward)
        right = np.cross(forward, [0.0, 1.0, 0.0])
        if np.linalg.norm(right) < 1e-9:
            right = np.array([1.0, 0.0, 0.0])
        right = right / np.linalg.norm(right)
        up = np.cross(right, forward)
        pose = np.eye(4)
        pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, up, -forward, self.eye
        return pose


def check_offscreen_rendering() -> str:
    """Choose the offscreen OpenGL back end (see :mod:`warpface.offscreen`) and return its name.

    Raises:
        warpface.offscreen.OffscreenUnavailable: no back end works; the message names what to install.
    """
    from .offscreen import choose_platform

    return choose_platform()


class PreviewRenderer:
    """A reusable offscreen renderer for one triangle topology (for videos and many frames).

    Args:
        triangles: (T, 3) vertex indices.
        size: (width, height) in pixels.
        camera: fixed camera; when omitted, framed on the first rendered points.
        background: RGB in [0, 1].
        interior: RGB in [0, 1] of the surface's back side (seen through eye and mouth openings of an
            open face surface); ``None`` shades both sides alike. Needs consistently wound triangles.
    """

    def __init__(
        self,
        triangles: np.ndarray,
        size: tuple[int, int] = (640, 480),
        camera: Camera | None = None,
        background=(1.0, 1.0, 1.0),
        interior=None,
    ):
        size = _image_size(size)
        platform = check_offscreen_rendering()
        from .offscreen import INSTALL_HINT, OffscreenUnavailable

        try:
            import pyrender

            self._renderer = pyrender.OffscreenRenderer(viewport_width=size[0], viewport_height=size[1])
        except Exception as exc:  # noqa: BLE001 — ImportError, OpenGL errors: all mean "no working GL here"
            raise OffscreenUnavailable(
                f"cannot start offscreen rendering with PYOPENGL_PLATFORM={platform} "
                f"({type(exc).__name__}: {' '.join(str(exc).split())[:200]}); {INSTALL_HINT}"
            ) from None
        self._pyrender = pyrender
        self.triangles = np.asarray(triangles, dtype=np.uint32)
        self.size = size
        self.camera = camera
        self.background = background
        self.interior = interior
        self._topology = None  # a FaceMesh built on the first frame: its Warp kernel gives the normals

    def render(self, points: np.ndarray, colors: np.ndarray | None = None) -> np.ndarray:
        """Shade ``points`` (V, 3) with per-vertex ``colors`` (V, 3) in [0, 1] or skin; returns (H, W, 3) uint8."""
        pyrender = self._pyrender
        points = np.asarray(points, dtype=np.float64)
        if not np.all(np.isfinite(points)):
            raise ValueError("preview: points contain non-finite values")
        if self.camera is None:
            self.camera = Camera.framing(points, aspect=self.size[0] / self.size[1])
        if self._topology is None:
            from .mesh import FaceMesh

            self._topology = FaceMesh(points, self.triangles.astype(np.int64), name="preview", degenerate="ignore")
        normals = self._topology.vertex_normals(points, device="cpu")
        if colors is None:
            colors = np.broadcast_to(np.asarray(SKIN_COLOR), points.shape)
        rgba = np.c_[np.asarray(colors, dtype=np.float32), np.ones(len(points), dtype=np.float32)]
        material = pyrender.MetallicRoughnessMaterial(
            baseColorFactor=(1.0, 1.0, 1.0, 1.0),
            metallicFactor=0.0,
            roughnessFactor=0.65,
            doubleSided=self.interior is None,
        )
        primitives = [
            pyrender.Primitive(
                positions=points.astype(np.float32),
                normals=normals.astype(np.float32),
                indices=self.triangles,
                color_0=rgba,
                material=material,
            )
        ]
        if self.interior is not None:  # the back side: the same triangles wound the other way, unlit flat colour
            inside = pyrender.MetallicRoughnessMaterial(
                baseColorFactor=(*self.interior, 1.0), metallicFactor=0.0, roughnessFactor=1.0, doubleSided=False
            )
            primitives.append(
                pyrender.Primitive(
                    positions=points.astype(np.float32),
                    normals=-normals.astype(np.float32),
                    indices=self.triangles[:, ::-1].copy(),
                    material=inside,
                )
            )
        scene = pyrender.Scene(bg_color=(*self.background, 1.0), ambient_light=(0.1, 0.1, 0.1))
        scene.add(pyrender.Mesh(primitives))
        pose = self.camera.pose()
        scene.add(
            pyrender.PerspectiveCamera(yfov=np.radians(self.camera.yfov_deg), aspectRatio=self.size[0] / self.size[1]),
            pose=pose,
        )
        scene.add(
            pyrender.DirectionalLight(color=np.ones(3), intensity=2.6), pose=_rotated(pose, yaw_deg=-35, pitch_deg=30)
        )
        scene.add(
            pyrender.DirectionalLight(color=np.ones(3), intensity=0.7), pose=_rotated(pose, yaw_deg=40, pitch_deg=-5)
        )
        color, _ = self._renderer.render(scene)
        return np.ascontiguousarray(color[..., :3])

    def close(self) -> None:
        self._renderer.delete()

    def __enter__(self) -> "PreviewRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _rotated(pose: np.ndarray, *, yaw_deg: float, pitch_deg: float) -> np.ndarray:
    """``pose`` rotated about its own up (yaw) and right (pitch) axes: a light placed off the view axis."""
    yaw, pitch = np.radians(yaw_deg), np.radians(pitch_deg)
    ry = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
    rx = np.array([[1, 0, 0], [0, np.cos(pitch), -np.sin(pitch)], [0, np.sin(pitch), np.cos(pitch)]])
    out = pose.copy()
    out[:3, :3] = pose[:3, :3] @ ry @ rx
    return out


def render(
    points: np.ndarray,
    triangles: np.ndarray,
    path: str | Path | None = None,
    *,
    colors=None,
    camera: Camera | None = None,
    size=(640, 480),
    label: str | None = None,
    background=(1.0, 1.0, 1.0),
    interior=None,
) -> np.ndarray:
    """Render one shaded image of a mesh; writes a PNG when ``path`` is given. Returns (H, W, 3) uint8 RGB.
    ``interior``: colour of the back side (see :class:`PreviewRenderer`)."""
    with PreviewRenderer(triangles, size=size, camera=camera, background=background, interior=interior) as renderer:
        image = renderer.render(points, colors)
    return _finish(image, label, path)


def render_comparison(
    views: Sequence[tuple[str, np.ndarray]],
    triangles: np.ndarray,
    path: str | Path | None = None,
    *,
    camera: Camera | None = None,
    size=(480, 480),
    colors: Sequence | None = None,
    background=(1.0, 1.0, 1.0),
    interior=None,
) -> np.ndarray:
    """Labelled views side by side, all with one camera (framed on the first). Returns the joined image."""
    if camera is None:
        camera = Camera.framing(np.asarray(views[0][1]), aspect=size[0] / size[1])
    images = []
    with PreviewRenderer(triangles, size=size, camera=camera, background=background, interior=interior) as renderer:
        for index, (title, points) in enumerate(views):
            images.append(_label(renderer.render(points, None if colors is None else colors[index]), title))
    joined = np.concatenate(images, axis=1)
    if path is not None:
        save_image(path, joined)
    return joined


def heat_colors(
    values: np.ndarray, *, vmin: float | None = None, vmax: float | None = None, cmap: str = "inferno"
) -> np.ndarray:
    """Map scalar values (V,) to RGB colours (V, 3) in [0, 1] with a matplotlib colormap."""
    from matplotlib import colormaps

    if not isinstance(cmap, str):
        raise TypeError(f"cmap: expected a matplotlib colormap name, got {type(cmap).__name__}")
    if cmap not in colormaps:
        raise ValueError(f"cmap: {str(cmap)[:40]!r} is not a matplotlib colormap")
    values = as_finite_array(values, "values", shape=(None,))
    lo = float(values.min(initial=0.0)) if vmin is None else as_bounded(vmin, "vmin", -1e300, 1e300)
    hi = float(values.max(initial=0.0)) if vmax is None else as_bounded(vmax, "vmax", -1e300, 1e300)
    scaled = np.clip((values - lo) / (hi - lo if hi > lo else 1.0), 0.0, 1.0)
    return colormaps[cmap](scaled)[:, :3]


def render_heat_map(
    points: np.ndarray,
    triangles: np.ndarray,
    values: np.ndarray,
    path: str | Path | None = None,
    *,
    title: str = "",
    units: str = "",
    camera: Camera | None = None,
    size=(640, 480),
    cmap: str = "inferno",
    scale: float = 1.0,
    vmin: float | None = None,
    vmax: float | None = None,
    background=(1.0, 1.0, 1.0),
    interior=None,
) -> np.ndarray:
    """Render ``points`` coloured by ``values`` (V,), with a colour bar and its range; returns the image.

    ``vmin``/``vmax`` fix the colour scale (default: the values' own range) — give several heat maps
    the same ones to compare them. ``scale`` multiplies the values shown on the colour bar (e.g. 1000
    to show metres as millimetres).
    """
    if _image_size(size)[1] < MIN_HEAT_MAP_HEIGHT:
        raise ValueError(
            f"size: a heat map needs at least {MIN_HEAT_MAP_HEIGHT} px of height for its colour bar, got {size[1]}"
        )
    scale = as_bounded(scale, "scale", -1e12, 1e12)
    values = as_finite_array(values, "values", shape=(None,))
    vmin = float(values.min(initial=0.0)) if vmin is None else as_bounded(vmin, "vmin", -1e300, 1e300)
    vmax = float(values.max(initial=0.0)) if vmax is None else as_bounded(vmax, "vmax", -1e300, 1e300)
    image = render(
        points,
        triangles,
        camera=camera,
        size=size,
        colors=heat_colors(values, vmin=vmin, vmax=vmax, cmap=cmap),
        background=background,
        interior=interior,
    )
    image = _color_bar(image, vmin * scale, vmax * scale, units, cmap)
    return _finish(image, title, path)


def write_video(
    frames: Iterable[np.ndarray],
    triangles: np.ndarray,
    path: str | Path,
    *,
    fps: float = 30.0,
    size=(640, 480),
    camera: Camera | None = None,
    label=None,
    progress: bool = True,
    total: int | None = None,
    background=(1.0, 1.0, 1.0),
    interior=None,
) -> Path:
    """Render each (V, 3) frame and write an MP4 (OpenCV, ``mp4v``) through a temporary file and a rename.

    ``label`` is drawn on every frame: a string (followed by the frame number) or a function of the
    frame index returning the text. ``total`` is the frame count for the progress bar (default
    ``len(frames)`` when it has one).
    """
    import cv2

    from ._files import atomic_path

    path = as_path(path, "path")
    size = _image_size(size)
    fps = as_positive(fps, "fps", maximum=1000.0)
    if progress:
        from tqdm import tqdm

        if total is None and hasattr(frames, "__len__"):
            total = len(frames)
        frames = tqdm(frames, desc=f"video {path.name}", unit="frame", total=total, leave=False)
    with atomic_path(path, path.suffix) as temporary:
        writer = cv2.VideoWriter(str(temporary), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), tuple(size))
        if not writer.isOpened():
            raise ValueError(f"cannot open a video writer for {path}")
        try:
            with PreviewRenderer(
                triangles, size=size, camera=camera, background=background, interior=interior
            ) as renderer:
                for index, points in enumerate(frames):
                    image = renderer.render(points)
                    if callable(label):
                        image = _label(image, label(index))
                    elif label:
                        image = _label(image, f"{label}  frame {index}")
                    writer.write(cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        finally:
            writer.release()
    return path


IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
"""File name endings :func:`save_image` writes (OpenCV picks the format from the ending)."""


def save_image(path: str | Path, image: np.ndarray) -> Path:
    """Write an RGB uint8 image as PNG via a temporary file and a rename."""
    import cv2

    from ._files import atomic_path

    path = as_path(path, "path")
    if path.suffix.lower() not in IMAGE_SUFFIXES:
        raise ValueError(f"{path}: an image file must end in one of {', '.join(IMAGE_SUFFIXES)}")
    pixels = as_finite_array(image, "image", max_abs=1e300)
    if pixels.ndim != 3 or pixels.shape[2] != 3 or not pixels.shape[0] or not pixels.shape[1]:
        raise ValueError(f"image: expected RGB pixels of shape (H, W, 3), got {pixels.shape}")
    if pixels.min() < 0 or pixels.max() > 255:
        raise ValueError("image: values must be in [0, 255]")
    image = pixels.astype(np.uint8)
    with atomic_path(path, path.suffix) as temporary:
        if not cv2.imwrite(str(temporary), cv2.cvtColor(np.asarray(image, dtype=np.uint8), cv2.COLOR_RGB2BGR)):
            raise ValueError(f"cannot write image {path}")
    return path


def _finish(image: np.ndarray, label: str | None, path) -> np.ndarray:
    """``image`` with ``label`` written on it (when given), saved to ``path`` (when given)."""
    if label:
        image = _label(image, label)
    if path is not None:
        save_image(path, image)
    return image


def _label(image: np.ndarray, text: str) -> np.ndarray:
    import cv2

    out = image.copy()
    scale = max(0.45, image.shape[0] / 900)
    color = (30, 30, 30) if image[:40].mean() > 128 else (235, 235, 235)  # dark text on light backgrounds
    cv2.putText(out, text, (10, int(28 * scale / 0.6)), cv2.FONT_HERSHEY_SIMPLEX, scale, color, 2, cv2.LINE_AA)
    return out


def scale_label(value: float, span: float) -> str:
    """``value`` written to the precision a colour bar of range ``span`` resolves (three significant
    digits of the span): 8.68e-08 on a 15 mm bar is "0", 14.97 is "15.0"."""
    import math

    value = as_bounded(value, "value", -1e300, 1e300)
    span = float(as_finite_array(span, "span", shape=()))
    span = abs(span) if math.isfinite(span) and span > 0 else abs(value) or 1.0
    decimals = max(0, 2 - math.floor(math.log10(span)))
    text = f"{round(value, decimals):.{decimals}f}"
    return "0" if float(text) == 0 else text


MIN_HEAT_MAP_HEIGHT = 120
"""Smallest image height [px] with room for a heat map's colour bar and its two labels."""


def _image_size(size) -> tuple[int, int]:
    """``(width, height)`` in pixels, each in [8, 16384]; ValueError naming ``size`` otherwise."""
    if not isinstance(size, (list, tuple, np.ndarray)):
        raise TypeError(f"size: expected (width, height) in pixels, got {type(size).__name__}")
    if shape_of(size) != (2,):
        raise ValueError(f"size: expected (width, height) in pixels, got shape {shape_of(size)}")
    return tuple(as_count(int(n) if isinstance(n, np.integer) else n, "size", minimum=8, maximum=16384) for n in size)


def _color_bar(image: np.ndarray, vmin: float, vmax: float, units: str, cmap: str) -> np.ndarray:
    """Append a vertical colour bar with its end values to the right of ``image``."""
    import cv2

    height = image.shape[0]
    background = image[0, 0]
    ink = (20, 20, 20) if background.mean() > 128 else (235, 235, 235)
    bar = np.empty((height, 110, 3), dtype=np.uint8)
    bar[:] = background
    ramp = heat_colors(np.linspace(1.0, 0.0, height - 80), vmin=0.0, vmax=1.0, cmap=cmap)
    bar[40 : height - 40, 15:40] = (ramp[:, None, :] * 255).astype(np.uint8)
    for y, value in ((50, vmax), (height - 35, vmin)):
        cv2.putText(bar, scale_label(value, vmax - vmin), (45, y), cv2.FONT_HERSHEY_SIMPLEX, 0.45, ink, 1, cv2.LINE_AA)
    if units:
        cv2.putText(bar, units, (15, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.45, ink, 1, cv2.LINE_AA)
    return np.concatenate([image, bar], axis=1)
