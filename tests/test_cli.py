"""The ``warpface`` command line: help everywhere, the demo's outputs, clear errors and exit codes."""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest

from warpface.cli import build_parser, main


def test_help_for_every_command(capsys):
    for command in ([], ["demo"], ["bake"], ["preview"], ["validate"], ["track"]):
        with pytest.raises(SystemExit) as exit_info:
            main([*command, "--help"])
        assert exit_info.value.code == 0
        assert "usage: warpface" in capsys.readouterr().out


def test_console_script_is_installed():
    result = subprocess.run(
        [sys.executable, "-m", "warpface.cli", "--help"], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0 and "demo" in result.stdout


@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    assert main(["--device", "cpu", "--quiet", "demo", "--out", str(out), "--seconds", "0.4", "--no-video"]) == 0
    return out


def test_demo_writes_stage_cache_and_pictures(demo_dir):
    from pxr import Usd, UsdGeom

    from warpface.usd import frame_times, read_rig, rig_prims

    for name in ("face.usda", "face_anim.usdc", "expressions.png", "smile.png", "heatmap_thinking.png"):
        assert (demo_dir / name).is_file(), name
    stage = Usd.Stage.Open(str(demo_dir / "face.usda"))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0 and UsdGeom.GetStageUpAxis(stage) == "Y"
    assert stage.GetTimeCodesPerSecond() == 30.0 and stage.GetFramesPerSecond() == 30.0
    times = frame_times(stage)
    assert len(times) == 4 * 12 + 1
    points = rig_prims(stage).skin.GetAttribute("points")
    rest = read_rig(stage).mesh.points
    moved = [np.abs(np.asarray(points.Get(Usd.TimeCode(t))) - rest).max() for t in times]
    assert moved[0] < 1e-6 and max(moved) > 1e-3  # neutral first, expressions later


def test_validate_exit_codes(demo_dir, tmp_path, capsys):
    assert main(["validate", str(demo_dir / "face.usda")]) == 0
    broken = tmp_path / "broken.usda"
    text = (demo_dir / "face.usda").read_text()
    broken.write_text(text.replace("rel warpFace:muscles = [", "rel warpFace:muscles = [\n            </Nowhere>,", 1))
    assert main(["validate", str(broken)]) == 1
    assert "Nowhere" in capsys.readouterr().out


def test_bad_input_gives_one_line_error_and_exit_code_2(tmp_path, capsys):
    assert main(["bake", str(tmp_path / "missing.usda")]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and error[0].startswith("warpface bake: error:")


def _one_line_error(capsys, argv, *fragments):
    """``main(argv)`` exits 2 with exactly one stderr line naming every fragment, nothing on stdout."""
    try:
        code = main(argv)
    except SystemExit as exit_info:  # argparse usage errors
        code = exit_info.code
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert code == 2 and len(lines) == 1, (argv, captured.err)
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    assert "Traceback" not in captured.err and "pxrInternal" not in captured.err
    return lines[0]


def test_pxr_and_file_errors_are_one_line(demo_dir, tmp_path, capsys):
    text_file = tmp_path / "notes.usda"
    text_file.write_text("shopping list: eggs, milk\n")
    _one_line_error(capsys, ["validate", str(text_file)], "notes.usda", "not a valid usda layer")
    _one_line_error(capsys, ["bake", str(text_file)], "notes.usda")
    _one_line_error(capsys, ["validate", str(tmp_path / "missing.usda")], "missing.usda", "not found")
    # a stage whose cache sublayer is a truncated .usdc
    truncated = tmp_path / "cut_anim.usdc"
    truncated.write_bytes((demo_dir / "face_anim.usdc").read_bytes()[:4000])
    stage = tmp_path / "cut.usda"
    stage.write_text((demo_dir / "face.usda").read_text().replace("@./face_anim.usdc@", "@./cut_anim.usdc@"))
    for command in ("validate", "bake", "preview"):
        _one_line_error(capsys, [command, str(stage)], "cut_anim.usdc", "truncated")
    # an existing cache file that is not sublayered and corrupt
    fresh = tmp_path / "fresh.usda"
    fresh.write_text((demo_dir / "face.usda").read_text().replace("@./face_anim.usdc@", ""))
    (tmp_path / "fresh_anim.usdc").write_bytes(b"garbage")
    _one_line_error(capsys, ["bake", str(fresh)], "fresh_anim.usdc")
    assert main(["--quiet", "validate", str(fresh)]) == 1
    assert "fresh_anim.usdc" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv, fragments",
    [
        (["demo", "--fps", "0"], ["--fps", "> 0"]),
        (["demo", "--seconds", "-1"], ["--seconds", "> 0"]),
        (["--device", "cuda:7", "demo"], ["cuda:7"]),
        (["demo", "--device", "gpu"], ["gpu", "unknown device"]),
    ],
)
def test_demo_argument_errors_write_nothing(tmp_path, capsys, argv, fragments):
    out = tmp_path / "never"
    _one_line_error(capsys, [*argv, "--out", str(out)] if argv[0] == "demo" else [*argv, "--out", str(out)], *fragments)
    assert not out.exists()


def test_device_is_checked_before_and_after_the_command(demo_dir, capsys):
    import warp as wp

    count = wp.get_cuda_device_count()
    stage = str(demo_dir / "face.usda")
    line = _one_line_error(capsys, ["--device", f"cuda:{count + 6}", "validate", stage], f"cuda:{count + 6}")
    assert ("no CUDA device is available" in line) == (count == 0)
    _one_line_error(capsys, ["preview", stage, "--device", f"cuda:{count}"], f"cuda:{count}")
    assert main(["validate", stage, "--device", "cpu", "--quiet"]) == 0
    assert "no problems" in capsys.readouterr().out


def test_bake_refuses_its_own_stage_as_cache(demo_dir, tmp_path, capsys):
    import shutil

    for name in ("face.usda", "face_anim.usdc"):
        shutil.copy(demo_dir / name, tmp_path / name)
    stage = tmp_path / "face.usda"
    before = stage.read_bytes()
    _one_line_error(capsys, ["bake", str(stage), "--cache", str(stage)], "is the stage itself")
    (tmp_path / "rig_part.usda").write_text('#usda 1.0\ndef Xform "Extra"\n{\n}\n')
    stage.write_text(stage.read_text().replace("@./face_anim.usdc@", "@./face_anim.usdc@, @./rig_part.usda@"))
    _one_line_error(
        capsys, ["bake", str(stage), "--cache", str(tmp_path / "rig_part.usda")], "rig_part.usda", "own layers"
    )
    stage.write_bytes(before)
    assert main(["--quiet", "bake", str(stage)]) == 0  # re-baking into the existing cache sublayer is fine
    assert "@./face_anim.usdc@" in stage.read_text() and stage.read_text().count("face_anim.usdc") == 1


@pytest.mark.parametrize(
    "argv, fragments",
    [
        (["--step", "0"], ["--step", "> 0"]),
        (["--step", "-2"], ["--step"]),
        (["--step", "nan"], ["--step", "finite"]),
        (["--step", "1e-9"], ["frames", "limit", "--max-frames"]),
        (["--end", "1e7"], ["frames", "limit", "--max-frames"]),
        (["--start", "5", "--end", "1"], ["before start"]),
    ],
)
def test_bake_refuses_bad_frame_ranges(demo_dir, capsys, argv, fragments):
    _one_line_error(capsys, ["bake", str(demo_dir / "face.usda"), *argv], *fragments)


def _edited_stage(demo_dir, tmp_path, name, edit):
    stage = tmp_path / name
    text = (demo_dir / "face.usda").read_text().replace("@./face_anim.usdc@", "")
    stage.write_text(edit(text))
    return stage


def _huge_contraction(text):
    start = text.index("double contraction.timeSamples = {")
    sample = text.index("                3: ", start)
    end = text.index("\n", sample)
    return text[:sample] + "                3: 1e30," + text[end:]


@pytest.mark.parametrize(
    "name, edit, fragment",
    [
        ("long.usda", lambda t: re.sub(r"endTimeCode = [0-9.]+", "endTimeCode = 1e15", t, count=1), "limit"),
        (
            "backwards.usda",
            lambda t: re.sub(r"endTimeCode = [0-9.]+", "endTimeCode = -5", t, count=1),
            "invalid time range",
        ),
        ("huge.usda", _huge_contraction, "time 3"),
    ],
)
def test_validate_reports_what_bake_refuses(demo_dir, tmp_path, capsys, name, edit, fragment):
    stage = _edited_stage(demo_dir, tmp_path, name, edit)
    assert stage.read_text() != (demo_dir / "face.usda").read_text().replace("@./face_anim.usdc@", "")
    assert main(["--quiet", "validate", str(stage)]) == 1
    assert fragment in capsys.readouterr().out
    _one_line_error(capsys, ["--quiet", "bake", str(stage)], fragment)
    assert not (tmp_path / stage.name.replace(".usda", "_anim.usdc")).exists()


def test_bake_streams_in_chunks_and_matches_whole_evaluation(demo_dir, tmp_path):
    import shutil

    from pxr import Usd

    from warpface import usd
    from warpface.expression import ExpressionModel

    shutil.copy(demo_dir / "face.usda", tmp_path / "face.usda")
    stage_path = tmp_path / "face.usda"
    cache = usd.bake(str(stage_path), chunk_frames=5, progress=False, device="cpu")
    stage = Usd.Stage.Open(str(stage_path))
    rig = usd.read_rig(stage)
    times = usd.frame_times(stage)
    animation = usd.read_animation(stage, times)
    expected = ExpressionModel.from_rig(rig, device="cpu").evaluate(  # muscles, then the jaw's controls
        animation.controls, wrinkle_depths=animation.wrinkle_depths
    )
    points = usd.rig_prims(stage).skin.GetAttribute("points")
    baked = np.stack([np.asarray(points.Get(Usd.TimeCode(t))) for t in times])
    assert cache.stat().st_size > 0 and np.array_equal(baked, expected)


def test_output_files_get_umask_permissions(tmp_path):
    import os
    import stat

    from warpface._files import atomic_path

    old = os.umask(0o027)
    try:
        with atomic_path(tmp_path / "out.txt") as temporary:
            temporary.write_text("x")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "out.txt").stat().st_mode) == 0o640
    (tmp_path / "out.txt").chmod(0o604)
    with atomic_path(tmp_path / "out.txt") as temporary:
        temporary.write_text("y")
    assert stat.S_IMODE((tmp_path / "out.txt").stat().st_mode) == 0o604  # an existing file keeps its mode


def test_the_umask_is_read_without_being_set(monkeypatch):
    """Bakes write files from worker threads: reading the umask must not set it, even for a moment."""
    import os
    import sys

    from warpface._files import new_file_mode, process_umask

    if not sys.platform.startswith("linux"):
        pytest.skip("/proc/self/status is Linux's")
    old = os.umask(0o027)
    try:
        calls = []
        monkeypatch.setattr(os, "umask", lambda mask: calls.append(mask) or 0)
        assert process_umask() == 0o027 and new_file_mode("/nonexistent/x") == 0o640
        assert calls == []
    finally:
        monkeypatch.undo()
        os.umask(old)


def test_atomic_path_without_creating_hands_out_a_fresh_name_and_cleans_up(tmp_path):
    """``create=False``: the temporary name does not exist yet, lies beside the target with its suffix, and is
    renamed onto the target on success; a failed block leaves the old target and no temporary behind."""
    from pxr import Sdf

    from warpface._files import atomic_path
    from warpface.usd._files import export_layer_atomically

    target = tmp_path / "root.usda"
    target.write_text("old")
    with atomic_path(target, ".usda", create=False) as temporary:
        assert not temporary.exists() and temporary.parent == tmp_path and temporary.suffix == ".usda"
        temporary.write_text("new")
    assert target.read_text() == "new"
    with pytest.raises(RuntimeError):
        with atomic_path(target, ".usda", create=False) as temporary:
            temporary.write_text("partial")
            raise RuntimeError("writer failed")
    assert target.read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == ["root.usda"]
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.comment = "exported"
    export_layer_atomically(layer, target)
    assert Sdf.Layer.OpenAsAnonymous(str(target)).comment == "exported"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["root.usda"]


def test_version_and_quiet_output():
    import warpface

    result = subprocess.run(
        [sys.executable, "-m", "warpface.cli", "--version"], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0 and result.stdout.strip() == f"warpface {warpface.__version__}"
    noise = subprocess.run(
        [
            sys.executable,
            "-c",
            "import warpface, warpface.assets; warpface.init_runtime(); warpface.assets.default_rig()",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert noise.returncode == 0 and noise.stdout == "" and noise.stderr == "", noise.stderr


def test_quiet_keeps_the_result_line(demo_dir, tmp_path):
    out = tmp_path / "q.png"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "warpface.cli",
            "--quiet",
            "preview",
            str(demo_dir / "face.usda"),
            "--out",
            str(out),
            "--width",
            "64",
            "--height",
            "72",
            "--device",
            "cpu",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0 and result.stdout.strip() == f"wrote {out}" and result.stderr == "", result.stderr


def test_every_option_has_help():
    parser = build_parser()
    subparsers = next(a for a in parser._actions if a.dest == "command").choices
    for name, sub in [("warpface", parser), *subparsers.items()]:
        for action in sub._actions:
            if action.option_strings and action.dest not in ("help", "version"):
                assert action.help, f"{name} {action.option_strings} has no help"


def test_preview_of_a_baked_frame(demo_dir, tmp_path, capsys):
    out = tmp_path / "frame.png"
    assert (
        main(
            [
                "preview",
                str(demo_dir / "face.usda"),
                "--time",
                "6",
                "--out",
                str(out),
                "--width",
                "160",
                "--height",
                "180",
                "--heat",
            ]
        )
        == 0
    )
    assert out.is_file()
    _one_line_error(
        capsys,
        ["preview", str(demo_dir / "face.usda"), "--time", "9999", "--out", str(tmp_path / "late.png")],
        "9999",
        "outside the stage's time range",
    )
    assert not (tmp_path / "late.png").exists()


def test_capture_from_track_is_previewed_and_validated(tmp_path, capsys):
    import cv2

    stage = tmp_path / "cap.usda"
    assert main(["--device", "cpu", "--quiet", "track", "synthetic", "--stage", str(stage), "--frames", "4"]) == 0
    capsys.readouterr()
    assert main(["validate", str(stage), "--quiet"]) == 0
    assert "no problems" in capsys.readouterr().out
    frame, video = tmp_path / "cap.png", tmp_path / "cap.mp4"
    assert (
        main(
            [
                "--quiet",
                "preview",
                str(stage),
                "--out",
                str(frame),
                "--video",
                str(video),
                "--width",
                "96",
                "--height",
                "112",
            ]
        )
        == 0
    )
    image = cv2.imread(str(frame))
    assert image.shape == (112, 96, 3) and image.std() > 5  # a face, not a blank frame
    capture = cv2.VideoCapture(str(video))
    assert int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) == 4
    capture.release()
    # a capture whose value clip is truncated is one line, not a traceback
    chunk = next((tmp_path / "cap_track").glob("chunk_*.usdc"))
    chunk.write_bytes(chunk.read_bytes()[:200])
    for command in ("validate", "preview"):
        _one_line_error(capsys, [command, str(stage), "--quiet"], "cap.usda", "truncated")
