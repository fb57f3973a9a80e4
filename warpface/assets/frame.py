"""A face's own coordinate frame, measured from its 68 iBUG landmarks, and points on its surface.

Everything the default rig places (muscle ends, wrinkle curves, thickness regions) is written in
this frame's coordinates, in units of the inter-ocular distance, so one description fits any face
in any units: the built-in face in metres and the ICT-FaceKit face in centimetres alike.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_finite_array, as_vec3
from ..errors import RigError
from ..expression.wrinkles import CylindricalProjection
from ..landmarks import IBUG_COUNT, LEFT_EYE, MOUTH, RIGHT_EYE
from ..mesh import FaceMesh

__all__ = ["FaceFrame", "SurfaceSampler", "check_landmarks", "head_cylinder"]

LANDMARK_COUNT = IBUG_COUNT


def check_landmarks(mesh: FaceMesh, landmarks, label: str = "landmarks") -> np.ndarray:
    """68 iBUG vertex indices as int64 (68,); raises RigError on a wrong shape, type or range."""
    array = np.asarray(landmarks)
    if array.shape != (LANDMARK_COUNT,):
        raise RigError(f"{label}: expected {LANDMARK_COUNT} iBUG vertex indices, got shape {array.shape}")
    if not np.issubdtype(array.dtype, np.integer):
        raise RigError(f"{label}: vertex indices must be integers, got dtype {array.dtype}")
    bad = np.flatnonzero((array < 0) | (array >= mesh.vertex_count))
    if len(bad):
        raise RigError(
            f"{label}: landmark {int(bad[0])} has vertex index {int(array[bad[0]])} outside [0, {mesh.vertex_count})"
        )
    return array.astype(np.int64)


@dataclass(frozen=True)
class FaceFrame:
    """An orthonormal frame on a face, scaled by its inter-ocular distance.

    ``origin`` is the midpoint of the two eye centres (means of iBUG 36–41 and 42–47); ``x_axis``
    points from the subject's right eye to the left eye, ``y_axis`` up (from the mouth centre
    toward the eyes, made orthogonal to x), ``z_axis = x × y`` out of the face. ``scale`` is the
    distance between the eye centres [mesh units]. Local coordinates are ``(p − origin)·axes / scale``.
    """

    origin: np.ndarray
    """Midpoint of the eye centres [mesh units], shape (3,)."""
    axes: np.ndarray
    """Rows x, y, z: unit axes, shape (3, 3)."""
    scale: float
    """Inter-ocular (eye-centre) distance [mesh units]."""

    @classmethod
    def from_landmarks(cls, landmark_points: np.ndarray, label: str = "landmarks") -> "FaceFrame":
        """Frame from the 68 landmark positions, shape (68, 3); RigError if they cannot define one."""
        points = np.asarray(landmark_points, dtype=np.float64)
        right_eye, left_eye = points[list(RIGHT_EYE)].mean(axis=0), points[list(LEFT_EYE)].mean(axis=0)
        across = left_eye - right_eye
        scale = float(np.linalg.norm(across))
        if not np.isfinite(scale) or scale <= 0.0:
            raise RigError(f"{label}: the two eye centres coincide; cannot measure the face")
        x_axis = across / scale
        origin = 0.5 * (left_eye + right_eye)
        up = origin - points[list(MOUTH)].mean(axis=0)
        up = up - np.dot(up, x_axis) * x_axis
        if np.linalg.norm(up) < 0.2 * scale:
            raise RigError(f"{label}: the mouth is not below the eyes (landmarks out of iBUG order?)")
        y_axis = up / np.linalg.norm(up)
        return cls(origin=origin, axes=np.stack([x_axis, y_axis, np.cross(x_axis, y_axis)]), scale=scale)

    def to_local(self, points: np.ndarray) -> np.ndarray:
        """Mesh-unit points (..., 3) → local coordinates in inter-ocular units (..., 3)."""
        return (_points3(points, "points") - self.origin) @ self.axes.T / self.scale

    def to_world(self, local: np.ndarray) -> np.ndarray:
        """Local coordinates (..., 3) in inter-ocular units → mesh-unit points (..., 3)."""
        return self.origin + self.scale * (_points3(local, "local") @ self.axes)

    def direction(self, local_direction) -> np.ndarray:
        """A local direction (3,) as a unit vector in mesh space."""
        vector = as_vec3(local_direction, "local_direction", max_abs=1e100) @ self.axes
        length = np.linalg.norm(vector)
        if not length > 0.0:
            raise ValueError("local_direction: zero-length vector")
        return vector / length


def _points3(value, name: str) -> np.ndarray:
    """Finite float64 points of shape (..., 3) (magnitudes up to 1e100, so transforms stay finite)."""
    points = as_finite_array(value, name, max_abs=1e100)
    if points.ndim == 0 or points.shape[-1] != 3:
        raise ValueError(f"{name}: expected shape (..., 3), got {points.shape}")
    return points


class SurfaceSampler:
    """Points on a face surface found by casting rays along the frame's −z axis (front view).

    A query ``(x, y)`` in local coordinates returns the front-most intersection with the mesh and
    the interpolated unit normal there. Where the ray misses (an eye or mouth opening, beyond the
    outline) the nearest front-facing vertex in the ``(x, y)`` plane stands in.

    Args:
        mesh: the rest surface.
        frame: the face frame.
        normals: unit vertex normals of ``mesh``, shape (V, 3).
    """

    def __init__(self, mesh: FaceMesh, frame: FaceFrame, normals: np.ndarray):
        self.frame = frame
        self.local = frame.to_local(mesh.points)
        self.normals = np.asarray(normals, dtype=np.float64)
        self.triangles = mesh.triangles
        corners = self.local[self.triangles]
        self._a = corners[:, 0, :2]
        self._ab = corners[:, 1, :2] - self._a
        self._ac = corners[:, 2, :2] - self._a
        self._det = self._ab[:, 0] * self._ac[:, 1] - self._ab[:, 1] * self._ac[:, 0]
        self._z = corners[:, :, 2]
        self._usable = np.abs(self._det) > 1e-14
        self._lo = corners[:, :, :2].min(axis=1)
        self._hi = corners[:, :, :2].max(axis=1)
        facing = self.normals @ frame.axes[2] > 0.0
        self._front_vertices = np.flatnonzero(facing) if facing.any() else np.arange(len(self.local))

    def hit(self, xy) -> tuple[np.ndarray, np.ndarray]:
        """Surface point [mesh units] (3,) and unit normal (3,) under local ``(x, y)``."""
        x, y = (float(c) for c in as_finite_array(xy, "xy", shape=(2,), max_abs=1e6))
        near = np.flatnonzero(
            self._usable & (self._lo[:, 0] <= x) & (self._hi[:, 0] >= x) & (self._lo[:, 1] <= y) & (self._hi[:, 1] >= y)
        )
        if len(near):
            offset = np.array([x, y]) - self._a[near]
            ab, ac, det = self._ab[near], self._ac[near], self._det[near]
            v = (offset[:, 0] * ac[:, 1] - offset[:, 1] * ac[:, 0]) / det
            w = (ab[:, 0] * offset[:, 1] - ab[:, 1] * offset[:, 0]) / det
            u = 1.0 - v - w
            inside = (u >= -1e-9) & (v >= -1e-9) & (w >= -1e-9)
            if inside.any():
                weights = np.stack([u, v, w], axis=1)[inside]
                depth = (weights * self._z[near[inside]]).sum(axis=1)
                best = int(np.argmax(depth))
                triangle = self.triangles[near[inside][best]]
                weight = weights[best]
                local = np.array([x, y, depth[best]])
                normal = weight @ self.normals[triangle]
                return self.frame.to_world(local), normal / np.linalg.norm(normal)
        candidates = self._front_vertices
        nearest = candidates[np.argmin(np.sum((self.local[candidates, :2] - [x, y]) ** 2, axis=1))]
        return self.frame.to_world(self.local[nearest]), self.normals[nearest] / np.linalg.norm(self.normals[nearest])

    def point(self, xy) -> np.ndarray:
        """Surface point [mesh units] (3,) under local ``(x, y)``."""
        return self.hit(xy)[0]

    def below(self, xy, depth: float) -> np.ndarray:
        """A point ``depth`` inter-ocular units beneath the surface at ``(x, y)``, along −normal [mesh units]."""
        point, normal = self.hit(xy)
        depth = float(as_finite_array(depth, "depth", shape=(), max_abs=1e6))
        return point - depth * self.frame.scale * normal


def head_cylinder(frame: FaceFrame, local_landmarks: np.ndarray) -> CylindricalProjection:
    """A cylinder around the head's vertical axis through the ear-level jaw points and the nasion.

    The axis is the frame's y axis, moved back to the centre of the circle through iBUG 0, 16 and
    27 (seen from above); θ = 0 faces the viewer.
    """
    ear_right, ear_left, nasion = local_landmarks[0], local_landmarks[16], local_landmarks[27]
    half_width = 0.5 * abs(ear_left[0] - ear_right[0])
    ear_z = 0.5 * (ear_left[2] + ear_right[2])
    # Circle centred on x = 0 through (±half_width, ear_z) and (0, nasion_z): solve for its centre z.
    if nasion[2] - ear_z <= 1e-6:
        raise RigError("landmarks: the nasion (iBUG 27) is not in front of the ear-level jaw points (0, 16)")
    centre_z = 0.5 * (nasion[2] ** 2 - ear_z**2 - half_width**2) / (nasion[2] - ear_z)
    radius = nasion[2] - centre_z
    return CylindricalProjection(
        origin=frame.to_world([0.0, 0.0, centre_z]),
        axis=frame.axes[1],
        reference=frame.axes[2],
        radius=radius * frame.scale,
    )
