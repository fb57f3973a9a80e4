"""MediaPipe Face Landmarker blendshape scores: text-format protobuf and JSON lines.

The text-proto form is a ``ClassificationList`` (``classification { index score label }`` blocks,
one frame), as MediaPipe's own test data stores it. Several frames may be given as repeated
``classification_list { … }`` blocks with an optional ``timestamp_ms`` each.

The JSON-lines form has one frame per line, an object with a time (``timestamp_ms`` in milliseconds,
or ``timestamp``/``time`` in seconds) and the scores, either as a list of categories
(``blendshapes``, ``face_blendshapes`` — first face — or ``categories``: objects with
``category_name``/``label`` and ``score``) or as an object ``{name: score}``. Frames without a time
are spaced at ``fps``. MediaPipe's extra ``_neutral`` category is dropped.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np

from .._files import atomic_path, read_text
from .._validate import as_path, expect_instance
from .channels import ARKIT_CHANNELS, Curves, canonical_channel

__all__ = ["read_mediapipe_textproto", "read_mediapipe_jsonl", "write_mediapipe_textproto", "write_mediapipe_jsonl"]

_SKIPPED = {"_neutral"}
_BLOCK = re.compile(r"classification\s*\{([^{}]*)\}", re.S)
_LIST = re.compile(r"classification_list\s*\{((?:[^{}]|\{[^{}]*\})*)\}", re.S)
_FIELD = re.compile(r"(\w+)\s*:\s*(\"(?:[^\"\\]|\\.)*\"|[^\s}]+)")


def _read_text(path: Path) -> str:
    text = read_text(path)
    if not text.strip():
        raise ValueError(f"{path}: empty file")
    return text


def _score(path: Path, where: str, value) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if not math.isfinite(number):
        raise ValueError(f"{path}: {where}: score {value!r} is not a finite number")
    return number


def _frames_to_curves(path: Path, frames: list[dict[str, float]], times: list[float | None], fps: float) -> Curves:
    """Curves from per-frame {channel: score}; channels are the union (a channel missing in a frame is an error)."""
    if not frames:
        raise ValueError(f"{path}: no blendshape frames")
    names = [canonical_channel(n) for n in frames[0] if n not in _SKIPPED]
    known = set(ARKIT_CHANNELS)
    unknown = sorted({n for n in names if n not in known})
    names = [n for n in names if n in known]
    if not names:
        raise ValueError(f"{path}: no ARKit blendshape categories")
    values = np.empty((len(frames), len(names)))
    for row, frame in enumerate(frames):
        canonical = {canonical_channel(k): v for k, v in frame.items()}
        for column, name in enumerate(names):
            if name not in canonical:
                raise ValueError(f"{path}: frame {row}: missing category {name!r}")
            values[row, column] = canonical[name]
    if all(t is None for t in times):
        stamps = np.arange(len(frames)) / float(fps)
    elif any(t is None for t in times):
        raise ValueError(
            f"{path}: frame {next(i for i, t in enumerate(times) if t is None)} has no timestamp, others do"
        )
    else:
        stamps = np.array(times, dtype=np.float64)
    notes = [f"{path.name}: ignored unknown categories {', '.join(unknown)}"] if unknown else []
    return Curves(times=stamps, names=names, values=values, source=path.name, notes=notes)


def _classifications(path: Path, text: str, where: str) -> dict[str, float]:
    scores: dict[str, float] = {}
    for number, block in enumerate(_BLOCK.findall(text)):
        fields = dict(_FIELD.findall(block))
        label = fields.get("label") or fields.get("display_name")
        if label is None:
            raise ValueError(f"{path}: {where}classification {number} has no label")
        label = bytes(label.strip('"'), "utf-8").decode("unicode_escape")
        if label in scores:
            raise ValueError(f"{path}: {where}category {label!r} appears twice")
        scores[label] = _score(path, f"{where}category {label!r}", fields.get("score"))
    return scores


def read_mediapipe_textproto(path, *, fps: float = 30.0) -> Curves:
    """Read blendshape scores from a text-format ``ClassificationList`` (one frame, at t = 0) or repeated
    ``classification_list`` blocks (frames at their ``timestamp_ms``, else spaced at ``fps``).

    Raises:
        ValueError: empty file, no classification, a score that is not a number, a repeated category.
    """
    path = as_path(path, "path")
    text = re.sub(r"#[^\n]*", "", _read_text(path))
    lists = _LIST.findall(text)
    if lists:
        frames, times = [], []
        for number, body in enumerate(lists):
            frames.append(_classifications(path, body, f"list {number}: "))
            stamp = re.search(r"timestamp_ms\s*:\s*([^\s}]+)", _BLOCK.sub("", body))
            times.append(_score(path, f"list {number}: timestamp_ms", stamp.group(1)) / 1000.0 if stamp else None)
    else:
        frames, times = [_classifications(path, text, "")], [None]
    if not frames[0]:
        raise ValueError(f"{path}: no 'classification {{ … }}' blocks")
    return _frames_to_curves(path, frames, times, fps)


def _json_frame(path: Path, line: int, record) -> tuple[dict[str, float], float | None]:
    where = f"line {line}"
    if not isinstance(record, dict):
        raise ValueError(f"{path}: {where}: expected a JSON object, got {type(record).__name__}")
    time = None
    if "timestamp_ms" in record:
        time = _score(path, f"{where}: timestamp_ms", record["timestamp_ms"]) / 1000.0
    else:
        for key in ("timestamp", "time"):
            if key in record:
                time = _score(path, f"{where}: {key}", record[key])
                break
    categories = None
    for key in ("blendshapes", "face_blendshapes", "faceBlendshapes", "categories", "scores"):
        if key in record:
            categories = record[key]
            break
    if categories is None:
        raise ValueError(f"{path}: {where}: no 'blendshapes' (or 'face_blendshapes', 'categories') entry")
    if isinstance(categories, list) and categories and isinstance(categories[0], list):
        categories = categories[0]  # face_blendshapes: one list per detected face
    if isinstance(categories, dict) and isinstance(categories.get("categories"), list):
        categories = categories["categories"]  # MediaPipe JS: {categories: [...]}
    scores: dict[str, float] = {}
    if isinstance(categories, dict):
        items = categories.items()
    elif isinstance(categories, list):
        items = []
        for number, entry in enumerate(categories):
            if not isinstance(entry, dict):
                raise ValueError(f"{path}: {where}: category {number} is not an object")
            name = next(
                (
                    entry[k]
                    for k in ("category_name", "categoryName", "label", "display_name", "displayName")
                    if entry.get(k)
                ),
                None,
            )
            if not isinstance(name, str):
                raise ValueError(f"{path}: {where}: category {number} has no name")
            items.append((name, entry.get("score")))
    else:
        raise ValueError(f"{path}: {where}: blendshapes must be a list or an object")
    for name, value in items:
        if name in scores:
            raise ValueError(f"{path}: {where}: category {name!r} appears twice")
        scores[str(name)] = _score(path, f"{where}: category {name!r}", value)
    return scores, time


def read_mediapipe_jsonl(path, *, fps: float = 30.0) -> Curves:
    """Read blendshape scores from JSON lines (one frame per line; see the module notes).

    Raises:
        ValueError: empty file, a line that is not JSON or lacks scores, a score that is not a number,
            timestamps missing on some lines only or not strictly increasing.
    """
    path = as_path(path, "path")
    frames, times = [], []
    for line, text in enumerate(_read_text(path).splitlines(), start=1):
        if not text.strip():
            continue
        try:
            record = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: line {line}: not JSON ({exc.msg})") from None
        scores, time = _json_frame(path, line, record)
        frames.append(scores)
        times.append(time)
    return _frames_to_curves(path, frames, times, fps)


def write_mediapipe_textproto(path, curves: Curves) -> Path:
    """Write ``curves``' ARKit channels as repeated ``classification_list`` blocks with ``timestamp_ms``
    (one per frame; a single frame is written as a plain ``ClassificationList``). Atomic."""
    expect_instance(curves, Curves, "curves")
    path = as_path(path, "path")
    columns = [k for k, n in enumerate(curves.names) if n in set(ARKIT_CHANNELS)]
    if not columns:
        raise ValueError(f"{path}: {curves.source} has no ARKit channels to write")

    def block(frame: int, indent: str) -> str:
        return "".join(
            f"{indent}classification {{\n{indent}  index: {i}\n{indent}  score: {float(curves.values[frame, k])!r}\n"
            f'{indent}  label: "{curves.names[k]}"\n{indent}}}\n'
            for i, k in enumerate(columns)
        )

    with atomic_path(path, path.suffix) as temporary:
        with open(temporary, "w") as handle:
            handle.write("# proto-message: ClassificationList (one per frame)\n")
            if curves.frame_count == 1 and curves.times[0] == 0.0:
                handle.write(block(0, ""))
            for frame in range(curves.frame_count if curves.frame_count > 1 or curves.times[0] != 0.0 else 0):
                handle.write(
                    "classification_list "
                    f"{{\n  timestamp_ms: {float(curves.times[frame]) * 1000.0!r}\n{block(frame, '  ')}}}\n"
                )
    return path


def write_mediapipe_jsonl(path, curves: Curves) -> Path:
    """Write one JSON object per frame, ``{"timestamp_ms": …, "blendshapes": [{"category_name", "score"}, …]}``,
    through a temporary file and a rename."""
    expect_instance(curves, Curves, "curves")
    path = as_path(path, "path")
    columns = [k for k, n in enumerate(curves.names) if n in set(ARKIT_CHANNELS)]
    if not columns:
        raise ValueError(f"{path}: {curves.source} has no ARKit channels to write")
    with atomic_path(path, path.suffix) as temporary:
        with open(temporary, "w") as handle:
            for frame, time in enumerate(curves.times):
                record = {
                    "timestamp_ms": float(time) * 1000.0,
                    "blendshapes": [
                        {"index": i, "category_name": curves.names[k], "score": float(curves.values[frame, k])}
                        for i, k in enumerate(columns)
                    ],
                }
                handle.write(json.dumps(record) + "\n")
    return path
