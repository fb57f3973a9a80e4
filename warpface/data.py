"""Locating the third-party face data kept beside the project (never inside it).

The data lives in ``../shared/data`` relative to the repository root. Tests, examples and benchmarks
find it only through :func:`shared_data_path`, and skip or fall back when it is absent.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["shared_data_path", "ict_face_region", "ict_landmark_indices"]

_ENV_VAR = "WARPFACE_SHARED_DATA"


def shared_data_path(*parts: str) -> Path | None:
    """Path to ``shared/data`` (or a file/folder inside it), or ``None`` when it does not exist.

    The environment variable ``WARPFACE_SHARED_DATA`` overrides the default location
    ``<repository>/../shared/data``.
    """
    root = os.environ.get(_ENV_VAR)
    base = Path(root) if root else Path(__file__).resolve().parent.parent.parent / "shared" / "data"
    path = base.joinpath(*parts)
    return path if path.exists() else None


def ict_face_region(shape: str = "neutral") -> Path | None:
    """Path to an ICT-FaceKit face-region OBJ (``neutral``, ``jawOpen``, ...), or ``None`` if absent."""
    return shared_data_path("ict_facekit", "face_region_tri", f"{shape}.obj")


def ict_landmark_indices() -> "numpy.ndarray | None":  # noqa: F821 - numpy imported lazily
    """The 68 iBUG-order landmark vertex indices (0-based) of the ICT face, shape (68,), or ``None``."""
    path = shared_data_path("ict_facekit", "landmarks_multipie68.txt")
    if path is None:
        return None
    import numpy as np

    rows = [line.split() for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]
    return np.array([int(r[1]) for r in rows], dtype=np.int64)
