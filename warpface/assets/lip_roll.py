"""The default rig's lip hinges (docs/RIG.md §15): each lip rolls in and out about an axis behind it.

In the :class:`~warpface.assets.frame.FaceFrame` (inter-ocular units), with the lips' contact line, its height
``φ`` below it and the mouth's half-width ``w`` of :mod:`warpface.assets.lips`, and ``m`` the midpoint of the
middle inner-lip pair (iBUG 62/66):

- a lip's *pivot* lies on the vertical through its inner margin: ``(m_x, y₆₂ + P·(y₃₃ − y₆₂), z₆₂)`` above the
  upper lip (``P`` = :data:`PIVOT_SHARE` of the way to the nose base, iBUG 33) and ``(m_x, y₆₆ − P·(y₆₆ − y₈),
  z₆₆)`` below the lower one (toward the chin, iBUG 8); the axis is the frame's x axis. A turn about a point
  straight above (below) the margin moves the margin back and away from the other lip, never toward it;
- a vertex of a lip (the side of :func:`~warpface.assets.jaw.lip_sided`) turns by ``Θ·g_v·c·s``: ``g_v`` is 1 on
  the red lip and the skin up to :data:`SKIN_BAND`\\ ``[0]`` of the way from the lip's outer border (iBUG 48–54
  above, 54–59 and 48 below, interpolated over x) to the nose base (chin), then falls as cos² to 0 over
  :data:`SKIN_BAND`\\ ``[1]``; ``c`` the corner fade of ``|x − m_x| / w`` over :data:`CORNER_BAND` (its own
  for rolling in and out); ``s`` the side's
  share, a cos² partition of unity over ``|x − m_x| ≤`` :data:`SPLIT_WIDTH`\\ ``· w`` (left + right = 1), so each
  side rolls on its own and both together roll the whole lip;
- ``Θ`` is :data:`ROLL_IN` (the lip curls into the mouth: the upper lip's front turns down and back, the lower's up
  and back) or −:data:`ROLL_OUT` (the lip everts, as in a sneer or a funnel), signs per lip.

Eight :class:`~warpface.expression.LidMuscle` hinges: ``lip_{upper,lower}_roll_{in,out}_{L,R}``. Nothing farther
than :data:`REACH` from ``m`` turns.
"""

from __future__ import annotations

import numpy as np

from ..expression.lids import LidMuscle
from ..mesh import FaceMesh
from .frame import FaceFrame
from .jaw import lip_sided
from .lips import band_fade, contact_line

__all__ = [
    "LIP_ROLL_NAMES",
    "default_lip_rolls",
    "ROLL_IN",
    "ROLL_OUT",
    "PIVOT_SHARE",
    "SKIN_BAND",
    "CORNER_BAND",
    "SPLIT_WIDTH",
    "ROLL_FIT_LIMIT",
]

ROLL_IN = 0.6
"""A lip's turn into the mouth per unit K [rad] (ICT-FaceKit's mouthRollUpper turns the upper lip by ~0.63 rad)."""
ROLL_OUT = 0.3
"""A lip's turn outward per unit K [rad] (ICT's mouthShrugUpper, mouthFunnel, mouthPucker: 0.1–0.26 rad)."""
PIVOT_SHARE = {"upper": 1.0, "lower": 0.5}
"""Per lip, the pivot's distance from the inner margin as a share of the way to the nose base (upper) or the chin
(lower): the upper pivot at the nose base's height (ICT-FaceKit's mouthRollUpper, one rigid turn of the upper lip's
midline, turns about a point 0.86 of the way), the lower half way; both chosen on the training shapes (docs/RIG.md
§15)."""
SKIN_BAND = (0.2, 0.9)
"""Share of the way from a lip's outer border to the nose base (chin) over which the skin turns fully, then the
share over which the turn fades to 0."""
CORNER_BAND = {"in": (0.6, 0.5), "out": (0.9, 0.5)}
"""Rolling in and out: distance from the mouth's middle [half-widths] turning fully, then the distance over which
the turn fades. A lip everts out to its corners and a little beyond (funnel, pucker); it rolls in less far (chosen on
the training shapes, docs/RIG.md §15)."""
SPLIT_WIDTH = 0.35
"""Half-width of the band across the midline [mouth half-widths] over which a lip's turn passes from one side's
hinge to the other's."""
REACH = 0.6
"""Nothing farther than this from the inner-lip midpoint turns [inter-ocular units]."""
ROLL_FIT_LIMIT = {"in": 1.0, "out": 2.0}
"""``fit_limit`` of the lip hinges that roll in and out: a fit turns a lip in at most by its full roll, out by
twice its turn (ICT's mouthShrugUpper, mouthFunnel and mouthPucker met the bound 1)."""

_UPPER_BORDER = (48, 49, 50, 51, 52, 53, 54)
_LOWER_BORDER = (54, 55, 56, 57, 58, 59, 48)

LIP_ROLL_NAMES: tuple[str, ...] = tuple(
    f"lip_{lip}_roll_{way}_{s}" for lip in ("upper", "lower") for way in ("in", "out") for s in ("L", "R")
)
"""The lip hinges' control names, in rig order."""


def _border(marks: np.ndarray, indices, x: np.ndarray) -> np.ndarray:
    """The local y of a lip's outer border (landmarks ``indices``) at each x, held flat beyond the corners."""
    points = marks[list(indices)]
    order = np.argsort(points[:, 0])
    return np.interp(x, points[order, 0], points[order, 1])


def lip_roll_turns(mesh: FaceMesh, frame: FaceFrame, landmarks: np.ndarray) -> dict[str, tuple]:
    """Per lip (``"upper"``, ``"lower"``): (``{"in": …, "out": …}``, the turn ``g_v·c`` per vertex in [0, 1] (V,) of
    rolling in and out, the side shares ``(s_L, s_R)`` (V,) each, the pivot in local units (3,)), as in the module
    docstring."""
    local, below, _, half_width = contact_line(mesh, frame, landmarks)
    marks = local[landmarks]
    middle = 0.5 * (marks[62] + marks[66])
    sided = lip_sided(mesh, frame, local, landmarks, below)
    across = np.abs(local[:, 0] - middle[0]) / half_width
    near = np.linalg.norm(local - middle, axis=1) < REACH
    right = band_fade((local[:, 0] - middle[0]) / (SPLIT_WIDTH * half_width), (-1.0, 2.0))
    shares = (1.0 - right, right)
    out = {}
    for lip, border, inner, far, on_lip in (
        ("upper", _UPPER_BORDER, 62, 33, sided < 0.0),
        ("lower", _LOWER_BORDER, 66, 8, sided >= 0.0),
    ):
        outer = _border(marks, border, local[:, 0])
        span = abs(marks[far, 1] - marks[border[3], 1])  # from the border's middle (iBUG 51 / 57) to the nose (chin)
        beyond = (local[:, 1] - outer) if lip == "upper" else (outer - local[:, 1])
        turn = band_fade(np.maximum(beyond, 0.0) / span, SKIN_BAND) * (on_lip & near)
        pivot = np.array([middle[0], 0.0, marks[inner, 2]])
        pivot[1] = marks[inner, 1] + PIVOT_SHARE[lip] * (marks[far, 1] - marks[inner, 1])
        out[lip] = ({way: turn * band_fade(across, band) for way, band in CORNER_BAND.items()}, shares, pivot)
    return out


def default_lip_rolls(mesh: FaceMesh, frame: FaceFrame, landmarks: np.ndarray) -> list[LidMuscle]:
    """The eight lip hinges of the default rig, in :data:`LIP_ROLL_NAMES` order (module docstring)."""
    hinges = {}
    # a positive turn about +x moves a point in front of the pivot down: the upper lip rolls in, the lower rolls out
    signs = {
        ("upper", "in"): ROLL_IN,
        ("upper", "out"): -ROLL_OUT,
        ("lower", "in"): -ROLL_IN,
        ("lower", "out"): ROLL_OUT,
    }
    for lip, (turn, shares, pivot) in lip_roll_turns(mesh, frame, landmarks).items():
        centre = frame.to_world(pivot)
        for way in ("in", "out"):
            for side, share in zip(("L", "R"), shares):
                angles = signs[lip, way] * turn[way] * share
                moved = np.flatnonzero(angles != 0.0)
                name = f"lip_{lip}_roll_{way}_{side}"
                hinges[name] = LidMuscle(
                    name, centre, frame.axes[0], moved, angles[moved], fit_limit=ROLL_FIT_LIMIT[way]
                )
    return [hinges[name] for name in LIP_ROLL_NAMES]
