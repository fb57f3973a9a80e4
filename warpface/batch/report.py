"""The batch's overview: ``report.json`` rewritten (atomically) as each take lands, and the contact sheet
``report.png`` with one picture per take at its most active moment and its status.

``report.json``::

    {"manifest": …, "engine": …, "total": N, "finished": false|true, "interrupted": false|true,
     "counts": {"done": …, "skipped": …, "failed": …},
     "takes": [{"id", "kind", "input", "status": "done"|"skipped"|"failed", "error", "stage", "frames", …}, …]}

``takes`` lists the takes that have landed so far, in the manifest's order; ``stage`` is the take's stage path
(None for a failed take), ``error`` its one-line error (None unless failed).
"""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["Report", "write_contact_sheet", "STATUSES"]

STATUSES = ("done", "skipped", "failed")

_COLORS = {"done": (70, 170, 70), "skipped": (170, 140, 60), "failed": (40, 40, 210)}
"""Status label colours (BGR, as OpenCV draws)."""


class Report:
    """The takes' entries, kept in manifest order and written to ``out/report.json`` on every change."""

    def __init__(self, out: Path, manifest, engine: str):
        self.path = Path(out) / "report.json"
        self._order = {take.id: index for index, take in enumerate(manifest.takes)}
        self._head = {"manifest": str(manifest.path), "engine": engine, "total": len(manifest.takes)}
        self.entries: dict[str, dict] = {}
        self.finished = False
        self.interrupted = False

    def add(self, entry: dict) -> None:
        """Record a landed take (``status`` one of :data:`STATUSES`) and rewrite the report."""
        if entry.get("status") not in STATUSES:
            raise ValueError(f"take {entry.get('id')!r}: status {entry.get('status')!r} is not one of {STATUSES}")
        self.entries[entry["id"]] = entry
        self.write()

    @property
    def takes(self) -> list[dict]:
        """The landed takes' entries in manifest order."""
        return sorted(self.entries.values(), key=lambda entry: self._order[entry["id"]])

    def count(self, status: str) -> int:
        return sum(entry["status"] == status for entry in self.entries.values())

    def write(self) -> None:
        """Rewrite ``report.json`` through a temporary file and a rename (a reader never sees half of it)."""
        from .._files import atomic_path

        document = {
            **self._head,
            "finished": self.finished,
            "interrupted": self.interrupted,
            "counts": {status: self.count(status) for status in STATUSES},
            "takes": self.takes,
        }
        with atomic_path(self.path, ".json") as temporary:
            temporary.write_text(json.dumps(document, indent=1) + "\n")


def write_contact_sheet(path: Path, entries: list[dict], *, tile=(240, 270), columns: int = 6) -> Path:
    """A PNG grid with one tile per take: its picture at its most active moment (``<take>/thumb.png``), its id
    and status; a failed take's tile shows its error instead. ``tile``: (width, height) of a picture [pixels]."""
    import cv2
    import numpy as np

    from .._files import atomic_path

    width, height = tile
    label = 34
    columns = max(1, min(columns, len(entries)))
    rows = max(1, -(-len(entries) // columns))
    sheet = np.full((rows * (height + label), columns * width, 3), 32, dtype=np.uint8)
    for index, entry in enumerate(entries):
        top, left = (index // columns) * (height + label), (index % columns) * width
        cell = sheet[top : top + height + label, left : left + width]
        picture = _picture(entry)
        if picture is not None:
            scale = min(width / picture.shape[1], height / picture.shape[0])
            size = (max(1, round(picture.shape[1] * scale)), max(1, round(picture.shape[0] * scale)))
            picture = cv2.resize(picture, size, interpolation=cv2.INTER_AREA)
            y, x = (height - size[1]) // 2, (width - size[0]) // 2
            cell[y : y + size[1], x : x + size[0]] = picture
        elif entry["status"] == "failed":
            _wrapped(cell, str(entry.get("error") or "failed"), width)
        else:
            _wrapped(cell, "no picture", width)
        status = entry["status"].upper() if entry["status"] == "failed" else entry["status"]
        cv2.putText(
            cell, entry["id"][:26], (6, height + 14), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (235, 235, 235), 1, cv2.LINE_AA
        )
        cv2.putText(
            cell, status, (6, height + 29), cv2.FONT_HERSHEY_SIMPLEX, 0.42, _COLORS[entry["status"]], 1, cv2.LINE_AA
        )
    with atomic_path(path, ".png") as temporary:
        if not cv2.imwrite(str(temporary), sheet):
            raise OSError(f"cannot write {path}")
    return path


def _picture(entry: dict):
    """The take's picture (BGR), or None."""
    import cv2

    if entry["status"] == "failed" or not entry.get("stage"):
        return None
    thumb = Path(entry["stage"]).parent / "thumb.png"
    return cv2.imread(str(thumb)) if thumb.is_file() else None


def _wrapped(cell, text: str, width: int) -> None:
    """Draw ``text`` word-wrapped into the top of ``cell``."""
    import cv2

    line, y = "", 20
    for word in text.split():
        if len(line) + len(word) + 1 > width // 8 and line:
            cv2.putText(cell, line, (6, y), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (200, 200, 255), 1, cv2.LINE_AA)
            line, y = "", y + 15
        line = f"{line} {word}".strip()
        if y > cell.shape[0] - 60:
            break
    cv2.putText(cell, line, (6, y), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (200, 200, 255), 1, cv2.LINE_AA)
