"""Shared ``@wp.func`` math: closest point on a segment and on a triangle, smoothstep, padded float32 bounds.

Written once here and reused by every kernel that needs them (tracking correspondence and transfer
weights in float32, the FEM embedding in float64). The closest-point functions are Warp generic
functions: their arguments are any ``vec3`` of one float type (``wp.vec3`` or ``wp.vec3d``) and they
compute and return in that type, so a float64 caller keeps float64 precision.
"""

from __future__ import annotations

import warp as wp

__all__ = ["closest_point_on_segment", "closest_point_on_triangle", "padded_corner", "smoothstep", "vec3_any"]

vec3_any = wp.types.vector(length=3, dtype=wp.Float)
"""Annotation for a 3-vector of any float type (``wp.vec3h``, ``wp.vec3``, ``wp.vec3d``)."""


@wp.func
def closest_point_on_segment(p: vec3_any, a: vec3_any, b: vec3_any):
    """Parameter ``t`` in [0, 1] (the vectors' scalar type) of the point ``a + t (b − a)`` of segment ab
    closest to ``p``.

    A zero-length segment returns ``t = 0``.
    """
    zero = p.dtype(0.0)
    ab = b - a
    length_sq = wp.dot(ab, ab)
    if length_sq <= zero:
        return zero
    return wp.clamp(wp.dot(p - a, ab) / length_sq, zero, p.dtype(1.0))


@wp.func
def _closest_on_edges(p: vec3_any, a: vec3_any, b: vec3_any, c: vec3_any):
    """Barycentric coordinates of the closest point of the three edges of abc (degenerate fallback)."""
    zero = p.dtype(0.0)
    one = p.dtype(1.0)
    t_ab = closest_point_on_segment(p, a, b)
    t_ac = closest_point_on_segment(p, a, c)
    t_bc = closest_point_on_segment(p, b, c)
    best = type(p)(one - t_ab, t_ab, zero)
    best_d = wp.length_sq(p - (a + t_ab * (b - a)))
    d_ac = wp.length_sq(p - (a + t_ac * (c - a)))
    if d_ac < best_d:
        best = type(p)(one - t_ac, zero, t_ac)
        best_d = d_ac
    d_bc = wp.length_sq(p - (b + t_bc * (c - b)))
    if d_bc < best_d:
        best = type(p)(zero, one - t_bc, t_bc)
    return best


@wp.func
def closest_point_on_triangle(p: vec3_any, a: vec3_any, b: vec3_any, c: vec3_any):
    """Barycentric coordinates ``(w_a, w_b, w_c)`` of the point of triangle abc closest to ``p``.

    The closest point is ``w_a a + w_b b + w_c c``; the weights are ≥ 0 and sum to 1, in the scalar
    type of the arguments (float32 for ``wp.vec3``, float64 for ``wp.vec3d``).

    ``p`` is classified into one of the triangle's seven Voronoi feature regions — three vertex
    regions, three edge regions, the face region — using signs of dot products with the edges
    (Kato eq. 4.1–4.14 do the same with barycentric signs of the plane projection), and the
    projection is clamped to that feature. Each test only needs dot products, so no plane
    projection is formed explicitly. A region of a zero-length edge is empty, and a triangle of
    (near-)zero area falls back to the best of its three edges, so degenerate input never yields NaN.
    """
    zero = p.dtype(0.0)
    one = p.dtype(1.0)
    ab = b - a
    ac = c - a
    ap = p - a
    d1 = wp.dot(ab, ap)
    d2 = wp.dot(ac, ap)
    if d1 <= zero and d2 <= zero:
        return type(p)(one, zero, zero)  # vertex region A

    bp = p - b
    d3 = wp.dot(ab, bp)
    d4 = wp.dot(ac, bp)
    if d3 >= zero and d4 <= d3:
        return type(p)(zero, one, zero)  # vertex region B

    # vc, vb, va are the (unnormalised) signed areas opposite C, B, A of p's plane projection.
    vc = d1 * d4 - d3 * d2
    ab_sq = d1 - d3  # = |ab|², ≥ 0
    if vc <= zero and d1 >= zero and d3 <= zero and ab_sq > zero:
        t = d1 / ab_sq
        return type(p)(one - t, t, zero)  # edge region AB

    cp = p - c
    d5 = wp.dot(ab, cp)
    d6 = wp.dot(ac, cp)
    if d6 >= zero and d5 <= d6:
        return type(p)(zero, zero, one)  # vertex region C

    vb = d5 * d2 - d1 * d6
    ac_sq = d2 - d6  # = |ac|²
    if vb <= zero and d2 >= zero and d6 <= zero and ac_sq > zero:
        t = d2 / ac_sq
        return type(p)(one - t, zero, t)  # edge region AC

    va = d3 * d6 - d5 * d4
    bc_sq = (d4 - d3) + (d5 - d6)  # = |bc|²
    if va <= zero and (d4 - d3) >= zero and (d5 - d6) >= zero and bc_sq > zero:
        t = (d4 - d3) / bc_sq
        return type(p)(zero, one - t, t)  # edge region BC

    area_sq = va + vb + vc  # = |ab × ac|²
    if area_sq <= p.dtype(1.0e-12) * wp.dot(ab, ab) * wp.dot(ac, ac) or area_sq <= zero:
        return _closest_on_edges(p, a, b, c)
    v = vb / area_sq
    w = vc / area_sq
    return type(p)(one - v - w, v, w)  # face region


@wp.func
def smoothstep(edge0: float, edge1: float, x: float) -> float:
    """Cubic Hermite step: 0 for ``x ≤ edge0``, 1 for ``x ≥ edge1``, C¹ in between (``edge0 < edge1``)."""
    t = wp.clamp((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


@wp.func
def padded_corner(corner: wp.vec3d, pad: float) -> wp.vec3:
    """A float64 bounding-box corner in float32 (a BVH's precision), moved by ``pad`` along every axis:
    ``pad < 0`` for the lower corner, ``pad > 0`` for the upper one."""
    return wp.vec3(float(corner[0]) + pad, float(corner[1]) + pad, float(corner[2]) + pad)
