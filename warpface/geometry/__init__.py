"""Shared geometric ``@wp.func`` math: closest point on a segment and on a triangle, smoothstep.

Written once here and reused by every kernel that needs them (tracking correspondence, transfer
weights). Functions work in float32 on CPU and CUDA alike.
"""

from __future__ import annotations

import warp as wp

__all__ = ["closest_point_on_segment", "closest_point_on_triangle", "smoothstep"]


@wp.func
def closest_point_on_segment(p: wp.vec3, a: wp.vec3, b: wp.vec3) -> float:
    """Parameter ``t`` in [0, 1] of the point ``a + t (b − a)`` of segment ab closest to ``p``.

    A zero-length segment returns ``t = 0``.
    """
    ab = b - a
    length_sq = wp.dot(ab, ab)
    if length_sq <= 0.0:
        return 0.0
    return wp.clamp(wp.dot(p - a, ab) / length_sq, 0.0, 1.0)


@wp.func
def _closest_on_edges(p: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3) -> wp.vec3:
    """Barycentric coordinates of the closest point of the three edges of abc (degenerate fallback)."""
    t_ab = closest_point_on_segment(p, a, b)
    t_ac = closest_point_on_segment(p, a, c)
    t_bc = closest_point_on_segment(p, b, c)
    best = wp.vec3(1.0 - t_ab, t_ab, 0.0)
    best_d = wp.length_sq(p - (a + t_ab * (b - a)))
    d_ac = wp.length_sq(p - (a + t_ac * (c - a)))
    if d_ac < best_d:
        best = wp.vec3(1.0 - t_ac, 0.0, t_ac)
        best_d = d_ac
    d_bc = wp.length_sq(p - (b + t_bc * (c - b)))
    if d_bc < best_d:
        best = wp.vec3(0.0, 1.0 - t_bc, t_bc)
    return best


@wp.func
def closest_point_on_triangle(p: wp.vec3, a: wp.vec3, b: wp.vec3, c: wp.vec3) -> wp.vec3:
    """Barycentric coordinates ``(w_a, w_b, w_c)`` of the point of triangle abc closest to ``p``.

    The closest point is ``w_a a + w_b b + w_c c``; the weights are ≥ 0 and sum to 1.

    ``p`` is classified into one of the triangle's seven Voronoi feature regions — three vertex
    regions, three edge regions, the face region — using signs of dot products with the edges
    (Kato eq. 4.1–4.14 do the same with barycentric signs of the plane projection), and the
    projection is clamped to that feature. Each test only needs dot products, so no plane
    projection is formed explicitly. A region of a zero-length edge is empty, and a triangle of
    (near-)zero area falls back to the best of its three edges, so degenerate input never yields NaN.
    """
    ab = b - a
    ac = c - a
    ap = p - a
    d1 = wp.dot(ab, ap)
    d2 = wp.dot(ac, ap)
    if d1 <= 0.0 and d2 <= 0.0:
        return wp.vec3(1.0, 0.0, 0.0)  # vertex region A

    bp = p - b
    d3 = wp.dot(ab, bp)
    d4 = wp.dot(ac, bp)
    if d3 >= 0.0 and d4 <= d3:
        return wp.vec3(0.0, 1.0, 0.0)  # vertex region B

    # vc, vb, va are the (unnormalised) signed areas opposite C, B, A of p's plane projection.
    vc = d1 * d4 - d3 * d2
    ab_sq = d1 - d3  # = |ab|², ≥ 0
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0 and ab_sq > 0.0:
        t = d1 / ab_sq
        return wp.vec3(1.0 - t, t, 0.0)  # edge region AB

    cp = p - c
    d5 = wp.dot(ab, cp)
    d6 = wp.dot(ac, cp)
    if d6 >= 0.0 and d5 <= d6:
        return wp.vec3(0.0, 0.0, 1.0)  # vertex region C

    vb = d5 * d2 - d1 * d6
    ac_sq = d2 - d6  # = |ac|²
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0 and ac_sq > 0.0:
        t = d2 / ac_sq
        return wp.vec3(1.0 - t, 0.0, t)  # edge region AC

    va = d3 * d6 - d5 * d4
    bc_sq = (d4 - d3) + (d5 - d6)  # = |bc|²
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0 and bc_sq > 0.0:
        t = (d4 - d3) / bc_sq
        return wp.vec3(0.0, 1.0 - t, t)  # edge region BC

    area_sq = va + vb + vc  # = |ab × ac|²
    if area_sq <= 1.0e-12 * wp.dot(ab, ab) * wp.dot(ac, ac) or area_sq <= 0.0:
        return _closest_on_edges(p, a, b, c)
    v = vb / area_sq
    w = vc / area_sq
    return wp.vec3(1.0 - v - w, v, w)  # face region


@wp.func
def smoothstep(edge0: float, edge1: float, x: float) -> float:
    """Cubic Hermite step: 0 for ``x ≤ edge0``, 1 for ``x ≥ edge1``, C¹ in between (``edge0 < edge1``)."""
    t = wp.clamp((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)
