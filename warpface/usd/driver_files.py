"""Reading any driver file into :class:`~warpface.drivers.Curves`: the one ``read_driver``.

The format comes from the file's first bytes and its extension (:func:`warpface.drivers.detect_format`).
The CSV and MediaPipe formats are read by :mod:`warpface.drivers` and need no usd-core; USD
``SkelAnimation`` layers (what Audio2Face exports) are read by :mod:`warpface.usd.skel_io`, which loads
``pxr`` only for them. It lives here, in the USD layer, because the drivers sit below USD I/O.
"""

from __future__ import annotations

import importlib.util

from .._validate import as_positive
from ..drivers.channels import Curves
from ..drivers.csv_formats import read_live_link, read_openface
from ..drivers.io import detect_format
from ..drivers.mediapipe_format import read_mediapipe_jsonl, read_mediapipe_textproto

__all__ = ["read_driver"]


def read_driver(path, *, fps: float | None = None) -> Curves:
    """Read a driver file in any of :data:`warpface.drivers.DRIVER_FORMATS` into :class:`Curves`.

    Args:
        path: the file: OpenFace or Live Link Face CSV, MediaPipe blendshapes as text-proto or JSON
            lines, or a USD layer with a ``SkelAnimation``.
        fps: frame rate for formats that do not store one (MediaPipe frames without timestamps;
            Live Link Face timecodes, overriding the detected rate).

    Raises:
        TypeError: ``path`` is not a path or ``fps`` not a number.
        ValueError: unreadable or malformed file, or a USD layer without usd-core installed (one line
            naming the file and the problem).
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
    if importlib.util.find_spec("pxr") is None:
        raise ValueError(f"{path}: a USD layer; reading it needs usd-core (pip install usd-core)")
    from .skel_io import read_skel_animation

    return read_skel_animation(path)
