"""warpface: muscle-driven facial expressions with geometric wrinkles and viscoelastic skin, on NVIDIA Warp.

The expression model (Bando et al.) is importable from here; the tissue FEM lives in
:mod:`warpface.fem`, USD I/O in :mod:`warpface.usd`, tracking in :mod:`warpface.tracking`.
"""

import os as _os
import sys as _sys
import tempfile as _tempfile


def _configure_warp_quietly() -> None:
    """Initialise Warp without its banner, per-module load lines or the native "could not find the CUDA
    driver" warning on CPU-only machines. Warp then logs warnings and errors only, unless the caller
    already chose a log level. Other native messages written during initialisation are passed on."""
    import warp

    info = getattr(warp, "LOG_INFO", 20)
    if getattr(warp.config, "log_level", info) == info:
        warp.config.log_level = getattr(warp, "LOG_WARNING", 30)
    warp.config.quiet = True  # Warp < 1.11 reads this flag instead of the log level
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


_configure_warp_quietly()

# First, before anything can touch Usd.SchemaRegistry: register the codeless USD schema plugin
# (skipped when usd-core is not installed; see warpface.usd.schema).
from .usd.schema import register_at_import

register_at_import()
del register_at_import

from .errors import RigError  # noqa: E402
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

__version__ = "0.1.0"

__all__ = [
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
