"""Rig-time fields kept on disk between processes, as Warp keeps its compiled kernels.

A rig's rig-time fields (:mod:`~warpface.expression.rig_fields`) take ~20 s on a whole head and ~4 s on the built-in
face, and every command that evaluates a rig (``animate``, ``bake``, ``track``, ``fit``, ``batch``) computes them. A
process that finds the fields of the same data, computed by the same code, in the cache folder reads them instead.

* **Where:** the folder ``$WARPFACE_CACHE`` (``off`` turns the cache off), else ``$XDG_CACHE_HOME/warpface``, else
  ``~/.cache/warpface``; the fields go to its ``rig_fields/`` as one ``.npz`` per rig, the newest :data:`KEPT_FILES`
  kept.
* **Key:** the fields' own digest (the rig's data and the device's kind) together with a digest of warpface's source
  files and the warpface, NumPy and Warp versions: fields computed by other code are never read.
* **Failures cost nothing but the time:** a folder that cannot be written, a full disk or a file that cannot be read
  back whole (another process killed while writing one only leaves a temporary file, which is not read) and the
  fields are computed as without a cache. A file is written under a temporary name and renamed when complete.
"""

from __future__ import annotations

import functools
import hashlib
import os
import zipfile
from pathlib import Path

import numpy as np

from .._files import atomic_path

__all__ = ["CACHE_ENV", "KEPT_FILES", "ARRAY_NAMES", "cache_folder", "read_fields", "write_fields", "code_digest"]

CACHE_ENV = "WARPFACE_CACHE"
"""The environment variable naming the cache folder (``off``: no cache)."""
KEPT_FILES = 8
"""How many rigs' fields the folder keeps (a whole head's are ~25 MB, the built-in face's ~5 MB): the oldest others are
removed."""
_OFF = ("off", "0", "no", "false", "none")
ARRAY_NAMES = ("offsets", "muscle", "weight", "shape_offsets", "wrinkle", "shape", "bulging", "faded")
"""The arrays of one rig's fields in a file: the muscle weights' CSR (``offsets``, ``muscle``, ``weight``), the wrinkle
profiles' (``shape_offsets``, ``wrinkle``, ``shape``), the guarded bulge ``h`` and profiles (``bulging``, ``faded``)."""


def cache_folder() -> Path | None:
    """The folder the fields are kept in, or None when the cache is off (:data:`CACHE_ENV`)."""
    value = os.environ.get(CACHE_ENV)
    if value is not None:
        return None if value.strip().lower() in _OFF or not value.strip() else Path(value).expanduser() / "rig_fields"
    base = os.environ.get("XDG_CACHE_HOME", "").strip()
    try:
        return (Path(base) if base else Path.home() / ".cache") / "warpface" / "rig_fields"
    except (RuntimeError, KeyError):  # no home folder to be found (a bare container's user): no cache
        return None


@functools.cache
def code_digest() -> str:
    """SHA-256 of the warpface package's Python sources (paths and bytes) and the warpface, NumPy and Warp versions."""
    import warp

    from .. import __version__

    digest = hashlib.sha256(f"warpface {__version__} numpy {np.__version__} warp {warp.config.version}".encode())
    package = Path(__file__).resolve().parent.parent
    for path in sorted(package.rglob("*.py")):
        digest.update(path.relative_to(package).as_posix().encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _path(folder: Path, key: str) -> Path:
    return folder / f"{hashlib.sha256((key + code_digest()).encode()).hexdigest()[:32]}.npz"


def read_fields(key: str, counts: tuple[int, int, int]) -> dict[str, np.ndarray] | None:
    """The arrays kept for the fields' digest ``key`` (:data:`ARRAY_NAMES`), or None: no cache, no such file, or one
    that is not whole and consistent with ``counts`` (vertices, muscles, wrinkles). A file read is marked as used."""
    folder = cache_folder()
    if folder is None:
        return None
    path = _path(folder, key)
    try:
        with np.load(path, allow_pickle=False) as stored:
            arrays = {name: stored[name] for name in ARRAY_NAMES}
        os.utime(path)  # the newest files are kept
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None
    return arrays if _consistent(arrays, *counts) else None


def _consistent(arrays: dict[str, np.ndarray], vertices: int, muscles: int, wrinkles: int) -> bool:
    """Whether the arrays have the shapes, types and index ranges of one rig's fields."""

    def csr(offsets, index, count) -> bool:
        return (
            offsets.shape == (vertices + 1,)
            and offsets.dtype.kind == index.dtype.kind == "i"
            and offsets[0] == 0
            and bool(np.all(np.diff(offsets) >= 0))
            and index.shape == (int(offsets[-1]),)
            and (len(index) == 0 or (index.min() >= 0 and index.max() < count))
        )

    floats = all(arrays[name].dtype == np.float64 for name in ("weight", "shape", "bulging", "faded"))
    entries = len(arrays["wrinkle"])
    return (
        floats
        and csr(arrays["offsets"], arrays["muscle"], muscles)
        and csr(arrays["shape_offsets"], arrays["wrinkle"], wrinkles)
        and arrays["weight"].shape == (len(arrays["muscle"]), 3)
        and arrays["shape"].shape == arrays["faded"].shape == (entries,)
        and arrays["bulging"].shape == (vertices,)
    )


def write_fields(key: str, arrays: dict[str, np.ndarray]) -> None:
    """Keep ``arrays`` (every name of :data:`ARRAY_NAMES`) for the fields' digest ``key``; does nothing when the
    cache is off or the folder cannot take the file."""
    folder = cache_folder()
    if folder is None:
        return
    try:
        with atomic_path(_path(folder, key), ".npz") as temporary:
            np.savez(temporary, **{name: arrays[name] for name in ARRAY_NAMES})
        _prune(folder)
    except (OSError, ValueError):  # ValueError: atomic_path's word for a folder it cannot write in
        pass


def _prune(folder: Path) -> None:
    """Remove all but the :data:`KEPT_FILES` newest kept files (another process may remove one first; the hidden
    temporary files of writes under way are not counted)."""
    kept = []
    for path in folder.glob("*.npz"):
        if not path.name.startswith("."):
            try:
                kept.append((path.stat().st_mtime, path))
            except OSError:
                continue
    for _, path in sorted(kept, reverse=True)[KEPT_FILES:]:
        path.unlink(missing_ok=True)
