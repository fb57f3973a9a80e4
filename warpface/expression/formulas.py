"""The expression model's formulas (SPEC §1, §6.2), each written once as a Warp function.

Every kernel that evaluates the model calls these: the staged and tiled frame kernels in float32, the
solver's value and Jacobian kernels in float64. The functions are Warp generics: scalars are any float
type (``wp.Float``) and vectors any float 3-vector (:data:`~warpface.geometry.funcs.vec3_any`), all of
one type per call; they compute and return in that type, so float32 callers get the same bits as
before and float64 callers keep float64 precision. Constants are made in the arguments' type
(``type(x)(1.0)``): Warp does not convert between float types implicitly.

Derivative functions (``d_…``) give the forward-mode pieces the solver's Jacobian needs; each is the
derivative of the value function next to it, checked against finite differences in the tests.
"""

from __future__ import annotations

import warp as wp

from ..geometry.funcs import vec3_any

__all__ = [
    "jaw_rotation",
    "jaw_slide",
    "jaw_blend",
    "muscle_pull",
    "area_vector",
    "d_area_vector",
    "area_ratio",
    "d_area_ratio",
    "stretch_ratio",
    "d_stretch_ratio",
    "unit_or_zero",
    "d_unit_or_zero",
    "bulge_growth",
    "d_bulge_growth",
    "bulge_point",
    "wrinkle_profile",
    "contraction_rate",
    "contraction_below",
    "contraction_above",
    "contraction_factor_from_rate",
    "contraction_factor",
    "contraction_factor_and_slope",
    "wrinkle_term",
    "wrinkle_point",
]


# ---------------------------------------------------------------- SPEC §6.2: the jaw
@wp.func
def jaw_rotation(angle: wp.Float, hinge_axis: vec3_any):
    """The jaw's rotation ``R(θ, a)``: ``angle`` [rad] about the unit ``hinge_axis``."""
    return wp.quat_from_axis_angle(hinge_axis, angle)


@wp.func
def jaw_slide(protrusion: wp.Float, lateral: wp.Float, forward: vec3_any, hinge_axis: vec3_any):
    """The jaw's translation ``t``: ``protrusion`` along ``forward`` plus ``lateral`` along the hinge axis."""
    return protrusion * forward + lateral * hinge_axis


@wp.func
def jaw_blend(
    x: vec3_any, w: wp.Float, pivot: vec3_any, rotation: wp.types.quaternion(dtype=wp.Float), slide: vec3_any
):
    """``x + w·(R(x − p) + p + t − x)``: the jaw's rigid motion of ``x`` blended by its weight ``w``."""
    moved = wp.quat_rotate(rotation, x - pivot) + pivot + slide
    return x + w * (moved - x)


# ---------------------------------------------------------------- SPEC §1.1: the muscle sum
@wp.func
def muscle_pull(x: vec3_any, contraction: wp.Float, weight: vec3_any):
    """One term of ``x1 = x + Σ_m K_m·w_m``: ``x + K·w`` (``w`` the muscle's displacement per unit K)."""
    return x + contraction * weight


# ---------------------------------------------------------------- SPEC §1.2: stretch ratio
@wp.func
def area_vector(p0: vec3_any, p1: vec3_any, p2: vec3_any, weight: wp.Float):
    """``weight·(p1 − p0) × (p2 − p0)``: twice the area times the unit normal (weight 0: an ignored triangle)."""
    return weight * wp.cross(p1 - p0, p2 - p0)


@wp.func
def d_area_vector(e1: vec3_any, e2: vec3_any, de1: vec3_any, de2: vec3_any, weight: wp.Float):
    """Derivative of :func:`area_vector` with edges ``e1 = p1 − p0``, ``e2 = p2 − p0`` and their derivatives."""
    return weight * (wp.cross(de1, e2) + wp.cross(e1, de2))


@wp.func
def area_ratio(area: vec3_any, rest_length: wp.Float):
    """``S'/S``: the deformed area vector's length over the rest one (1 for ignored triangles, whose area is 0)."""
    return wp.length(area) / rest_length


@wp.func
def d_area_ratio(area: vec3_any, d_area: vec3_any, rest_length: wp.Float):
    """Derivative of :func:`area_ratio`; 0 where the area vanishes (the length is not differentiable there)."""
    length = wp.length(area)
    if length > type(length)(0.0):
        return wp.dot(area, d_area) / (length * rest_length)
    return type(length)(0.0)


@wp.func
def stretch_ratio(ratio_sum: wp.Float, count: wp.Float):
    """``r``: the mean of ``count`` incident ratios S'/S summed in ``ratio_sum``; 1 for a vertex without any."""
    if count > type(count)(0.0):
        return ratio_sum / count
    return type(count)(1.0)


@wp.func
def d_stretch_ratio(d_ratio_sum: wp.Float, count: wp.Float):
    """Derivative of :func:`stretch_ratio` given the summed ratios' derivative; 0 for a vertex without any."""
    if count > type(count)(0.0):
        return d_ratio_sum / count
    return type(count)(0.0)


# ---------------------------------------------------------------- SPEC §1.3: the bulge
@wp.func
def unit_or_zero(v: vec3_any):
    """``v / |v|``, or the zero vector when ``|v|`` is 0 (an isolated or fully collapsed vertex's normal)."""
    length = wp.length(v)
    if length > type(length)(0.0):
        return v / length
    zero = type(length)(0.0)
    return type(v)(zero, zero, zero)


@wp.func
def d_unit_or_zero(v: vec3_any, dv: vec3_any):
    """Derivative of :func:`unit_or_zero`: ``(dv − n (n·dv)) / |v|``; 0 where ``v`` vanishes."""
    length = wp.length(v)
    zero = type(length)(0.0)
    if length > zero:
        n = v / length
        return (dv - n * wp.dot(n, dv)) / length
    return type(v)(zero, zero, zero)


@wp.func
def bulge_growth(r: wp.Float, floor: wp.Float):
    """``1/r − 1`` with ``r`` floored at ``floor`` (fully collapsed skin stays finite): the relative thickening."""
    return type(r)(1.0) / wp.max(r, floor) - type(r)(1.0)


@wp.func
def d_bulge_growth(r: wp.Float, dr: wp.Float, floor: wp.Float):
    """Derivative of :func:`bulge_growth` given ``dr``: ``−dr/r²`` above the floor, 0 on it."""
    if r > floor:
        return -dr / (r * r)
    return type(r)(0.0)


@wp.func
def bulge_point(x1: vec3_any, normal_sum: vec3_any, r: wp.Float, h: wp.Float, floor: wp.Float):
    """``x2 = x1 + (1/r − 1)·h·N``, ``N`` the normalised ``normal_sum`` (sum of incident area vectors of x1)."""
    return x1 + (bulge_growth(r, floor) * h) * unit_or_zero(normal_sum)


# ---------------------------------------------------------------- SPEC §1.4: wrinkles
@wp.func
def wrinkle_profile(distance: wp.Float, width: wp.Float):
    """``s = S(d)/k_d = (d/k_w − 1)·exp(−d/k_w)``: the furrow's profile at distance ``d`` from its curve."""
    scaled = distance / width
    return (scaled - type(scaled)(1.0)) * wp.exp(-scaled)


@wp.func
def contraction_rate(kr: wp.Float):
    """``1 − 1/k_r``, the rate of C(r)'s exponential above r = 1 (0 for ``k_r ≤ 0``, where C is 0 there)."""
    if kr > type(kr)(0.0):
        return type(kr)(1.0) - type(kr)(1.0) / kr
    return type(kr)(0.0)


@wp.func
def contraction_below(r: wp.Float, kr: wp.Float):
    """C(r) on the compressed side (r ≤ 1): ``(k_r − 1)·r + 1``; its slope is ``k_r − 1``."""
    return (kr - type(kr)(1.0)) * r + type(kr)(1.0)


@wp.func
def contraction_above(r: wp.Float, kr: wp.Float, rate: wp.Float):
    """C(r) on the stretched side (r > 1): ``k_r·exp(rate·(r − 1))``, 0 for ``k_r ≤ 0``; its slope is ``rate·C``."""
    if kr <= type(kr)(0.0):
        return type(kr)(0.0)
    return kr * wp.exp(rate * (r - type(r)(1.0)))


@wp.func
def contraction_factor_from_rate(r: wp.Float, kr: wp.Float, rate: wp.Float):
    """C(r) with its :func:`contraction_rate` given (computed once per wrinkle instead of per frame)."""
    if r <= type(r)(1.0):
        return contraction_below(r, kr)
    return contraction_above(r, kr, rate)


@wp.func
def contraction_factor(r: wp.Float, kr: wp.Float):
    """C(r) (SPEC eq. 5): ``(k_r − 1)·r + 1`` for r ≤ 1, ``k_r·exp((1 − 1/k_r)(r − 1))`` above, 0 there if k_r = 0."""
    if r <= type(r)(1.0):
        return contraction_below(r, kr)
    return contraction_above(r, kr, contraction_rate(kr))


@wp.func
def contraction_factor_and_slope(r: wp.Float, kr: wp.Float, knee: wp.Float):
    """``(C(r), dC/dr)``, the compressed side's branch taken for ``r ≤ knee`` (1, or a hair above to pick the
    side a derivative at rest is taken from)."""
    if r <= knee:
        return contraction_below(r, kr), kr - type(kr)(1.0)
    rate = contraction_rate(kr)
    factor = contraction_above(r, kr, rate)
    return factor, rate * factor


@wp.func
def wrinkle_term(depth: wp.Float, shape: wp.Float, factor: wp.Float):
    """One wrinkle's height ``k_d·s·C(r)`` (depth, profile :func:`wrinkle_profile`, :func:`contraction_factor`)."""
    return depth * shape * factor


@wp.func
def wrinkle_point(x2: vec3_any, height: wp.Float, normal_sum: vec3_any):
    """``x3 = x2 + h_w·N(x2)``, ``h_w = Σ_w k_d·s_w·C_w(r)`` and ``N`` the normalised ``normal_sum`` of x2."""
    return x2 + height * unit_or_zero(normal_sum)
