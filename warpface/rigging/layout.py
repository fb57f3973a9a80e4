"""Is a set of 68 landmarks in iBUG order? A check that names what is wrong in words a user can act on.

The landmarks are put in a frame that does not trust their order: origin at their centroid, front
from the skin's outward normals under them, up from the chin (iBUG 8, the lowest jaw point in any
68-point scheme that starts with the jaw) toward the centroid, scale their RMS spread. Each iBUG
group (jaw, brows, nose bridge and base, eyes, mouth) should then sit near where the built-in face's landmarks put
it. A group nearer another group's place is reported: two groups in each other's place as swapped,
any other misplacement as out of order (menpo's grouping, for one, lists the eyes before the brows).
"""

from __future__ import annotations

import functools

import numpy as np

from ..errors import RigError
from ..landmarks import IBUG_COUNT
from .template import template

__all__ = ["GROUPS", "check_layout", "layout_frame"]

GROUPS: tuple[tuple[str, int, int], ...] = (
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


def layout_frame(marks: np.ndarray, front: np.ndarray) -> np.ndarray:
    """The 68 points (68, 3) in the order-free frame (x to the subject's left, y up, z front), RMS spread 1."""
    centre = marks.mean(axis=0)
    up = centre - marks[8]
    front = front - (front @ up) / (up @ up) * up
    if np.linalg.norm(up) == 0.0 or np.linalg.norm(front) == 0.0:
        raise RigError("landmarks: they coincide or lie on a line; cannot tell where the face is")
    up, front = up / np.linalg.norm(up), front / np.linalg.norm(front)
    axes = np.stack([np.cross(up, front), up, front])
    local = (marks - centre) @ axes.T
    return local / np.sqrt(np.mean(np.sum(local**2, axis=1)))


@functools.lru_cache(maxsize=1)
def _reference() -> np.ndarray:
    """Group centroids of the built-in face's landmarks in the order-free frame."""
    model = template()
    local = layout_frame(model.points[model.landmarks], np.array([0.0, 0.0, 1.0]))
    return np.stack([local[a:b].mean(axis=0) for _, a, b in GROUPS])


def _span(a: int, b: int) -> str:
    return f"{a}–{b - 1}"


def check_layout(marks, front, label: str = "landmarks") -> None:
    """Raise RigError when the 68 landmark points (68, 3) are not laid out in iBUG order.

    Args:
        marks: landmark positions in mesh coordinates.
        front: the direction the face looks (e.g. the mean outward skin normal at the landmarks).
        label: names the landmarks in the message.
    """
    marks = np.asarray(marks, dtype=np.float64)
    if marks.shape != (IBUG_COUNT, 3):
        raise RigError(f"{label}: expected {IBUG_COUNT} iBUG landmarks, got shape {marks.shape}")
    if np.ptp(marks, axis=0).max() == 0.0:
        raise RigError(f"{label}: all landmarks are the same point")
    local = layout_frame(marks, np.asarray(front, dtype=np.float64))
    reference = _reference()
    centroids = np.stack([local[a:b].mean(axis=0) for _, a, b in GROUPS])
    nearest = np.argmin(np.linalg.norm(centroids[:, None, :] - reference[None, :, :], axis=2), axis=1)
    wrong = [g for g in range(len(GROUPS)) if nearest[g] != g]
    if not wrong:
        return
    swapped = [(g, int(nearest[g])) for g in wrong if nearest[nearest[g]] == g and g < nearest[g]]
    if len(swapped) == len(wrong) // 2 and len(wrong) % 2 == 0 and swapped:
        parts = []
        for g, h in swapped:
            (name_g, a, b), (name_h, c, d) = GROUPS[g], GROUPS[h]
            side = "right of" if centroids[g][0] > centroids[h][0] else "left of"
            parts.append(
                f"{name_g} and {name_h} landmarks look swapped (iBUG {_span(a, b)} are {side} {_span(c, d)} "
                "from the face's front)"
            )
        raise RigError(f"{label}: " + "; ".join(parts) + "; reorder them to iBUG order")
    described = ", ".join(
        f"iBUG {_span(GROUPS[g][1], GROUPS[g][2])} ({GROUPS[g][0]}) lie where the {GROUPS[int(nearest[g])][0]} is"
        for g in wrong
    )
    raise RigError(
        f"{label}: not in iBUG order: {described}; iBUG order is jaw 0–16, brows 17–26, nose 27–35, "
        "eyes 36–47, mouth 48–67 (menpo's grouping lists the eyes before the brows: reorder it)"
    )
