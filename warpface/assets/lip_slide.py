"""The default rig's lip slides (docs/RIG.md §16): each lip moves as one piece, up or down, forward and sideways.

A lip slide is a :class:`~warpface.expression.LidMuscle` with no turn, only its per-vertex slide along one axis of
the :class:`~warpface.assets.frame.FaceFrame`: per unit ``K`` a vertex moves by ``SLIDE · d · g_v·c·s`` along the
axis (``d`` the inter-ocular distance, ``g_v·c`` the turn profile of :func:`~warpface.assets.lip_roll.lip_roll_turns`
with the rolling-out corner fade, ``s`` the side's share where a side is named). Twelve controls:

- ``lip_upper_raise_{L,R}`` (+y) and ``lip_lower_depress_{L,R}`` (−y): a lip drawn away from the other one as a
  whole (ICT-FaceKit's mouthUpperUp and mouthLowerDown lift and drop the red lip and the skin above or below it
  together, which the Waters muscles' cones reach only at their insertions);
- ``lip_{upper,lower}_protrude_{L,R}`` (+z): a lip pushed forward (pucker, funnel), which fits otherwise took from
  the jaw's protrusion;
- ``lip_{upper,lower}_slide_{left,right}`` (±x, the whole lip): the mouth drawn to one side (mouthLeft, mouthRight).

Each moves a lip's vertices only (the side of :func:`~warpface.assets.jaw.lip_sided`), away from the other lip or
level with it, so no slide closes the inner-lip pairs (docs/RIG.md §12). Like the lip hinges they are fitted, not
mapped: no preset or mapping uses them.
"""

from __future__ import annotations

import numpy as np

from ..expression.lids import LidMuscle
from ..mesh import FaceMesh
from .frame import FaceFrame
from .lip_roll import LIP_ROLL_NAMES, lip_roll_turns

__all__ = ["LIP_SLIDE_NAMES", "LIP_HINGE_NAMES", "SLIDE", "default_lip_slides"]

SLIDE = 0.1
"""A lip's largest slide per unit K [inter-ocular units] (6 mm on ICT-FaceKit's face; its mouthUpperUp lifts the
upper lip 3–5 mm)."""

# (lip, name, frame axis, sign, per side): the per-side slides split the lip with the hinges' side shares
_SLIDES = (
    ("upper", "raise", 1, 1.0, True),
    ("lower", "depress", 1, -1.0, True),
    ("upper", "protrude", 2, 1.0, True),
    ("lower", "protrude", 2, 1.0, True),
    ("upper", "slide_left", 0, 1.0, False),
    ("upper", "slide_right", 0, -1.0, False),
    ("lower", "slide_left", 0, 1.0, False),
    ("lower", "slide_right", 0, -1.0, False),
)

LIP_SLIDE_NAMES: tuple[str, ...] = tuple(
    name
    for lip, way, _, _, sided in _SLIDES
    for name in ((f"lip_{lip}_{way}_L", f"lip_{lip}_{way}_R") if sided else (f"lip_{lip}_{way}",))
)
"""The lip slides' control names, in rig order."""

LIP_HINGE_NAMES: tuple[str, ...] = LIP_ROLL_NAMES + LIP_SLIDE_NAMES
"""Every control that moves a lip as a body (the hinges of docs/RIG.md §15 and the slides of §16): the controls a
:class:`~warpface.solve.Solver` holds unless ``lip_rolls`` frees them."""


def default_lip_slides(mesh: FaceMesh, frame: FaceFrame, landmarks: np.ndarray) -> list[LidMuscle]:
    """The twelve lip slides of the default rig, in :data:`LIP_SLIDE_NAMES` order (module docstring)."""
    turns = lip_roll_turns(mesh, frame, landmarks)
    slides = []
    for lip, way, axis, sign, sided in _SLIDES:
        turn, shares, pivot = turns[lip]
        profile = turn["out"]
        parts = zip(("_L", "_R"), shares) if sided else (("", np.ones_like(profile)),)
        for suffix, share in parts:
            amount = SLIDE * frame.scale * profile * share
            name = f"lip_{lip}_{way}{suffix}"
            slides.append(LidMuscle.pure_slide(name, frame.to_world(pivot), sign * frame.axes[axis], amount))
    return slides
