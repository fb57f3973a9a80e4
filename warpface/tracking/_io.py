"""File helpers for the tracking package: JSON written atomically (temporary file + rename)."""

from __future__ import annotations

import json
from pathlib import Path

from .._files import atomic_path

__all__ = ["atomic_path", "write_json_atomic"]


def write_json_atomic(path: str | Path, data) -> None:
    """Write ``data`` as indented JSON through a temporary file and rename."""
    with atomic_path(path, ".json") as tmp:
        tmp.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
