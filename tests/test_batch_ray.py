"""``warpface batch --engine ray``: on a local Ray the takes are baked to the same points as on the local engine, the
corrupt take fails alone with the same error, and a Ray worker killed mid-take has its take retried complete.

Runs on a local cluster of 2 CPUs (``ray.init(num_cpus=2)``), shut down after; skipped without Ray
(``pip install 'warpface[ray]'``).
"""

from __future__ import annotations

import json
import os
import signal
import threading
import time

import numpy as np
import pytest

from warpface.cli import main
from warpface.data import shared_data_path
from warpface.drivers import ARKIT_CHANNELS

ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'warpface[ray]')")

OPENFACE = shared_data_path("auplayer_openface_au", "19_3_au.txt")
MEDIAPIPE = shared_data_path("mediapipe", "face_blendshapes_out.prototxt")


def brow_csv(path, frames: int):
    """A hand-written Live Link Face CSV: the inner brows rise and the jaw opens."""
    columns = [name[0].upper() + name[1:] for name in ARKIT_CHANNELS]
    rows = ["Timecode,BlendshapeCount," + ",".join(columns)]
    for frame in range(frames):
        level = {"browInnerUp": frame / (frames - 1), "jawOpen": 0.5 * frame / (frames - 1)}
        rows.append(f"00:00:00:{frame:02d}.000,52," + ",".join(f"{level.get(n, 0.0):.4f}" for n in ARKIT_CHANNELS))
    path.write_text("\n".join(rows) + "\n")
    return path


def skin_frames(stage_path):
    from pxr import Usd

    from warpface import usd

    stage = Usd.Stage.Open(str(stage_path))
    attribute = usd.rig_prims(stage).skin.GetAttribute("points")
    return [np.asarray(attribute.Get(t)) for t in attribute.GetTimeSamples()]


def test_warpface_starts_a_local_ray_and_shuts_it_down(tmp_path, capsys, classic_rig_stage):
    assert not ray.is_initialized()
    brow_csv(tmp_path / "a.csv", 6)
    (tmp_path / "m.csv").write_text(f"id,input,kind,rig,options\na,a.csv,animate,{classic_rig_stage},--no-video\n")
    argv = ["--quiet", "--device", "cpu", "batch", str(tmp_path / "m.csv"), "--out", str(tmp_path / "out")]
    assert main([*argv, "--engine", "ray"]) == 0
    assert not ray.is_initialized()  # what warpface started, it stopped
    assert json.loads((tmp_path / "out" / "report.json").read_text())["takes"][0]["status"] == "done"
    assert len(skin_frames(tmp_path / "out" / "a" / "a.usda")) == 6


@pytest.fixture(scope="module")
def cluster():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


@pytest.mark.slow
@pytest.mark.skipif(OPENFACE is None or MEDIAPIPE is None, reason="../shared/data (OpenFace, MediaPipe) is not present")
def test_ray_and_local_engines_bake_identical_points(cluster, tmp_path):
    from warpface.batch import run

    brow_csv(tmp_path / "brows.csv", 8)
    (tmp_path / "corrupt.csv").write_text("Timecode,BlendshapeCount,BrowInnerUp\n00:00:00:01.000,52,nan\n")
    (tmp_path / "m.csv").write_text(
        "id,input,kind,options\n"
        "brows,brows.csv,animate,--no-video\n"
        f"openface,{OPENFACE},animate,--no-video\n"
        f"mediapipe,{MEDIAPIPE},animate,--no-video\n"
        "corrupt,corrupt.csv,animate,--no-video\n"
    )
    results = {
        engine: run(tmp_path / "m.csv", tmp_path / engine, engine=engine, device="cpu", progress=False)
        for engine in ("ray", "local")
    }
    for engine, result in results.items():
        assert [e["status"] for e in result.takes] == ["done", "done", "done", "failed"], engine
    assert results["ray"].takes[3]["error"] == results["local"].takes[3]["error"]
    assert "corrupt.csv" in results["ray"].takes[3]["error"]
    for take in ("brows", "openface", "mediapipe"):
        on_ray, local = (skin_frames(tmp_path / engine / take / f"{take}.usda") for engine in ("ray", "local"))
        assert len(on_ray) == len(local) > 0
        for a, b in zip(on_ray, local):
            np.testing.assert_array_equal(a, b)
    brows = skin_frames(tmp_path / "ray" / "brows" / "brows.usda")
    assert np.abs(brows[-1] - brows[0]).max() > 1e-3  # metres: the take moves the face, it is not a still
    again = run(tmp_path / "m.csv", tmp_path / "ray", engine="ray", device="cpu", progress=False)
    assert [e["status"] for e in again.takes] == ["skipped", "skipped", "skipped", "failed"]


@pytest.mark.slow
def test_a_ray_worker_killed_mid_take_has_its_take_retried(cluster, tmp_path):
    from warpface.batch import run

    for name in ("a", "b"):
        brow_csv(tmp_path / f"{name}.csv", 30)
    (tmp_path / "m.csv").write_text(
        "id,input,kind,options\na,a.csv,animate,--video-max-frames 30\nb,b.csv,animate,--video-max-frames 30\n"
    )
    out = tmp_path / "out"
    killed = []

    def kill_b_mid_take():
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and not killed:
            for partial in out.glob(".b.partial-*"):
                if (partial / "b_anim.usdc").exists():
                    pid = int(partial.name.rpartition("-")[2])
                    os.kill(pid, signal.SIGKILL)
                    killed.append((partial, pid))
                    return
            time.sleep(0.01)

    killer = threading.Thread(target=kill_b_mid_take, daemon=True)
    killer.start()
    result = run(tmp_path / "m.csv", out, engine="ray", device="cpu", progress=False)
    killer.join(timeout=5)
    assert killed, "the take finished before it could be killed"
    assert [e["status"] for e in result.takes] == ["done", "done"], result.takes
    assert not killed[0][0].exists() and not [p for p in out.iterdir() if p.name.startswith(".")]
    a, b = skin_frames(out / "a" / "a.usda"), skin_frames(out / "b" / "b.usda")
    assert len(b) == 30 and all(np.array_equal(x, y) for x, y in zip(a, b))
