"""The head body's motion over one step, and the inertial body force it puts on the tissue (docs/NEWTON.md §2).

The tissue is simulated in the head body's frame ``X_H = (p, R)`` (Newton's ``body_q``: the body origin and its
rotation). A node at head-frame position ``r = X + d`` moves in the world as ``x = p + R r``; in that frame its
equation of motion gains, per unit mass, the body acceleration

    b = Rᵀ (g − a_O) − α × r − ω × (ω × r) − 2 ω × ḋ − b_rest

with ``a_O`` the acceleration of the frame's origin, ``ω`` and ``α`` the body's angular velocity and
acceleration (all here in the head frame, ``ω = Rᵀ ω_world``), ``g`` the gravity and ``b_rest = R₀ᵀ g₀`` the
gravity the rest shape already balances (the captured face hangs in its own gravity). The nodal force is
``f = M b`` (the tissue's consistent mass). A head at rest under the reference gravity feels ``b = 0``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["HeadMotion", "body_force", "head_motion", "origin_velocity"]


@dataclass(frozen=True)
class HeadMotion:
    """The head frame at the end of a step and its motion over the step (world frame, float64)."""

    position: np.ndarray
    """Origin ``p`` [m], shape (3,)."""
    rotation: np.ndarray
    """Rotation ``R`` (head frame -> world), shape (3, 3)."""
    velocity: np.ndarray
    """Origin velocity [m/s], shape (3,)."""
    angular_velocity: np.ndarray
    """ω [rad/s], shape (3,)."""
    acceleration: np.ndarray
    """Origin acceleration ``a_O`` [m/s²], shape (3,)."""
    angular_acceleration: np.ndarray
    """α [rad/s²], shape (3,)."""

    @staticmethod
    def at_rest(position=(0.0, 0.0, 0.0), rotation=None) -> HeadMotion:
        """A frame that does not move (the world, or a head body at rest)."""
        zero = np.zeros(3)
        rot = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
        return HeadMotion(np.asarray(position, dtype=np.float64), rot, zero, zero, zero, zero)


def quat_matrix(q) -> np.ndarray:
    """Rotation matrix of a unit quaternion ``(x, y, z, w)`` (Warp's order), shape (3, 3)."""
    x, y, z, w = (float(c) for c in q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def origin_velocity(body_q: np.ndarray, body_qd: np.ndarray, com: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(v_origin, ω)`` [m/s, rad/s] of a body from Newton's pose (7,), twist (6,: COM linear velocity, then
    angular velocity, world frame) and body-frame COM (3,)."""
    rotation = quat_matrix(body_q[3:7])
    omega = np.asarray(body_qd[3:6], dtype=np.float64)
    return np.asarray(body_qd[:3], dtype=np.float64) - np.cross(omega, rotation @ com), omega


def head_motion(model, state_in, state_out, body: int, dt: float) -> HeadMotion:
    """The motion of ``body`` over a step from ``state_in`` to ``state_out`` (both already hold the body's pose
    and twist: a rigid solver, or a prescribed motion, stepped it first); accelerations are the change of the
    origin's velocity and of ω over ``dt``. ``body`` -1 is the world (at rest)."""
    if body < 0:
        return HeadMotion.at_rest()
    com = np.asarray(model.body_com.numpy()[body], dtype=np.float64)
    q_out = np.asarray(state_out.body_q.numpy()[body], dtype=np.float64)
    v_in, w_in = origin_velocity(state_in.body_q.numpy()[body], state_in.body_qd.numpy()[body], com)
    v_out, w_out = origin_velocity(q_out, state_out.body_qd.numpy()[body], com)
    return HeadMotion(
        position=q_out[:3],
        rotation=quat_matrix(q_out[3:7]),
        velocity=v_out,
        angular_velocity=w_out,
        acceleration=(v_out - v_in) / dt,
        angular_acceleration=(w_out - w_in) / dt,
    )


def body_force(
    motion: HeadMotion, gravity, rest_gravity: np.ndarray, r: np.ndarray, velocity: np.ndarray
) -> np.ndarray:
    """The inertial body acceleration ``b`` (module docstring) at head-frame positions ``r`` (N, 3) [m] moving at
    ``velocity`` (N, 3) [m/s] in the head frame; returns (N, 3) [m/s²], float64."""
    rt = motion.rotation.T
    uniform = rt @ (np.asarray(gravity, dtype=np.float64) - motion.acceleration) - rest_gravity
    omega, alpha = rt @ motion.angular_velocity, rt @ motion.angular_acceleration
    b = np.broadcast_to(uniform, r.shape).copy()
    if np.any(alpha):
        b -= np.cross(alpha, r)
    if np.any(omega):
        b -= np.cross(omega, np.cross(omega, r)) + 2.0 * np.cross(omega, velocity)
    return b
