"""Animation on USD stages: control time samples, bakes into a usdc cache, re-bakes, interruptions."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("pxr")

from helpers import small_face_rig  # noqa: E402
from pxr import Sdf, Usd, UsdGeom, Vt  # noqa: E402

import warpface.usd._files as usd_files  # noqa: E402
from warpface import ExpressionModel, RigError  # noqa: E402
from warpface.usd import bake, frame_times, read_animation, read_rig, validate_stage, write_animation, write_rig  # noqa: E402

FRAMES = np.arange(0.0, 24.0)


def controls(times: np.ndarray, amplitude: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Contractions (F, 3) and wrinkle depths (F, 2) for the small rig: smooth, all different."""
    phase = times / len(times) * 2 * np.pi
    contractions = amplitude * np.stack(
        [0.012 * np.sin(phase), 0.008 * (1 - np.cos(phase)), 0.4 * np.sin(2 * phase)], axis=1
    )
    depths = np.stack([0.002 + 0.001 * np.sin(phase), 0.0015 * np.cos(phase)], axis=1)
    return contractions, depths


@pytest.fixture
def rig_file(tmp_path, small_rig):
    """A rig layer on disk with an animation of FRAMES, saved."""
    path = tmp_path / "face.usda"
    stage = write_rig(path, small_rig)
    contractions, depths = controls(FRAMES)
    write_animation(stage, FRAMES, contractions=contractions, wrinkle_depths=depths)
    stage.GetRootLayer().Save()
    return path


@pytest.fixture(scope="module")
def cpu_model():
    return ExpressionModel.from_rig(small_face_rig(), device="cpu")


def baked_points(path, times) -> np.ndarray:
    stage = Usd.Stage.Open(str(path))  # keep a reference: prims of a collected stage are invalid
    points = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Skin")).GetPointsAttr()
    return np.stack([np.asarray(points.Get(t), dtype=np.float32) for t in times])


# ---------------------------------------------------------------------------------------------- controls


def test_control_samples_read_back_exactly(small_rig):
    stage = write_rig(Usd.Stage.CreateInMemory(), small_rig)
    contractions, depths = controls(FRAMES)
    write_animation(stage, FRAMES, contractions=contractions, wrinkle_depths=depths, fps=24)
    animation = read_animation(stage, FRAMES)
    assert np.array_equal(animation.contractions, contractions) and np.array_equal(animation.wrinkle_depths, depths)
    assert animation.muscle_names == small_rig.muscle_names and animation.wrinkle_names == small_rig.wrinkle_names
    assert (
        stage.GetStartTimeCode(),
        stage.GetEndTimeCode(),
        stage.GetTimeCodesPerSecond(),
        stage.GetFramesPerSecond(),
    ) == (0, 23, 24, 24)
    assert np.array_equal(frame_times(stage), FRAMES)
    attr = stage.GetPrimAtPath("/Face/Muscles/frontalis_R").GetAttribute("contraction")
    assert attr.GetTimeSamples() == FRAMES.tolist()
    assert attr.Get(2.5) == pytest.approx(
        0.5 * (contractions[2, 1] + contractions[3, 1]), rel=1e-12
    )  # USD interpolates


def test_jaw_controls_round_trip_and_reach_the_bake(tmp_path):
    from warpface.assets import default_rig

    rig = default_rig(device="cpu")
    stage = Usd.Stage.CreateInMemory("jaw.usda")
    write_rig(stage, rig, meters_per_unit=0.01)  # a centimetre stage: slides scale, the angle does not
    times = np.arange(4.0)
    jaw = np.array([[0.0, 0.0, 0.0], [0.1, 0.001, -0.002], [0.3, 0.002, 0.0], [0.2, 0.0, 0.003]])
    write_animation(stage, times, contractions={rig.muscle_names[0]: np.full(4, 0.001)}, jaw=jaw)
    animation = read_animation(stage)
    np.testing.assert_array_equal(animation.times, times)
    np.testing.assert_allclose(animation.jaw, jaw, rtol=1e-12, atol=1e-15)
    assert animation.control_names == rig.control_names and animation.controls.shape == (4, len(rig.control_names))
    jaw_prim = next(p for p in stage.Traverse() if p.GetTypeName() == "WarpFaceJaw")
    assert jaw_prim.GetAttribute("jawForward").Get(1) == pytest.approx(0.1)  # 1 mm in centimetres
    with pytest.raises(ValueError, match="unknown jaw control name 'jaw_up'"):
        write_animation(stage, times, jaw={"jaw_up": np.zeros(4)})
    with pytest.raises(ValueError, match="jaw"):
        write_animation(stage, times, jaw=np.full((4, 3), np.nan))
    layer = tmp_path / "jaw.usda"
    stage.GetRootLayer().Export(str(layer))
    bake(str(layer), device="cpu", progress=False)
    baked = Usd.Stage.Open(str(layer))
    skin = next(p for p in baked.Traverse() if p.IsA(UsdGeom.Mesh))
    model = rig.model(device="cpu")
    controls = read_animation(layer, meters_per_unit=0.01).controls[2]  # the rig's numbers are centimetres here
    assert controls[-3] == pytest.approx(0.3) and controls[-2] == pytest.approx(0.2)
    expected = model.evaluate(controls)
    points = np.asarray(skin.GetAttribute("points").Get(2), dtype=np.float64)
    np.testing.assert_allclose(points, expected, atol=2e-6)
    assert np.abs(points - rig.mesh.points).max() > 1e-3  # the jaw moved the skin


def test_animation_on_a_rig_without_a_jaw_refuses_jaw_controls(small_rig):
    stage = Usd.Stage.CreateInMemory("nojaw.usda")
    write_rig(stage, small_rig)
    with pytest.raises(ValueError, match="has no jaw"):
        write_animation(stage, [0.0], jaw=np.zeros((1, 3)))
    assert read_animation(stage, [0.0]).jaw is None


def test_rewriting_a_range_keeps_samples_outside_it(small_rig):
    stage = write_rig(Usd.Stage.CreateInMemory(), small_rig)
    contractions, _ = controls(FRAMES)
    write_animation(stage, FRAMES, contractions=contractions)
    write_animation(stage, [10.0, 12.5, 14.0], contractions={"orbicularis_oris": [0.9, 0.8, 0.7]})
    samples = stage.GetPrimAtPath("/Face/Muscles/orbicularis_oris").GetAttribute("contraction").GetTimeSamples()
    assert samples == sorted([t for t in FRAMES.tolist() if not 10 <= t <= 14] + [10.0, 12.5, 14.0])
    animation = read_animation(stage, FRAMES)
    keep = (FRAMES < 10) | (FRAMES > 14)
    assert np.array_equal(animation.contractions[keep], contractions[keep])
    assert np.array_equal(animation.contractions[:, :2], contractions[:, :2])  # other muscles untouched
    assert animation.contractions[FRAMES == 10, 2] == 0.9 and animation.contractions[FRAMES == 14, 2] == 0.7


def test_centimetre_stage_animation_is_converted(small_rig):
    from helpers import scaled_rig

    stage = write_rig(Usd.Stage.CreateInMemory(), scaled_rig(small_rig, 100.0), meters_per_unit=0.01)
    contractions, depths = controls(FRAMES)
    write_animation(stage, FRAMES, contractions=contractions, wrinkle_depths=depths)  # values in metres
    stored = read_animation(stage, FRAMES, meters_per_unit=0.01)  # as authored, in centimetres
    assert np.allclose(stored.contractions[:, :2], contractions[:, :2] * 100, rtol=1e-14)
    assert np.array_equal(stored.contractions[:, 2], contractions[:, 2])  # sphincters are dimensionless
    assert np.allclose(stored.wrinkle_depths, depths * 100, rtol=1e-14)
    back = read_animation(stage, FRAMES)
    assert np.allclose(back.contractions, contractions, rtol=1e-14) and np.allclose(
        back.wrinkle_depths, depths, rtol=1e-14
    )


def test_bad_control_input(small_rig):
    stage = write_rig(Usd.Stage.CreateInMemory(), small_rig)
    contractions, _ = controls(FRAMES)
    with pytest.raises(ValueError, match=r"contractions: expected shape \(24, 3\)"):
        write_animation(stage, FRAMES, contractions=contractions[:, :2])
    with pytest.raises(ValueError, match="unknown muscle name 'masseter'"):
        write_animation(stage, FRAMES, contractions={"masseter": np.zeros(24)})
    bad = contractions.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="non-finite value at index"):
        write_animation(stage, FRAMES, contractions=bad)
    with pytest.raises(ValueError, match="time codes repeat"):
        write_animation(stage, [0.0, 1.0, 1.0], contractions=contractions[:3])
    assert stage.GetPrimAtPath("/Face/Muscles/frontalis_R").GetAttribute("contraction").GetNumTimeSamples() == 0
    stage.GetPrimAtPath("/Face/Muscles/frontalis_R").GetAttribute("contraction").Set(float("inf"), 4.0)
    with pytest.raises(RigError, match=r"^/Face/Muscles/frontalis_R.contraction: bad value inf at time 0.0"):
        read_animation(stage, FRAMES)


# ---------------------------------------------------------------------------------------------- bake


def test_bake_writes_the_model_output_as_a_usdc_cache(rig_file, small_rig, cpu_model):
    cache = bake(rig_file, device="cpu", progress=False)
    assert cache == rig_file.with_name("face_anim.usdc") and cache.read_bytes()[:8] == b"PXR-USDC"
    assert [p.name for p in rig_file.parent.iterdir() if p.name.startswith(".")] == []
    root = Sdf.Layer.OpenAsAnonymous(str(rig_file))
    assert list(root.subLayerPaths) == ["./face_anim.usdc"]
    contractions, depths = controls(FRAMES)
    expected = cpu_model.evaluate(contractions, wrinkle_depths=depths)
    got = baked_points(rig_file, FRAMES)
    assert np.array_equal(got, expected)
    assert not np.array_equal(got[5], small_rig.mesh.points.astype(np.float32))  # it moved
    stage = Usd.Stage.Open(str(rig_file))
    extent = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Skin")).GetExtentAttr()
    assert np.array_equal(np.asarray(extent.Get(7)), np.stack([expected[7].min(axis=0), expected[7].max(axis=0)]))
    # the rest shape is still what the rig reads; the stage metadata covers the bake
    from helpers import assert_rigs_equal

    assert_rigs_equal(read_rig(stage), small_rig)
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, 23)
    assert Sdf.Layer.FindOrOpen(str(cache)).timeCodesPerSecond == stage.GetTimeCodesPerSecond()
    assert [p for p in validate_stage(stage) if p.severity == "error"] == []


def test_rebaking_a_range_replaces_only_that_range(rig_file, cpu_model):
    bake(rig_file, device="cpu", progress=False, chunk_frames=5)
    before = baked_points(rig_file, FRAMES)
    stage = Usd.Stage.Open(str(rig_file))
    contractions, depths = controls(FRAMES, amplitude=-1.5)
    write_animation(stage, FRAMES[6:12], contractions=contractions[6:12])
    stage.GetRootLayer().Save()
    bake(stage, frames=FRAMES[6:12], model=cpu_model, progress=False)
    after = baked_points(rig_file, FRAMES)
    outside = (FRAMES < 6) | (FRAMES > 11)
    assert np.array_equal(after[outside], before[outside])
    _, original_depths = controls(FRAMES)
    assert np.array_equal(after[6:12], cpu_model.evaluate(contractions[6:12], wrinkle_depths=original_depths[6:12]))
    assert not np.array_equal(after[6:12], before[6:12])
    assert UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Skin")).GetPointsAttr().GetTimeSamples() == FRAMES.tolist()
    assert list(Sdf.Layer.OpenAsAnonymous(str(rig_file)).subLayerPaths) == ["./face_anim.usdc"]  # not added twice


def test_interrupted_bake_leaves_previous_files_intact(rig_file, cpu_model, monkeypatch):
    cache = bake(rig_file, model=cpu_model, progress=False)
    files = {p: p.read_bytes() for p in (rig_file, cache)}
    stage = Usd.Stage.Open(str(rig_file))
    write_animation(stage, FRAMES, contractions=controls(FRAMES, amplitude=2.0)[0])
    calls = []

    def interrupted_batch(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt  # Ctrl-C in the middle of the frames
        return ExpressionModel.evaluate(cpu_model, *args, **kwargs)

    monkeypatch.setattr(cpu_model, "evaluate", interrupted_batch)
    with pytest.raises(KeyboardInterrupt):
        bake(stage, model=cpu_model, progress=False, chunk_frames=8)
    monkeypatch.undo()

    def crash_on_rename(*args):
        raise OSError("disk full")

    monkeypatch.setattr(usd_files.os, "replace", crash_on_rename)
    with pytest.raises(OSError, match="disk full"):
        bake(stage, model=cpu_model, progress=False)
    monkeypatch.undo()
    assert {p: p.read_bytes() for p in files} == files
    assert sorted(p.name for p in rig_file.parent.iterdir()) == ["face.usda", "face_anim.usdc"]


def test_bake_refuses_rest_points_that_would_hide_the_cache(tmp_path, small_rig):
    path = tmp_path / "face.usda"
    stage = write_rig(path, small_rig)
    write_animation(stage, FRAMES, contractions=controls(FRAMES)[0])
    UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Skin")).GetPointsAttr().Set(
        Vt.Vec3fArray.FromNumpy(small_rig.mesh.points.astype(np.float32))
    )
    with pytest.raises(RigError, match=r"^/Face/Skin.points: authored directly in layer .*stronger than the cache"):
        bake(stage, device="cpu", progress=False)
    assert not (tmp_path / "face_anim.usdc").exists()


def test_bake_in_memory_and_bad_arguments(tmp_path, small_rig, cpu_model):
    stage = write_rig(Usd.Stage.CreateInMemory(), small_rig)
    with pytest.raises(ValueError, match="nothing to bake"):
        bake(stage, model=cpu_model, progress=False, cache_path=tmp_path / "c.usdc")
    write_animation(stage, FRAMES[:4], contractions=controls(FRAMES)[0][:4])
    with pytest.raises(ValueError, match="in memory; pass cache_path"):
        bake(stage, model=cpu_model, progress=False)
    with pytest.raises(ValueError, match="does not exist"):
        bake(stage, model=cpu_model, progress=False, cache_path=tmp_path / "no" / "c.usdc")
    with pytest.raises(ValueError, match="must end in"):
        bake(stage, model=cpu_model, progress=False, cache_path=tmp_path / "c.abc")
    with pytest.raises(ValueError, match="time codes repeat"):
        bake(stage, [1.0, 1.0], model=cpu_model, progress=False, cache_path=tmp_path / "c.usdc")
    other = ExpressionModel.from_rig(small_face_rig(n=6), device="cpu")
    with pytest.raises(ValueError, match="vertices"):
        bake(stage, model=other, progress=False, cache_path=tmp_path / "c.usdc")
    assert list(tmp_path.iterdir()) == []
    cache = bake(stage, model=cpu_model, progress=False, cache_path=tmp_path / "c.usdc")
    assert list(stage.GetRootLayer().subLayerPaths) == [str(cache)]
    points = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Skin")).GetPointsAttr()
    assert points.GetTimeSamples() == [0.0, 1.0, 2.0, 3.0]
    assert np.array_equal(np.asarray(points.Get(2.0)), cpu_model.evaluate(controls(FRAMES)[0][2]))


def test_baked_stage_plays_without_the_plugin(rig_file, cpu_model):
    bake(rig_file, model=cpu_model, progress=False)
    expected = baked_points(rig_file, [3.0, 17.0])
    code = f"""
import json
from pxr import Usd, UsdGeom, Tf
assert Tf.Type.FindByName("WarpFaceSkinAPI").isUnknown
stage = Usd.Stage.Open({str(rig_file)!r})
points = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Skin")).GetPointsAttr()
print(json.dumps(dict(samples=len(points.GetTimeSamples()), fps=stage.GetTimeCodesPerSecond(),
      frames=[[list(p) for p in points.Get(t)] for t in (3.0, 17.0)],
      muscle=stage.GetPrimAtPath("/Face/Muscles/frontalis_R").GetAttribute("contraction").Get(5.0))))
"""
    env = {k: v for k, v in os.environ.items() if k != "PXR_PLUGINPATH_NAME"}
    result = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout.strip().splitlines()[-1])
    assert out["samples"] == len(FRAMES) and out["fps"] == 30
    assert np.array_equal(np.array(out["frames"], dtype=np.float32), expected)
    assert out["muscle"] == controls(FRAMES)[0][5, 1]
