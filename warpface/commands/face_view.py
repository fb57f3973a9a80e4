"""Pictures framed on a rig's face: the face's own frame, a portrait camera, landmark and muscle overlays.

The points are turned into the face's landmark frame (x to the subject's left, y up, z out of the face)
before rendering, so a head in any up axis and facing is drawn upright from the front, and the camera
frames forehead to chin rather than the whole bust. Used by ``warpface preview``, ``animate``'s video and
``fit``'s heat maps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FaceView", "face_view_of", "rig_of_stage", "project", "draw_landmarks", "draw_muscles"]

LANDMARK_COLOR = (40, 90, 220)
MUSCLE_COLOR = (215, 40, 40)
SPHINCTER_COLOR = (240, 150, 20)


def rig_of_stage(stage, meters_per_unit: float):
    """The rig on ``stage`` (in ``meters_per_unit`` units) when it has 68 landmarks, else None (an OBJ, a capture
    of landmarks only)."""
    from ..errors import RigError
    from ..landmarks import IBUG_COUNT
    from ..usd import read_rig

    try:
        rig = read_rig(stage, meters_per_unit=meters_per_unit)
    except (RigError, ValueError):
        return None
    return rig if rig.landmarks is not None and len(rig.landmarks) == IBUG_COUNT else None


@dataclass(frozen=True)
class FaceView:
    """A rigid map of mesh points into the face's frame (lengths kept)."""

    origin: np.ndarray
    axes: np.ndarray
    """Rows: the face's x (subject's left), y (up), z (out of the face) in mesh coordinates."""

    @classmethod
    def of(cls, rig) -> "FaceView":
        """The view of a rig's face, from its rest shape and 68 landmarks."""
        from ..assets.rig import face_frame

        frame = face_frame(rig.mesh, rig.landmarks)
        return cls(origin=frame.origin, axes=frame.axes)

    def __call__(self, points) -> np.ndarray:
        return (np.asarray(points, dtype=np.float64) - self.origin) @ self.axes.T

    def camera(self, landmark_points, *, yaw_deg: float, pitch_deg: float):
        """A portrait camera on the face from its landmark positions in mesh coordinates."""
        from ..preview import Camera

        return Camera.for_face(self(landmark_points), yaw_deg=yaw_deg, pitch_deg=pitch_deg)


def face_view_of(rig) -> FaceView | None:
    """The view of ``rig``'s face, or None when it has no 68 landmarks (then the mesh's own axes are used)."""
    from ..landmarks import IBUG_COUNT

    if rig.landmarks is None or len(rig.landmarks) != IBUG_COUNT:
        return None
    return FaceView.of(rig)


def project(camera, size: tuple[int, int], points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel positions (N, 2) of ``points`` (N, 3) seen by ``camera`` in an image of ``size`` (width, height), as
    the preview renderer's perspective draws them, and which of them lie in front of the camera."""
    width, height = size
    world_to_camera = np.linalg.inv(camera.pose())
    local = np.asarray(points, dtype=np.float64) @ world_to_camera[:3, :3].T + world_to_camera[:3, 3]
    depth = -local[:, 2]
    in_front = depth > 1e-9
    tangent = np.tan(np.radians(camera.yfov_deg) / 2.0)
    safe = np.where(in_front, depth, 1.0)
    x = local[:, 0] / safe / (tangent * width / height)
    y = local[:, 1] / safe / tangent
    return np.stack([(x + 1.0) * 0.5 * width, (1.0 - y) * 0.5 * height], axis=1), in_front


def _pixel(point) -> tuple[int, int]:
    return int(round(float(point[0]))), int(round(float(point[1])))


def draw_landmarks(image: np.ndarray, camera, points: np.ndarray) -> np.ndarray:
    """``image`` (H, W, 3) RGB with the 68 landmark positions (in the camera's frame) drawn as numbered dots."""
    import cv2

    image = np.ascontiguousarray(image).copy()
    size = (image.shape[1], image.shape[0])
    pixels, visible = project(camera, size, points)
    for index, (pixel, seen) in enumerate(zip(pixels, visible)):
        if seen:
            cv2.circle(image, _pixel(pixel), 2, LANDMARK_COLOR, -1, cv2.LINE_AA)
            cv2.putText(
                image, str(index), _pixel(pixel + 3), cv2.FONT_HERSHEY_SIMPLEX, 0.28, LANDMARK_COLOR, 1, cv2.LINE_AA
            )
    return image


def draw_muscles(image: np.ndarray, camera, muscles, view: FaceView) -> np.ndarray:
    """``image`` with each linear muscle as a line from its bone attachment to its skin insertion (a dot) and each
    sphincter as its ellipse (lid hinges and the lip seal are not drawn)."""
    import cv2

    from ..expression.muscles import LinearMuscle, SphincterMuscle

    image = np.ascontiguousarray(image).copy()
    size = (image.shape[1], image.shape[0])
    angles = np.linspace(0.0, 2.0 * np.pi, 49)
    for muscle in muscles:
        if isinstance(muscle, LinearMuscle):
            pixels, visible = project(camera, size, view(np.stack([muscle.attachment, muscle.insertion])))
            if visible.all():
                cv2.line(image, _pixel(pixels[0]), _pixel(pixels[1]), MUSCLE_COLOR, 1, cv2.LINE_AA)
                cv2.circle(image, _pixel(pixels[1]), 2, MUSCLE_COLOR, -1, cv2.LINE_AA)
        elif isinstance(muscle, SphincterMuscle):  # a lid hinge or the lip seal has no line or ring to draw
            (lx, ly), (ex, ey) = muscle.semi_axes, (np.asarray(muscle.axis_x), np.asarray(muscle.axis_y))
            ring = muscle.center + np.outer(lx * np.cos(angles), ex) + np.outer(ly * np.sin(angles), ey)
            pixels, visible = project(camera, size, view(ring))
            if visible.all():
                cv2.polylines(image, [np.round(pixels).astype(np.int32)], True, SPHINCTER_COLOR, 1, cv2.LINE_AA)
    return image
