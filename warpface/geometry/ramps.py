"""NumPy blends between two values: what a falloff, a fade or a weight band is built from."""

from __future__ import annotations

import numpy as np

__all__ = ["smooth_ramp"]


def smooth_ramp(edge0, edge1, values):
    """The cubic Hermite step of ``values`` (any shape) from 0 at ``edge0`` to 1 at ``edge1``, C¹, clamped outside
    (``edge0 > edge1`` ramps down): ``t² (3 − 2t)`` with ``t = clip((x − edge0) / (edge1 − edge0), 0, 1)``. The array
    twin of the ``@wp.func`` :func:`~warpface.geometry.funcs.smoothstep`."""
    t = np.clip((values - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)
