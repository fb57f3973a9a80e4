"""The default subcutaneous thickness: a grayscale map painted by facial region, then blurred (SPEC §1.5).

Regions are ellipses and polygons placed from the 68 landmarks in the face frame, painted into an
image laid over the head cylinder (:func:`~warpface.assets.frame.head_cylinder`), Gaussian-blurred so
thickness varies smoothly, and sampled per vertex by :class:`~warpface.ThicknessMap`.

Values are physiological soft-tissue depths for an adult face with a 63 mm inter-ocular distance,
scaled by the face's own inter-ocular distance: eyelids ~1 mm, nose bridge ~1.5 mm, forehead
~2.5 mm, lips and chin ~6 mm, upper lip ~7 mm, cheeks (malar fat pad) ~10 mm, elsewhere ~4 mm.
"""

from __future__ import annotations

import numpy as np

from .._validate import expect_instance
from ..expression.thickness import ThicknessMap
from ..expression.wrinkles import project_points
from ..landmarks import LEFT_EYE, MOUTH, RIGHT_EYE
from ..mesh import FaceMesh
from .frame import FaceFrame, SurfaceSampler, check_landmarks, head_cylinder

__all__ = ["default_thickness", "thickness_map", "THICKNESS_MM", "REFERENCE_INTEROCULAR_MM"]

REFERENCE_INTEROCULAR_MM = 63.0
"""Inter-ocular distance of the adult face the millimetre values below refer to."""

THICKNESS_MM: dict[str, float] = {
    "base": 4.0,
    "forehead": 2.5,
    "temple": 3.0,
    "cheek": 8.0,
    "upper_lip": 7.0,
    "lips": 6.0,
    "chin": 6.0,
    "nose_tip": 3.0,
    "nose_bridge": 1.5,
    "eyelid": 1.0,
}
"""Soft-tissue thickness per painted region [mm at the reference inter-ocular distance]."""

_WHITE_MM = 12.0
"""Thickness at full luminance; all painted values lie below it."""
_IMAGE_ROWS = 256
_BLUR = 0.08
"""Gaussian blur standard deviation [inter-ocular units]."""


def default_thickness(mesh: FaceMesh | None = None, landmarks=None, *, device=None) -> np.ndarray:
    """Per-vertex subcutaneous thickness [mesh units], shape (V,), float64, all > 0.

    Args:
        mesh, landmarks: a face and its 68 iBUG vertex indices; both omitted for the built-in face.
        device: Warp device for normals and projection.
    """
    if mesh is None:
        from .face import default_face, default_landmarks

        mesh = default_face()
        landmarks = default_landmarks() if landmarks is None else landmarks
    painted = thickness_map(mesh, landmarks, device=device)
    return painted.sample(mesh.points, device=device)


def thickness_map(mesh: FaceMesh, landmarks, *, device=None) -> ThicknessMap:
    """The painted, blurred thickness image of a face over its head cylinder."""
    expect_instance(mesh, FaceMesh, "mesh")
    import cv2

    if landmarks is None:
        raise ValueError(f"thickness map: mesh {mesh.name!r} needs its 68 iBUG landmark vertex indices")
    landmarks = check_landmarks(mesh, landmarks)
    frame = FaceFrame.from_landmarks(mesh.points[landmarks])
    local = frame.to_local(mesh.points[landmarks])
    cylinder = head_cylinder(frame, local)
    surface = SurfaceSampler(mesh, frame, mesh.vertex_normals(device=device))
    xy = local[:, :2]

    def to_uv(points_xy):
        world = np.array([surface.point(p) for p in points_xy])
        return project_points(cylinder, world, device=device)

    edge_uv = to_uv([xy[0], xy[16]])
    margin = 0.35 * frame.scale
    u_range = (float(edge_uv[:, 0].min()) - margin, float(edge_uv[:, 0].max()) + margin)
    brow_top = float(xy[17:27, 1].max())
    v_range = ((xy[8, 1] - 0.6) * frame.scale, (brow_top + 1.5) * frame.scale)
    rows = _IMAGE_ROWS
    columns = max(16, int(round(rows * (u_range[1] - u_range[0]) / (v_range[1] - v_range[0]))))

    def to_pixels(points_xy):
        uv = to_uv(points_xy)
        column = (uv[:, 0] - u_range[0]) / (u_range[1] - u_range[0]) * columns - 0.5
        row = (v_range[1] - uv[:, 1]) / (v_range[1] - v_range[0]) * rows - 0.5
        return np.round(np.stack([column, row], axis=1) * 16).astype(np.int32)  # 4 fractional bits

    def level(region):
        return THICKNESS_MM[region] / _WHITE_MM

    image = np.full((rows, columns), level("base"), dtype=np.float32)

    def paint(region, outline_xy):
        cv2.fillPoly(image, [to_pixels(outline_xy)], float(level(region)), lineType=cv2.LINE_AA, shift=4)

    def ellipse(centre, radii, count=48):
        angle = np.linspace(0.0, 2.0 * np.pi, count, endpoint=False)
        return np.stack([centre[0] + radii[0] * np.cos(angle), centre[1] + radii[1] * np.sin(angle)], axis=1)

    eye_right, eye_left = xy[list(RIGHT_EYE)].mean(axis=0), xy[list(LEFT_EYE)].mean(axis=0)
    mouth = xy[list(MOUTH)].mean(axis=0)
    mouth_half = 0.5 * abs(xy[54, 0] - xy[48, 0])
    paint(
        "forehead",
        [
            (-1.1, brow_top + 0.05),
            (-0.45, brow_top + 0.02),
            (0.45, brow_top + 0.02),
            (1.1, brow_top + 0.05),
            (1.1, brow_top + 1.6),
            (-1.1, brow_top + 1.6),
        ],
    )
    for sign, eye in ((-1.0, eye_right), (1.0, eye_left)):
        paint("temple", ellipse((sign * 1.05, eye[1] + 0.35), (0.22, 0.35)))
        paint("cheek", ellipse((sign * 0.62, eye[1] - 0.58), (0.36, 0.32)))
        paint("eyelid", ellipse(eye, (0.30, 0.16)))
    paint("upper_lip", ellipse((0.0, 0.5 * (xy[33, 1] + xy[51, 1])), (0.55, 0.16)))
    paint("lips", ellipse(mouth, (1.05 * mouth_half, 0.17)))
    paint("chin", ellipse((0.0, 0.55 * xy[8, 1] + 0.45 * xy[57, 1]), (0.30, 0.22)))
    paint("nose_tip", ellipse((0.0, xy[30, 1] - 0.06), (0.26, 0.16)))
    paint(
        "nose_bridge",
        [(-0.10, xy[27, 1] + 0.12), (0.10, xy[27, 1] + 0.12), (0.12, xy[30, 1] + 0.12), (-0.12, xy[30, 1] + 0.12)],
    )

    pixels_per_unit = rows / (v_range[1] - v_range[0]) * frame.scale
    scale_mm = frame.scale / REFERENCE_INTEROCULAR_MM  # mesh units per millimetre at this face's size
    return ThicknessMap(
        image=np.clip(image, 0.0, 1.0),
        projection=cylinder,
        u_range=u_range,
        v_range=v_range,
        black=0.0,
        white=_WHITE_MM * scale_mm,
        blur_sigma=_BLUR * pixels_per_unit,
    )
