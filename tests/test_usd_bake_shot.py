"""``bake(..., shot=)`` and ``warpface bake``: the cache in a layer of its own under a shot stage, the rig layer
left byte for byte as it was."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

pytest.importorskip("pxr")

from helpers import small_face_rig  # noqa: E402
from pxr import Sdf, Usd, UsdGeom  # noqa: E402

from warpface import ExpressionModel  # noqa: E402
from warpface.cli import main  # noqa: E402
from warpface.usd import bake, read_animation, read_rig, write_animation, write_rig  # noqa: E402

FRAMES = np.arange(0.0, 10.0)


def _digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def animated(tmp_path):
    """A rig layer in centimetres with a contraction curve on every muscle, saved; and its rig."""
    rig = small_face_rig()
    path = tmp_path / "face.usda"
    stage = write_rig(path, rig, meters_per_unit=0.01)
    phase = FRAMES / len(FRAMES) * 2 * np.pi
    contractions = np.stack([0.01 * np.sin(phase), 0.008 * (1 - np.cos(phase)), 0.3 * np.sin(2 * phase)], axis=1)
    depths = np.stack([0.002 + 0.001 * np.sin(phase), 0.0015 * np.cos(phase)], axis=1)
    write_animation(stage, FRAMES, contractions=contractions, wrinkle_depths=depths)
    stage.GetRootLayer().Save()
    return path, (contractions, depths)


def _expected(path) -> np.ndarray:
    """The model of the rig on ``path`` evaluated at its control samples, all in stage units (cm)."""
    stage = Usd.Stage.Open(str(path))
    model = ExpressionModel.from_rig(read_rig(stage, meters_per_unit=0.01), device="cpu")
    animation = read_animation(stage, FRAMES, meters_per_unit=0.01)
    return model.evaluate(animation.controls, wrinkle_depths=animation.wrinkle_depths)


def _points(stage_path, times) -> np.ndarray:
    stage = Usd.Stage.Open(str(stage_path))
    points = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Skin")).GetPointsAttr()
    return np.stack([np.asarray(points.Get(t), dtype=np.float32) for t in times])


def test_bake_into_a_shot_leaves_the_rig_layer_unchanged_and_reads_back(animated, tmp_path):
    path, _ = animated
    before = path.read_bytes()
    shot = tmp_path / "shot.usda"
    cache = bake(path, device="cpu", progress=False, shot=shot)
    assert path.read_bytes() == before  # not a byte of the rig layer changed
    assert cache == tmp_path / "face_anim.usdc" and shot.is_file()
    layer = Sdf.Layer.FindOrOpen(str(shot))
    assert list(layer.subLayerPaths) == ["./face_anim.usdc", "./face.usda"]
    stage = Usd.Stage.Open(str(shot))
    assert UsdGeom.GetStageMetersPerUnit(stage) == pytest.approx(0.01)
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0.0, 9.0)
    expected = _expected(path)
    np.testing.assert_array_equal(_points(shot, FRAMES), expected)
    # The rig stage itself still composes its rest shape: the cache is only seen through the shot.
    rig_stage = Usd.Stage.Open(str(path))  # keep a reference: prims of a collected stage are invalid
    assert UsdGeom.Mesh(rig_stage.GetPrimAtPath("/Face/Skin")).GetPointsAttr().GetNumTimeSamples() == 0
    # A re-bake replaces the shot and the cache, and still leaves the rig layer alone.
    bake(path, FRAMES[:4], device="cpu", progress=False, shot=shot)
    assert path.read_bytes() == before
    np.testing.assert_array_equal(_points(shot, FRAMES), expected)


def test_shot_refusals_write_nothing(animated, tmp_path):
    path, _ = animated
    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(ValueError, match="is one of the stage's own layers"):
        bake(path, device="cpu", progress=False, shot=path)
    with pytest.raises(ValueError, match="is the cache file"):
        bake(path, device="cpu", progress=False, shot=tmp_path / "c.usda", cache_path=tmp_path / "c.usda")
    with pytest.raises(ValueError, match="must end in"):
        bake(path, device="cpu", progress=False, shot=tmp_path / "shot.abc")
    stage = Usd.Stage.Open(str(path))
    stage.GetRootLayer().startTimeCode = 3.0  # an unsaved edit the shot could not see
    with pytest.raises(ValueError, match="unsaved edits"):
        bake(stage, device="cpu", progress=False, shot=tmp_path / "shot.usda")
    memory = write_rig(Usd.Stage.CreateInMemory(), small_face_rig())
    write_animation(memory, FRAMES[:2], contractions=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="in memory"):
        bake(memory, device="cpu", progress=False, shot=tmp_path / "s.usda", cache_path=tmp_path / "c.usdc")
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_warpface_bake_writes_a_shot_beside_the_stage(animated, tmp_path, capsys):
    path, _ = animated
    digest = _digest(path)
    assert main(["--quiet", "--device", "cpu", "bake", str(path)]) == 0
    shot = tmp_path / "face_shot.usda"
    assert f"play {shot}" in capsys.readouterr().out
    assert _digest(path) == digest
    np.testing.assert_array_equal(_points(shot, FRAMES), _expected(path))
    other = tmp_path / "takes" / "one.usda"
    other.parent.mkdir()
    assert main(["--quiet", "--device", "cpu", "bake", str(path), "--shot", str(other), "--end", "4"]) == 0
    assert _digest(path) == digest and list(Sdf.Layer.FindOrOpen(str(other)).subLayerPaths) == [
        "../face_anim.usdc",
        "../face.usda",
    ]
