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

from .errors import RigError

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
    "LAYOUT_GROUPS",
    "LAYOUT_REFERENCE",
    "layout_frame",
    "check_layout",
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


# The layout check: are 68 points in iBUG order? It runs wherever landmarks enter a rig (the ``rig``
# command, ``default_rig``, ``validate``), so it lives here, below every one of them.

LAYOUT_GROUPS: tuple[tuple[str, int, int], ...] = (
    ("jaw", 0, 17),
    ("right brow", 17, 22),
    ("left brow", 22, 27),
    ("nose bridge", 27, 31),
    ("nose base", 31, 36),
    ("right eye", 36, 42),
    ("left eye", 42, 48),
    ("mouth", 48, 68),
)
"""iBUG groups: (name, first index, end index)."""

# fmt: off
LAYOUT_REFERENCE = np.array(
    (
        (0.000, -0.423, -0.601), (-0.670, 1.000, 0.101), (0.670, 1.000, 0.101), (0.000, 0.317, 0.514),
        (0.000, -0.139, 0.407), (-0.512, 0.625, -0.003), (0.512, 0.625, -0.003), (0.000, -0.544, 0.258),
    )
)
# fmt: on
"""Centroids of the :data:`LAYOUT_GROUPS` of the built-in face's landmarks in the :func:`layout_frame`
(tests/test_landmark_layout.py recomputes them from :func:`warpface.assets.default_face`)."""


def layout_frame(marks: np.ndarray, front: np.ndarray) -> np.ndarray:
    """The 68 points (68, 3) in a frame that does not trust their order: origin at their centroid, y up from
    the chin (iBUG 8, the lowest jaw point in any 68-point scheme that starts with the jaw), z along ``front``
    made orthogonal to y, x to the subject's left; RMS spread 1."""
    centre = marks.mean(axis=0)
    up = centre - marks[8]
    if np.linalg.norm(up) == 0.0:
        raise RigError("landmarks: they coincide or lie on a line; cannot tell where the face is")
    front = front - (front @ up) / (up @ up) * up
    if np.linalg.norm(front) == 0.0:
        raise RigError("landmarks: they coincide or lie on a line; cannot tell where the face is")
    up, front = up / np.linalg.norm(up), front / np.linalg.norm(front)
    axes = np.stack([np.cross(up, front), up, front])
    local = (marks - centre) @ axes.T
    return local / np.sqrt(np.mean(np.sum(local**2, axis=1)))


def _span(a: int, b: int) -> str:
    return f"{a}–{b - 1}"


def check_layout(marks, front, label: str = "landmarks") -> None:
    """Raise RigError when 68 landmark points (68, 3) are not laid out in iBUG order.

    Each iBUG group should sit nearest its own place on the built-in face (in :func:`layout_frame`); a
    group nearer another group's place is reported in words a user can act on: two groups in each
    other's place as swapped, any other misplacement as out of order (menpo's grouping, for one, lists
    the eyes before the brows).

    Args:
        marks: landmark positions in mesh coordinates.
        front: the direction the face looks (e.g. the mean outward skin normal at the landmarks).
        label: names the landmarks in the message.
    """
    marks = np.asarray(marks, dtype=np.float64)
    if marks.shape != (IBUG_COUNT, 3):
        raise RigError(f"{label}: expected {IBUG_COUNT} iBUG landmarks, got shape {marks.shape}")
    if not np.isfinite(marks).all():
        raise RigError(f"{label}: landmark positions are not finite")
    if np.ptp(marks, axis=0).max() == 0.0:
        raise RigError(f"{label}: all landmarks are the same point")
    local = layout_frame(marks, np.asarray(front, dtype=np.float64).reshape(3))
    centroids = np.stack([local[a:b].mean(axis=0) for _, a, b in LAYOUT_GROUPS])
    distances = np.linalg.norm(centroids[:, None, :] - LAYOUT_REFERENCE[None, :, :], axis=2)
    nearest = np.argmin(distances, axis=1)
    wrong = [g for g in range(len(LAYOUT_GROUPS)) if nearest[g] != g]
    if not wrong:
        return
    swapped = [(g, int(nearest[g])) for g in wrong if nearest[nearest[g]] == g and g < nearest[g]]
    if swapped and len(wrong) == 2 * len(swapped):
        parts = []
        for g, h in swapped:
            (name_g, a, b), (name_h, c, d) = LAYOUT_GROUPS[g], LAYOUT_GROUPS[h]
            side = "right of" if centroids[g][0] > centroids[h][0] else "left of"
            parts.append(
                f"{name_g} and {name_h} landmarks look swapped (iBUG {_span(a, b)} are {side} {_span(c, d)} "
                "from the face's front)"
            )
        raise RigError(f"{label}: " + "; ".join(parts) + "; reorder them to iBUG order")
    described = ", ".join(
        f"iBUG {_span(LAYOUT_GROUPS[g][1], LAYOUT_GROUPS[g][2])} ({LAYOUT_GROUPS[g][0]}) lie where the "
        f"{LAYOUT_GROUPS[int(nearest[g])][0]} is"
        for g in wrong
    )
    raise RigError(
        f"{label}: not in iBUG order: {described}; iBUG order is jaw 0–16, brows 17–26, nose 27–35, "
        "eyes 36–47, mouth 48–67 (menpo's grouping lists the eyes before the brows: reorder it)"
    )
