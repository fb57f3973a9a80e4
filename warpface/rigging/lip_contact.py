"""The mouth placed by the geometry of a closed mouth: where its lips touch, and where that contact ends.

A head modelled with its mouth closed has two lip surfaces lying against each other along the mouth's slit: pairs
of skin vertices a hair apart whose normals face each other. Where that contact ends on either side are the
mouth's inner corners (iBUG 60 and 64: on the ICT head 0.4–1.1 mm from the annotation, on every warp of it
tried). The registration can leave the mouth a few millimetres off along the face where the face is unlike the
template: slid sideways, narrower, or one side lower. The carried mouth landmarks are moved onto the contact's
ends (:meth:`MouthContact.move`), and a corner takes its end where the two then agree (docs/RIG.md §9, step 6b).
A scan without a slit (one surface over the lips) has no contact, and one whose lips part before the corners
(the Lee Perry-Smith scan) a contact neither of whose ends agrees: nothing changes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .nonrigid import SkinTarget

__all__ = ["CONTACT_GAP", "CORNER_AGREEMENT", "INNER_CORNERS", "LEVEL_TOLERANCE", "MouthContact", "mouth_contact"]

CONTACT_GAP = 0.005
"""Lips closer than this [inter-ocular units, ~0.3 mm] touch (the ICT head's lips: 0.06 mm at the corners)."""
CONTACT_FACING = -0.5
"""Touching lips face each other: their normals' cosine is below this."""
NEAR_INNER_LIP = 0.3
"""Contact is looked for within this of the carried inner-lip landmarks 60–67 [inter-ocular units, ~18 mm]: the
ICT lips part in the middle, so a side of the mouth carried 9 mm off can hold the only contact near it."""
MIN_CONTACT = 12
"""Fewer touching vertices than this are no slit."""
WIDTH_RATIO = (0.6, 1.6)
"""The contact's width over the carried inner corners' distance must lie in this range to be the mouth's."""
LEVEL_TOLERANCE = 0.03
"""Up and back, a side of the mouth moves only by what its end lies beyond this from its corner [inter-ocular
units, ~2 mm]: an end is the upper or the lower lip's vertex, ~1 mm apart, and moving a side by that moved the ICT
head's well-placed points (0.14 → 0.23 mm mean)."""
CORNER_AGREEMENT = 0.05
"""A corner takes the contact's end only when the moved carried corner lies this near it [inter-ocular units]:
a scan whose lips part near the corners has a contact shorter than its mouth."""
INNER_CORNERS = (60, 64)
INNER_LIP = slice(60, 68)
MOUTH = slice(48, 68)


@dataclass(frozen=True)
class MouthContact:
    """The lips' contact on one skin (template frame)."""

    skin: SkinTarget
    ends: tuple[int, int]
    """Skin indices of the contact's two ends: toward the subject's right (−x), then left."""

    def move(self, marks: np.ndarray) -> tuple[np.ndarray, dict[int, int]]:
        """The carried landmarks (68, 3) with the mouth (iBUG 48–67) moved across the face (template x) onto the
        contact, and the corners that take an end: {iBUG: skin index}.

        The mouth first moves by the mean of the ends' offsets from the carried inner corners; then a side whose
        end lies farther out than its corner is widened to it (lips touch only within the mouth, so a contact
        reaching past a corner shows the mouth is wider there) and a side whose end lies more than
        :data:`LEVEL_TOLERANCE` above, below, in front of or behind its corner moves by the excess, each mouth point
        by the sides' offsets blended linearly across the mouth. A contact shorter than the mouth narrows nothing.
        When neither end then agrees with its corner, the landmarks are returned as they were."""
        ends = self.skin.points[list(self.ends)]
        corners = list(INNER_CORNERS)
        shift = float(np.mean(ends[:, 0] - marks[corners, 0]))
        moved = marks.copy()
        moved[MOUTH, 0] += shift
        right, left = ends[:, 0] - moved[corners, 0]
        x_right, x_left = moved[corners[0], 0], moved[corners[1], 0]
        share = np.clip((moved[MOUTH, 0] - x_right) / (x_left - x_right), 0.0, 1.0)
        moved[MOUTH, 0] += (1.0 - share) * min(right, 0.0) + share * max(left, 0.0)
        rest = ends - moved[corners]  # what is left, up and back along the face, per side
        rest[:, 0] = 0.0
        length = np.linalg.norm(rest, axis=1, keepdims=True)
        rest *= np.clip(length - LEVEL_TOLERANCE, 0.0, None) / np.maximum(length, 1e-12)
        moved[MOUTH] += (1.0 - share)[:, None] * rest[0] + share[:, None] * rest[1]
        taken = {
            corner: end
            for corner, end, where in zip(INNER_CORNERS, self.ends, ends)
            if np.linalg.norm(where - moved[corner]) < CORNER_AGREEMENT
        }
        if not taken:  # neither end where a corner could be: a contact of another length than the mouth's
            return marks, {}
        return moved, taken


def mouth_contact(skin: SkinTarget, marks: np.ndarray) -> MouthContact | None:
    """The lips' contact near the carried mouth, or None when the mouth shows none like a closed mouth's.

    Args:
        skin: the skin in the template frame (x toward the subject's left).
        marks: the 68 carried landmark points in that frame, (68, 3).
    """
    near = np.flatnonzero(
        cKDTree(marks[INNER_LIP]).query(skin.points, distance_upper_bound=NEAR_INNER_LIP)[0] < NEAR_INNER_LIP
    )
    if len(near) < 2:
        return None
    pairs = cKDTree(skin.points[near]).query_pairs(CONTACT_GAP, output_type="ndarray")
    if len(pairs) == 0:
        return None
    facing = np.sum(skin.normals[near[pairs[:, 0]]] * skin.normals[near[pairs[:, 1]]], axis=1) < CONTACT_FACING
    touching = np.unique(near[pairs[facing].ravel()])
    if len(touching) < MIN_CONTACT:
        return None
    across = skin.points[touching, 0]
    right, left = int(touching[np.argmin(across)]), int(touching[np.argmax(across)])
    carried = marks[INNER_CORNERS[1], 0] - marks[INNER_CORNERS[0], 0]
    width = skin.points[left, 0] - skin.points[right, 0]
    if carried <= 0.0 or not WIDTH_RATIO[0] <= width / carried <= WIDTH_RATIO[1]:
        return None
    return MouthContact(skin, (right, left))
