"""Opening stages and writing layers safely (temporary file + rename, never half-written)."""

from __future__ import annotations

import os
from pathlib import Path

from pxr import Sdf, Usd

from .._files import atomic_path

__all__ = ["open_stage", "writable_path", "export_layer_atomically", "LAYER_SUFFIXES"]

LAYER_SUFFIXES = (".usda", ".usdc", ".usd")
"""File extensions warpface writes layers to."""


def open_stage(stage_or_path) -> Usd.Stage:
    """``stage_or_path`` itself when it is a ``Usd.Stage``, else the stage opened from that file.

    Raises:
        ValueError: the file does not exist or is not a USD layer.
    """
    if isinstance(stage_or_path, Usd.Stage):
        return stage_or_path
    if not isinstance(stage_or_path, (str, os.PathLike)):
        raise ValueError(f"expected a Usd.Stage or a path to a USD file, got {type(stage_or_path).__name__}")
    path = Path(stage_or_path)
    if not path.is_file():
        raise ValueError(f"USD file not found: {path}")
    try:
        stage = Usd.Stage.Open(str(path))
    except Exception as exc:  # pxr raises Tf.ErrorException with the parser's message
        raise ValueError(f"{path}: cannot open as a USD stage ({str(exc).strip()})") from None
    if stage is None:
        raise ValueError(f"{path}: cannot open as a USD stage")
    return stage


def writable_path(path, suffixes: tuple[str, ...] = LAYER_SUFFIXES) -> Path:
    """``path`` as an absolute Path after checking it can be written, before any work is done.

    Raises:
        ValueError: wrong extension, missing or unwritable folder, or the path is a folder.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"output path: expected a str or path, got {type(path).__name__}")
    path = Path(path).absolute()
    if path.suffix not in suffixes:
        raise ValueError(f"{path}: output must end in one of {', '.join(suffixes)}")
    folder = path.parent
    if not folder.is_dir():
        raise ValueError(f"cannot write {path}: folder {folder} does not exist")
    if path.is_dir():
        raise ValueError(f"cannot write {path}: it is a folder")
    if not os.access(folder, os.W_OK | os.X_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise ValueError(f"cannot write {path}: permission denied")
    return path


def export_layer_atomically(layer: Sdf.Layer, path: Path) -> None:
    """Write ``layer``'s content to ``path`` through a temporary file in the same folder and a rename.

    A crash or Ctrl-C before the rename leaves the previous file untouched; the rename itself is
    atomic on POSIX and Windows. A layer already open from ``path`` (``layer`` itself included) is
    reloaded, so stages holding it see the new content and it is no longer dirty.
    """
    path = Path(path)
    with atomic_path(path, path.suffix) as temporary:
        if not layer.Export(str(temporary)):
            raise OSError(f"cannot write {temporary}")
    opened = Sdf.Layer.Find(str(path))
    if opened is not None:
        opened.Reload(force=True)
