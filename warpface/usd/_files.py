"""Opening stages and writing layers safely (temporary file + rename, never half-written)."""

from __future__ import annotations

import os
import re
from pathlib import Path

from pxr import Sdf, Usd

from .._files import atomic_path
from .._validate import as_path

__all__ = [
    "open_stage",
    "open_layer",
    "writable_path",
    "export_layer_atomically",
    "usd_error_message",
    "without_usd_warnings",
    "LAYER_SUFFIXES",
    "checked_prim_path",
]

LAYER_SUFFIXES = (".usda", ".usdc", ".usd")
"""File extensions warpface writes layers to."""


_PXR_NAMESPACE = re.compile(r"pxrInternal_v[0-9_]+?__pxrReserved__::")
_PXR_DIAGNOSTIC = re.compile(
    r"\s*(?:Error|Warning|Coding Error|Fatal Error) in '[^']*' at line \d+ in file [^\n]*? : '"
)


_WRITE_FAILURES = (
    ("No space left", "the disk is full (No space left on device)"),
    ("File too large", "the disk is full or the file size limit is reached (File too large)"),
    ("Disk quota exceeded", "the disk quota is exceeded"),
)
"""pxr write errors whose first symptom says it all: (text in pxr's message, what to print instead)."""


def usd_error_message(error: BaseException) -> str:
    """One line from a pxr ``Tf.ErrorException`` (or any exception): the diagnostics' own messages
    joined with "; ", without C++ function names, source files and line numbers."""
    messages = []
    for piece in _PXR_DIAGNOSTIC.split(str(error)):
        piece = piece.strip()
        if piece.endswith("'"):
            piece = piece[:-1]
        piece = " ".join(_PXR_NAMESPACE.sub("", piece).split())
        if piece:
            messages.append(piece)
    joined = "; ".join(dict.fromkeys(messages)) or type(error).__name__
    for symptom, meaning in _WRITE_FAILURES:
        if symptom in joined:  # a failed write: pxr's follow-up messages ("crate file corrupt ...") are noise
            return meaning
    return joined


def checked_prim_path(value, name: str) -> Sdf.Path:
    """``value`` (a ``str`` or ``Sdf.Path``) as an absolute prim path, checked before pxr sees it (pxr raises
    Boost.Python errors for other types and prints warnings for malformed strings).

    Raises:
        TypeError: not a string or ``Sdf.Path``. ValueError: not an absolute prim path (the root ``/``
            included). Both name ``name``.
    """
    if not isinstance(value, (str, Sdf.Path)):
        raise TypeError(f"{name}: expected an absolute prim path such as '/Face', got {type(value).__name__}")
    text = str(value)
    valid = Sdf.Path.IsValidPathString(text)  # (False, reason) when invalid
    path = Sdf.Path(text) if (valid[0] if isinstance(valid, tuple) else valid) else None
    if path is None or not path.IsAbsolutePath() or not path.IsPrimPath() or path == Sdf.Path.absoluteRootPath:
        raise ValueError(f"{name}: {text[:60]!r} is not an absolute prim path such as '/Face'")
    return path


def open_layer(path, *, referenced_by: str | None = None) -> Sdf.Layer | None:
    """The USD layer in file ``path`` (already open or read now), with its sublayers checked recursively.

    A sublayer file that does not exist is skipped (``None``), as USD composition does — a deleted
    cache is recreated by the next bake, and ``validate`` reports it; one that exists but cannot be
    read is an error.

    Raises:
        ValueError: the file is missing, or it or a sublayer is not a USD layer or is corrupt — named
            in the message.
    """
    path = as_path(path, "path" if referenced_by is None else f"sublayer of {referenced_by}")
    label = f"{path}" if referenced_by is None else f"sublayer {path} of {referenced_by}"
    if not Path(path).is_file():
        if referenced_by is not None and not Path(path).exists():
            return None
        raise ValueError(f"{label}: file not found")
    try:
        layer = Sdf.Layer.FindOrOpen(str(path))
    except Exception as exc:  # pxr raises Tf.ErrorException with the parser's message
        raise ValueError(f"{label}: cannot open as a USD layer ({usd_error_message(exc)})") from None
    if layer is None:
        raise ValueError(f"{label}: cannot open as a USD layer")
    for entry in layer.subLayerPaths:
        resolved = Sdf.ComputeAssetPathRelativeToLayer(layer, entry) or entry
        if Path(resolved) == Path(layer.realPath):
            raise ValueError(f"{path}: lists itself as a sublayer")
        open_layer(resolved, referenced_by=str(path))
    return layer


def open_stage(stage_or_path) -> Usd.Stage:
    """``stage_or_path`` itself when it is a ``Usd.Stage``, else the stage opened from that file.

    The root layer and every sublayer are read first, so a missing, truncated or foreign sublayer
    is an error naming that file (USD itself would only warn and skip it); a sublayer file that does
    not exist is skipped quietly, as USD does.

    Raises:
        TypeError: neither a stage nor a path. ValueError: the file or a sublayer does not exist or is not
            a readable USD layer.
    """
    if isinstance(stage_or_path, Usd.Stage):
        return stage_or_path
    if not isinstance(stage_or_path, (str, os.PathLike)):
        raise TypeError(
            f"stage_or_path: expected a Usd.Stage or a path to a USD file, got {type(stage_or_path).__name__}"
        )
    path = as_path(stage_or_path, "path")
    if not path.is_file():
        raise ValueError(f"USD file not found: {path}")
    root = open_layer(path)
    try:
        # a missing referenced asset is reported by warpface's own check (asset_io.check_asset), in one line
        stage = without_usd_warnings(
            lambda: Usd.Stage.Open(root), dropping=("Could not load sublayer", "Could not open asset")
        )
    except Exception as exc:
        raise ValueError(f"{path}: cannot open as a USD stage ({usd_error_message(exc)})") from None
    if stage is None:
        raise ValueError(f"{path}: cannot open as a USD stage")
    return stage


def without_usd_warnings(call, dropping: tuple[str, ...] = ("Could not load sublayer",)):
    """``call()`` with the lines USD's C++ diagnostics write to fd 2 that contain one of ``dropping``
    removed; every other line written meanwhile is passed on."""
    import sys
    import tempfile

    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):
        return call()
    with tempfile.TemporaryFile() as captured:
        os.dup2(captured.fileno(), 2)
        try:
            result = call()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        captured.seek(0)
        kept = [
            line
            for line in captured.read().decode(errors="replace").splitlines()
            if not any(text in line for text in dropping)
        ]
    if kept:
        print("\n".join(kept), file=sys.stderr)
    return result


def writable_path(path, suffixes: tuple[str, ...] = LAYER_SUFFIXES) -> Path:
    """``path`` as an absolute Path after checking it can be written, before any work is done.

    Raises:
        TypeError: not a path. ValueError: wrong extension, missing or unwritable folder, or the path is a
            folder.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"output path: expected a str or path, got {type(path).__name__}")
    path = as_path(path, "path").absolute()
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
    path = as_path(path, "path")
    with atomic_path(path, path.suffix, create=False) as temporary:
        try:
            exported = layer.Export(str(temporary))
        except Exception as exc:  # Tf.ErrorException: full disk, permissions, ...
            raise OSError(f"cannot write {path}: {usd_error_message(exc)}") from None
        if not exported:
            raise OSError(f"cannot write {path}")
    opened = Sdf.Layer.Find(str(path))
    if opened is not None:
        opened.Reload(force=True)
