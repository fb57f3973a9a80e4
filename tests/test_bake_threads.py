"""The bake's worker threads: the cache holds exactly the per-frame model's points, whatever the thread
count or the order chunks finish in; the first bad frame in time order is the one reported."""

from __future__ import annotations

import random
import threading
import time

import numpy as np
import pytest

pytest.importorskip("pxr")

from helpers import small_face_rig  # noqa: E402
from pxr import Usd, UsdGeom  # noqa: E402

import warpface.usd.baking as baking  # noqa: E402
from warpface import ExpressionModel  # noqa: E402
from warpface.expression.tissue import neighbourhood_averager, neighbourhood_mean  # noqa: E402
from warpface.usd import bake, read_animation, rig_prims, write_animation, write_rig  # noqa: E402

FRAMES = np.arange(0.0, 40.0)


@pytest.fixture(scope="module")
def model():
    return ExpressionModel.from_rig(small_face_rig(), device="cpu")


@pytest.fixture
def animated_rig(tmp_path):
    """A rig layer with 40 frames of smooth, all-different controls."""
    path = tmp_path / "face.usda"
    stage = write_rig(path, small_face_rig())
    phase = FRAMES / len(FRAMES) * 2 * np.pi
    contractions = np.stack([0.012 * np.sin(phase), 0.008 * (1 - np.cos(phase)), 0.4 * np.sin(2 * phase)], axis=1)
    depths = np.stack([0.002 + 0.001 * np.sin(phase), 0.0015 * np.cos(phase)], axis=1)
    write_animation(stage, FRAMES, contractions=contractions, wrinkle_depths=depths)
    stage.GetRootLayer().Save()
    return path


def baked(path) -> np.ndarray:
    stage = Usd.Stage.Open(str(path))
    points = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Skin")).GetPointsAttr()
    return np.stack([np.asarray(points.Get(t), dtype=np.float32) for t in FRAMES])


def one_frame_at_a_time(model, path) -> np.ndarray:
    """The reference: the stage's controls, each frame through the single-frame ``evaluate``."""
    animation = read_animation(path, FRAMES)
    return np.stack(
        [model.evaluate(c, wrinkle_depths=d) for c, d in zip(animation.contractions, animation.wrinkle_depths)]
    )


def shuffled_finish(model, monkeypatch):
    """Worker chunks finish in a random order (earlier chunks often last)."""
    rng = random.Random(3)
    lock = threading.Lock()

    def slow_batch(*args, **kwargs):
        with lock:
            delay = rng.uniform(0.0, 0.03)
        time.sleep(delay)
        return ExpressionModel.evaluate(model, *args, **kwargs)

    monkeypatch.setattr(model, "evaluate", slow_batch)


@pytest.mark.parametrize("workers", [1, 4])
def test_threaded_bake_writes_the_single_frame_points_bit_for_bit(animated_rig, model, monkeypatch, workers):
    shuffled_finish(model, monkeypatch)
    cache = bake(animated_rig, model=model, progress=False, chunk_frames=3, workers=workers)
    points = baked(animated_rig)
    assert np.array_equal(points, one_frame_at_a_time(model, animated_rig))
    stage = Usd.Stage.Open(str(animated_rig))  # kept: prims of a collected stage are invalid
    extent = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Skin")).GetExtentAttr()
    for frame in (0, 17, 39):
        box = np.asarray(extent.Get(FRAMES[frame]))
        assert np.array_equal(box, np.stack([points[frame].min(axis=0), points[frame].max(axis=0)]))
    assert cache.exists()


def test_threads_report_the_first_bad_frame_in_time_order_and_write_nothing(animated_rig, model, monkeypatch):
    stage = Usd.Stage.Open(str(animated_rig))
    bad = np.zeros((len(FRAMES), 3))
    bad[[7, 12], 0] = 1e7  # beyond any muscle's range: the model refuses these frames
    write_animation(stage, FRAMES, contractions=bad)
    stage.GetRootLayer().Save()
    before = animated_rig.read_bytes()

    def late_first_chunks(contractions, **kwargs):
        """Chunk [6, 7, 8] (frame 7 bad) fails only after chunk [12, 13, 14] has failed."""
        if len(contractions) == 3 and contractions[1, 0] > 1e6:
            time.sleep(0.3)
        return ExpressionModel.evaluate(model, contractions, **kwargs)

    monkeypatch.setattr(model, "evaluate", late_first_chunks)
    with pytest.raises(ValueError, match=r"^/Face/Skin: controls at time 7: "):
        bake(animated_rig, model=model, progress=False, chunk_frames=3, workers=4)
    assert animated_rig.read_bytes() == before
    assert sorted(p.name for p in animated_rig.parent.iterdir()) == ["face.usda"]


def test_bake_default_workers_use_the_cores_on_the_cpu(model):
    assert 1 <= baking._evaluation_workers(model) <= 8


@pytest.mark.parametrize(
    "workers, error", [(0, ValueError), (-1, ValueError), (1.5, TypeError), (True, TypeError), ("2", TypeError)]
)
def test_bad_worker_counts_are_refused_before_anything_is_written(animated_rig, model, workers, error):
    with pytest.raises(error, match=r"^workers: "):
        bake(animated_rig, model=model, progress=False, workers=workers)
    assert sorted(p.name for p in animated_rig.parent.iterdir()) == ["face.usda"]


def test_neighbourhood_averager_equals_the_one_shot_mean():
    rng = np.random.default_rng(0)
    points = rng.uniform(size=(400, 3))
    average = neighbourhood_averager(points, 0.15)
    for values in (rng.normal(size=400), rng.normal(size=(400, 3))):
        assert np.array_equal(average(values), neighbourhood_mean(points, values, 0.15))


def test_read_animation_equals_per_time_gets_for_constant_single_and_sampled_controls(tmp_path):
    stage = write_rig(tmp_path / "face.usda", small_face_rig())
    write_animation(stage, np.arange(0.0, 12.0), contractions={"frontalis_R": np.linspace(0.0, 0.01, 12)})  # sampled
    write_animation(stage, [5.0], wrinkle_depths={"crow_L": [0.003]})  # one sample: held at every time
    asked = np.array([-2.0, 0.0, 3.5, 5.0, 11.0, 20.0])
    animation = read_animation(stage, asked)
    rig = rig_prims(stage)
    for table, items, name in (
        (animation.contractions, rig.muscles, "contraction"),
        (animation.wrinkle_depths, rig.wrinkles, "depth"),
    ):
        expected = np.array([[item.GetAttribute(name).Get(t) for item in items] for t in asked.tolist()])
        assert np.array_equal(table, expected)
    assert np.all(animation.wrinkle_depths[:, 1] == 0.003)
    assert len(np.unique(animation.contractions[:, 1])) == 4  # held before the first and after the last sample


def test_held_controls_are_evaluated_once_and_give_the_same_points(tmp_path, model, monkeypatch):
    path = tmp_path / "face.usda"
    stage = write_rig(path, small_face_rig())
    held = np.repeat(np.array([[0.0, 0.0, 0.0], [0.01, 0.004, 0.2], [0.0, 0.0, 0.0], [-0.0, 0.0, 0.0]]), 10, axis=0)
    write_animation(stage, FRAMES, contractions=held)
    stage.GetRootLayer().Save()
    evaluated = []

    def counting(contractions, **kwargs):
        evaluated.append(len(contractions))
        return ExpressionModel.evaluate(model, contractions, **kwargs)

    monkeypatch.setattr(model, "evaluate", counting)
    bake(path, model=model, progress=False, chunk_frames=40)
    monkeypatch.undo()
    assert evaluated == [3]  # zeros, the pull, and -0.0 (a different bit pattern, so evaluated on its own)
    assert np.array_equal(baked(path), one_frame_at_a_time(model, path))


def test_animate_cache_equals_the_single_frame_model_on_the_built_in_face(tmp_path):
    from warpface.assets import default_rig
    from warpface.commands.animate import animate
    from warpface.drivers import ARKIT_CHANNELS, Curves, write_live_link

    frames = 45
    rng = np.random.default_rng(5)
    weights = np.clip(rng.uniform(-0.3, 1.0, (frames, len(ARKIT_CHANNELS))), 0.0, 1.0)
    weights[10:20] = weights[10]  # a held stretch: evaluated once per chunk
    curves = Curves(times=np.arange(frames) / 30.0, names=list(ARKIT_CHANNELS), values=weights, fps=30.0)
    driver = write_live_link(tmp_path / "take.csv", curves)
    result = animate(driver, tmp_path / "face.usda", video=False, device="cpu", progress=False)
    stage = Usd.Stage.Open(str(result.stage))
    points = UsdGeom.Mesh(stage.GetPrimAtPath(rig_prims(stage).skin.GetPath())).GetPointsAttr()
    times = np.arange(float(result.frame_count))
    animation = read_animation(stage, times)
    model = default_rig().model(device="cpu")
    for time_code, controls, depths in zip(times.tolist(), animation.controls, animation.wrinkle_depths):
        assert np.array_equal(
            np.asarray(points.Get(time_code), dtype=np.float32), model.evaluate(controls, wrinkle_depths=depths)
        )
    assert set(result.seconds) == {
        "read driver and rig",
        "clean and map",
        "write controls",
        "model",
        "bake",
        "save stage",
    }


FRESH_PROCESS_THREADS = """
import sys, threading
import numpy as np
import warp as wp
wp.config.quiet = True
from helpers import small_face_rig
model = small_face_rig().model(device="cpu")
controls = np.random.default_rng(0).uniform(0.0, 0.3, (16, len(model.control_names)))
results = [None, None]
def evaluate(k):
    results[k] = model.evaluate(controls)
threads = [threading.Thread(target=evaluate, args=(k,)) for k in range(2)]
[t.start() for t in threads]
[t.join() for t in threads]
sys.exit(0 if np.array_equal(results[0], results[1]) else 3)
"""


def test_threads_of_a_fresh_process_evaluate_at_once_without_crashing():
    """The bake's first chunks start in two threads of a process whose kernels are not loaded yet: both threads
    recording (and so loading Warp modules) at once crashed the process in about half the runs (the demo's bake
    segfaulted); six fresh processes in a row must all finish with equal results."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    tests = Path(__file__).parent
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(tests.parent), str(tests), os.environ.get("PYTHONPATH", "")]),
    }
    codes = [
        subprocess.run(
            [sys.executable, "-c", FRESH_PROCESS_THREADS], env=env, cwd=tests, capture_output=True, timeout=300
        ).returncode
        for _ in range(6)
    ]
    assert codes == [0] * 6, codes
