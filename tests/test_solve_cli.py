"""``warpface fit`` and fitted controls as presets on the rig stage (USD round trips)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import small_face_rig

from warpface import usd
from warpface.cli import main
from warpface.usd.presets_io import read_presets, write_presets

pytest.importorskip("pxr")


def write_obj(path, points, triangles):
    with open(path, "w") as handle:
        handle.writelines(f"v {x!r} {y!r} {z!r}\n" for x, y, z in np.asarray(points, dtype=np.float64).tolist())
        handle.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in triangles)


@pytest.fixture
def rig_stage(tmp_path):
    rig = small_face_rig()
    path = tmp_path / "face.usda"
    usd.write_rig(path, rig)
    return rig, path


def test_presets_round_trip_in_stage_units(rig_stage, tmp_path):
    rig, path = rig_stage
    stage = usd.open_stage(path)
    presets = {"half smile": {"zygomaticus major L": 0.004, "orbicularis_oris": 0.3}, "brow": {"frontalis_R": 0.002}}
    write_presets(stage, presets, residuals={"brow": 1e-4})
    stage.GetRootLayer().Save()
    back = read_presets(path)
    assert set(back) == set(presets)
    for name, values in presets.items():
        for muscle in rig.muscle_names:
            assert back[name][muscle] == pytest.approx(values.get(muscle, 0.0), abs=1e-15)
    in_mm = read_presets(path, meters_per_unit=0.001)
    assert in_mm["half smile"]["zygomaticus major L"] == pytest.approx(4.0)
    assert in_mm["half smile"]["orbicularis_oris"] == pytest.approx(0.3)  # dimensionless
    with pytest.raises(ValueError, match="unknown muscle 'nose'"):
        write_presets(stage, {"x": {"nose": 1.0}})
    with pytest.raises(ValueError, match="non-finite"):
        write_presets(stage, {"x": {"frontalis_R": np.nan}})


def test_fit_command_writes_presets_and_reports(rig_stage, tmp_path, capsys):
    rig, path = rig_stage
    truth = {"zygomaticus major L": 0.006, "orbicularis_oris": 0.25}
    target = rig.model(device="cpu").evaluate(truth)
    obj = tmp_path / "grin.obj"
    write_obj(obj, target, rig.mesh.triangles)
    assert main(["--device", "cpu", "fit", str(obj), "--rig", str(path), "--out", str(tmp_path / "maps")]) == 0
    out = capsys.readouterr().out
    assert "preset 'grin': converged" in out and "before mean" in out and "controls: " in out
    presets = read_presets(path)
    for muscle, value in truth.items():
        assert presets["grin"][muscle] == pytest.approx(value, rel=1e-3)
    assert presets["grin"]["frontalis_R"] == pytest.approx(0.0, abs=1e-6)
    assert (tmp_path / "maps" / "grin_error.png").stat().st_size > 0
    assert usd.read_rig(path).muscle_names == rig.muscle_names  # the rig itself is intact


def test_fit_command_errors_name_the_file(rig_stage, tmp_path, capsys):
    rig, path = rig_stage
    short = tmp_path / "short.obj"
    write_obj(short, rig.mesh.points[:-1], rig.mesh.triangles[:1])
    assert main(["--device", "cpu", "fit", str(short), "--rig", str(path), "--no-images"]) == 2
    assert "short.obj" in capsys.readouterr().err
    flipped = tmp_path / "flipped.obj"
    write_obj(flipped, rig.mesh.points, rig.mesh.triangles[:, ::-1])
    assert main(["--device", "cpu", "fit", str(flipped), "--rig", str(path), "--no-images"]) == 2
    assert "topology differs" in capsys.readouterr().err
    assert main(["--device", "cpu", "fit", str(tmp_path / "missing.obj"), "--rig", str(path)]) == 2
    assert read_presets(path) == {}


def test_fit_command_reads_usd_targets_in_their_units(rig_stage, tmp_path, capsys):
    from pxr import Usd, UsdGeom

    rig, path = rig_stage
    truth = {"frontalis_R": 0.004}
    target = rig.model(device="cpu").evaluate(truth).astype(np.float64)
    shape = tmp_path / "brow.usda"
    stage = Usd.Stage.CreateNew(str(shape))
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)  # centimetres: converted to the rig stage's metres
    mesh = UsdGeom.Mesh.Define(stage, "/Scan")
    mesh.CreatePointsAttr([tuple(p) for p in (target * 100.0).tolist()])
    stage.GetRootLayer().Save()
    assert main(["--device", "cpu", "fit", str(shape), "--rig", str(path), "--no-images", "--name", "raised"]) == 0
    assert read_presets(path)["raised"]["frontalis_R"] == pytest.approx(0.004, rel=1e-3)
    assert "preset 'raised'" in capsys.readouterr().out
