"""``warpface calibrate``: bad input is one line naming the file (exit 2, nothing written); a run writes a rig,
a report and a picture."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from warpface import usd
from warpface.assets import default_rig
from warpface.assets.rig import face_frame
from warpface.cli import main

pytest.importorskip("pxr")


def write_obj(path, points, triangles):
    with open(path, "w") as handle:
        handle.writelines(f"v {x!r} {y!r} {z!r}\n" for x, y, z in np.asarray(points, dtype=np.float64).tolist())
        handle.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in triangles)
    return path


@pytest.fixture(scope="module")
def stage(tmp_path_factory):
    rig = default_rig(device="cpu", calibrated=False)
    # the default face with the muscles the examples use and the jaw, no wrinkles: every stage of the calibration
    # runs, on a rig that rebuilds (each muscle's fold guard) and refits in a fraction of the full rig's time
    rig = replace(rig, muscles=[m for m in rig.muscles if m.name.startswith("zygomaticus_major")], wrinkles=[])
    path = tmp_path_factory.mktemp("rig") / "face.usda"
    usd.write_rig(path, rig)
    return rig, path


def _error_line(capsys) -> str:
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


def test_bad_input_is_one_line_naming_the_file(stage, tmp_path, capsys):
    rig, path = stage
    mesh = rig.mesh
    good = write_obj(tmp_path / "jawOpen.obj", mesh.points, mesh.triangles)
    out = tmp_path / "out.usda"
    nan = mesh.points.copy()
    nan[3] = np.nan
    cases = [
        ([str(write_obj(tmp_path / "smirk.obj", mesh.points, mesh.triangles))], ["--names", "arkit"], "smirk.obj"),
        ([str(write_obj(tmp_path / "bad.obj", nan, mesh.triangles))], [], "bad.obj"),
        ([str(write_obj(tmp_path / "few.obj", mesh.points[:5], [[0, 1, 2]]))], [], "few.obj"),
        ([str(tmp_path / "missing.obj")], [], "missing.obj"),
        ([str(good)], ["--holdout", "nope"], "nope"),
    ]
    for shapes, extra, needle in cases:
        code = main(["calibrate", str(path), "--shapes", *shapes, "--out", str(out), *extra, "--quiet"])
        line = _error_line(capsys)
        assert code == 2 and needle in line, line
        assert not out.exists()
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["calibrate", str(path), "--shapes", str(empty), "--out", str(out)]) == 2
    assert "no example shapes" in _error_line(capsys)
    assert main(["calibrate", str(path), "--shapes", str(good), "--out", str(tmp_path / "out.txt")]) == 2
    assert ".usda" in _error_line(capsys)
    assert not out.exists()


@pytest.mark.slow
def test_calibrate_writes_rig_report_and_picture(stage, tmp_path, capsys):
    rig, path = stage
    scale = face_frame(rig.mesh, rig.landmarks).scale
    model = rig.model(device="cpu")
    folder = tmp_path / "shapes"
    folder.mkdir()
    for name, controls in {
        "mouthSmile_L": {"zygomaticus_major_L": 0.12 * scale},
        "mouthSmile_R": {"zygomaticus_major_R": 0.12 * scale},
        "jawOpen": {"jaw_open": 0.2},
    }.items():
        write_obj(folder / f"{name}.obj", model.evaluate(controls), rig.mesh.triangles)
    out = tmp_path / "calibrated.usda"
    code = main(
        ["calibrate", str(path), "--shapes", str(folder), "--names", "arkit", "--out", str(out)]
        + ["--holdout", "mouthSmileRight", "--iterations", "1", "--device", "cpu", "--quiet"]
    )
    printed = capsys.readouterr().out
    assert code == 0, printed
    report = json.loads(out.with_name("calibrated_calibration.json").read_text())
    assert out.with_name("calibrated_calibration.png").stat().st_size > 1000
    assert [s["name"] for s in report["reach"]["held_out"]["before"]["shapes"]] == ["mouthSmileRight"]
    assert {s["name"] for s in report["reach"]["train"]["after"]["shapes"]} == {"mouthSmileLeft", "jawOpen"}
    back = usd.read_rig(usd.open_stage(out))
    assert back.muscle_names == rig.muscle_names
    # the shapes came from this very rig: already reached, so a calibration can only keep or improve it
    train = report["reach"]["train"]
    assert train["after"]["mean_reduction"] >= train["before"]["mean_reduction"] - 1e-9
    assert report["message"] in printed


def test_help(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["calibrate", "--help"])
    assert exit_info.value.code == 0
    text = capsys.readouterr().out
    assert "usage: warpface calibrate" in text and "--holdout" in text and "--names" in text
