"""The expression model (SPEC §1): muscles, skin stretch and bulge, wrinkles, thickness."""

from .evaluator import ExpressionEvaluator, ExpressionStages
from .jaw import JAW_CONTROL_NAMES, Jaw, jaw_points
from .lids import LidMuscle
from .model import ExpressionModel
from .muscles import LinearMuscle, Muscle, MuscleLobe, SphincterMuscle, muscle_weights
from .seal import LipSeal
from .thickness import ThicknessMap, validate_thickness
from .wrinkles import CylindricalProjection, PlanarProjection, Projection, Wrinkle, bezier_distances, project_points

__all__ = [
    "ExpressionModel",
    "ExpressionEvaluator",
    "ExpressionStages",
    "LinearMuscle",
    "MuscleLobe",
    "SphincterMuscle",
    "LidMuscle",
    "LipSeal",
    "Muscle",
    "muscle_weights",
    "Jaw",
    "JAW_CONTROL_NAMES",
    "jaw_points",
    "Wrinkle",
    "PlanarProjection",
    "CylindricalProjection",
    "Projection",
    "bezier_distances",
    "project_points",
    "ThicknessMap",
    "validate_thickness",
]
