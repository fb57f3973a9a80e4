"""The ``warpface`` command line: help everywhere, the demo's outputs, clear errors and exit codes."""

from __future__ import annotations

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
    result = subprocess.run([sys.executable, "-m", "warpface.cli", "--help"], capture_output=True, text=True, timeout=120)
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


def test_preview_of_a_baked_frame(demo_dir, tmp_path):
    out = tmp_path / "frame.png"
    assert main(["preview", str(demo_dir / "face.usda"), "--time", "6", "--out", str(out), "--width", "160", "--height", "180", "--heat"]) == 0
    assert out.is_file()
