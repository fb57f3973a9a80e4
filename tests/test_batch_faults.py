"""``warpface batch`` under faults and with every kind: a worker killed with SIGKILL mid-take has its take retried
(complete, never partial); Ctrl-C keeps the finished takes and leaves no partial one; track and fit takes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from warpface.data import shared_data_path
from warpface.drivers import ARKIT_CHANNELS

ROOT = Path(__file__).resolve().parents[1]
OPENFACE = shared_data_path("auplayer_openface_au", "10_3_au.txt")


def ramp_csv(path, frames: int, channel: str):
    """A hand-written Live Link Face CSV: ``channel`` rises from 0 to 1."""
    columns = [name[0].upper() + name[1:] for name in ARKIT_CHANNELS]
    rows = ["Timecode,BlendshapeCount," + ",".join(columns)]
    for frame in range(frames):
        seconds, sub = divmod(frame, 30)
        weights = [f"{frame / (frames - 1):.4f}" if name == channel else "0" for name in ARKIT_CHANNELS]
        rows.append(f"00:00:{seconds:02d}:{sub:02d}.000,52," + ",".join(weights))
    path.write_text("\n".join(rows) + "\n")
    return path


def _sigint_as_in_a_terminal():
    """In the child before it runs: SIGINT at its default. A harness that starts the tests in the background (``&``,
    ``nohup``) ignores SIGINT, every child inherits that, and the batch would rightly not stop on Ctrl-C."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start_batch(manifest, out, *extra):
    """``warpface batch`` as its own process (in its own session with SIGINT at its default, as a terminal runs
    it)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    command = [sys.executable, "-m", "warpface.cli", "--quiet", "--device", "cpu", "batch", str(manifest)]
    return subprocess.Popen(
        command + ["--out", str(out), *extra],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=_sigint_as_in_a_terminal,
    )


def wait_for(condition, process, timeout=240.0):
    """Poll ``condition()`` until it gives a value; fail if the batch ends or time runs out first."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = condition()
        if found:
            return found
        if process.poll() is not None:
            pytest.fail(f"the batch ended first: {process.communicate()}")
        time.sleep(0.01)
    process.kill()
    pytest.fail("timed out")


def mid_take(out, take_id):
    """(partial folder, worker pid) once the take's worker has baked its cache but not yet published the take."""
    for partial in out.glob(f".{take_id}.partial-*"):
        if (partial / f"{take_id}_anim.usdc").exists():
            return partial, int(partial.name.rpartition("-")[2])
    return None


def landed(out):
    try:
        return json.loads((out / "report.json").read_text())["takes"]
    except (OSError, ValueError, KeyError):
        return []


@pytest.mark.slow
def test_a_worker_killed_mid_take_has_its_take_retried_complete(tmp_path, classic_rig_stage):
    for name in ("a", "b", "c"):
        ramp_csv(tmp_path / f"{name}.csv", 40, "mouthSmileLeft")
    (tmp_path / "m.csv").write_text(
        "id,input,kind,rig,options\n"
        + "".join(f"{n},{n}.csv,animate,{classic_rig_stage},--video-max-frames 40\n" for n in ("a", "b", "c"))
    )
    out = tmp_path / "out"
    process = start_batch(tmp_path / "m.csv", out, "--jobs", "2")
    partial, pid = wait_for(lambda: mid_take(out, "b"), process)
    os.kill(pid, signal.SIGKILL)
    stdout, stderr = process.communicate(timeout=300)
    assert process.returncode == 0, stderr
    takes = {entry["id"]: entry for entry in landed(out)}
    assert [takes[n]["status"] for n in "abc"] == ["done"] * 3
    assert not partial.exists() and sorted(p.name for p in out.iterdir() if p.name.startswith(".")) == []
    record = json.loads((out / "b" / "take.json").read_text())
    assert record["frames"] == 40 and (out / "b" / "b.mp4").is_file()
    from pxr import Usd

    from warpface import usd

    stages = [Usd.Stage.Open(str(out / n / f"{n}.usda")) for n in "ab"]
    points = [np.asarray(usd.rig_prims(s).skin.GetAttribute("points").Get(39)) for s in stages]
    np.testing.assert_array_equal(points[0], points[1])  # the same driver: the retried take equals the other


@pytest.mark.slow
def test_ctrl_c_keeps_finished_takes_and_leaves_no_partial_one(tmp_path, classic_rig_stage):
    names = [f"t{k}" for k in range(5)]
    for name in names:
        ramp_csv(tmp_path / f"{name}.csv", 30, "browInnerUp")
    (tmp_path / "m.csv").write_text(
        "id,input,kind,rig,options\n"
        + "".join(f"{n},{n}.csv,animate,{classic_rig_stage},--video-max-frames 30\n" for n in names)
    )
    out = tmp_path / "out"
    process = start_batch(tmp_path / "m.csv", out, "--jobs", "2")
    wait_for(lambda: landed(out) and any(out.glob(".*.partial-*")), process)
    os.killpg(process.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole process group
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 130 and "interrupted" in stderr
    document = json.loads((out / "report.json").read_text())
    assert document["interrupted"] and not document["finished"]
    finished = {entry["id"] for entry in document["takes"]}
    assert finished and finished < set(names)
    for name in names:  # a take is complete (and reported) or absent
        assert (out / name / "take.json").is_file() == (name in finished)
        assert (out / name).exists() == (name in finished)
    assert not [p for p in out.iterdir() if p.name.startswith(".")]
    assert (out / "shoot.usda").is_file() and (out / "report.png").is_file()


@pytest.mark.slow
def test_track_and_fit_takes_run_through_their_commands(tmp_path):
    from pxr import Usd

    from warpface import usd
    from warpface.assets import default_rig
    from warpface.batch import run

    rig = default_rig(device="cpu")
    usd.write_rig(tmp_path / "rig.usda", rig)
    controls = np.zeros(len(rig.control_names))
    controls[rig.control_names.index("zygomaticus_major_L")] = 0.5
    target = rig.model(device="cpu").evaluate(controls[None])[0]
    obj = [f"v {x:.8f} {y:.8f} {z:.8f}" for x, y, z in target] + [
        f"f {a + 1} {b + 1} {c + 1}" for a, b, c in rig.mesh.triangles
    ]
    (tmp_path / "smile.obj").write_text("\n".join(obj) + "\n")
    rig_before = (tmp_path / "rig.usda").read_bytes()
    (tmp_path / "m.json").write_text(
        json.dumps(
            [
                {"id": "tracked", "input": "synthetic", "kind": "track", "options": {"frames": 3}},
                {
                    "id": "fitted",
                    "input": "smile.obj",
                    "kind": "fit",
                    "rig": "rig.usda",
                    "options": {"landmarks": True},
                },
            ]
        )
    )
    result = run(tmp_path / "m.json", tmp_path / "out", device="cpu", progress=False)
    assert [entry["status"] for entry in result.takes] == ["done", "done"], result.takes
    from warpface.usd.frames import open_frames

    tracked = open_frames(tmp_path / "out" / "tracked" / "tracked.usda")
    assert len(tracked.times) == 3 and tracked.kind == "capture"
    from warpface.usd.presets_io import read_presets

    fitted = Usd.Stage.Open(str(tmp_path / "out" / "fitted" / "fitted.usda"))
    preset = read_presets(fitted)["smile"]
    assert preset["zygomaticus_major_L"] == pytest.approx(0.5, abs=0.02)
    assert (tmp_path / "rig.usda").read_bytes() == rig_before  # the manifest's rig is left as it was
    shoot = Usd.Stage.Open(str(result.shoot))
    variants = shoot.GetPrimAtPath("/Shoot/Character").GetVariantSet("take")
    assert sorted(variants.GetVariantNames()) == ["fitted", "tracked"]
    variants.SetVariantSelection("tracked")
    face = shoot.GetPrimAtPath("/Shoot/Character/Face")
    assert len(face.GetAttribute("points").GetTimeSamples()) == 3  # value clips play through the reference
