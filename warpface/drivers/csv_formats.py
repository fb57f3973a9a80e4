"""OpenFace 2.x and Live Link Face CSV files: read into :class:`Curves`, and written back.

OpenFace 2.x (``FeatureExtraction``) writes one row per video frame: ``frame, timestamp, confidence,
success``, then head pose, gaze, landmarks and the action units, ``AU01_r`` … (intensity 0–5) and
``AU01_c`` … (presence 0/1). Headers often carry a leading space (``" timestamp"``). Frames with
``success`` 0 were not tracked (their AU values are zeros, not measurements) and are dropped.

Live Link Face (Epic Games' iOS app) writes ``Timecode, BlendshapeCount``, the 52 ARKit weights in
capitalised spelling (``EyeBlinkLeft`` … ``TongueOut``), then head and eye rotations (``HeadYaw`` …
``RightEyeRoll``). ``Timecode`` is ``HH:MM:SS:FF.fff``: frame ``FF`` of the second plus a sub-frame
fraction. The frame rate is not stored; it is the smallest standard rate above every ``FF`` seen.
"""

from __future__ import annotations

import csv
import io
import math
import re
from pathlib import Path

import numpy as np

from .._files import atomic_path, read_text
from .._validate import as_path, expect_instance
from .channels import ARKIT_CHANNELS, Curves, canonical_channel

__all__ = [
    "read_openface",
    "write_openface",
    "read_live_link",
    "write_live_link",
    "LIVE_LINK_EXTRA_COLUMNS",
    "STANDARD_FRAME_RATES",
]

LIVE_LINK_EXTRA_COLUMNS = (
    "HeadYaw",
    "HeadPitch",
    "HeadRoll",
    "LeftEyeYaw",
    "LeftEyePitch",
    "LeftEyeRoll",
    "RightEyeYaw",
    "RightEyePitch",
    "RightEyeRoll",
)
"""Live Link Face's rotation columns after the 52 weights (radians-like, not channels for the rig)."""

STANDARD_FRAME_RATES = (24.0, 25.0, 30.0, 48.0, 50.0, 60.0, 72.0, 90.0, 100.0, 120.0, 240.0)

_OPENFACE_AU = re.compile(r"^AU\d{2}_r$")
_OPENFACE_PRESENCE = re.compile(r"^AU\d{2}_c$")
_TIMECODE = re.compile(r"^(\d+):(\d{1,2}):(\d{1,2})[:;](\d+)(?:\.(\d+))?$")


def _rows(path: Path) -> tuple[list[str], list[list[str]]]:
    """Header (stripped) and data rows of a CSV file; blank lines skipped."""
    text = read_text(path)
    rows = [row for row in csv.reader(io.StringIO(text)) if any(cell.strip() for cell in row)]
    if not rows:
        raise ValueError(f"{path}: empty file")
    header = [cell.strip() for cell in rows[0]]
    if len(rows) == 1:
        raise ValueError(f"{path}: header only, no frames")
    for number, row in enumerate(rows[1:], start=2):
        if len(row) < len(header):
            raise ValueError(f"{path}: line {number} has {len(row)} columns, the header {len(header)}")
    return header, rows[1:]


def _column(path: Path, header: list[str], rows: list[list[str]], name: str) -> np.ndarray:
    """One numeric column; a clear error naming the line for anything that is not a finite number."""
    index = header.index(name)
    cells = [row[index] for row in rows]
    try:  # NumPy parses the whole column; the loop below only runs to name a bad cell (or parse 1_000)
        out = np.array(cells, dtype=np.float64)
        if np.isfinite(out).all():
            return out
    except ValueError:
        pass
    out = np.empty(len(rows), dtype=np.float64)
    for row_number, row in enumerate(rows):
        try:
            value = float(row[index])
        except ValueError:
            value = math.nan
        if not math.isfinite(value):
            raise ValueError(
                f"{path}: column {name!r} line {row_number + 2}: {row[index].strip()!r} is not a finite number"
            )
        out[row_number] = value
    return out


def read_openface(path) -> Curves:
    """Read an OpenFace 2.x CSV: AU intensities (``AUxx_r`` → channel ``AUxx``) of the tracked frames.

    Returns:
        Curves with ``times`` = the file's ``timestamp`` column [s], one channel per ``AU.._r``
        column (values 0–5), only frames with ``success`` = 1 (a note says how many were dropped).

    Raises:
        ValueError: empty file, no ``timestamp`` or no ``AU.._r`` column, a value that is not a
            number, no tracked frame, timestamps not strictly increasing.
    """
    path = as_path(path, "path")
    header, rows = _rows(path)
    if "timestamp" not in header:
        raise ValueError(f"{path}: missing column 'timestamp' (not an OpenFace CSV?)")
    au_columns = [name for name in header if _OPENFACE_AU.match(name)]
    if not au_columns:
        raise ValueError(f"{path}: no action-unit intensity columns (AU01_r, …)")
    times = _column(path, header, rows, "timestamp")
    values = np.stack([_column(path, header, rows, name) for name in au_columns], axis=1)
    notes = []
    if "success" in header:
        tracked = _column(path, header, rows, "success") > 0.5
        if not tracked.any():
            raise ValueError(f"{path}: no frame was tracked (success = 0 everywhere)")
        if not tracked.all():
            notes.append(f"{path.name}: dropped {int((~tracked).sum())} untracked frames (success = 0)")
        times, values = times[tracked], values[tracked]
    steps = np.diff(times)
    fps = float(1.0 / np.median(steps)) if len(steps) and np.median(steps) > 0 else None
    return Curves(
        times=times,
        names=[canonical_channel(n) for n in au_columns],
        values=values,
        source=path.name,
        fps=fps,
        notes=notes,
    )


def write_openface(path, curves: Curves) -> Path:
    """Write ``curves``' action-unit channels as an OpenFace 2.x-style CSV (``frame, timestamp,
    confidence, success, AUxx_r …``); other channels are left out. Written atomically."""
    expect_instance(curves, Curves, "curves")
    path = as_path(path, "path")
    aus = [k for k, name in enumerate(curves.names) if re.match(r"^AU\d{2}$", name)]
    if not aus:
        raise ValueError(f"{path}: {curves.source} has no action-unit channels to write")
    header = ["frame", "timestamp", "confidence", "success"] + [f"{curves.names[k]}_r" for k in aus]
    with atomic_path(path, ".csv") as temporary:
        with open(temporary, "w", newline="") as handle:
            handle.write(", ".join(header) + "\n")
            for frame, time in enumerate(curves.times):
                cells = [str(frame + 1), repr(float(time)), "0.98", "1"] + [
                    repr(float(curves.values[frame, k])) for k in aus
                ]
                handle.write(", ".join(cells) + "\n")
    return path


def _parse_timecode(path: Path, text: str, line: int) -> tuple[float, int, float]:
    """(whole seconds, frame number, sub-frame fraction) of ``HH:MM:SS:FF.fff``."""
    match = _TIMECODE.match(text.strip())
    if not match:
        raise ValueError(f"{path}: line {line}: timecode {text.strip()!r} is not HH:MM:SS:FF.fff")
    hours, minutes, seconds, frame = (int(g) for g in match.groups()[:4])
    if minutes > 59 or seconds > 59:
        raise ValueError(f"{path}: line {line}: timecode {text.strip()!r} has minutes or seconds above 59")
    fraction = float("0." + match.group(5)) if match.group(5) else 0.0
    return hours * 3600.0 + minutes * 60.0 + seconds, frame, fraction


def read_live_link(path, *, fps: float | None = None) -> Curves:
    """Read a Live Link Face CSV: the ARKit weights, timed by ``Timecode``.

    Args:
        path: the CSV file.
        fps: the recording's frame rate; default: the smallest of :data:`STANDARD_FRAME_RATES` above
            every frame number in the timecodes.

    Returns:
        Curves with ARKit lowerCamel channel names; ``times`` from the timecodes, relative to the first
        frame [s]; ``fps`` set. Head/eye rotation columns are skipped; other unknown columns are named
        in a note and skipped.

    Raises:
        ValueError: empty file, no ``Timecode`` column or no ARKit column, a malformed timecode or value,
            timecodes not strictly increasing.
    """
    path = as_path(path, "path")
    header, rows = _rows(path)
    if "Timecode" not in header:
        raise ValueError(f"{path}: missing column 'Timecode' (not a Live Link Face CSV?)")
    known = set(ARKIT_CHANNELS)
    columns, unknown = [], []
    for name in header:
        if name.lower() in ("timecode", "blendshapecount") or name in LIVE_LINK_EXTRA_COLUMNS:
            continue
        (columns if canonical_channel(name) in known else unknown).append(name)
    if not columns:
        raise ValueError(f"{path}: no ARKit blendshape columns (EyeBlinkLeft, …)")
    index = header.index("Timecode")
    parsed = [_parse_timecode(path, row[index], number) for number, row in enumerate(rows, start=2)]
    seconds = np.array([p[0] for p in parsed])
    frames = np.array([p[1] + p[2] for p in parsed])
    if fps is None:
        highest = max(p[1] for p in parsed)
        rate = next((r for r in STANDARD_FRAME_RATES if r > highest), None)
        if rate is None:
            raise ValueError(f"{path}: timecode frame number {highest} is above every standard frame rate; pass fps")
    else:
        rate = float(fps)
        if not (math.isfinite(rate) and rate > 0):
            raise ValueError(f"{path}: fps must be a positive number, got {fps!r}")
    absolute = seconds + frames / rate
    values = np.stack([_column(path, header, rows, name) for name in columns], axis=1)
    notes = [f"{path.name}: ignored unknown columns {', '.join(unknown)}"] if unknown else []
    return Curves(
        times=absolute - absolute[0],
        names=[canonical_channel(n) for n in columns],
        values=values,
        source=path.name,
        fps=rate,
        notes=notes,
    )


def _timecode(seconds: float, fps: float) -> str:
    """``HH:MM:SS:FF.fff`` of a time [s] at a whole frame rate (sub-frame in thousandths of a frame)."""
    frame_count, thousandths = divmod(int(round(seconds * fps * 1000.0)), 1000)
    total, frame = divmod(frame_count, int(round(fps)))
    hours, rest = divmod(int(total), 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours:02d}:{minutes:02d}:{secs:02d}:{frame:02d}.{thousandths:03d}"


def write_live_link(path, curves: Curves, *, fps: float | None = None, start_seconds: float = 0.0) -> Path:
    """Write ``curves``' ARKit channels as a Live Link Face CSV (all 52 columns, missing ones 0; head and
    eye rotations 0). ``fps`` (default ``curves.fps``, else 60) must be a whole frame rate. Atomic."""
    expect_instance(curves, Curves, "curves")
    path = as_path(path, "path")
    rate = float(fps if fps is not None else (curves.fps or 60.0))
    if not math.isfinite(rate) or rate <= 0 or abs(rate - round(rate)) > 1e-9:
        raise ValueError(f"{path}: Live Link timecodes need a whole frame rate, got {rate!r}")
    columns = {name: k for k, name in enumerate(curves.names)}
    with atomic_path(path, ".csv") as temporary:
        with open(temporary, "w", newline="") as handle:
            capitalised = [name[0].upper() + name[1:] for name in ARKIT_CHANNELS]
            handle.write(",".join(["Timecode", "BlendshapeCount", *capitalised, *LIVE_LINK_EXTRA_COLUMNS]) + "\n")
            zeros = ",".join("0" for _ in LIVE_LINK_EXTRA_COLUMNS)
            for frame, time in enumerate(curves.times):
                weights = [
                    repr(float(curves.values[frame, columns[n]])) if n in columns else "0" for n in ARKIT_CHANNELS
                ]
                handle.write(
                    ",".join([_timecode(start_seconds + float(time), rate), str(len(ARKIT_CHANNELS)), *weights, zeros])
                    + "\n"
                )
    return path
