"""The jaw (SPEC §6.2): a rigid mandible motion applied to the rest skin before the muscles.

``x_jaw = x_rest + w(x) · (R(θ, a)(x_rest − p) + p + t − x_rest)``, with ``R`` the rotation by the
opening angle ``θ`` about the hinge axis ``a`` through the pivot ``p`` and ``t = f·e_forward + l·e_left``
(protrusion and lateral slide). ``w ∈ [0, 1]`` is a per-vertex weight (1 on chin, lower lip and jaw
line, 0 on the upper face; see :func:`warpface.assets.jaw_weights` for the default rig's construction).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from .._validate import as_finite_array, as_points, as_vec3, expect_instance, orthogonal_unit_vector, unit_vector
from .formulas import jaw_blend, jaw_rotation, jaw_slide

__all__ = ["Jaw", "JAW_CONTROL_NAMES", "JAW_RANGE", "jaw_points"]

JAW_CONTROL_NAMES: tuple[str, ...] = ("jaw_open", "jaw_forward", "jaw_left")
"""The jaw's controls, in order: opening angle θ [rad] (positive opens the mouth), protrusion along
``forward`` [mesh units] and slide toward the subject's left [mesh units]."""

JAW_RANGE: dict[str, tuple[float, float]] = {
    "jaw_open": (-0.05, 0.6),
    "jaw_forward": (-0.1, 0.15),
    "jaw_left": (-0.15, 0.15),
}
"""The mandible's range of motion (the solver's default bounds): the opening angle [rad] (a slight
over-closure up to a maximal opening of ~34°, ~50 mm between the incisors), protrusion and lateral
slide as fractions of the inter-ocular distance (~6 mm back to ~9 mm forward, ~9 mm either side)."""


@dataclass(frozen=True, eq=False)
class Jaw:
    """A mandible hinge and the skin's per-vertex jaw weights.

    Args:
        pivot: hinge point ``p`` [mesh units], shape (3,) (between the temporomandibular joints).
        axis: hinge axis ``a``, shape (3,), normalised; a positive angle about it opens the mouth
            (the right-hand rule: for a face looking along +z with y up, ``a`` points to the subject's left).
        forward: protrusion direction, shape (3,), normalised and made orthogonal to ``axis``.
        weights: per-vertex weight ``w`` ∈ [0, 1], shape (V,).
        name: prim name of the jaw.

    Raises:
        ValueError: non-finite or degenerate vectors, weights outside [0, 1] or not 1-D.
    """

    pivot: np.ndarray
    axis: np.ndarray
    forward: np.ndarray
    weights: np.ndarray
    name: str = "Jaw"

    def __post_init__(self) -> None:
        label = f"jaw {self.name!r}"
        if not isinstance(self.name, str):
            raise TypeError(f"{label}: name must be a string, got {type(self.name).__name__}")
        if not self.name:
            raise ValueError(f"{label}: name must be a non-empty string")
        set_ = object.__setattr__
        set_(self, "pivot", as_vec3(self.pivot, f"{label}: pivot"))
        axis = unit_vector(self.axis, f"{label}: axis")
        set_(self, "axis", axis)
        forward = unit_vector(self.forward, f"{label}: forward")
        if np.linalg.norm(forward - np.dot(forward, axis) * axis) < 1e-6:
            raise ValueError(f"{label}: forward is parallel to the hinge axis")
        set_(self, "forward", orthogonal_unit_vector(forward, axis, f"{label}: forward"))
        weights = as_finite_array(self.weights, f"{label}: weights")
        if weights.ndim != 1:
            raise ValueError(f"{label}: weights must be 1-D (one per vertex), got shape {weights.shape}")
        if weights.size and (weights.min() < 0.0 or weights.max() > 1.0):
            raise ValueError(f"{label}: weights must lie in [0, 1], got [{weights.min()}, {weights.max()}]")
        set_(self, "weights", weights)

    @property
    def left(self) -> np.ndarray:
        """Lateral slide direction (the subject's left): ``axis`` (unit, shape (3,))."""
        return self.axis.copy()

    def check_vertex_count(self, vertex_count: int) -> None:
        """Raise ValueError unless there is one weight per vertex."""
        if len(self.weights) != vertex_count:
            raise ValueError(f"jaw {self.name!r}: {len(self.weights)} weights for a mesh of {vertex_count} vertices")


@wp.func
def _jaw_point(x: wp.vec3d, w: wp.float64, pivot: wp.vec3d, axis: wp.vec3d, forward: wp.vec3d, controls: wp.vec3d):
    """``x_jaw`` of one point with weight ``w``; ``controls`` = (θ [rad], protrusion, lateral slide)."""
    rotation = jaw_rotation(controls[0], axis)
    return jaw_blend(x, w, pivot, rotation, jaw_slide(controls[1], controls[2], forward, axis))


def jaw_points(jaw: Jaw, rest_points: np.ndarray, controls) -> np.ndarray:
    """``x_jaw`` in float64 on the CPU (rig-time use and references), shape (V, 3): the formulas the kernels use.

    Args:
        jaw: the jaw.
        rest_points: shape (V, 3).
        controls: ``(jaw_open [rad], jaw_forward, jaw_left)`` [mesh units], shape (3,).
    """
    expect_instance(jaw, Jaw, "jaw")
    values = as_finite_array(controls, "jaw controls", shape=(3,))
    rest = as_points(rest_points, "rest_points")
    if len(rest) != len(jaw.weights):
        raise ValueError(f"rest_points: {len(rest)} points but the jaw has weights for {len(jaw.weights)} vertices")
    if len(rest) == 0:
        return np.zeros((0, 3))
    points = wp.array(rest, dtype=wp.vec3d, device="cpu")
    weights = wp.array(jaw.weights, dtype=wp.float64, device="cpu")
    pose = (wp.vec3d(*v) for v in (jaw.pivot, jaw.axis, jaw.forward, values))
    return wp.map(_jaw_point, points, weights, *pose, device="cpu").numpy()
