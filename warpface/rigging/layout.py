"""Is a set of 68 landmarks in iBUG order? The check itself lives in :mod:`warpface.landmarks` (the
geometry layer), so that ``default_rig`` (content) and ``validate`` (io) run the very same one; the
rigging package re-exports it under its historical names."""

from __future__ import annotations

from ..landmarks import LAYOUT_GROUPS as GROUPS
from ..landmarks import check_layout, layout_frame

__all__ = ["GROUPS", "check_layout", "layout_frame"]
