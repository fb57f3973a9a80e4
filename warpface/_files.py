"""Atomic file writes: a temporary file beside the target, renamed onto it only on success."""

from __future__ import annotations

import os
import stat
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path

from ._validate import as_path

__all__ = [
    "atomic_path",
    "new_file_mode",
    "process_umask",
    "read_text",
    "check_output_folder",
    "create_missing_folders",
    "remove_created_folders",
]


def new_file_mode(path: str | Path) -> int:
    """The permission bits ``open(path, "w")`` would leave: an existing file keeps its own, a new one
    gets 0o666 less the process umask."""
    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except FileNotFoundError:
        return 0o666 & ~process_umask()


_umask_lock = threading.Lock()
_umask_cache: list[int] = []


def process_umask() -> int:
    """The process's umask, read without changing it.

    Linux reports it in ``/proc/self/status``; elsewhere it can only be read by setting it, which races
    with threads creating files (bakes write from worker threads), so that is done once, under a lock,
    and the value cached.
    """
    try:
        with open("/proc/self/status", encoding="ascii", errors="replace") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    with _umask_lock:
        if not _umask_cache:
            umask = os.umask(0o077)
            os.umask(umask)
            _umask_cache.append(umask)
        return _umask_cache[0]


@contextmanager
def atomic_path(path: str | Path, suffix: str = "", *, create: bool = True):
    """Yield a temporary path beside ``path``; rename it onto ``path`` only if the block succeeds.

    A crash or exception inside the block leaves any previous ``path`` untouched and removes the
    temporary file. ``suffix`` is the temporary file's extension (writers that pick a format by
    extension — USD layers, images, videos — need the real one). The renamed file gets the
    permissions ``open()`` would give it (:func:`new_file_mode`), not the temporary file's 0600.

    With ``create=False`` the temporary path does not exist yet when the block starts (its unique name
    reserved, then released). That suits writers which replace an existing file through a temporary file
    and a rename of their own, as OpenUSD's layer export does: renaming over an existing (reserved) file
    makes ext4 write the new data out at once, which costs time (measured in benchmarks/README.md, Tracking).
    """
    path = as_path(path, "path")
    if path.is_dir():
        raise ValueError(f"{path}: is a folder, not a file")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        mode = new_file_mode(path)
        handle, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or ".tmp", dir=path.parent)
    except OSError as exc:
        raise ValueError(f"{path}: cannot write there ({exc.strerror or exc})") from None
    os.close(handle)
    tmp_path = Path(tmp)
    if not create:
        tmp_path.unlink()
    try:
        yield tmp_path
        os.chmod(tmp_path, mode)
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def read_text(path) -> str:
    """The text of a UTF-8 file (a byte-order mark is dropped); ValueError naming the file when it is not
    text or cannot be read."""
    try:
        return as_path(path, "path").read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text file") from None
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from None


def check_output_folder(folder, option: str, path) -> None:
    """ValueError (naming ``option`` and ``path``) unless ``folder`` exists as a writable folder or can be
    created: its nearest existing ancestor is a writable folder. Nothing is created here."""
    folder = Path(folder).absolute()
    existing = folder
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"{option} {path}: {existing} is a file, not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"{option} {path}: cannot write in {existing}")


def create_missing_folders(folder) -> list[Path]:
    """Create ``folder`` and its missing parents; returns the ones created, outermost first."""
    folder = Path(folder).absolute()
    missing = []
    while not folder.exists():
        missing.append(folder)
        folder = folder.parent
    for path in reversed(missing):
        path.mkdir()
    return list(reversed(missing))


def remove_created_folders(created: list[Path]) -> None:
    """Remove the folders :func:`create_missing_folders` made, innermost first, as long as they are empty."""
    for path in reversed(created):
        try:
            path.rmdir()
        except OSError:
            return
