"""The default rig's eyelid hinges (docs/RIG.md §11), placed from the lid landmarks.

Per eye, in the :class:`~warpface.assets.frame.FaceFrame` (inter-ocular units): the eyeball's centre
``c`` lies :data:`EYEBALL_RADIUS` behind the mean depth of the four lid midpoints, at the mean (x, y)
of the eye's six landmarks; the hinge axis is the frame's x axis. A point's *lid angle* is
``α = atan2(y − c_y, z − c_z)`` (0 straight ahead, positive up). Over x, PCHIP curves through the
landmarks give the upper margin's angle ``α_u(x)`` (corners and iBUG 37/38 or 43/44) and the lower's
``α_l(x)``; the gap is ``Δ = α_u − α_l`` (0 at and beyond the corners) and the lids meet at
``α_m = α_l + f·Δ`` (``f`` = :data:`LOWER_SHARE`: in ICT-FaceKit's eyeBlink the lower lid hardly moves).

Three hinges per eye, ``θ_v`` per unit K (positive turns down), ``g`` a C¹ cos² fade, ``e = 1 − ε``:

- ``lid_upper_close_{s}`` (palpebral orbicularis, blink): lid skin above the margin turns by
  ``e·(α_u − α_m)·g(α − α_u)``, full over :data:`UPPER_BAND` then fading; a surface inside the opening
  (an eye a scan closed over) turns by ``e·(α − α_m)``, so at K = 1 the margin and everything between it
  and ``α_m`` lands within ``ε·Δ`` of the meeting line and no upper vertex passes below it.
- ``lid_lower_close_{s}``: the lower lid up to the meeting line, mirrored (:data:`LOWER_BAND`).
- ``lid_upper_raise_{s}`` (levator palpebrae, eyeWide): the upper lid up by ``RAISE·Δ``
  (:data:`RAISE_SHARE`, ICT's eyeWide), the skin above folding into the crease (:data:`RAISE_BAND`).

Every angle also fades with the distance ``ρ`` from the axis (:data:`RADIAL_BAND` eyeball radii), so
the brow and the cheek do not turn. The margins need not lie on one circle about the axis or straight
above each other: the upper margin also slides along the axis and lifts off it, so each lid midpoint
lands on its partner's (iBUG 37 on 41, 38 on 40, 43 on 47, 44 on 46); the centre is the point behind
the midpoint pairs most nearly equidistant from both points of each pair.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PchipInterpolator

from ..expression.lids import MAX_LID_ANGLE, LidMuscle
from ..mesh import FaceMesh
from .frame import FaceFrame

__all__ = [
    "LID_CONTROL_NAMES",
    "LidShape",
    "default_lids",
    "EYEBALL_RADIUS",
    "LOWER_SHARE",
    "RAISE_SHARE",
    "TAPER_SHARE",
    "LOWER_FIT_LIMIT",
]

EYEBALL_RADIUS = 0.19
"""The eyeball's radius [inter-ocular units]: 12 mm at a 63 mm inter-ocular distance."""
LOWER_SHARE = 0.10
"""Share of the lid gap the lower lid closes in a blink (ICT-FaceKit's eyeBlink: ~2 %)."""
RAISE_SHARE = 0.35
"""The levator's raise of the upper margin per unit K as a share of the gap (ICT's eyeWide: 2.9 of 8.3 mm)."""
CLOSURE = 0.99
"""``1 − ε``: the closing lids stop ``ε·Δ`` apart (0.1 mm on a 9 mm gap), so a surface a scan has across
the opening keeps a sliver of area."""
TAPER_SHARE = 1.0
"""Each hinge's ``taper_share`` (:func:`~warpface.expression.lids.hinge_taper`): a vertex that turns by at least this
share of the hinge's largest turn gets no wrinkle or bulge (docs/RIG.md §11, §14). 1: the plain taper. With the fold
guards' lift guard (§14) fading what folds and the upper lid meeting its partner's line, a scan's blink closes to
0.13 mm with it, while 0.5 (saturating at half the widest turn) folded 11 triangles of the ICT face's blink."""
LOWER_FIT_LIMIT = 2.0
"""``fit_limit`` of ``lid_lower_close_{s}``: a fit may raise the lower margin by twice its blink share (20 % of the
opening), as a squint or an upward look does (ICT's eyeLookUp fits K = 1.56 when free); the other hinges stop at 1
(docs/RIG.md §11, "Range in a fit")."""
UPPER_BAND = (0.35, 0.55)
"""Upper lid: angle above the margin [rad] turning fully, then the angle over which the turn fades."""
LOWER_BAND = (0.15, 0.40)
"""Lower lid: the same below its margin [rad]."""
RAISE_BAND = (0.15, 0.45)
"""Levator: the same above the upper margin [rad] (the skin above folds into the crease)."""
RADIAL_BAND = (1.35, 1.9)
"""Distance from the hinge axis [eyeball radii] turning fully, and where the turn has faded to 0."""


@dataclass(frozen=True)
class LidShape:
    """The hinges' shape constants (the module's defaults; the calibration's ``eyelids`` group moves them,
    docs/RIG.md §13): ``lower_share`` = f, ``raise_share``, the (full, fading) angle bands [rad] and the radial
    band [eyeball radii]."""

    lower_share: float = LOWER_SHARE
    raise_share: float = RAISE_SHARE
    upper_band: tuple[float, float] = UPPER_BAND
    lower_band: tuple[float, float] = LOWER_BAND
    raise_band: tuple[float, float] = RAISE_BAND
    radial_band: tuple[float, float] = RADIAL_BAND


_EYES = {"R": ((36, 37, 38, 39), (36, 41, 40, 39)), "L": ((42, 43, 44, 45), (42, 47, 46, 45))}
"""Side → (upper margin landmarks, lower margin landmarks), corners first and last."""

LID_CONTROL_NAMES: tuple[str, ...] = tuple(
    f"lid_{part}_{s}" for part in ("upper_close", "lower_close", "upper_raise") for s in ("L", "R")
)
"""The hinges' control names, in rig order."""


def _equidistant_centre(tops: np.ndarray, bottoms: np.ndarray) -> np.ndarray:
    """(y, z) of the hinge centre: as nearly equidistant from each (top, bottom) midpoint pair as least squares
    allows (so a turn brings the top onto the bottom), about :data:`EYEBALL_RADIUS` behind the pairs."""
    direction = tops - bottoms
    direction = direction / np.linalg.norm(direction, axis=1, keepdims=True)
    middle = 0.5 * (tops + bottoms)
    behind = np.array([middle[:, 0].mean(), middle[:, 1].mean() - EYEBALL_RADIUS])
    weight = 0.3  # the depth prior: keeps the centre near one eyeball radius back when the pairs are parallel
    rows = np.vstack([direction, weight * np.eye(2)[1:]])
    values = np.concatenate([np.sum(direction * middle, axis=1), [weight * behind[1]]])
    centre = np.linalg.lstsq(rows, values, rcond=None)[0]
    return centre


def _fade(t: np.ndarray, band: tuple[float, float]) -> np.ndarray:
    """1 for ``t ≤ band[0]``, ``cos²`` down to 0 at ``band[0] + band[1]``, 0 beyond (C¹)."""
    s = np.clip((t - band[0]) / band[1], 0.0, 1.0)
    return np.cos(0.5 * np.pi * s) ** 2


class _Eye:
    """One eye's hinge geometry in local coordinates (module docstring)."""

    def __init__(self, local_landmarks: np.ndarray, side: str, shape: LidShape):
        self.shape = shape
        upper, lower = _EYES[side]
        ring = local_landmarks[list(upper) + list(lower[1:3])]
        tops, bottoms = local_landmarks[list(upper[1:3])], local_landmarks[list(lower[1:3])]
        self.centre = np.array([ring[:, 0].mean(), *_equidistant_centre(tops[:, 1:], bottoms[:, 1:])])
        self._upper = self._curve(local_landmarks[list(upper)])
        self._lower = self._curve(local_landmarks[list(lower)])
        self._upper_y = self._curve(local_landmarks[list(upper)], height=True)
        self._lower_y = self._curve(local_landmarks[list(lower)], height=True)
        corners = local_landmarks[[upper[0], upper[3]], 0]
        # the lateral slide and the lift off the axis that bring each margin midpoint onto its partner on the other lid
        offset = bottoms[:, 0] - tops[:, 0]
        lift = EYEBALL_RADIUS * (self.radius(bottoms) - self.radius(tops))
        self._offset = self._knots(corners, tops[:, 0], offset)
        f = shape.lower_share
        self._upper_slide = self._knots(corners, tops[:, 0], (1.0 - f) * offset)
        self._lower_slide = self._knots(corners, bottoms[:, 0], -f * offset)
        self._upper_lift = self._knots(corners, tops[:, 0], (1.0 - f) * lift)
        self._lower_lift = self._knots(corners, bottoms[:, 0], -f * lift)

    @staticmethod
    def _knots(corners: np.ndarray, x: np.ndarray, values: np.ndarray) -> PchipInterpolator:
        knots_x, knots_v = np.concatenate([corners, x]), np.concatenate([[0.0, 0.0], values])
        order = np.argsort(knots_x)
        return PchipInterpolator(knots_x[order], knots_v[order], extrapolate=False)

    def slides(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The upper and the lower margin's slide along x and lift off the axis at full closure [inter-ocular
        units]."""
        curves = (self._upper_slide, self._lower_slide, self._upper_lift, self._lower_lift)
        return tuple(np.nan_to_num(curve(x)) for curve in curves)

    def partner_meeting(self, x: np.ndarray) -> np.ndarray:
        """The meeting angle ``α_m`` where the upper margin at each x lands: at ``x + o(x)``, ``o`` the lateral offset
        from an upper margin midpoint to its lower partner (0 at the corners), so a midpoint meets its partner
        where the meeting line slopes along x (0 beyond the corners)."""
        partner = x + np.nan_to_num(self._offset(x))
        upper, lower, gap = self.margins(partner)
        return lower + self.shape.lower_share * gap

    def angle(self, local: np.ndarray) -> np.ndarray:
        return np.arctan2(local[..., 1] - self.centre[1], local[..., 2] - self.centre[2])

    def radius(self, local: np.ndarray) -> np.ndarray:
        return np.hypot(local[..., 1] - self.centre[1], local[..., 2] - self.centre[2]) / EYEBALL_RADIUS

    def _curve(self, points: np.ndarray, height: bool = False) -> PchipInterpolator:
        order = np.argsort(points[:, 0])
        values = points[order, 1] if height else self.angle(points[order])
        return PchipInterpolator(points[order, 0], values, extrapolate=False)

    def in_opening(self, local: np.ndarray) -> np.ndarray:
        """Whether each point lies between the margins seen from the front (local y between their curves)."""
        top, bottom = self._upper_y(local[:, 0]), self._lower_y(local[:, 0])
        return np.nan_to_num(local[:, 1] < top) & np.nan_to_num(local[:, 1] > bottom)

    def heights(self, x: np.ndarray) -> np.ndarray:
        """The upper and the lower margin's local y at each x (NaN beyond the corners), shape (2, n)."""
        return np.stack([self._upper_y(x), self._lower_y(x)])

    def margins(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(α_u, α_l, Δ)`` at each x; the gap is 0 outside the corners."""
        upper, lower = self._upper(x), self._lower(x)
        gap = np.nan_to_num(np.maximum(upper - lower, 0.0))
        return np.nan_to_num(upper), np.nan_to_num(lower), gap


def _hinge_angles(eye: _Eye, local: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """(θ [rad], lateral slide, lift [inter-ocular units]) per vertex and unit K of one eye's three hinges
    (module docstring); slide and lift follow the turn's share of the margin's."""
    shape = eye.shape
    upper, lower, gap = eye.margins(local[:, 0])
    meet = lower + shape.lower_share * gap
    landing = eye.partner_meeting(local[:, 0])  # where the upper lid meets the lower one
    alpha = eye.angle(local)
    radial = _fade(eye.radius(local), (shape.radial_band[0], shape.radial_band[1] - shape.radial_band[0]))
    radial = np.where(local[:, 2] > eye.centre[2], radial, 0.0) * (gap > 0.0)
    # lid skin: beyond a margin's angle, or seen from the front above (below) the opening even where the skin's
    # fold puts it at a smaller (larger) angle; only what lies in the opening from the front is inside
    opening = eye.in_opening(local)
    high = local[:, 1] >= 0.5 * (eye.heights(local[:, 0]).sum(axis=0))
    above = (alpha >= upper) | (~opening & high)
    below = ~above & ((alpha <= lower) | ~opening)
    inside_upper = ~above & ~below & (alpha >= meet)
    inside_lower = ~above & ~below & (alpha < meet)
    over, under = np.maximum(alpha - upper, 0.0), np.maximum(lower - alpha, 0.0)
    close_upper = np.where(above, (upper - landing) * _fade(over, shape.upper_band), 0.0)
    close_upper = np.where(inside_upper, alpha - landing, close_upper)
    close_lower = np.where(below, (lower - meet) * _fade(under, shape.lower_band), 0.0)
    close_lower = np.where(inside_lower, alpha - meet, close_lower)
    raise_upper = np.where(above, -shape.raise_share * gap * _fade(over, shape.raise_band), 0.0)
    share = np.divide(alpha - meet, upper - meet, out=np.zeros_like(alpha), where=upper - meet > 0.0)
    raise_upper = np.where(inside_upper, -shape.raise_share * gap * share, raise_upper)
    upper_slide, lower_slide, upper_lift, lower_lift = eye.slides(local[:, 0])
    share_upper = np.divide(close_upper, upper - landing, out=np.zeros_like(alpha), where=upper - landing > 0.0)
    share_lower = np.divide(close_lower, lower - meet, out=np.zeros_like(alpha), where=meet - lower > 0.0)
    upper_share, lower_share = CLOSURE * share_upper * radial, CLOSURE * share_lower * radial
    return {
        "upper_close": (CLOSURE * close_upper * radial, upper_slide * upper_share, upper_lift * upper_share),
        "lower_close": (CLOSURE * close_lower * radial, lower_slide * lower_share, lower_lift * lower_share),
        "upper_raise": (raise_upper * radial, np.zeros_like(alpha), np.zeros_like(alpha)),
    }


def _eyes(mesh: FaceMesh, frame: FaceFrame, landmarks: np.ndarray, shape: LidShape):
    local_landmarks = frame.to_local(mesh.points[landmarks])
    return frame.to_local(mesh.points), {side: _Eye(local_landmarks, side, shape) for side in _EYES}


def default_lids(
    mesh: FaceMesh, frame: FaceFrame, landmarks: np.ndarray, shape: LidShape | None = None
) -> list[LidMuscle]:
    """The six :class:`~warpface.expression.LidMuscle` hinges of the default rig, in :data:`LID_CONTROL_NAMES`
    order (module docstring); ``shape``: the constants (default: the module's)."""
    local, eyes = _eyes(mesh, frame, landmarks, shape or LidShape())
    hinges = {}
    for side, eye in eyes.items():
        centre = frame.to_world(eye.centre)
        for part, (angles, slides, lifts) in _hinge_angles(eye, local).items():
            moved = np.flatnonzero(angles != 0.0)
            angles = np.clip(angles, -MAX_LID_ANGLE, MAX_LID_ANGLE)  # misplaced lid landmarks: docs/RIG.md §11
            name = f"lid_{part}_{side}"
            slides, lifts = slides[moved] * frame.scale, lifts[moved] * frame.scale
            limit = LOWER_FIT_LIMIT if part == "lower_close" else 1.0
            hinges[name] = LidMuscle(
                name,
                centre,
                frame.axes[0],
                moved,
                angles[moved],
                slides,
                lifts,
                taper_share=TAPER_SHARE,
                fit_limit=limit,
            )
    return [hinges[name] for name in LID_CONTROL_NAMES]
