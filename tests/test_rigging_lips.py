"""The mouth placed by where a closed mouth's lips touch (warpface.rigging.lip_contact, docs/RIG.md §9 step 6b): on the
ICT face, whose lips are modelled touching, the contact's ends are the annotated inner corners; carried mouth
landmarks slid sideways are moved back; a mouth with no contact, or one shorter than the mouth, changes nothing."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from warpface.assets import default_face, default_landmarks
from warpface.data import ict_landmark_indices, shared_data_path
from warpface.mesh import load_obj
from warpface.rigging.lip_contact import CORNER_AGREEMENT, INNER_CORNERS, LEVEL_TOLERANCE, mouth_contact
from warpface.rigging.nonrigid import SkinTarget
from warpface.rigging.surface import vertex_normals

ICT = shared_data_path("ict_facekit", "face_region_tri", "neutral.obj")
EYE_CM = 6.2
"""The ICT face's eye-centre distance, roughly [cm]: one template unit."""


def _skin(points, triangles, scale):
    """The skin in template-like units (x toward the subject's left, as the ICT face has it)."""
    local = points * scale
    used = np.unique(triangles)
    normals = vertex_normals(local, triangles)
    boundary = np.zeros(len(local), bool)
    return SkinTarget(local[used], normals[used], boundary[used], cKDTree(local[used])), used


@pytest.fixture(scope="module")
def ict():
    if ICT is None:
        pytest.skip("ICT-FaceKit data not in ../shared/data (set WARPFACE_SHARED_DATA)")
    points, triangles = load_obj(ICT)
    skin, used = _skin(points, triangles, 1.0 / EYE_CM)
    truth = points[ict_landmark_indices()] / EYE_CM
    return skin, used, points, truth


def test_the_ends_of_the_ict_lips_contact_are_the_annotated_inner_corners(ict):
    skin, used, points, truth = ict
    contact = mouth_contact(skin, truth)
    assert contact is not None
    for corner, end in zip(INNER_CORNERS, contact.ends):
        assert np.linalg.norm(points[used[end]] - truth[corner] * EYE_CM) < 0.12  # cm
    moved, taken = contact.move(truth)
    assert set(taken) == set(INNER_CORNERS)
    assert np.abs(moved[48:68, 0] - truth[48:68, 0]).max() < 0.01  # nothing to move: under 0.6 mm


@pytest.mark.parametrize("slide", [-0.06, 0.04])
def test_a_mouth_slid_sideways_is_moved_back_onto_the_contact(ict, slide):
    skin, _, _, truth = ict
    slid = truth.copy()
    slid[48:68, 0] += slide  # ~4 mm along the face, as the registration leaves a warped head's mouth
    moved, taken = mouth_contact(skin, slid).move(slid)
    assert np.abs(moved[48:68, 0] - truth[48:68, 0]).max() < 0.01
    assert np.array_equal(moved[:48], truth[:48]) and set(taken) == set(INNER_CORNERS)


def test_no_contact_or_a_contact_shorter_than_the_mouth_changes_nothing(ict):
    face = default_face()  # its lips are one surface: no slit
    skin, _ = _skin(np.asarray(face.points), np.asarray(face.triangles), 1.0 / 0.062)
    assert mouth_contact(skin, np.asarray(face.points)[default_landmarks()] / 0.062) is None
    skin, _, _, truth = ict
    wide = truth.copy()
    wide[[48, 49, 59, 60, 61, 67], 0] -= 1.5 * CORNER_AGREEMENT  # a mouth wider on both sides than the contact
    wide[[53, 54, 55, 63, 64, 65], 0] += 1.5 * CORNER_AGREEMENT
    contact = mouth_contact(skin, wide)
    assert contact is not None
    moved, taken = contact.move(wide)
    assert taken == {} and np.array_equal(moved, wide)


def test_a_mouth_narrower_or_lower_on_one_side_than_its_contact_is_moved_onto_it(ict):
    skin, _, _, truth = ict
    corners = truth[list(INNER_CORNERS), 0]
    share = np.clip((truth[48:68, 0] - corners[0]) / (corners[1] - corners[0]), 0.0, 1.0)
    narrow = truth.copy()
    narrow[48:68, 0] -= 0.08 * share  # the subject's left side carried ~5 mm too far in
    moved, taken = mouth_contact(skin, narrow).move(narrow)
    assert np.abs(moved[48:68, 0] - truth[48:68, 0]).max() < 0.01 and set(taken) == set(INNER_CORNERS)
    low = truth.copy()
    low[48:68, 1] -= 0.12 * share  # the left side ~7 mm low, as a warp can tilt the mouth against the template
    moved, taken = mouth_contact(skin, low).move(low)
    assert np.abs(moved[48:68, 1] - truth[48:68, 1]).max() < LEVEL_TOLERANCE + 0.01
    assert np.abs(moved[48:68, 1] - truth[48:68, 1]).max() < 0.5 * np.abs(low[48:68, 1] - truth[48:68, 1]).max()
