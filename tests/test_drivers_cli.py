"""``warpface animate``: drivers in every format animate a rig stage end to end; bad input exits 2 cleanly."""

from __future__ import annotations

import math

import numpy as np
import pytest

from warpface.cli import main
from warpface.data import shared_data_path
from warpface.drivers import ARKIT_CHANNELS


def live_link_csv(path, rows: dict[str, np.ndarray], fps: int = 30, extra_header: str = ""):
    """A Live Link Face CSV written here by hand (not by warpface's writer)."""
    frames = len(next(iter(rows.values())))
    columns = [name[0].upper() + name[1:] for name in ARKIT_CHANNELS]
    lines = ["Timecode,BlendshapeCount," + ",".join(columns) + ",HeadYaw,HeadPitch,HeadRoll" + extra_header]
    for frame in range(frames):
        seconds, sub = divmod(frame, fps)
        weights = [f"{rows[n][frame]:.6f}" if n in rows else "0" for n in ARKIT_CHANNELS]
        lines.append(
            f"10:20:{seconds:02d}:{sub:02d}.000,52,"
            + ",".join(weights)
            + ",0.1,0.0,0.0"
            + (",1" if extra_header else "")
        )
    path.write_text("\n".join(lines) + "\n")
    return path


def baked_points(stage_path, time_code):
    from pxr import Usd

    from warpface import usd

    stage = Usd.Stage.Open(str(stage_path))
    return np.asarray(
        usd.rig_prims(stage).skin.GetAttribute("points").Get(Usd.TimeCode(time_code)), dtype=np.float64
    ), stage


@pytest.fixture(scope="module")
def landmarks():
    from warpface.assets import default_landmarks

    return default_landmarks()


def test_live_link_drives_brows_and_a_one_sided_smile(tmp_path, capsys, landmarks):
    pulse = np.r_[np.zeros(5), np.linspace(0, 1, 10), np.ones(5)]
    quiet = np.zeros_like(pulse)
    driver = live_link_csv(
        tmp_path / "take.csv",
        {"browInnerUp": np.r_[pulse, quiet], "mouthSmileLeft": np.r_[quiet, pulse], "jawOpen": np.r_[quiet, quiet]},
        extra_header=",Mystery",
    )
    out = tmp_path / "out.usda"
    assert main(["--quiet", "--device", "cpu", "animate", str(driver), "--out", str(out), "--no-video"]) == 0
    printed = capsys.readouterr().out
    assert "ignored unknown columns Mystery" in printed and printed.count("jawOpen") == 0  # the rig's jaw drives it
    rest, stage = baked_points(out, 0)
    assert stage.GetTimeCodesPerSecond() == 30 and stage.GetFramesPerSecond() == 30
    assert stage.GetPrimAtPath("/Face/Drivers/default/mouthSmileLeft")
    brows, _ = baked_points(out, 19)
    rise = (brows - rest)[landmarks[[21, 22]], 1]
    assert rise.min() > 2e-3  # metres: the inner brows go up by millimetres
    smile, _ = baked_points(out, 39)
    lift = (smile - rest)[landmarks[[54, 48]], 1]
    assert lift[0] > 2e-3 and lift[0] > 5 * abs(lift[1])  # the subject's left corner (+x) rises, the right barely


def test_jaw_open_drops_the_chin_in_the_baked_cache(tmp_path, landmarks):
    opening = np.r_[np.zeros(3), np.linspace(0, 1, 8), np.ones(3)]
    driver = live_link_csv(tmp_path / "jaw.csv", {"jawOpen": opening})
    out = tmp_path / "jaw.usda"
    assert main(["--quiet", "--device", "cpu", "animate", str(driver), "--out", str(out), "--no-video"]) == 0
    rest, stage = baked_points(out, 0)
    opened, _ = baked_points(out, 13)
    jaw = next(p for p in stage.Traverse() if p.GetTypeName() == "WarpFaceJaw")
    assert jaw.GetAttribute("jawOpen").GetNumTimeSamples() == len(opening)
    assert jaw.GetAttribute("jawOpen").Get(13) > 0.05  # radians
    drop = (opened - rest)[landmarks[8]]  # iBUG 8, the chin's lowest point [m]
    assert drop[1] < -3e-3, f"chin moved {drop * 1000} mm"
    brows = np.abs(opened - rest)[landmarks[17:27]].max()
    assert brows < 1e-4  # the upper face stays


def test_audio2face_style_stage_drives_the_rig(tmp_path):
    from pxr import Usd, UsdSkel

    path = tmp_path / "a2f.usda"
    stage = Usd.Stage.CreateNew(str(path))
    stage.SetTimeCodesPerSecond(60)
    animation = UsdSkel.Animation.Define(stage, "/World/A2F/anim")
    animation.CreateBlendShapesAttr(["browInnerUp", "noseSneerLeft", "eyeLookUpLeft"])
    weights = animation.CreateBlendShapeWeightsAttr()
    for frame in range(0, 61, 2):
        weights.Set([frame / 60, 0.5, 0.2], Usd.TimeCode(frame))
    stage.Save()
    out = tmp_path / "a2f_out.usdc"
    assert (
        main(["--quiet", "--device", "cpu", "animate", str(path), "--out", str(out), "--no-video", "--fps", "30"]) == 0
    )
    rest, baked = baked_points(out, 0)
    assert baked.GetEndTimeCode() == 30
    last, _ = baked_points(out, 30)
    assert np.abs(last - rest).max() > 1e-3


@pytest.mark.parametrize("face", ["built-in", "ict"])
def test_real_openface_recording_animates_a_face(tmp_path, face, capsys):
    recording = shared_data_path("auplayer_openface_au", "19_3_au.txt")
    if recording is None:
        pytest.skip("../shared/data/auplayer_openface_au is not present")
    arguments = [
        "--quiet",
        "--device",
        "cpu",
        "animate",
        str(recording),
        "--out",
        str(tmp_path / "of.usda"),
        "--video-max-frames",
        "100",
    ]
    if face == "ict":
        from warpface import usd
        from warpface.assets import default_rig
        from warpface.data import ict_face_region, ict_landmark_indices
        from warpface.mesh import FaceMesh

        if ict_face_region() is None:
            pytest.skip("ICT-FaceKit data not found in ../shared/data")
        ict = default_rig(FaceMesh.from_obj(ict_face_region()), ict_landmark_indices(), name="ICTFace", device="cpu")
        usd.write_rig(tmp_path / "ict.usda", ict, meters_per_unit=0.01, fps=20.0)
        arguments += ["--rig", str(tmp_path / "ict.usda"), "--no-video"]
    assert main(arguments) == 0
    printed = capsys.readouterr().out
    assert "AU26" not in printed  # the jaw drop drives the rig's jaw
    from warpface import usd

    animation = usd.read_animation(tmp_path / "of.usda")
    assert len(animation.times) > 250 and np.abs(animation.contractions).max() > 0
    smile = animation.contractions[:, animation.muscle_names.index("zygomaticus_major_L")]
    assert smile.max() > 3 * max(smile.min(), 1e-12)  # follows the recording's AU12, not a constant
    if face == "built-in":
        import cv2

        video = cv2.VideoCapture(str(tmp_path / "of.mp4"))
        frames = int(video.get(cv2.CAP_PROP_FRAME_COUNT))
        video.release()
        assert frames == len(range(0, len(animation.times), math.ceil(len(animation.times) / 100)))
        assert (tmp_path / "of_anim.usdc").exists()


def test_stored_mapping_on_the_rig_stage_is_used_and_edits_matter(tmp_path):
    from warpface import usd
    from warpface.assets import default_rig
    from warpface.drivers import Mapping
    from warpface.usd.mapping_io import write_mapping

    rig = default_rig(device="cpu")
    stage = usd.write_rig(tmp_path / "rig.usda", rig)
    write_mapping(stage, Mapping.from_entries([("browInnerUp", "zygomaticus_major_R", 0.01)], name="default"))
    stage.GetRootLayer().Save()
    driver = live_link_csv(tmp_path / "t.csv", {"browInnerUp": np.linspace(0, 1, 40)})
    assert (
        main(
            [
                "--quiet",
                "--device",
                "cpu",
                "animate",
                str(driver),
                "--rig",
                str(tmp_path / "rig.usda"),
                "--out",
                str(tmp_path / "o.usda"),
                "--no-video",
            ]
        )
        == 0
    )
    animation = usd.read_animation(tmp_path / "o.usda")
    driven = animation.contractions[:, animation.muscle_names.index("zygomaticus_major_R")]
    np.testing.assert_allclose(driven[-1], 0.01, rtol=1e-9)
    assert (
        np.abs(np.delete(animation.contractions, animation.muscle_names.index("zygomaticus_major_R"), axis=1)).max()
        == 0
    )
    write_mapping(stage, Mapping.from_entries([("browInnerUp", "procerus", 0.004)], name="strong"))
    stage.GetRootLayer().Save()
    assert (
        main(
            [
                "--quiet",
                "--device",
                "cpu",
                "animate",
                str(driver),
                "--rig",
                str(tmp_path / "rig.usda"),
                "--map",
                "strong",
                "--out",
                str(tmp_path / "o.usda"),
                "--no-video",
            ]
        )
        == 0
    )
    animation = usd.read_animation(tmp_path / "o.usda")
    np.testing.assert_allclose(animation.contractions[-1, animation.muscle_names.index("procerus")], 0.004, rtol=1e-9)
    assert animation.contractions[:, animation.muscle_names.index("zygomaticus_major_R")].max() == 0


def test_weights_outside_range_are_clamped_and_reported_once(tmp_path, capsys):
    driver = live_link_csv(tmp_path / "t.csv", {"browInnerUp": np.array([0.0, 1.7, 0.5, -0.2])})
    assert (
        main(["--quiet", "--device", "cpu", "animate", str(driver), "--out", str(tmp_path / "o.usda"), "--no-video"])
        == 0
    )
    printed = capsys.readouterr().out
    assert printed.count("clamped") == 1 and "2 values outside [0, 1]" in printed


def _bad_inputs(tmp_path):
    header = "Timecode,BlendshapeCount,BrowInnerUp\n"
    cases = {
        "empty": "",
        "missing column": "BlendshapeCount,BrowInnerUp\n52,0.1\n",
        "nan": header + "00:00:00:01.000,52,0.1\n00:00:00:02.000,52,NaN\n",
        "duplicate timestamp": header + "00:00:00:01.000,52,0.1\n00:00:00:01.000,52,0.2\n",
        "non-monotonic": header + "00:00:00:03.000,52,0.1\n00:00:00:01.000,52,0.2\n",
        "only unknown channels": (
            "Timecode,BlendshapeCount,EyeLookUpLeft\n00:00:00:01.000,52,0.1\n00:00:00:02.000,52,0.1\n"
        ),
    }
    paths = {}
    for name, text in cases.items():
        paths[name] = tmp_path / f"{name.replace(' ', '_')}.csv"
        paths[name].write_text(text)
    return paths


def test_bad_input_one_line_exit_2_nothing_written(tmp_path, capsys):
    from warpface import usd
    from warpface.assets import default_rig
    from warpface.drivers import Mapping
    from warpface.usd.mapping_io import write_mapping

    out_dir = tmp_path / "out"
    out_dir.mkdir()
    good = live_link_csv(tmp_path / "good.csv", {"jawOpen": np.linspace(0, 1, 5), "browInnerUp": np.linspace(0, 1, 5)})
    stage = usd.write_rig(tmp_path / "jaw_map.usda", default_rig(device="cpu"))
    write_mapping(stage, Mapping.from_entries([("jawOpen", "jaw_right", 0.3)], name="jaw"))  # jaw_left < 0 here
    stage.GetRootLayer().Save()
    runs = {name: [str(path)] for name, path in _bad_inputs(tmp_path).items()}
    runs["missing file"] = [str(tmp_path / "nope.csv")]
    runs["rig missing a mapped control"] = [str(good), "--map", f"{tmp_path / 'jaw_map.usda'}:jaw"]
    runs["bad rig"] = [str(good), "--rig", str(good)]
    runs["bad output"] = [str(good), "--out", str(out_dir / "x.obj")]
    for name, arguments in runs.items():
        if "--out" not in arguments:
            arguments = arguments + ["--out", str(out_dir / "o.usda")]
        code = main(["--quiet", "--device", "cpu", "animate", *arguments, "--no-video"])
        captured = capsys.readouterr()
        assert code == 2, name
        lines = captured.err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("warpface animate: error:"), (name, captured.err)
        assert list(out_dir.iterdir()) == [], name


@pytest.mark.parametrize("suffix", [".csv", ".usda"])
def test_animated_rig_exports_arkit_weights_that_reproduce_the_take(tmp_path, suffix):
    from warpface.usd import read_driver
    from warpface.usd.skel_io import export_arkit_weights

    t = np.arange(45) / 30.0
    take = {
        "mouthSmileLeft": np.sin(np.pi * t / t[-1]) ** 2,
        "noseSneerRight": 0.6 * t / t[-1],
        "jawOpen": 0.5 * t / t[-1],
    }
    driver = live_link_csv(tmp_path / "take.csv", take)
    assert (
        main(["--quiet", "--device", "cpu", "animate", str(driver), "--out", str(tmp_path / "o.usda"), "--no-video"])
        == 0
    )
    exported = read_driver(export_arkit_weights(tmp_path / "o.usda", tmp_path / f"arkit{suffix}"))
    assert set(exported.names) <= set(ARKIT_CHANNELS) and exported.frame_count == 45
    np.testing.assert_allclose(exported.times, t, atol=1e-4)
    for name, values in take.items():
        np.testing.assert_allclose(exported.channel(name), values, atol=0.02)
    others = [k for k, n in enumerate(exported.names) if n not in take]
    assert exported.values[:, others].max() < 0.02
