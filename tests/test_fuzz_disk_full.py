"""A full disk during ``bake``, ``track`` and ``animate`` (issue 9): one stderr line, exit code 2, no
partial or temporary file left behind, and nothing written before lost.

The full disk is simulated per process with ``RLIMIT_FSIZE`` (SIGXFSZ ignored, so a write past the
limit fails with EFBIG, as a write to a full disk fails with ENOSPC): every file the command writes
stops growing at the limit, exactly where a disk with that much room left would stop it.
"""

from __future__ import annotations

import errno
import hashlib
import os
import resource
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import small_face_rig

REPO = Path(__file__).resolve().parents[1]


def _limited(limit: int):
    def apply() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return apply


def _warpface(folder: Path, *argv: str, limit: int | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run(
        [sys.executable, "-m", "warpface.cli", "--device", "cpu", "--quiet", *argv],
        cwd=folder,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        preexec_fn=None if limit is None else _limited(limit),
    )


def _snapshot(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _assert_clean_failure(result: subprocess.CompletedProcess, command: str, before: dict, after: dict) -> None:
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2, result.stderr[-2000:]
    assert len(lines) == 1 and lines[0].startswith(f"warpface {command}: error: cannot write"), result.stderr
    assert "disk is full" in lines[0] and "pxrInternal" not in lines[0] and "Traceback" not in result.stderr
    assert after == before, f"files changed or left behind: {sorted(set(after) ^ set(before))}"


def _stage_with_animation(folder: Path, frames: int = 10) -> Path:
    from warpface.usd import write_animation, write_rig

    rig = small_face_rig(8)
    stage = write_rig(folder / "s.usda", rig)
    write_animation(
        stage, np.arange(float(frames)), contractions={m.name: np.linspace(0.0, 1.0, frames) for m in rig.muscles}
    )
    stage.GetRootLayer().Save()
    return folder / "s.usda"


def test_bake_on_a_full_disk_keeps_the_previous_cache(tmp_path):
    _stage_with_animation(tmp_path)
    assert _warpface(tmp_path, "bake", "s.usda").returncode == 0
    before = _snapshot(tmp_path)
    cache_size = (tmp_path / "s_anim.usdc").stat().st_size
    # a longer bake needs a bigger cache than the disk has room for
    result = _warpface(tmp_path, "bake", "s.usda", "--end", "40", limit=cache_size // 2)
    _assert_clean_failure(result, "bake", before, _snapshot(tmp_path))
    from warpface.usd import open_stage

    assert open_stage(tmp_path / "s.usda").GetEndTimeCode() == 9.0  # the old cache still composes


def test_animate_on_a_full_disk_keeps_the_previous_output(tmp_path):
    from warpface.drivers import Curves, write_live_link

    times = np.arange(20) / 30.0
    write_live_link(
        tmp_path / "drv.csv",
        Curves(times, ["jawOpen", "mouthSmileLeft"], np.linspace(0, 1, 20)[:, None] * [1.0, 0.5], fps=30.0),
    )
    argv = ("animate", "drv.csv", "--out", "o.usda", "--no-video")
    assert _warpface(tmp_path, *argv).returncode == 0
    before = _snapshot(tmp_path)
    _assert_clean_failure(_warpface(tmp_path, *argv, limit=100_000), "animate", before, _snapshot(tmp_path))


def test_track_on_a_full_disk_leaves_no_stub(tmp_path):
    """The first chunk does not fit: no stage, no static layer, no empty folder is left."""
    (tmp_path / "keep.txt").write_text("written before")
    before = _snapshot(tmp_path)
    result = _warpface(tmp_path, "track", "synthetic", "--stage", "cap/out.usda", limit=400_000)
    _assert_clean_failure(result, "track", before, _snapshot(tmp_path))
    assert not (tmp_path / "cap" / "out_track").exists()


def test_capture_keeps_every_flushed_chunk_when_the_disk_fills(tmp_path, monkeypatch):
    """The disk fills at the third chunk: the error names the file, and the stage still lists and reads
    back every frame of the two chunks flushed before it; no temporary file is left."""
    from warpface.usd import tracking_io
    from warpface.usd.tracking_io import TrackingStageWriter, read_tracking

    real_export = tracking_io.export_layer_atomically
    written = []

    def export(layer, path):
        if Path(path).name == "chunk_0002.usdc":
            raise OSError(errno.ENOSPC, f"cannot write {path}: the disk is full (No space left on device)")
        real_export(layer, path)
        written.append(Path(path).name)

    monkeypatch.setattr(tracking_io, "export_layer_atomically", export)
    names = ["a", "b", "c"]
    writer = TrackingStageWriter(tmp_path / "cap.usda", names, 30.0, chunk_frames=4, flush_seconds=1e9)
    with pytest.raises(OSError, match="disk is full"):
        for frame in range(20):
            writer.add(frame / 30.0, np.full((3, 3), 0.01 * frame), np.ones(3))
    back = read_tracking(tmp_path / "cap.usda")
    assert len(back["times"]) == 8 and writer.frames_written == 8
    np.testing.assert_allclose(back["landmarks"][:, 0, 0], 0.01 * np.arange(8), atol=1e-7)
    assert not [p for p in tmp_path.rglob(".*") if p.is_file()], "temporary files left behind"
    with pytest.raises(OSError, match="disk is full"):
        writer.close()  # the queued frames still have nowhere to go: said again, nothing lost on disk
    assert len(read_tracking(tmp_path / "cap.usda")["times"]) == 8
