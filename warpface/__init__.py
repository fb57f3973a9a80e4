"""warpface: muscle-driven facial expressions with geometric wrinkles and viscoelastic skin, on NVIDIA Warp.

The expression model (Bando et al.) is importable from here; the tissue FEM lives in
:mod:`warpface.fem`, USD I/O in :mod:`warpface.usd`, tracking in :mod:`warpface.tracking`.
"""

# First, before anything can touch Usd.SchemaRegistry: register the codeless USD schema plugin
# (skipped when usd-core is not installed; see warpface.usd.schema).
from .usd.schema import _register_at_import

_register_at_import()

from .errors import RigError  # noqa: E402
from .expression import (
    CylindricalProjection,
    ExpressionModel,
    ExpressionStages,
    LinearMuscle,
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
    "SphincterMuscle",
    "Wrinkle",
    "PlanarProjection",
    "CylindricalProjection",
    "ThicknessMap",
]
