"""warpface: muscle-driven facial expressions with geometric wrinkles and viscoelastic skin, on NVIDIA Warp.

The expression model (Bando et al.) is importable from here; the tissue FEM lives in
:mod:`warpface.fem`, USD I/O in :mod:`warpface.usd`, tracking in :mod:`warpface.tracking`.

Importing warpface leaves Warp's runtime, the process's file descriptors and its umask alone: Warp
initialises itself on first use with its own defaults, or when :func:`init_runtime` is called (the
``warpface`` command line calls it to keep Warp's start-up lines out of its output).
"""

import os as _os
import sys as _sys
import tempfile as _tempfile
import threading as _threading

from .errors import RigError
from .expression import (
    CylindricalProjection,
    ExpressionModel,
    ExpressionStages,
    LinearMuscle,
    MuscleLobe,
    PlanarProjection,
    SphincterMuscle,
    ThicknessMap,
    Wrinkle,
)
from .mesh import FaceMesh, load_obj
from .rig import FaceRig
from .usd.schema import register_at_import

# Before anything can touch Usd.SchemaRegistry: register the codeless USD schema plugin (skipped, without
# importing pxr, when usd-core is not installed; see warpface.usd.schema).
register_at_import()
del register_at_import


_runtime_lock = _threading.Lock()
_runtime_ready = False


def init_runtime(*, quiet: bool = True) -> None:
    """Initialise Warp now (once per process; later calls do nothing).

    With ``quiet`` Warp starts without its banner, its per-module load lines and the native "could not
    find the CUDA driver" warning of CPU-only machines, and then logs warnings and errors only unless
    the caller already chose a log level; other native messages written meanwhile are passed on to
    stderr. Without ``quiet`` this is ``warp.init()``.
    """
    global _runtime_ready
    if not isinstance(quiet, bool):
        raise TypeError(f"quiet: expected a bool, got {type(quiet).__name__}")
    with _runtime_lock:
        if _runtime_ready:
            return
        import warp

        if quiet:
            info = getattr(warp, "LOG_INFO", 20)
            if getattr(warp.config, "log_level", info) == info:
                warp.config.log_level = getattr(warp, "LOG_WARNING", 30)
            warp.config.quiet = True  # Warp < 1.11 reads this flag instead of the log level
            _init_filtering_stderr(warp)
        else:
            warp.init()
        _runtime_ready = True


def _init_filtering_stderr(warp) -> None:
    """``warp.init()`` with the CUDA-driver warning removed from what native code writes to fd 2."""
    try:
        _sys.stderr.flush()
        saved = _os.dup(2)
    except (OSError, ValueError):  # no real stderr (embedded interpreters): nothing to filter
        warp.init()
        return
    with _tempfile.TemporaryFile(mode="w+b") as captured:
        _os.dup2(captured.fileno(), 2)
        try:
            warp.init()
        finally:
            _os.dup2(saved, 2)
            _os.close(saved)
        captured.seek(0)
        lines = captured.read().decode(errors="replace").splitlines()
    kept = [line for line in lines if "NVIDIA CUDA driver" not in line]
    if kept:
        print("\n".join(kept), file=_sys.stderr)


__version__ = "0.1.0"

__all__ = [
    "init_runtime",
    "FaceMesh",
    "load_obj",
    "FaceRig",
    "RigError",
    "ExpressionModel",
    "ExpressionStages",
    "LinearMuscle",
    "MuscleLobe",
    "SphincterMuscle",
    "Wrinkle",
    "PlanarProjection",
    "CylindricalProjection",
    "ThicknessMap",
]
