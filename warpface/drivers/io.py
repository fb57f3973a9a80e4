"""Which driver format a file holds, from its first bytes and its extension.

The one reader of every format, USD ``SkelAnimation`` layers included, is :func:`warpface.usd.read_driver`
(it sits in the USD layer, above the drivers).
"""

from __future__ import annotations

from .._validate import as_path

__all__ = ["detect_format", "DRIVER_FORMATS"]

DRIVER_FORMATS = ("openface", "livelink", "mediapipe-textproto", "mediapipe-jsonl", "usdskel")
"""Formats :func:`warpface.usd.read_driver` understands."""

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
