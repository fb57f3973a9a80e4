"""Solve a rig's controls from captured motion (SPEC §6.1): landmarks, surface points, dense shapes.

    >>> from warpface.assets import default_rig
    >>> from warpface.solve import fit
    >>> rig = default_rig()
    >>> shape = rig.model().evaluate({"zygomaticus_major_L": 0.01})
    >>> result = fit(rig, shape)            # dense target with the rig's topology
    >>> round(result.controls["zygomaticus_major_L"], 3)
    0.01

:func:`fit` solves one target; :class:`Solver` keeps the target locations fixed and solves frame
after frame (warm-started, optionally smoothed in time) or many frames at once.
"""

from .local_kernels import LocalExpression
from .local_model import RigOperators
from .solver import SPHINCTER_MAX, BatchFit, Fit, SolveOptions, Solver, fit

__all__ = ["fit", "Fit", "BatchFit", "Solver", "SolveOptions", "SPHINCTER_MAX", "LocalExpression", "RigOperators"]
