"""A worker's rigs and expression models kept between takes (``RigModels``): takes through one worker bake exactly
what fresh ``animate`` runs bake, the model is built once per rig file and device, a changed rig file is read
afresh."""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest
from helpers import live_link_csv


def skin_frames(stage_path) -> np.ndarray:
    """Every time sample of the skin's points, (F, V, 3)."""
    from pxr import Usd

    from warpface import usd

    stage = Usd.Stage.Open(str(stage_path))
    points = usd.rig_prims(stage).skin.GetAttribute("points")
    return np.array([np.asarray(points.Get(t)) for t in points.GetTimeSamples()])


def test_two_takes_through_one_worker_equal_two_fresh_animate_runs(classic_rig_stage, tmp_path):
    from warpface.batch.manifest import read_manifest
    from warpface.batch.take import run_take, take_digest
    from warpface.commands.animate import animate
    from warpface.commands.rig_models import RigModels

    live_link_csv(tmp_path / "smile.csv", 12, {"mouthSmileLeft": 0.9, "browInnerUp": 0.6})
    live_link_csv(tmp_path / "frown.csv", 10, {"browDownLeft": 0.8, "mouthFrownRight": 0.7, "jawOpen": 0.5})
    (tmp_path / "m.csv").write_text(
        "id,input,kind,rig,options\n"
        + "".join(f"{n},{n}.csv,animate,{classic_rig_stage},--no-video\n" for n in ("smile", "frown"))
    )
    out = tmp_path / "out"
    out.mkdir()
    rigs = RigModels()
    for take in read_manifest(tmp_path / "m.csv").takes:
        entry = run_take(take, out, device="cpu", digest=take_digest(take), rigs=rigs)
        assert entry["status"] == "done", entry["error"]
    assert rigs.builds == 1
    for name in ("smile", "frown"):
        fresh = animate(
            tmp_path / f"{name}.csv",
            tmp_path / "fresh" / f"{name}.usda",
            rig=classic_rig_stage,
            video=False,
            device="cpu",
        )
        kept = skin_frames(out / name / f"{name}.usda")
        assert kept.shape == (fresh.frame_count, 11492, 3) and np.abs(kept - kept[0]).max() > 1e-4  # it moves
        np.testing.assert_array_equal(kept, skin_frames(fresh.stage))


def test_a_model_is_built_once_per_rig_file_and_device_and_afresh_when_the_file_changes(classic_rig_stage, tmp_path):
    from warpface import usd
    from warpface.commands.rig_models import RigModels

    rigs = RigModels(capacity=2)

    def model_of(path):
        return rigs.model(rigs.load(path)[0], device="cpu")

    model = model_of(classic_rig_stage)
    face = rigs.load(classic_rig_stage)[0]
    assert model_of(classic_rig_stage) is model and rigs.load(classic_rig_stage)[0] is face
    assert rigs.builds == 1
    changed = tmp_path / "changed.usda"
    usd.write_rig(changed, face)
    other = model_of(changed)
    assert other is not model and model_of(changed) is other and rigs.builds == 2
    thicker = dataclasses.replace(face, thickness=2.0 * np.asarray(face.thickness))
    before = os.stat(changed).st_mtime_ns
    usd.write_rig(tmp_path / "elsewhere.usda", thicker)
    os.replace(tmp_path / "elsewhere.usda", changed)  # changed behind USD's back, as by another process
    os.utime(changed, ns=(before + 10**9, before + 10**9))  # a new modification time whatever the clock's step
    again = model_of(changed)
    assert again is not other and rigs.builds == 3
    controls = np.zeros((1, len(face.control_names)))
    controls[0, face.control_names.index("zygomaticus_major_L")] = 0.02
    np.testing.assert_array_equal(again.evaluate(controls), thicker.model(device="cpu").evaluate(controls))
    assert np.abs(again.evaluate(controls) - other.evaluate(controls)).max() > 1e-6  # the thickness counts
    assert model_of(classic_rig_stage) is model and rigs.builds == 3  # the changed file's old entry went first
    usd.write_rig(tmp_path / "third.usda", face)
    model_of(tmp_path / "third.usda")
    assert model_of(changed) is not again and rigs.builds == 5  # capacity 2: the least recently used went
    assert rigs.model(thicker, device="cpu") is not rigs.model(thicker, device="cpu")  # not a rig of the cache


def test_bad_arguments(tmp_path):
    from warpface.commands.animate import animate
    from warpface.commands.rig_models import RigModels

    with pytest.raises(ValueError, match="capacity"):
        RigModels(capacity=0)
    driver = live_link_csv(tmp_path / "a.csv", 3, {"jawOpen": 0.5})
    with pytest.raises(TypeError, match="rigs: expected a RigModels, got dict"):
        animate(driver, tmp_path / "a.usda", rigs={}, video=False, device="cpu")
    assert not (tmp_path / "a.usda").exists()
