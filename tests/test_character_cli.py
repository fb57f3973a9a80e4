"""Every command takes the user's character: track --rig (synthetic and recorded), preview framing and overlays,
presets, fit's jaw presets, animate into a missing folder. Built on the built-in face turned Z-up and facing −y,
as a Blender export would be (a rig of one's own that is not in warpface's frame)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from warpface.assets import default_face, default_landmarks, default_rig
from warpface.cli import main
from warpface.mesh import FaceMesh

TURN = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
"""Warpface's frame → a Z-up frame with the face looking along −y (x stays the subject's left)."""
OFFSET = np.array([0.3, -0.1, 1.2])


@pytest.fixture(scope="module")
def zup_rig():
    face = default_face()
    mesh = FaceMesh(face.points @ TURN.T + OFFSET, face.triangles, name="zup")
    return default_rig(mesh, default_landmarks(), device="cpu")


@pytest.fixture(scope="module")
def zup_stage(zup_rig, tmp_path_factory):
    from pxr import Usd, UsdGeom

    from warpface.usd import write_rig

    path = tmp_path_factory.mktemp("zup") / "zup.usda"
    stage = Usd.Stage.CreateNew(str(path))
    write_rig(stage, zup_rig, meters_per_unit=1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    stage.GetRootLayer().Save()
    return path


def test_synthetic_capture_films_a_turned_rig_upright_and_maps_back_exactly(zup_rig):
    from warpface.pipelines.capture import synthetic_capture, upright_turn

    np.testing.assert_array_equal(upright_turn(zup_rig), TURN.T)
    np.testing.assert_array_equal(upright_turn(default_rig(device="cpu")), np.eye(3))
    capture = synthetic_capture(zup_rig, seconds=0.1, noise=False, device="cpu")
    try:
        seen = capture.camera.camera_points(2)  # camera frame (OpenCV: z forward)
        back = seen @ capture.camera_to_rig[:3, :3].T + capture.camera_to_rig[:3, 3]
        np.testing.assert_allclose(back, capture.truth[2], atol=1e-9)
        nose = capture.camera.camera_points(0)[zup_rig.landmarks[30]]
        assert abs(nose[0]) < 0.02 and abs(nose[1]) < 0.05 and 0.55 < nose[2] < 0.65  # face on, nose 0.6 m away
    finally:
        capture.camera.close()


def _residual_mm(printed: str) -> float:
    return float(re.search(r"mean landmark residual ([\d.]+) mm", printed).group(1))


@pytest.mark.slow  # end to end, over 20 s on the 2-core CI machine
def test_track_synthetic_solves_a_turned_rig(zup_stage, tmp_path, capsys):
    out = tmp_path / "new" / "folder" / "capture.usda"
    arguments = ["--quiet", "--device", "cpu", "track", "synthetic", "--solve", "--frames", "8", "--stage"]
    assert main([*arguments, str(out), "--rig", str(zup_stage)]) == 0
    assert _residual_mm(capsys.readouterr().out) < 0.8  # the built-in face, upright: ~0.4 mm

    from warpface.pipelines.track_solve import read_solved_capture

    solved = read_solved_capture(out)
    skin = solved["skin"]
    assert skin.shape[0] == 8 and np.isfinite(skin).all()
    face = default_face()
    rest = face.points @ TURN.T + OFFSET
    assert np.abs(skin[0] - rest).max() < 0.004  # the skin stays in the rig's own (Z-up) frame


def test_track_recorded_rgbd_folder_drives_a_turned_rig(zup_rig, zup_stage, tmp_path, capsys):
    from warpface.pipelines.capture import synthetic_capture
    from warpface.tracking import RGBDFolder
    from warpface.usd.tracking_io import read_tracking

    capture = synthetic_capture(zup_rig, seconds=0.2, noise=False, device="cpu")
    try:
        folder = RGBDFolder.write(
            tmp_path / "take",
            capture.camera.frames(),
            capture.camera.intrinsics,
            fps=capture.camera.fps,
            fiducials=capture.camera.fiducial_layout(),
        )
    finally:
        capture.camera.close()
    out, upright = tmp_path / "recorded.usda", tmp_path / "upright.usda"
    assert main(["--quiet", "--device", "cpu", "track", str(folder), "--rig", str(zup_stage), "--stage", str(out)]) == 0
    assert "tracked 7 frames" in capsys.readouterr().out
    assert main(["--quiet", "--device", "cpu", "track", str(folder), "--stage", str(upright)]) == 0
    dense, reference = read_tracking(out)["dense"], read_tracking(upright)["dense"]
    # The camera saw the turned rig exactly as it sees the upright built-in face: the same track, turned (float32
    # points 1.2 m from the origin: a few vertices on a sparse triangle's edge land in its neighbour).
    difference = np.linalg.norm(dense - (reference @ TURN.T + OFFSET), axis=2)
    assert np.quantile(difference, 0.99) < 2e-5 and difference.max() < 1e-3
    moved = np.linalg.norm(capture.truth[3] - capture.truth[0], axis=1)  # the smile's peak
    error = np.linalg.norm(dense[3] - capture.truth[3], axis=1)
    assert error.mean() < 0.6 * moved.mean()


def test_track_rig_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys):
    for rig, expected in ((tmp_path / "nope.usda", "file not found"), (tmp_path / "rig.obj", "expected a rig stage")):
        out = tmp_path / "missing" / "c.usda"
        assert main(["--quiet", "track", "synthetic", "--rig", str(rig), "--stage", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and expected in err[0]
        assert not (tmp_path / "missing").exists()


def test_preview_frames_the_turned_face_upright_with_overlays(zup_stage, tmp_path):
    import cv2

    plain, marked = tmp_path / "plain.png", tmp_path / "marked.png"
    common = ["--quiet", "--device", "cpu", "preview", str(zup_stage), "--yaw", "0", "--pitch", "0"]
    assert main([*common, "--out", str(plain)]) == 0
    assert main([*common, "--out", str(marked), "--landmarks", "--muscles"]) == 0
    image = cv2.imread(str(plain))[:, :, ::-1].astype(int)
    skin = np.abs(image - image[0, 0]).sum(axis=2) > 30  # not background
    rows, cols = np.flatnonzero(skin.any(axis=1)), np.flatnonzero(skin.any(axis=0))
    height, width = skin.shape
    assert rows.size and 0.35 * width < cols.mean() < 0.65 * width  # centred, upright: the face fills the frame
    assert rows[-1] - rows[0] > 0.6 * height
    overlay = cv2.imread(str(marked))[:, :, ::-1].astype(int)
    blue = (overlay[:, :, 2] > overlay[:, :, 0] + 80) & ~(image[:, :, 2] > image[:, :, 0] + 80)
    red = (overlay[:, :, 0] > overlay[:, :, 2] + 120) & (overlay[:, :, 1] < 90)
    assert blue.sum() > 68 * 4 and red.sum() > 100
    # the landmark dots are where the face is: the chin (8) below the nose tip (30)
    from warpface.commands.face_view import FaceView, project
    from warpface.usd import read_rig

    rig = read_rig(zup_stage)
    view = FaceView.of(rig)
    camera = view.camera(rig.mesh.points[rig.landmarks], yaw_deg=0.0, pitch_deg=0.0)
    pixels, visible = project(camera, (width, height), view(rig.mesh.points[rig.landmarks]))
    assert visible.all() and pixels[8, 1] > pixels[30, 1] > pixels[27, 1]
    assert pixels[45, 0] > pixels[36, 0]  # the subject's left eye corner (45) on the image's right, seen face on


def test_preview_overlays_need_a_rig(tmp_path, capsys):
    face = default_face()
    obj = tmp_path / "face.obj"
    obj.write_text(
        "".join(f"v {x} {y} {z}\n" for x, y, z in face.points)
        + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in face.triangles)
    )
    assert main(["--quiet", "preview", str(obj), "--landmarks", "--out", str(tmp_path / "x.png")]) == 2
    assert "need a rig stage" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()


def test_presets_lists_relative_values_and_values_on_a_rig(zup_stage, tmp_path, capsys):
    from warpface.assets import PRESETS, preset_controls
    from warpface.usd import read_rig

    assert main(["presets"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 1 + len(PRESETS) and lines[1 + list(PRESETS).index("jawOpen")] == "jawOpen: jaw_open 0.25"
    assert main(["presets", "--rig", str(zup_stage), "mouthSmileLeft"]) == 0
    printed = capsys.readouterr().out.splitlines()[1]
    expected = preset_controls("mouthSmileLeft", read_rig(zup_stage))["zygomaticus_major_L"] * 1e3
    assert f"zygomaticus_major_L {expected:.4g} mm" in printed
    assert main(["presets", "nosuch"]) == 2
    assert "unknown preset 'nosuch'" in capsys.readouterr().err


@pytest.mark.slow  # end to end, over 20 s on the 2-core CI machine
def test_fit_on_a_turned_rig_keeps_the_jaw_in_the_preset(zup_rig, zup_stage, tmp_path, capsys):
    import shutil

    from warpface.usd.presets_io import read_presets

    rig_path = tmp_path / "rig.usda"
    shutil.copy(zup_stage, rig_path)
    controls = np.zeros(len(zup_rig.control_names))
    controls[zup_rig.control_names.index("jaw_open")] = 0.15
    controls[zup_rig.control_names.index("zygomaticus_major_L")] = 0.006
    target = zup_rig.model(device="cpu").evaluate(controls[None])[0]
    obj = tmp_path / "open.obj"
    obj.write_text(
        "".join(f"v {x:.7f} {y:.7f} {z:.7f}\n" for x, y, z in target)
        + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in zup_rig.mesh.triangles)
    )
    assert main(["--quiet", "--device", "cpu", "fit", str(obj), "--rig", str(rig_path), "--no-images"]) == 0
    preset = read_presets(rig_path)["open"]
    assert abs(preset["jaw_open"] - 0.15) < 0.01 and abs(preset["zygomaticus_major_L"] - 0.006) < 0.001


def test_animate_creates_a_missing_output_folder_and_removes_it_on_error(tmp_path, capsys):
    from warpface.drivers import ARKIT_CHANNELS

    columns = [name[0].upper() + name[1:] for name in ARKIT_CHANNELS]
    rows = ["Timecode,BlendshapeCount," + ",".join(columns)]
    for frame in range(6):
        weights = ["0"] * len(columns)
        weights[list(ARKIT_CHANNELS).index("jawOpen")] = f"{frame / 5:.3f}"
        rows.append(f"00:00:00:{frame:02d}.000,52," + ",".join(weights))
    take = tmp_path / "take.csv"
    take.write_text("\n".join(rows) + "\n")
    out = tmp_path / "a" / "b" / "anim.usda"
    assert main(["--quiet", "--device", "cpu", "animate", str(take), "--out", str(out), "--no-video"]) == 0
    assert out.is_file() and (out.parent / "anim_anim.usdc").is_file()
    bad = tmp_path / "c" / "d" / "anim.usda"
    assert main(["--quiet", "animate", str(take), "--out", str(bad), "--rig", str(take), "--no-video"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1 and not (tmp_path / "c").exists()
    blocked = tmp_path / "file"
    blocked.write_text("x")
    assert main(["--quiet", "animate", str(take), "--out", str(blocked / "anim.usda"), "--no-video"]) == 2
    assert "is a file, not a folder" in capsys.readouterr().err


def test_jaw_controls_in_presets_round_trip_through_a_centimetre_stage(zup_rig, tmp_path):
    from dataclasses import replace

    from pxr import Usd

    from warpface.usd import read_rig, write_rig
    from warpface.usd.presets_io import read_presets, write_presets

    stage = Usd.Stage.CreateInMemory("cm.usda")
    write_rig(stage, zup_rig, meters_per_unit=1.0)  # the rig in metres...
    path = tmp_path / "cm.usda"
    centimetres = Usd.Stage.CreateNew(str(path))
    write_rig(centimetres, read_rig(stage, meters_per_unit=0.01), meters_per_unit=0.01)  # ...and in centimetres
    preset = {"jaw_open": 0.2, "jaw_forward": 0.003, "jaw_left": -0.002, "zygomaticus_major_L": 0.004}
    write_presets(centimetres, {"open": preset}, meters_per_unit=1.0)
    centimetres.GetRootLayer().Save()
    back = read_presets(path)
    assert set(back["open"]) >= set(preset)
    for control, value in preset.items():
        assert abs(back["open"][control] - value) < 1e-9, control
    in_cm = read_presets(path, meters_per_unit=0.01)["open"]
    assert abs(in_cm["jaw_forward"] - 0.3) < 1e-9 and abs(in_cm["jaw_open"] - 0.2) < 1e-12
    no_jaw = Usd.Stage.CreateInMemory("nojaw.usda")
    write_rig(no_jaw, replace(zup_rig, jaw=None))
    with pytest.raises(ValueError, match="unknown muscle 'jaw_open'"):
        write_presets(no_jaw, {"open": {"jaw_open": 0.1}})
