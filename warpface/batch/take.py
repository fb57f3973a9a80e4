"""One take from input to a complete output folder: what every engine's worker runs.

The take is built in ``DIR/.<id>.partial-<pid>`` (stage, cache, preview, ``log.txt`` with the command's output,
``thumb.png`` at the take's most active moment, ``take.json`` last) and renamed to ``DIR/<id>`` when complete,
so ``DIR/<id>`` is either a complete take or absent, whatever kills the worker. A re-run skips a take whose
``take.json`` records the same digest of inputs and options (:func:`take_digest`).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import time
from pathlib import Path

__all__ = [
    "run_take",
    "take_digest",
    "completed_take",
    "remove_leftovers",
    "failed_entry",
    "TAKE_RECORD",
    "THUMB_SIZE",
]

TAKE_RECORD = "take.json"
"""The file that makes a take folder complete: id, kind, digest, stage, frames, seconds."""

THUMB_SIZE = (240, 270)
"""Width and height of a take's contact-sheet picture [pixels]."""

_DIGEST_VERSION = 1
"""Bumped when a take's outputs change for the same inputs (old takes are then redone)."""

_ACTIVITY_SAMPLES = 240
"""Frames examined at most when looking for a take's most active moment."""


def take_digest(take) -> str:
    """SHA-256 over everything that decides a take's output: kind, input, rig, mapping file, options (as parsed,
    defaults included) and the warpface version. Files count by content; a folder (an RGB-D recording) by the
    names, sizes and modification times of its files."""
    from .. import __version__

    digest = hashlib.sha256()
    record = {
        "version": [_DIGEST_VERSION, __version__],
        "kind": take.kind,
        "mapping": take.mapping,
        "settings": take.settings,
    }
    digest.update(json.dumps(record, sort_keys=True, default=str).encode())
    mapping_file = None if take.mapping is None else take.mapping.rpartition(":")[0] or take.mapping
    for path in (take.input, take.rig, mapping_file):
        digest.update(_path_digest(None if path is None else Path(path)).encode())
    return digest.hexdigest()


def _path_digest(path: Path | None) -> str:
    if path is None or not path.exists():
        return f"none:{path}"
    if path.is_dir():
        listing = hashlib.sha256()
        for item in sorted(p for p in path.rglob("*") if p.is_file()):
            stat = item.stat()
            listing.update(f"{item.relative_to(path)}\0{stat.st_size}\0{stat.st_mtime_ns}\n".encode())
        return "folder:" + listing.hexdigest()
    content = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            content.update(block)
    return "file:" + content.hexdigest()


def completed_take(out: Path, take_id: str, digest: str | None = None) -> dict | None:
    """The record of the complete take ``out/<id>`` (with ``digest`` when given), else None."""
    record_path = out / take_id / TAKE_RECORD
    try:
        record = json.loads(record_path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict) or (digest is not None and record.get("digest") != digest):
        return None
    stage = out / take_id / str(record.get("stage", ""))
    return record if stage.is_file() else None


def remove_leftovers(out: Path, take_id: str) -> None:
    """Remove what an interrupted attempt at ``take_id`` left in ``out`` (its partial and set-aside folders)."""
    for leftover in out.glob(f".{take_id}.*-*"):
        if leftover.name.startswith((f".{take_id}.partial-", f".{take_id}.old-")):
            shutil.rmtree(leftover, ignore_errors=True)


def run_take(take, out: Path, *, device: str | None, digest: str, rigs=None) -> dict:
    """Run one take into ``out/<id>`` atomically; returns its report entry (``status`` ``done`` or ``failed``).

    ``rigs``: the worker's :class:`~warpface.commands.rig_models.RigModels`, kept between its takes (see
    :func:`~warpface.batch.kinds.run_kind`).

    The take's own errors (a corrupt input, unknown channels) are caught and reported as one line; only a lost
    worker leaves the take undone (absent), for the engine to retry.
    """
    from ..commands.common import one_line

    started = time.perf_counter()
    remove_leftovers(out, take.id)
    partial = out / f".{take.id}.partial-{os.getpid()}"
    try:
        partial.mkdir()
        with open(partial / "log.txt", "w") as log, contextlib.redirect_stdout(log):
            stage = _run_in(take, partial, device, rigs)
            frames, moment = _most_active_moment(stage)
            thumb_note = _thumbnail(stage, moment, partial / "thumb.png", take.kind)
        seconds = time.perf_counter() - started
        record = {
            "id": take.id,
            "kind": take.kind,
            "input": str(take.input),
            "digest": digest,
            "stage": stage.name,
            "frames": frames,
            "moment": moment,
            "seconds": round(seconds, 3),
            "device": device,
            "thumbnail": None if thumb_note else "thumb.png",
            "notes": [thumb_note] if thumb_note else [],
        }
        (partial / TAKE_RECORD).write_text(json.dumps(record, indent=1) + "\n")
        _publish(partial, out / take.id)
    except Exception as error:  # noqa: BLE001 — a take's own failure is reported, never retried
        shutil.rmtree(partial, ignore_errors=True)
        return failed_entry(take, digest, one_line(error))
    return {**record, "status": "done", "error": None, "stage": str(out / take.id / stage.name)}


def failed_entry(take, digest: str, error: str | None) -> dict:
    """The report entry of a take that failed with the one-line ``error``."""
    return {
        "id": take.id,
        "kind": take.kind,
        "input": str(take.input),
        "digest": digest,
        "status": "failed",
        "error": error,
        "stage": None,
        "frames": 0,
    }


def _run_in(take, folder: Path, device: str | None, rigs) -> Path:
    from .kinds import run_kind

    return run_kind(take, folder, device=device, rigs=rigs)


def _publish(partial: Path, final: Path) -> None:
    """Rename the finished ``partial`` folder to ``final``; an older ``final`` is set aside first and removed after
    (between the two renames the take is absent, never mixed)."""
    old = None
    if final.exists():
        old = final.with_name(f".{final.name}.old-{os.getpid()}")
        os.replace(final, old)
    os.replace(partial, final)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _most_active_moment(stage: Path) -> tuple[int, float | None]:
    """(frame count, time code where the face is furthest from rest) of a take's stage; (0, None) when still."""
    import numpy as np

    from ..usd.frames import open_frames

    frames = open_frames(stage, max_frames=None)
    if not len(frames.times):
        return 0, None
    sampled = frames.times[np.unique(np.linspace(0, len(frames.times) - 1, _ACTIVITY_SAMPLES).round().astype(int))]
    activity = [float(np.abs(frames.points_at(t) - frames.rest).max()) for t in sampled.tolist()]
    return len(frames.times), float(sampled[int(np.argmax(activity))])


def _thumbnail(stage: Path, moment: float | None, path: Path, kind: str) -> str | None:
    """Render the take's contact-sheet picture at ``moment``; returns None, or why there is no picture (no
    offscreen OpenGL on this machine)."""
    from ..errors import OffscreenUnavailable
    from .kinds import render_still

    try:
        if kind == "fit" and (heat_maps := sorted((stage.parent / "fit").glob("*_error.png"))):
            _fit_into(heat_maps[0], path)
        else:
            render_still(stage, moment, path, THUMB_SIZE)
    except OffscreenUnavailable as error:
        return f"no picture: {' '.join(str(error).split())}"
    return None


def _fit_into(source: Path, path: Path) -> None:
    """Scale the picture ``source`` to fit :data:`THUMB_SIZE` (aspect kept) and write it to ``path``."""
    import cv2

    image = cv2.imread(str(source))
    if image is None:
        raise ValueError(f"{source}: not a readable picture")
    scale = min(THUMB_SIZE[0] / image.shape[1], THUMB_SIZE[1] / image.shape[0])
    size = (max(1, round(image.shape[1] * scale)), max(1, round(image.shape[0] * scale)))
    cv2.imwrite(str(path), cv2.resize(image, size, interpolation=cv2.INTER_AREA))
