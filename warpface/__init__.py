"""warpface: muscle-driven facial expressions with geometric wrinkles and viscoelastic skin, on NVIDIA Warp.

The expression model (Bando et al.) is importable from here; the tissue FEM lives in
:mod:`warpface.fem`, USD I/O in :mod:`warpface.usd`, tracking in :mod:`warpface.tracking`.
"""

from .errors import RigError
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
