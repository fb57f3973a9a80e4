"""Calibration of a rig's muscle geometry from example shapes (docs/RIG.md §13).

    >>> from warpface.calibration import calibrate, read_shapes
    >>> shapes = read_shapes("blendshapes/", rig, names="arkit")
    >>> result = calibrate(rig, shapes, holdout=["mouthSmileLeft"])
    >>> result.rig, result.message

The parameters (:mod:`warpface.assets.calibrated`) move each muscle's ends, widen or narrow its zone and
falloff, and change its skin response, the same for a muscle and its mirror twin, in the landmark frame.
"""

from .api import Calibration, calibrate
from .reach import ShapeReach, reach
from .report import write_report
from .shapes import ExampleShape, read_shapes

__all__ = ["calibrate", "Calibration", "read_shapes", "ExampleShape", "reach", "ShapeReach", "write_report"]
