"""The lip seal (docs/RIG.md §12): each muscle's field keeps the inner-lip pairs from closing; lips never cross."""

from __future__ import annotations

import numpy as np
import pytest

import warpface as wf
from benchmarks.face_quality import ROLLS, channel_frames, preset_frames, random_combinations
from warpface.assets import ARKIT_PRESET_NAMES, default_rig
from warpface.assets.quality import LIP_PAIRS, face_up, flipped_triangles, pair_heights
from warpface.data import ict_face_region, ict_landmark_indices
from warpface.expression.seal import LipSeal, seal_fields

DEVICE = "cpu"


def test_seal_adds_the_least_share_that_keeps_every_pair_from_closing():
    rng = np.random.default_rng(5)
    pairs = np.array([[0, 1], [2, 3], [4, 5]])
    seal = LipSeal("seal", np.zeros(3), [1, 0, 0], np.arange(6), np.full(6, 0.1), pairs=pairs)
    part = np.zeros((12, 3))
    part[[0, 2, 4]], part[[1, 3, 5]] = [0.0, 1.0, 0.0], [0.0, -1.0, 0.0]  # parts each pair by 2 along y
    closing = rng.normal(size=(12, 3)) * 0.1
    closing[[0, 2, 4], 1] -= [0.3, 0.5, 0.1]  # the upper points move down
    parting = np.zeros((12, 3))
    parting[0, 1] = 0.2
    lid = wf.expression.LidMuscle("lid", np.zeros(3), [1, 0, 0], [7], [0.2])
    muscles = [seal, "closing", "parting", lid]
    out = seal_fields(muscles, [part, closing, parting, closing])
    assert out[0] is part and out[2] is parting and out[3] is closing  # the seal, a parting field and lids stay
    relative = (out[1][pairs[:, 0]] - out[1][pairs[:, 1]])[:, 1]
    assert relative.min() == pytest.approx(0.0, abs=1e-12)  # the binding pair just stays sealed
    before = (closing[pairs[:, 0]] - closing[pairs[:, 1]])[:, 1]
    share = max(0.0, (-before / 2.0).max())
    np.testing.assert_allclose(out[1], closing + share * part, atol=1e-15)
    with pytest.raises(ValueError, match="at most one"):
        seal_fields([seal, seal], [part, part])
    with pytest.raises(ValueError, match="does not part"):
        seal_fields([seal, "m"], [np.zeros((12, 3)), closing])
    with pytest.raises(ValueError, match="pairs"):
        LipSeal("seal", np.zeros(3), [1, 0, 0], [0], [0.1], pairs=np.zeros((0, 2), dtype=int))


def _lips(rig, frames):
    points = rig.model(device=DEVICE).evaluate(frames)
    return pair_heights(points, rig.landmarks, LIP_PAIRS, face_up(rig.mesh, rig.landmarks), 1000.0)


def test_lips_never_cross_on_the_built_in_face():
    rig = default_rig(device=DEVICE)
    assert _lips(rig, preset_frames(rig, ARKIT_PRESET_NAMES)).min() >= -0.2
    assert _lips(rig, random_combinations(rig, 100)).min() >= -0.2


def test_lips_never_cross_at_any_preset_on_the_ict_face():
    path, landmarks = ict_face_region(), ict_landmark_indices()
    if path is None or landmarks is None:
        pytest.skip("ICT-FaceKit data not found in ../shared/data (set WARPFACE_SHARED_DATA)")
    source = wf.FaceMesh.from_obj(path)
    rig = default_rig(wf.FaceMesh(source.points * 0.01, source.triangles), landmarks, device=DEVICE)
    assert _lips(rig, preset_frames(rig, ARKIT_PRESET_NAMES)).min() >= -0.2


def test_no_triangle_turns_over_on_the_built_in_face():
    """Issue 25's surface check: flipped triangles summed over every ARKit and FACS channel at weight 1 (the
    lips' rolls excepted) stay within 10 (58 before the lid hinges and the jaw weights' diffusion)."""
    rig = default_rig(device=DEVICE)
    model = rig.model(device=DEVICE)
    total = 0
    for kind in ("arkit", "facs"):
        names, frames = channel_frames(rig, kind)
        keep = [i for i, name in enumerate(names) if name not in ROLLS]
        total += int(flipped_triangles(rig.mesh, model.evaluate(frames[keep])).sum())
    assert total <= 10
