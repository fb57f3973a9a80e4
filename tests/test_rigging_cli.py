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


def _quads(triangles):
    """Consecutive triangles sharing an edge merged into quads (p, q, s, r); the others stay triangles."""
    faces, index = [], 0
    while index < len(triangles):
        a = [int(v) for v in triangles[index]]
        b = [int(v) for v in triangles[index + 1]] if index + 1 < len(triangles) else []
        if len(set(a) & set(b)) == 2:
            p = next(v for v in a if v not in b)
            k = a.index(p)
            q, r = a[(k + 1) % 3], a[(k + 2) % 3]
            faces.append([p, q, next(v for v in b if v not in a), r])
            index += 2
        else:
            faces.append(a)
            index += 1
    return faces


def _write_usd_head(path, points, triangles, meters_per_unit):
    """A Z-up USD stage with the head as one Mesh of quads and triangles."""
    from pxr import Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    mesh = UsdGeom.Mesh.Define(stage, "/Head/Geo")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)))
    faces = _quads(triangles)
    mesh.CreateFaceVertexCountsAttr([len(f) for f in faces])
    mesh.CreateFaceVertexIndicesAttr([v for f in faces for v in f])
    stage.GetRootLayer().Save()
    return path, sum(len(f) == 4 for f in faces)


def test_rig_of_a_z_up_millimetre_usd_head_keeps_its_frame_and_finds_the_landmarks(tmp_path, capsys):
    from pxr import Usd, UsdGeom

    from warpface.assets import default_landmarks
    from warpface.assets.rig import face_frame
    from warpface.rigging.template import LANDMARK_POINTS
    from warpface.usd import read_rig

    face = default_face()
    z_up = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # y → z
    head, quads = _write_usd_head(tmp_path / "head.usda", 1000.0 * face.points @ z_up.T, face.triangles, 0.001)
    assert quads > 1000
    out, png = tmp_path / "out" / "rig.usda", tmp_path / "rig.png"
    assert main(["--device", "cpu", "rig", str(head), "--out", str(out), "--preview", str(png)]) == 0
    printed = capsys.readouterr()
    assert "landmarks found" in printed.out
    assert "landmarks:" in printed.err and "orientation" in printed.err  # the stages' progress bar
    stage = Usd.Stage.Open(str(out))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    confidence = stage.GetPrimAtPath("/Face/Skin").GetCustomDataByKey("warpface:landmarkConfidence")
    assert len(confidence) == 68 and 0.5 < np.mean(confidence) <= 1.0
    rig = read_rig(out)  # metres, in the head's own (Z-up) frame
    np.testing.assert_allclose(rig.mesh.points, face.points @ z_up.T, atol=1e-6)
    # The template registered onto itself: the landmarks land where its landmark points are, within a few mm.
    expected = face_frame(face, default_landmarks()).to_world(LANDMARK_POINTS) @ z_up.T
    gap_mm = 1000.0 * np.linalg.norm(rig.mesh.points[rig.landmarks] - expected, axis=1)
    assert gap_mm.mean() < 2.0 and gap_mm.max() < 6.0
    assert len(rig.muscles) > 20 and rig.jaw is not None
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_usd_head_under_a_scaled_root_gets_the_unit_its_points_are_in(tmp_path, capsys):
    """Points in mm under a root Xform scaled by 0.001 on a metre stage (a common export): the rig stage says
    0.001 m per unit, as the mesh's own points are, not a 1,000× head (the reference does not bring the root)."""
    from pxr import Gf, Usd, UsdGeom

    from warpface.usd import read_rig

    face = default_face()
    head, _ = _write_usd_head(tmp_path / "head.usda", 1000.0 * face.points, face.triangles, 1.0)
    stage = Usd.Stage.Open(str(head))
    UsdGeom.Xform.Define(stage, "/Head").AddScaleOp().Set(Gf.Vec3f(0.001, 0.001, 0.001))
    stage.GetRootLayer().Save()
    out = tmp_path / "out" / "rig.usda"
    assert main(["--device", "cpu", "rig", str(head), "--out", str(out)]) == 0
    assert "landmarks found" in capsys.readouterr().out
    assert UsdGeom.GetStageMetersPerUnit(Usd.Stage.Open(str(out))) == pytest.approx(0.001)
    np.testing.assert_allclose(read_rig(out).mesh.points, face.points, atol=1e-6)  # metres
    assert main(["validate", str(out)]) == 0


def test_a_usd_head_with_time_sampled_points_only_is_refused_saying_so(tmp_path, capsys):
    from pxr import Usd, UsdGeom, Vt

    face = default_face()
    head, _ = _write_usd_head(tmp_path / "head.usda", 100.0 * face.points, face.triangles, 0.01)
    stage = Usd.Stage.Open(str(head))
    points = UsdGeom.Mesh(stage.GetPrimAtPath("/Head/Geo")).GetPointsAttr()
    points.Clear()
    points.Set(Vt.Vec3fArray.FromNumpy((100.0 * face.points).astype(np.float32)), Usd.TimeCode(1))
    stage.GetRootLayer().Save()
    out = tmp_path / "out" / "rig.usda"
    assert main(["rig", str(head), "--out", str(out)]) == 2
    assert "only 1 time sample(s); export the neutral head with default points" in capsys.readouterr().err
    assert not out.parent.exists()


def test_rig_from_a_landmark_file_and_refusals_leave_nothing_behind(face_obj, tmp_path, capsys):
    from warpface.assets import default_landmarks
    from warpface.usd import read_rig

    marks = tmp_path / "marks.json"
    marks.write_text(json.dumps(default_landmarks().tolist()))
    out = tmp_path / "given.usdc"
    assert main(["--quiet", "rig", str(face_obj), "--out", str(out), "--landmarks", str(marks)]) == 0
    np.testing.assert_array_equal(read_rig(out).landmarks, default_landmarks())
    # Wound inside out: the layout check still sees the face's front, and the rig is built on outward faces.
    face = default_face()
    flipped = _write_obj(tmp_path / "flipped.obj", 100.0 * face.points, face.triangles[:, ::-1])
    assert main(["--quiet", "rig", str(flipped), "--out", str(out), "--landmarks", str(marks)]) == 0
    rig = read_rig(out)
    assert rig.mesh.vertex_normals()[default_landmarks()[30]][2] > 0.7  # the nose tip's normal points out
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
