"""The default rig's mouth corners (docs/RIG.md §17): the modiolus moved up, down, back and out.

At each corner of the mouth the zygomaticus major, risorius, buccinator, levator and depressor anguli oris meet in a
knot of fibres, the modiolus, that carries the corner and the skin around it as one piece (a smile draws it up and
back along the cheek, a stretch out, a frown down). Each direction is a :class:`~warpface.expression.LidMuscle` with
no turn, only a per-vertex slide along one axis of the :class:`~warpface.assets.frame.FaceFrame`: per unit ``K`` a
vertex moves by

``SLIDE · d · g(|x − m|)``,  ``g(r) = 1`` for ``r ≤ r₀``, ``cos²(π/2 · (r − r₀)/r₁)`` up to ``r₀ + r₁``, 0 beyond,

``x`` and ``m`` (the corner, iBUG 54 on the left, 48 on the right) in inter-ocular units ``d``, ``(r₀, r₁)`` =
:data:`CORNER_RADII`. Eight controls: ``mouth_corner_{up,down,back,out}_{L,R}`` (``+y``, ``−y``, ``−z``, and ``±x``
away from the midline). The lips' seal (docs/RIG.md §12) applies to them as to the Waters muscles (they turn
nothing), so none brings the inner lips together.
"""

from __future__ import annotations

import numpy as np

from ..expression.lids import LidMuscle
from ..mesh import FaceMesh
from .frame import FaceFrame

__all__ = ["MOUTH_CORNER_NAMES", "CORNER_RADII", "CORNER_SLIDE", "corner_weight", "default_mouth_corners"]

CORNER_SLIDE = 0.1
"""A corner's largest slide per unit K [inter-ocular units] (6 mm on ICT-FaceKit's face)."""
CORNER_RADII = (0.1, 0.35)
"""``(r₀, r₁)`` [inter-ocular units]: the skin within ``r₀`` of the corner moves fully, the slide fades to 0 over the
next ``r₁`` (chosen on the training shapes, docs/RIG.md §17)."""

_CORNERS = {"L": 54, "R": 48}
# direction name → (frame axis, sign on the left corner, sign on the right corner)
_DIRECTIONS = {"up": (1, 1.0, 1.0), "down": (1, -1.0, -1.0), "back": (2, -1.0, -1.0), "out": (0, 1.0, -1.0)}

MOUTH_CORNER_NAMES: tuple[str, ...] = tuple(f"mouth_corner_{way}_{side}" for way in _DIRECTIONS for side in _CORNERS)
"""The mouth corners' control names, in rig order."""


def corner_weight(mesh: FaceMesh, frame: FaceFrame, landmarks: np.ndarray, side: str) -> np.ndarray:
    """``g`` of the module docstring at every vertex for the corner of ``side`` (``"L"`` or ``"R"``), shape (V,)."""
    local = frame.to_local(mesh.points)
    distance = np.linalg.norm(local - local[landmarks[_CORNERS[side]]], axis=1)
    inner, fade = CORNER_RADII
    t = np.clip((distance - inner) / fade, 0.0, 1.0)
    return np.where(t < 1.0, np.cos(0.5 * np.pi * t) ** 2, 0.0)


def default_mouth_corners(mesh: FaceMesh, frame: FaceFrame, landmarks: np.ndarray) -> list[LidMuscle]:
    """The eight mouth-corner controls of the default rig, in :data:`MOUTH_CORNER_NAMES` order (module docstring)."""
    weights = {side: corner_weight(mesh, frame, landmarks, side) for side in _CORNERS}
    corners = []
    for way, (axis, left, right) in _DIRECTIONS.items():
        for side, sign in (("L", left), ("R", right)):
            amount = CORNER_SLIDE * frame.scale * weights[side]
            centre = mesh.points[landmarks[_CORNERS[side]]]
            corners.append(LidMuscle.pure_slide(f"mouth_corner_{way}_{side}", centre, sign * frame.axes[axis], amount))
    return corners
