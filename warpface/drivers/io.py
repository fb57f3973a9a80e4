"""Reading any driver file: the format is chosen from the extension, then confirmed from the content."""

from __future__ import annotations

from .._validate import as_path, as_positive
from .channels import Curves
from .csv_formats import read_live_link, read_openface
from .mediapipe_format import read_mediapipe_jsonl, read_mediapipe_textproto

__all__ = ["read_driver", "detect_format", "DRIVER_FORMATS"]

DRIVER_FORMATS = ("openface", "livelink", "mediapipe-textproto", "mediapipe-jsonl", "usdskel")
"""Formats :func:`read_driver` understands."""

_USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")


def detect_format(path) -> str:
    """One of :data:`DRIVER_FORMATS` for ``path``, from its first bytes and its extension.

    Raises:
        ValueError: missing, empty or unrecognised file.
    """
    path = as_path(path, "path")
    if not path.is_file():
        raise ValueError(f"driver file not found: {path}")
    try:
        with open(path, "rb") as handle:
            head = handle.read(4096)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not head.strip():
        raise ValueError(f"{path}: empty file")
    suffix = path.suffix.lower()
    if head.startswith((b"#usda", b"PXR-USDC")) or (suffix in _USD_SUFFIXES and head.startswith(b"PK")):
        return "usdskel"
    text = head.decode("utf-8", errors="replace").lstrip("\ufeff")
    first_line = text.strip().splitlines()[0] if text.strip() else ""
    if "Timecode" in first_line and ("BlendshapeCount" in first_line or "," in first_line):
        return "livelink"
    if "timestamp" in first_line and "AU" in first_line:
        return "openface"
    stripped = text.lstrip()
    if stripped.startswith("{") or suffix in (".jsonl", ".ndjson", ".json"):
        return "mediapipe-jsonl"
    if "classification" in text or suffix in (".pbtxt", ".prototxt", ".txtpb", ".textproto"):
        return "mediapipe-textproto"
    raise ValueError(
        f"{path}: unrecognised driver format (expected OpenFace or Live Link Face CSV, MediaPipe "
        f"blendshapes as text-proto or JSON lines, or a USD SkelAnimation)"
    )


def read_driver(path, *, fps: float | None = None) -> Curves:
    """Read a driver file in any of :data:`DRIVER_FORMATS` but ``usdskel`` into :class:`Curves`.

    USD ``SkelAnimation`` layers are read by :func:`warpface.usd.read_driver` (every format, USD
    included): USD I/O lives in :mod:`warpface.usd`, which sits above the drivers.

    Args:
        path: the file.
        fps: frame rate for formats that do not store one (MediaPipe frames without timestamps;
            Live Link Face timecodes, overriding the detected rate).

    Raises:
        ValueError: unreadable or malformed file, or a USD layer (one line naming the file and the problem).
    """
    if fps is not None:
        fps = as_positive(fps, "fps", maximum=1e6)
    kind = detect_format(path)
    if kind == "openface":
        return read_openface(path)
    if kind == "livelink":
        return read_live_link(path, fps=fps)
    if kind == "mediapipe-jsonl":
        return read_mediapipe_jsonl(path, fps=fps or 30.0)
    if kind == "mediapipe-textproto":
        return read_mediapipe_textproto(path, fps=fps or 30.0)
    raise ValueError(f"{path}: a USD SkelAnimation layer; read it with warpface.usd.read_driver")
