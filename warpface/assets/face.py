"""A procedural human face surface, generated entirely by code (no scanned or third-party data).

Construction, in four steps:

1. **Parameter plane.** A point is addressed by ``(θ, y)``: ``θ`` the angle around the head's
   vertical axis (0 = straight ahead, +θ toward +x, the subject's left) and ``y`` the height [m].
   A hexagonal lattice is laid over the face's outline in ``(s, y)``, where ``s`` is an arc-length-like
   coordinate that is finer in front (|θ| < 45°) than at the sides, so the resolution goes where
   the features and wrinkles are.
2. **Holes.** The eye openings and the mouth slit are closed curves in front-view coordinates
   ``(x, y)``. Lattice points inside or within ``0.7 h`` of a curve (or of the outline) are dropped
   and the curves are sampled at spacing ``h`` instead, so a Delaunay triangulation of the plane
   contains the curves as edges (their diametral circles are empty); triangles inside a hole or
   outside the outline are then removed. This gives smooth lid and lip margins and a manifold surface
   with four boundary loops (outline, two eyes, mouth).
3. **Base head.** Each ``(θ, y)`` maps to a horizontal ellipse of half-width ``a(y)`` and depth
   ``b(y)`` whose front lies at ``z = F(y)``: the coarse head and jaw shape.
4. **Features.** Smooth bumps and grooves (brow ridge, orbits, lids, nose, cheeks, lips, chin …) are
   summed into a height ``H(x, y)`` and added along the base surface's normal.

Units are metres, +y up, +z toward the viewer, the subject's left at +x (DESIGN.md). The head's
vertical axis is the line x = z = 0; y = 0 is the level of the eye corners. The face is ~0.21 m
tall (hairline to under the chin) and symmetric: every vertex has a mirror twin.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..geometry.ramps import smooth_ramp
from ..landmarks import IBUG_NAMES, INNER_LIPS, LEFT_EYE, RIGHT_EYE
from ..mesh import FaceMesh

__all__ = ["default_face", "default_landmarks", "LANDMARK_NAMES", "FACE_SPACING"]

FACE_SPACING = 0.002
"""Lattice spacing in the front of the face [m] (edges ~2 mm); it grows to 1.5× at the sides."""

_SIDE_SPACING_RATIO = 1.5
_FINE_HALF_ANGLE = np.radians(45.0)
_COARSE_HALF_ANGLE = np.radians(65.0)
_ARC_RADIUS = 0.08
"""Converts the angle θ into an arc-length-like lattice coordinate s = R·∫ dθ / ratio(θ) [m]."""
_BOUNDARY_CLEARANCE = 0.7
"""Lattice points closer than this × spacing to a hole or the outline are replaced by curve samples."""

LANDMARK_NAMES = IBUG_NAMES
"""Names of the 68 iBUG / Multi-PIE landmarks, in iBUG order (:data:`warpface.landmarks.IBUG_NAMES`)."""


# ------------------------------------------------------------------------------------------------
# Anatomical layout [m]. Proportions follow common anthropometric ratios for an adult face with an
# inter-ocular (eye-centre) distance of 63 mm; only the right half (x ≥ 0 mirrored) is written down.


@dataclass(frozen=True)
class _Eye:
    inner: tuple[float, float] = (0.0200, -0.0010)
    outer: tuple[float, float] = (0.0505, 0.0020)
    upper_height: float = 0.0058
    """Upper-lid margin above the corner line at its apex."""
    lower_height: float = 0.0040
    upper_apex: float = 0.45
    """Fraction of the way from the inner to the outer corner at which the upper lid peaks."""
    lower_apex: float = 0.56

    def lids(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Front-view ``x`` and the upper/lower margin ``y`` at fractions ``t`` ∈ [0, 1] (inner → outer)."""
        t = np.clip(t, 0.0, 1.0)
        x = self.inner[0] + t * (self.outer[0] - self.inner[0])
        line = self.inner[1] + t * (self.outer[1] - self.inner[1])
        up = np.sin(np.pi * t ** (np.log(0.5) / np.log(self.upper_apex))) ** 0.75
        down = np.sin(np.pi * t ** (np.log(0.5) / np.log(self.lower_apex))) ** 0.85
        return x, line + self.upper_height * up, line - self.lower_height * down

    @property
    def center(self) -> tuple[float, float]:
        return (0.5 * (self.inner[0] + self.outer[0]), 0.5 * (self.inner[1] + self.outer[1]) + 0.0008)


@dataclass(frozen=True)
class _Mouth:
    corner: tuple[float, float] = (0.0250, -0.0655)
    """Mouth corner (the end of the slit)."""
    stomion: float = -0.0665
    """Height of the lip line at the midline."""
    gap: float = 0.0022
    """Opening of the slit at the midline (lips slightly parted)."""
    upper_vermilion: float = 0.0085
    lower_vermilion: float = 0.0100

    def line(self, x: np.ndarray) -> np.ndarray:
        """Height of the lip line at ``x`` (rises slightly toward the corners)."""
        t = np.clip(np.abs(x) / self.corner[0], 0.0, 1.0)
        return self.stomion + (self.corner[1] - self.stomion) * t**2

    def slit(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Upper and lower margin of the opening at ``x``."""
        t = np.clip(np.abs(x) / self.corner[0], 0.0, 1.0)
        half = 0.5 * self.gap * (1.0 - t**2) ** 0.7
        middle = self.line(x)
        return middle + 0.8 * half, middle - 1.2 * half

    def vermilion(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Upper-lip border (with the Cupid's bow) and lower-lip border heights at ``x``."""
        X = np.abs(x)
        t = np.clip(X / self.corner[0], 0.0, 1.0)
        upper = self.upper_vermilion * (1.0 - t**2) ** 0.55 * (1.0 - 0.18 * np.exp(-((X / 0.0035) ** 2)))
        upper = upper + 0.0012 * np.exp(-(((X - 0.0065) / 0.003) ** 2))
        lower = self.lower_vermilion * (1.0 - t**2.2) ** 0.6
        line = self.line(x)
        return line + upper, line - lower


_EYE = _Eye()
_MOUTH = _Mouth()
_BROW = ((0.060, 0.0200), (0.051, 0.0260), (0.040, 0.0285), (0.029, 0.0270), (0.017, 0.0225))
"""iBUG brow points 17–21 of the right brow as (|x|, y), outer → inner."""
_NOSE_BRIDGE_Y = (0.004, -0.008, -0.019, -0.031)
_NOSE_BASE = ((0.0115, -0.0405), (0.0058, -0.0437), (0.0, -0.0450))
_JAW = (
    (0.0710, 0.0000),
    (0.0700, -0.0200),
    (0.0675, -0.0395),
    (0.0640, -0.0585),
    (0.0570, -0.0775),
    (0.0455, -0.0935),
    (0.0320, -0.1040),
    (0.0165, -0.1105),
    (0.0, -0.1125),
)
"""iBUG jaw points 0–8 as (|x|, y): the face's front-view contour, ear level to chin."""


# ------------------------------------------------------------------------------------------------
# Base head: horizontal ellipses x = a(y)·sin θ, z = F(y) − b(y)·(1 − cos θ).


def _smooth_table(knots_y, values):
    """A C¹ monotone-preserving interpolant of a height profile (PCHIP)."""
    from scipy.interpolate import PchipInterpolator

    return PchipInterpolator(np.asarray(knots_y, float), np.asarray(values, float), extrapolate=True)


@functools.lru_cache(maxsize=1)
def _profiles():
    half_width = _smooth_table(
        [-0.15, -0.13, -0.10, -0.07, -0.04, -0.01, 0.02, 0.05, 0.08, 0.10, 0.12],
        [0.044, 0.050, 0.057, 0.064, 0.0695, 0.0715, 0.0715, 0.0700, 0.0665, 0.0620, 0.055],
    )
    front = _smooth_table(
        [-0.15, -0.13, -0.115, -0.10, -0.08, -0.06, -0.03, 0.0, 0.02, 0.04, 0.06, 0.08, 0.095, 0.12],
        [0.058, 0.068, 0.078, 0.085, 0.089, 0.091, 0.090, 0.091, 0.093, 0.092, 0.088, 0.080, 0.071, 0.052],
    )
    depth = _smooth_table(
        [-0.15, -0.10, -0.05, 0.0, 0.05, 0.10, 0.12],
        [0.070, 0.080, 0.086, 0.090, 0.092, 0.092, 0.090],
    )
    return half_width, front, depth


def _base_surface(theta: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Base head points and unit outward normals at ``(θ, y)``, each shape (N, 3)."""
    a_of, f_of, b_of = _profiles()
    a, f, b = a_of(y), f_of(y), b_of(y)
    da, df, db = a_of(y, 1), f_of(y, 1), b_of(y, 1)
    s, c = np.sin(theta), np.cos(theta)
    points = np.stack([a * s, y, f - b * (1.0 - c)], axis=1)
    d_theta = np.stack([a * c, np.zeros_like(y), -b * s], axis=1)
    d_y = np.stack([da * s, np.ones_like(y), df - db * (1.0 - c)], axis=1)
    normals = np.cross(d_theta, d_y)
    return points, normals / np.linalg.norm(normals, axis=1, keepdims=True)


def _front_x(theta: np.ndarray, y: np.ndarray) -> np.ndarray:
    return _profiles()[0](y) * np.sin(theta)


def _theta_of_front_x(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.arcsin(np.clip(x / _profiles()[0](y), -1.0, 1.0))


# ------------------------------------------------------------------------------------------------
# Lattice coordinate s(θ): arc-length-like, spacing ratio 1 in front growing to 1.5 at the sides.


@functools.lru_cache(maxsize=1)
def _s_table() -> tuple[np.ndarray, np.ndarray]:
    theta = np.linspace(0.0, np.pi, 2049)
    blend = np.clip((theta - _FINE_HALF_ANGLE) / (_COARSE_HALF_ANGLE - _FINE_HALF_ANGLE), 0.0, 1.0)
    ratio = 1.0 + (_SIDE_SPACING_RATIO - 1.0) * blend * blend * (3.0 - 2.0 * blend)
    ds = _ARC_RADIUS / ratio
    s = np.concatenate([[0.0], np.cumsum(0.5 * (ds[1:] + ds[:-1]) * np.diff(theta))])
    return theta, s


def _s_of_theta(theta: np.ndarray) -> np.ndarray:
    table_theta, table_s = _s_table()
    return np.sign(theta) * np.interp(np.abs(theta), table_theta, table_s)


def _theta_of_s(s: np.ndarray) -> np.ndarray:
    table_theta, table_s = _s_table()
    return np.sign(s) * np.interp(np.abs(s), table_s, table_theta)


# ------------------------------------------------------------------------------------------------
# Outline (in θ, y) and hole curves (in front-view x, y).

_OUTLINE_TOP = ((0.0, 0.096), (30.0, 0.094), (50.0, 0.088), (65.0, 0.077), (78.0, 0.062), (88.0, 0.045))
_OUTLINE_BOTTOM = (
    (0.0, -0.1245),
    (15.0, -0.1225),
    (30.0, -0.1150),
    (45.0, -0.1030),
    (58.0, -0.0910),
    (68.0, -0.0800),
    (78.0, -0.0600),
    (86.0, -0.0350),
    (88.0, -0.0200),
)
_OUTLINE_SIDE_DEG = 88.0


@functools.lru_cache(maxsize=1)
def _outline_tables():
    top, bottom = np.array(_OUTLINE_TOP), np.array(_OUTLINE_BOTTOM)
    return _smooth_table(np.radians(top[:, 0]), top[:, 1]), _smooth_table(np.radians(bottom[:, 0]), bottom[:, 1])


def _inside_outline(theta: np.ndarray, y: np.ndarray) -> np.ndarray:
    top, bottom = _outline_tables()
    t = np.abs(theta)
    return (t < np.radians(_OUTLINE_SIDE_DEG)) & (y < top(t)) & (y > bottom(t))


def _outline_curve_half(samples: int = 4000) -> np.ndarray:
    """Right-going half of the outline in (θ, y), from the top centre to the bottom centre."""
    top, bottom = _outline_tables()
    side = np.radians(_OUTLINE_SIDE_DEG)
    t = np.linspace(0.0, side, samples)
    upper = np.stack([t, top(t)], axis=1)
    y_side = np.linspace(top(side), bottom(side), samples // 8)[1:-1]
    lower = np.stack([t[::-1], bottom(t[::-1])], axis=1)
    return np.concatenate([upper, np.stack([np.full_like(y_side, side), y_side], axis=1), lower])


def _eye_curve(samples: int = 2000) -> np.ndarray:
    """Closed right-eye margin (x > 0 mirror image of the subject's left eye) in front-view (x, y)."""
    t = 0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, samples))
    x, upper, lower = _EYE.lids(t)
    return np.concatenate([np.stack([x, upper], 1), np.stack([x[::-1], lower[::-1]], 1)[1:-1]])


def _inside_eye(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    X = np.abs(x)
    t = (X - _EYE.inner[0]) / (_EYE.outer[0] - _EYE.inner[0])
    _, upper, lower = _EYE.lids(t)
    return (t > 0.0) & (t < 1.0) & (y < upper) & (y > lower)


def _mouth_curve_half(samples: int = 2000) -> np.ndarray:
    """Right half of the mouth opening in (x, y): upper margin from the midline to the corner, then back."""
    x = _MOUTH.corner[0] * np.sin(np.linspace(0.0, np.pi / 2, samples))
    upper, lower = _MOUTH.slit(x)
    return np.concatenate([np.stack([x, upper], 1), np.stack([x[::-1], lower[::-1]], 1)[1:]])


def _inside_mouth(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    upper, lower = _MOUTH.slit(x)
    return (np.abs(x) < _MOUTH.corner[0]) & (y < upper) & (y > lower)


# ------------------------------------------------------------------------------------------------
# Feature height field H(x, y) [m], added along the base normal.


def _gauss(X, y, cx, cy, sx, sy):
    return np.exp(-0.5 * (((X - cx) / sx) ** 2 + ((y - cy) / sy) ** 2))


def _skewed_bump(v, peak, below, above):
    """A smooth bump of height 1 at ``peak`` with Gaussian widths ``below`` and ``above`` on each side."""
    width = np.where(v < peak, below, above)
    return np.exp(-(((v - peak) / width) ** 2))


def _curve_distance(curve: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    from scipy.spatial import cKDTree

    distance, _ = cKDTree(curve).query(np.stack([x, y], axis=1))
    return distance


@functools.lru_cache(maxsize=1)
def _dense_curves():
    eye = _eye_curve()
    mouth = _mouth_curve_half()
    return eye, np.concatenate([mouth, mouth[::-1] * [-1.0, 1.0]])


def _heights(x: np.ndarray, y: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Feature height [m] at front-view ``(x, y)`` (θ for the roll-under at the outline)."""
    X = np.abs(x)
    eye_curve, mouth_curve = _dense_curves()
    h = np.zeros_like(x)

    # Forehead: gentle frontal eminences, flat temples.
    h += 0.0022 * _gauss(X, y, 0.028, 0.062, 0.020, 0.020)
    h -= 0.0045 * _gauss(X, y, 0.068, 0.030, 0.010, 0.022)

    # Brow ridge and glabella, nasion dip below it.
    h += 0.0050 * _gauss(X, y, 0.027, 0.0215, 0.019, 0.0075)
    h += 0.0030 * _gauss(X, y, 0.050, 0.0200, 0.012, 0.0070)
    h += 0.0030 * _gauss(X, y, 0.000, 0.0200, 0.012, 0.0100)

    # Orbit: a recess around the eye, the eyeball bulging the lids, lid margins tucked in.
    cx, cy = _EYE.center
    h -= 0.0115 * _gauss(X, y, cx, cy + 0.001, 0.0165, 0.0115)
    h += 0.0048 * np.exp(-0.5 * (((X - cx) / 0.0125) ** 2 + ((y - cy) / 0.0105) ** 2) ** 1.5)
    eye_distance = np.where(_inside_eye(x, y), 0.0, _curve_distance(eye_curve, X, y))
    h -= 0.0032 * np.exp(-((eye_distance / 0.0026) ** 2))
    h += 0.0010 * np.exp(-(((eye_distance - 0.0035) / 0.0022) ** 2))
    lid_span = smooth_ramp(_EYE.inner[0] - 0.008, _EYE.inner[0], X) * smooth_ramp(
        _EYE.outer[0] + 0.010, _EYE.outer[0] + 0.002, X
    )
    above = smooth_ramp(cy - 0.002, cy + 0.003, y)
    h -= 0.0012 * lid_span * above * np.exp(-(((eye_distance - 0.0075) / 0.0018) ** 2))  # upper-lid crease
    h -= 0.0007 * lid_span * (1.0 - above) * np.exp(-(((eye_distance - 0.0085) / 0.0025) ** 2))  # lower-lid edge

    # Cheeks: malar fat pad and cheekbone.
    h += 0.0075 * _gauss(X, y, 0.040, -0.030, 0.016, 0.015)
    h += 0.0040 * _gauss(X, y, 0.055, -0.012, 0.012, 0.010)
    h -= 0.0025 * _gauss(X, y, 0.058, -0.055, 0.010, 0.018)  # under the cheekbone

    # Nose: dorsum with a height profile and a width profile, rounded tip, alae, nostrils.
    dorsum = np.interp(
        y,
        [-0.048, -0.044, -0.040, -0.034, -0.031, -0.020, -0.008, 0.004, 0.014, 0.022],
        [0.000, 0.008, 0.0165, 0.0215, 0.0222, 0.0170, 0.0118, 0.0072, 0.0040, 0.0],
    )
    width = np.interp(y, [-0.048, -0.040, -0.030, -0.015, 0.0, 0.012], [0.0085, 0.0100, 0.0085, 0.0068, 0.0060, 0.0080])
    h += dorsum * np.exp(-(np.abs(x / width) ** 2.2))
    h += 0.0030 * _gauss(X, y, 0.0, -0.0335, 0.0068, 0.0058)
    h += 0.0068 * _gauss(X, y, 0.0135, -0.0395, 0.0052, 0.0048)
    alar_ring = np.hypot((X - 0.0135) / 1.05, y + 0.0395)
    # Features narrower than ~1.2 lattice spacings (2 mm) alias into lumps: widths stay above that,
    # and no feature is cut off by a step.
    h -= 0.0014 * np.exp(-(((alar_ring - 0.0068) / 0.0024) ** 2)) * smooth_ramp(-0.049, -0.043, y)
    h -= 0.0026 * _gauss(X, y, 0.0058, -0.0432, 0.0032, 0.0024)

    # Upper lip: maxillary protrusion, philtrum, vermilion.
    h += 0.0065 * _gauss(X, y, 0.0, -0.066, 0.024, 0.020)
    h += 0.0005 * _gauss(X, y, 0.0045, -0.052, 0.0028, 0.006)
    h -= 0.0004 * _gauss(X, y, 0.0, -0.052, 0.0030, 0.006)
    line = _MOUTH.line(x)
    upper_border, lower_border = _MOUTH.vermilion(x)
    corner_fade = smooth_ramp(_MOUTH.corner[0] * 1.05, _MOUTH.corner[0] * 0.55, X)
    v = (y - line) / np.maximum(upper_border - line, 0.002)  # 0 at the lip line, 1 at the upper border
    h += 0.0038 * corner_fade * _skewed_bump(v, 0.70, 0.45, 0.95) * (v > 0.0)
    v = (line - y) / np.maximum(line - lower_border, 0.002)  # 0 at the lip line, 1 at the lower border
    h += 0.0062 * corner_fade * _skewed_bump(v, 0.45, 0.42, 0.62) * (v > 0.0)
    mouth_distance = np.where(_inside_mouth(x, y), 0.0, _curve_distance(mouth_curve, x, y))
    h -= 0.0022 * np.exp(-((mouth_distance / 0.0026) ** 2))
    h += 0.0010 * _gauss(X, y, _MOUTH.corner[0] + 0.003, _MOUTH.corner[1] - 0.001, 0.004, 0.005)  # modiolus

    # Nasolabial fold: the cheek stands proud lateral to the line from the nose wing past the mouth.
    a0, a1 = np.array([0.0185, -0.0400]), np.array([0.0330, -0.0760])
    direction = (a1 - a0) / np.linalg.norm(a1 - a0)
    rel_x, rel_y = X - a0[0], y - a0[1]
    along = rel_x * direction[0] + rel_y * direction[1]
    across = rel_x * direction[1] - rel_y * direction[0]
    span = np.exp(-(((along - 0.018) / 0.022) ** 4))
    h += 0.0035 * span * smooth_ramp(-0.002, 0.008, across) * np.exp(-np.maximum(across - 0.008, 0.0) / 0.02)

    # Chin: mentolabial sulcus, then the chin boss.
    h -= 0.0036 * _gauss(X, y, 0.0, -0.0845, 0.018, 0.0045)
    h += 0.0085 * _gauss(X, y, 0.0, -0.1010, 0.0160, 0.0115)

    # Jaw line: roll the surface under along the lower outline so it ends in a rounded edge.
    _, bottom = _outline_tables()
    above_bottom = y - bottom(np.abs(theta))
    under = smooth_ramp(np.radians(75.0), np.radians(55.0), np.abs(theta))
    h -= 0.010 * under * (1.0 - smooth_ramp(0.0, 0.016, above_bottom)) ** 2
    return h


# ------------------------------------------------------------------------------------------------
# Triangulation.


def _resample(curve: np.ndarray, spacing: float, closed: bool) -> np.ndarray:
    """Points at equal arc length ``≈ spacing`` along a polyline (endpoints kept when open)."""
    path = np.concatenate([curve, curve[:1]]) if closed else curve
    lengths = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    count = max(int(round(lengths[-1] / spacing)), 3)
    targets = np.linspace(0.0, lengths[-1], count + 1)
    if closed:
        targets = targets[:-1]
    return np.stack([np.interp(targets, lengths, path[:, k]) for k in range(2)], axis=1)


def _front_to_lattice(curve_xy: np.ndarray) -> np.ndarray:
    theta = _theta_of_front_x(curve_xy[:, 0], curve_xy[:, 1])
    return np.stack([_s_of_theta(theta), curve_xy[:, 1]], axis=1)


def _boundary_samples(spacing: float) -> list[np.ndarray]:
    """Boundary curves sampled at ``spacing`` in the lattice plane (s, y), mirror-symmetric.

    Returns [outline, right eye, left eye, mouth], each (n, 2), ordered along the curve.
    """
    outline = _outline_curve_half()
    outline = np.stack([_s_of_theta(outline[:, 0]), outline[:, 1]], axis=1)
    half = _resample(outline, spacing, closed=False)
    outline = np.concatenate([half, half[-2:0:-1] * [-1.0, 1.0]])

    eye = _resample(_front_to_lattice(_eye_curve()), spacing, closed=True)
    eye_left = eye
    eye_right = eye[::-1] * [-1.0, 1.0]

    mouth_half = _resample(_front_to_lattice(_mouth_curve_half()), spacing, closed=False)
    mouth = np.concatenate([mouth_half, mouth_half[-2:0:-1] * [-1.0, 1.0]])
    return [outline, eye_right, eye_left, mouth]


def _inside_domain(s: np.ndarray, y: np.ndarray) -> np.ndarray:
    theta = _theta_of_s(s)
    x = _front_x(theta, y)
    return _inside_outline(theta, y) & ~_inside_eye(x, y) & ~_inside_mouth(x, y)


@functools.lru_cache(maxsize=1)
def _build() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (V, 3) float64, triangles (T, 3) int32 and the 68 landmark vertex indices."""
    from scipy.spatial import Delaunay, cKDTree

    h = FACE_SPACING
    curves = _boundary_samples(h)
    boundary = np.concatenate(curves)
    curve_id = np.concatenate([np.full(len(c), k) for k, c in enumerate(curves)])

    # Hexagonal lattice, symmetric about s = 0 (even rows hold s = 0, odd rows ±h/2).
    s_max = float(_s_of_theta(np.radians(_OUTLINE_SIDE_DEG))) + h
    row_height = h * np.sqrt(3.0) / 2.0
    rows = np.arange(np.floor(-0.135 / row_height), np.ceil(0.105 / row_height) + 1)
    columns = np.arange(-np.ceil(s_max / h), np.ceil(s_max / h) + 1)
    col, row = np.meshgrid(columns, rows)
    lattice = np.stack([(col + 0.5 * (row % 2 != 0)) * h, row * row_height], axis=-1).reshape(-1, 2)
    lattice = lattice[_inside_domain(lattice[:, 0], lattice[:, 1])]
    dense = np.concatenate([_resample(c, h / 12.0, closed=k != 0) for k, c in enumerate(curves)])
    clearance, _ = cKDTree(dense).query(lattice)
    lattice = lattice[clearance > _BOUNDARY_CLEARANCE * h]

    plane = np.concatenate([boundary, lattice])
    on_curve = np.concatenate([curve_id, np.full(len(lattice), -1)])
    triangles = Delaunay(plane).simplices
    ids = on_curve[triangles]
    same_curve = (ids[:, 0] >= 0) & (ids[:, 0] == ids[:, 1]) & (ids[:, 1] == ids[:, 2])
    centroid = plane[triangles].mean(axis=1)
    keep = ~same_curve & _inside_domain(centroid[:, 0], centroid[:, 1])
    triangles = triangles[keep]

    used = np.zeros(len(plane), dtype=bool)
    used[triangles.reshape(-1)] = True
    remap = np.cumsum(used) - 1
    plane = plane[used]
    triangles = remap[triangles]

    theta = _theta_of_s(plane[:, 0])
    base, normal = _base_surface(theta, plane[:, 1])
    x = base[:, 0]
    points = base + _heights(x, plane[:, 1], theta)[:, None] * normal

    # Orient every triangle outward (+z in front): the (s, y) plane maps with positive orientation.
    p = plane[triangles]
    signed = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 1, 1] - p[:, 0, 1]) * (
        p[:, 2, 0] - p[:, 0, 0]
    )
    triangles = np.where((signed < 0.0)[:, None], triangles[:, [0, 2, 1]], triangles)

    landmarks = _landmark_vertices(plane, used[: len(boundary)], curves)
    return points, triangles.astype(np.int32), landmarks


# ------------------------------------------------------------------------------------------------
# Landmarks.


def _landmark_targets() -> np.ndarray:
    """Front-view (x, y) of the 68 iBUG landmarks [m]; −x is the subject's right."""
    targets = np.zeros((68, 2))
    jaw = np.array(_JAW)
    targets[0:9] = jaw * [-1.0, 1.0]
    targets[9:17] = jaw[7::-1]
    brow = np.array(_BROW)
    targets[17:22] = brow * [-1.0, 1.0]
    targets[22:27] = brow[::-1]
    targets[27:31] = np.stack([np.zeros(4), _NOSE_BRIDGE_Y], axis=1)
    base = np.array(_NOSE_BASE)
    targets[31:34] = base * [-1.0, 1.0]
    targets[34:36] = base[1::-1]
    fractions = np.array([1.0, 2 / 3, 1 / 3, 0.0])
    x, upper, lower = _EYE.lids(fractions)
    _, _, lower_mid = _EYE.lids(np.array([1 / 3, 2 / 3]))
    right_eye = np.array(
        [
            [x[0], upper[0]],
            [x[1], upper[1]],
            [x[2], upper[2]],
            [x[3], upper[3]],
            [x[2], lower_mid[0]],
            [x[1], lower_mid[1]],
        ]
    )
    targets[36:42] = right_eye * [-1.0, 1.0]
    targets[42:48] = right_eye[[3, 2, 1, 0, 5, 4]]
    # Outer lip contour 48–59: corners just outside the slit, upper border 49–53, lower border 55–59.
    corner = np.array([_MOUTH.corner[0] + 0.002, _MOUTH.corner[1]])
    upper_x = np.array([0.0170, 0.0068, 0.0])
    upper_y = _MOUTH.vermilion(upper_x)[0]
    lower_x = np.array([0.0180, 0.0100, 0.0])
    lower_y = _MOUTH.vermilion(lower_x)[1]
    targets[48] = corner * [-1.0, 1.0]
    targets[49:52] = np.stack([-upper_x, upper_y], axis=1)
    targets[52:54] = np.stack([upper_x[1::-1], upper_y[1::-1]], axis=1)
    targets[54] = corner
    targets[55:58] = np.stack([lower_x, lower_y], axis=1)
    targets[58:60] = np.stack([-lower_x[1::-1], lower_y[1::-1]], axis=1)
    # Inner contour 60–67 on the margin of the opening.
    top, bottom = _MOUTH.slit(np.array([0.0100, 0.0]))
    targets[60] = (-_MOUTH.corner[0], _MOUTH.corner[1])
    targets[61:64] = [(-0.0100, top[0]), (0.0, top[1]), (0.0100, top[0])]
    targets[64] = _MOUTH.corner
    targets[65:68] = [(0.0100, bottom[0]), (0.0, bottom[1]), (-0.0100, bottom[0])]
    return targets


def _landmark_vertices(plane: np.ndarray, boundary_used: np.ndarray, curves: list[np.ndarray]) -> np.ndarray:
    """Vertex index of each landmark: the nearest vertex in the lattice plane; lid and inner-lip points
    are restricted to their hole's margin so they lie on the opening."""
    from scipy.spatial import cKDTree

    targets = _front_to_lattice(_landmark_targets())
    index = cKDTree(plane).query(targets)[1]
    # Midline landmarks come from the midline column (s = 0) so that the landmark set is mirror-symmetric.
    midline = np.flatnonzero(np.abs(plane[:, 0]) < 1e-12)
    on_midline = np.flatnonzero(np.abs(targets[:, 0]) < 1e-12)
    index[on_midline] = midline[np.abs(plane[midline, 1][None, :] - targets[on_midline, 1][:, None]).argmin(axis=1)]
    # Boundary vertices come first in ``plane`` (in curve order), compacted by ``boundary_used``.
    compact = np.cumsum(boundary_used) - 1
    start = np.cumsum([0] + [len(c) for c in curves])
    for curve, members in ((1, RIGHT_EYE), (2, LEFT_EYE), (3, INNER_LIPS)):
        rows = np.arange(start[curve], start[curve + 1])
        rows = rows[boundary_used[rows]]
        vertices = compact[rows]
        nearest = cKDTree(plane[vertices]).query(targets[list(members)])[1]
        index[list(members)] = vertices[nearest]
    return index.astype(np.int64)


@functools.lru_cache(maxsize=1)
def default_face() -> FaceMesh:
    """The built-in procedural face: ~10k vertices [m], manifold, four boundary loops (outline, eyes, mouth).

    Deterministic and cached: every call returns the same :class:`~warpface.FaceMesh`, whose
    ``points`` (V, 3) float64 and ``triangles`` (T, 3) int32 are read-only. Copy them to edit.
    """
    points, triangles, _ = _build()
    mesh = FaceMesh(points.copy(), triangles.copy(), name="default_face")
    mesh.points.setflags(write=False)
    mesh.triangles.setflags(write=False)
    return mesh


def default_landmarks() -> np.ndarray:
    """Vertex indices of the 68 iBUG landmarks on :func:`default_face`, shape (68,), int64 (a copy)."""
    return _build()[2].copy()
