"""``warpface rig``: a stage that reads back with the found landmarks, the picture, and one-line refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest

from warpface.assets import default_face
from warpface.cli import main
from warpface.data import shared_data_path


def _write_obj(path, points, triangles):
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in points]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in triangles]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def face_obj(tmp_path_factory):
    face = default_face()
    return _write_obj(tmp_path_factory.mktemp("head") / "head_cm.obj", 100.0 * face.points, face.triangles)


def test_rig_writes_a_stage_with_the_landmarks_found_and_a_picture(face_obj, tmp_path, capsys):
    from warpface.rigging import find_landmarks
    from warpface.usd import read_rig

    out, png = tmp_path / "out" / "rig.usda", tmp_path / "rig.png"
    assert main(["--device", "cpu", "rig", str(face_obj), "--out", str(out), "--preview", str(png)]) == 0
    assert "landmarks found" in capsys.readouterr().out
    rig = read_rig(out)  # metres
    face = default_face()
    found = find_landmarks(100.0 * face.points, face.triangles)
    np.testing.assert_array_equal(rig.landmarks, found.indices)
    np.testing.assert_allclose(rig.mesh.points, face.points, atol=1e-6)  # cm on disk, metres read back
    assert len(rig.muscles) > 20 and rig.jaw is not None
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_rig_from_a_landmark_file_and_refusals_leave_nothing_behind(face_obj, tmp_path, capsys):
    from warpface.assets import default_landmarks
    from warpface.usd import read_rig

    marks = tmp_path / "marks.json"
    marks.write_text(json.dumps(default_landmarks().tolist()))
    out = tmp_path / "given.usdc"
    assert main(["--quiet", "rig", str(face_obj), "--out", str(out), "--landmarks", str(marks)]) == 0
    np.testing.assert_array_equal(read_rig(out).landmarks, default_landmarks())
    capsys.readouterr()

    swapped = default_landmarks()
    swapped[36:42], swapped[42:48] = default_landmarks()[42:48], default_landmarks()[36:42]
    marks.write_text(json.dumps(swapped.tolist()))
    bad = tmp_path / "bad.usda"
    assert main(["rig", str(face_obj), "--out", str(bad), "--landmarks", str(marks)]) == 2
    error = capsys.readouterr().err.strip()
    assert "iBUG 36–41 are right of 42–47 from the face's front" in error and "\n" not in error
    assert not bad.exists()

    empty = tmp_path / "empty.obj"
    empty.write_text("")
    assert main(["rig", str(empty), "--out", str(bad)]) == 2
    assert "empty file" in capsys.readouterr().err
    cloud = _write_obj(tmp_path / "cloud.obj", np.random.default_rng(0).normal(size=(40, 3)), [])
    assert main(["rig", str(cloud), "--out", str(bad)]) == 2
    assert "point cloud" in capsys.readouterr().err
    far = _write_obj(tmp_path / "km.obj", 1e-3 * default_face().points, default_face().triangles)
    assert main(["rig", str(far), "--out", str(bad)]) == 2
    assert "not a human head in m, cm or mm" in capsys.readouterr().err
    assert main(["rig", str(face_obj), "--out", str(tmp_path / "rig.txt")]) == 2
    assert not bad.exists() and not list(tmp_path.glob(".*"))


JAMES = shared_data_path("menpo3d_james")


@pytest.mark.skipif(JAMES is None, reason="menpo3d james not in ../shared/data (set WARPFACE_SHARED_DATA)")
def test_menpo_ordered_landmarks_are_refused_naming_the_groups(tmp_path, capsys):
    out = tmp_path / "james.usda"
    code = main(["rig", str(JAMES / "james.obj"), "--out", str(out), "--landmarks", str(JAMES / "james.ljson")])
    error = capsys.readouterr().err
    assert code == 2 and not out.exists()
    assert "not in iBUG order" in error and "(right brow) lie where the right eye is" in error
