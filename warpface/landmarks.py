"""Face landmarks, defined once: the 68 iBUG / Multi-PIE points, their index sets per feature and side,
mirrored pairs, and Kato's anthropometric points as affine combinations of them.

iBUG numbering is 0-based. "Right" and "left" are the subject's: iBUG point 0 and the right eye
(36–41) lie at −x in warpface's frame (+x is the subject's left, +y up, +z toward the viewer).

Kato's landmarks (thesis table 2.2, Farkas' anthropometric names) have no iBUG points of their own,
so each is a fixed affine combination of iBUG points (:data:`KATO_LANDMARKS`), applied to positions
at every time: a tracked or simulated face gives tracked Kato landmarks.

================  ====  =========================================================  ==================
Kato landmark     key   iBUG definition                                            where
================  ====  =========================================================  ==================
glabella          g     mean of 21, 22 (inner brow ends)                            between the brows
exocanthion       ex    36 (R), 45 (L)                                              outer eye corner
palp. inferius    pi    mean of 40, 41 (R); mean of 46, 47 (L)                      lowest lid point
pronasale         prn   30                                                          nose tip
alare             al    31 (R), 35 (L)                                              nose wing
crista phil. sup. cphs  33 + 0.6 (50 − 51) (R); 33 + 0.6 (52 − 51) (L)               philtrum top
crista phil. inf. cphi  50 (R), 52 (L)                                              cupid's-bow peaks
cheilion          ch    48 (R), 54 (L)                                              mouth corner
================  ====  =========================================================  ==================

cphs has no iBUG point: the tops of the philtral columns sit at the nose base (subnasale, 33),
spread sideways by a little less than the cupid's-bow peaks below them (the columns converge
upward), hence ``33 + 0.6 (cphi − 51)`` with 51 the bow's midline.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

__all__ = [
    "IBUG_COUNT",
    "IBUG_NAMES",
    "JAW",
    "RIGHT_BROW",
    "LEFT_BROW",
    "NOSE_BRIDGE",
    "NOSE_BASE",
    "RIGHT_EYE",
    "LEFT_EYE",
    "OUTER_LIPS",
    "INNER_LIPS",
    "MOUTH",
    "IBUG_MIRROR",
    "MIRROR_PAIRS",
    "FaceSide",
    "LEFT_SIDE",
    "RIGHT_SIDE",
    "KATO_LANDMARKS",
    "kato_landmarks",
]

IBUG_COUNT = 68
"""Number of iBUG / Multi-PIE landmarks."""

IBUG_NAMES: tuple[str, ...] = (
    *(f"jaw_{i}" for i in range(17)),
    "right_brow_outer",
    "right_brow_2",
    "right_brow_3",
    "right_brow_4",
    "right_brow_inner",
    "left_brow_inner",
    "left_brow_4",
    "left_brow_3",
    "left_brow_2",
    "left_brow_outer",
    "nasion",
    "nose_bridge_1",
    "nose_bridge_2",
    "pronasale",
    "right_nose_wing",
    "right_nostril",
    "subnasale",
    "left_nostril",
    "left_nose_wing",
    "right_eye_outer",
    "right_eye_upper_outer",
    "right_eye_upper_inner",
    "right_eye_inner",
    "right_eye_lower_inner",
    "right_eye_lower_outer",
    "left_eye_inner",
    "left_eye_upper_inner",
    "left_eye_upper_outer",
    "left_eye_outer",
    "left_eye_lower_outer",
    "left_eye_lower_inner",
    "right_mouth_corner",
    "right_upper_lip_outer",
    "right_cupid_peak",
    "upper_lip_top",
    "left_cupid_peak",
    "left_upper_lip_outer",
    "left_mouth_corner",
    "left_lower_lip_outer",
    "left_lower_lip",
    "lower_lip_bottom",
    "right_lower_lip",
    "right_lower_lip_outer",
    "right_inner_corner",
    "right_upper_lip_inner",
    "upper_lip_inner",
    "left_upper_lip_inner",
    "left_inner_corner",
    "left_lower_lip_inner",
    "lower_lip_inner",
    "right_lower_lip_inner",
)
"""Names of the 68 iBUG landmarks, in iBUG order."""

# Index sets, in iBUG order (tuples: usable as NumPy fancy indices and hashable).
JAW = tuple(range(0, 17))
"""Jaw line, subject's right ear level (0) → chin (8) → left ear level (16)."""
RIGHT_BROW = tuple(range(17, 22))
"""Right brow, outer (17) → inner (21)."""
LEFT_BROW = tuple(range(22, 27))
"""Left brow, inner (22) → outer (26)."""
NOSE_BRIDGE = tuple(range(27, 31))
"""Nasion (27) → pronasale, the nose tip (30)."""
NOSE_BASE = tuple(range(31, 36))
"""Right nose wing (31) → subnasale (33) → left nose wing (35)."""
RIGHT_EYE = tuple(range(36, 42))
"""Right eye: outer corner 36, upper lid 37–38, inner corner 39, lower lid 40–41."""
LEFT_EYE = tuple(range(42, 48))
"""Left eye: inner corner 42, upper lid 43–44, outer corner 45, lower lid 46–47."""
OUTER_LIPS = tuple(range(48, 60))
"""Outer lip contour: right corner 48, upper border 49–53, left corner 54, lower border 55–59."""
INNER_LIPS = tuple(range(60, 68))
"""Inner lip contour (the opening): right 60, upper 61–63, left 64, lower 65–67."""
MOUTH = OUTER_LIPS + INNER_LIPS
"""All 20 lip points."""

MIRROR_PAIRS: tuple[tuple[int, int], ...] = (
    *((i, 16 - i) for i in range(8)),
    *((17 + i, 26 - i) for i in range(5)),
    (31, 35),
    (32, 34),
    (36, 45),
    (37, 44),
    (38, 43),
    (39, 42),
    (40, 47),
    (41, 46),
    (48, 54),
    (49, 53),
    (50, 52),
    (59, 55),
    (58, 56),
    (60, 64),
    (61, 63),
    (67, 65),
)
"""(right, left) iBUG index pairs that are each other's mirror image across the face's midline."""


def _mirror_table() -> np.ndarray:
    table = np.arange(IBUG_COUNT)
    for right, left in MIRROR_PAIRS:
        table[right], table[left] = left, right
    table.setflags(write=False)
    return table


IBUG_MIRROR = _mirror_table()
"""Index of each landmark's mirror twin, shape (68,), int, read-only (midline points map to themselves)."""


@dataclass(frozen=True)
class FaceSide:
    """iBUG indices of the features on one side of the face, and the sign of x on that side."""

    sign: float
    """+1 on the subject's left (+x), −1 on the right."""
    brow: tuple[int, ...]
    """Brow points, outer → inner."""
    eye_outer: int
    """Outer eye corner (exocanthion)."""
    eye_inner: int
    """Inner eye corner (endocanthion)."""
    eye: tuple[int, ...]
    """The six eye points."""
    nose_wing: int
    """Nose wing (alare)."""
    mouth_corner: int
    """Outer mouth corner (cheilion)."""
    upper_lip: int
    """Upper-lip border point between Cupid's peak and the corner."""
    lower_lip: int
    """Lower-lip border point near the midline."""
    jaw: tuple[int, ...]
    """Jaw points, ear level → chin."""


LEFT_SIDE = FaceSide(+1.0, LEFT_BROW[::-1], 45, 42, LEFT_EYE, 35, 54, 53, 56, tuple(range(16, 7, -1)))
"""The subject's left side (+x)."""
RIGHT_SIDE = FaceSide(-1.0, RIGHT_BROW, 36, 39, RIGHT_EYE, 31, 48, 49, 58, tuple(range(0, 9)))
"""The subject's right side (−x)."""


KATO_LANDMARKS = MappingProxyType(
    {
        "glabella": ((21, 0.5), (22, 0.5)),
        "pronasale": ((30, 1.0),),
        "ex_R": ((36, 1.0),),
        "ex_L": ((45, 1.0),),
        "pi_R": ((40, 0.5), (41, 0.5)),
        "pi_L": ((46, 0.5), (47, 0.5)),
        "al_R": ((31, 1.0),),
        "al_L": ((35, 1.0),),
        "cphs_R": ((33, 1.0), (50, 0.6), (51, -0.6)),
        "cphs_L": ((33, 1.0), (52, 0.6), (51, -0.6)),
        "cphi_R": ((50, 1.0),),
        "cphi_L": ((52, 1.0),),
        "ch_R": ((48, 1.0),),
        "ch_L": ((54, 1.0),),
    }
)
"""Kato landmark name -> ((iBUG index, weight), ...); weights sum to 1 (affine combinations)."""


def kato_landmarks(ibug_points) -> dict[str, np.ndarray]:
    """Kato landmark positions from iBUG-68 positions.

    Args:
        ibug_points: Positions of the 68 iBUG landmarks, shape (..., 68, 3) (e.g. (68, 3) for one
            face, (T, 68, 3) for a track).

    Returns:
        Name (see :data:`KATO_LANDMARKS`) -> positions of shape (..., 3), float64.

    Raises:
        ValueError: wrong shape or non-finite positions.
    """
    if isinstance(ibug_points, (str, bytes, dict)) or ibug_points is None:
        raise TypeError(
            f"kato_landmarks: expected iBUG positions of shape (..., 68, 3), got {type(ibug_points).__name__}"
        )
    try:
        p = np.asarray(ibug_points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        error = TypeError if isinstance(exc, TypeError) or np.asarray(ibug_points).dtype.kind in "USO" else ValueError
        raise error(
            f"kato_landmarks: expected iBUG positions of shape (..., 68, 3), got {type(ibug_points).__name__}"
        ) from None
    if p.ndim < 2 or p.shape[-2:] != (IBUG_COUNT, 3):
        raise ValueError(f"kato_landmarks: expected iBUG positions of shape (..., 68, 3), got {p.shape}")
    if not np.isfinite(p).all():
        bad = np.argwhere(~np.isfinite(p))[0]
        raise ValueError(f"kato_landmarks: iBUG position at index {tuple(int(i) for i in bad)} is not finite")
    return {name: sum(weight * p[..., index, :] for index, weight in terms) for name, terms in KATO_LANDMARKS.items()}
