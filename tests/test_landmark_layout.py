"""The one iBUG layout check (warpface.landmarks) where landmarks enter a rig: its reference, default_rig and
validate; validate's face-size check against the stage's stated unit."""

from __future__ import annotations

import numpy as np
import pytest

from warpface.assets import default_face, default_landmarks, default_rig
from warpface.errors import RigError
from warpface.landmarks import LAYOUT_GROUPS, LAYOUT_REFERENCE, check_layout, layout_frame
from warpface.mesh import FaceMesh


def _swap_eyes(landmarks):
    swapped = np.array(landmarks).copy()
    swapped[36:42], swapped[42:48] = landmarks[42:48], landmarks[36:42]
    return swapped


def test_reference_is_the_built_in_faces_group_centroids():
    face = default_face()
    local = layout_frame(face.points[default_landmarks()], np.array([0.0, 0.0, 1.0]))
    centroids = np.stack([local[a:b].mean(axis=0) for _, a, b in LAYOUT_GROUPS])
    np.testing.assert_allclose(centroids, LAYOUT_REFERENCE, atol=1e-3)


def test_check_layout_names_swapped_eyes_and_passes_the_built_in_face():
    face = default_face()
    marks = face.points[default_landmarks()]
    check_layout(marks, [0.0, 0.0, 1.0])
    with pytest.raises(RigError, match=r"right eye and left eye landmarks look swapped \(iBUG 36–41"):
        check_layout(marks[_swap_eyes(np.arange(68))], [0.0, 0.0, 1.0])


def test_default_rig_refuses_swapped_eyes_and_names_inward_winding():
    face = default_face()
    with pytest.raises(RigError, match="default_rig: .*eye landmarks look swapped"):
        default_rig(face, _swap_eyes(default_landmarks()), device="cpu")
    inward = FaceMesh(face.points, face.triangles[:, [0, 2, 1]], name="inward")
    with pytest.raises(RigError, match="wound inward"):
        default_rig(inward, default_landmarks(), device="cpu")


def _rig_stage(path, scale, meters_per_unit, landmarks=None):
    from pxr import Usd, UsdGeom

    from warpface.usd import write_rig

    face = default_face()
    rig = default_rig(FaceMesh(face.points * scale, face.triangles, name="skin"), default_landmarks(), device="cpu")
    if landmarks is not None:
        from dataclasses import replace

        rig = replace(rig, landmarks=landmarks)
    stage = Usd.Stage.CreateNew(str(path))
    write_rig(stage, rig, meters_per_unit=meters_per_unit or 1.0)
    if meters_per_unit is None:
        stage.ClearMetadata(UsdGeom.Tokens.metersPerUnit)
    stage.GetRootLayer().Save()
    return path


def test_validate_flags_a_millimetre_rig_without_meters_per_unit(tmp_path, capsys):
    from warpface.cli import main
    from warpface.usd import validate_stage

    good = _rig_stage(tmp_path / "mm_ok.usda", 1000.0, 0.001)
    assert not [p for p in validate_stage(good, bake_checks=False, device="cpu") if p.source == "warpface"]
    bad = _rig_stage(tmp_path / "mm_unstated.usda", 1000.0, None)
    problems = [p for p in validate_stage(bad, bake_checks=False, device="cpu") if p.source == "warpface"]
    assert len(problems) == 1 and problems[0].severity == "error"
    assert "not authored" in problems[0].message and "metersPerUnit = 0.001" in problems[0].message
    assert main(["validate", str(bad), "--quiet", "--device", "cpu"]) == 1
    assert "head is ~" in capsys.readouterr().out


def test_validate_flags_landmarks_out_of_ibug_order(tmp_path):
    from warpface.usd import validate_stage

    bad = _rig_stage(tmp_path / "swapped.usda", 1.0, 1.0, landmarks=_swap_eyes(default_landmarks()))
    messages = [p.message for p in validate_stage(bad, bake_checks=False, device="cpu") if p.severity == "error"]
    assert any("look swapped" in m for m in messages), messages
