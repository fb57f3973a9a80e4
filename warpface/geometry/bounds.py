"""A BVH over the float32 bounding boxes of float64 elements (triangles, tets), padded for rounding.

Shared by the FEM embedding (tets holding a point) and the surface self-intersection check (triangles
overlapping a triangle): both query a ``wp.Bvh`` whose boxes must never exclude an element that touches.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .funcs import padded_corner

__all__ = ["padded_element_bvh"]


@wp.kernel
def _padded_bounds(
    points: wp.array(dtype=wp.vec3d),
    elements: wp.array2d(dtype=wp.int32),
    pad: float,
    lowers: wp.array(dtype=wp.vec3),
    uppers: wp.array(dtype=wp.vec3),
):
    """Per element: the float32 box of its corners, grown by ``pad`` on every side."""
    e = wp.tid()
    lo = points[elements[e, 0]]
    hi = lo
    for k in range(1, elements.shape[1]):
        p = points[elements[e, k]]
        lo = wp.min(lo, p)
        hi = wp.max(hi, p)
    lowers[e] = padded_corner(lo, -pad)
    uppers[e] = padded_corner(hi, pad)


def padded_element_bvh(points: wp.array, elements: np.ndarray, pad: float) -> tuple[wp.Bvh, wp.array, wp.array]:
    """``(bvh, lowers, uppers)``: a BVH over the elements' boxes (float32, each grown by ``pad``) on the
    device of ``points`` (vec3d, float64 positions); ``elements`` are corner indices, shape (E, k).
    The boxes are returned too: a query for the elements near element ``e`` uses its own box."""
    device = points.device
    elements = wp.array(np.ascontiguousarray(elements, dtype=np.int32), dtype=wp.int32, device=device)
    lowers = wp.empty(elements.shape[0], dtype=wp.vec3, device=device)
    uppers = wp.empty(elements.shape[0], dtype=wp.vec3, device=device)
    wp.launch(
        _padded_bounds, dim=elements.shape[0], inputs=[points, elements, pad], outputs=[lowers, uppers], device=device
    )
    return wp.Bvh(lowers, uppers), lowers, uppers
