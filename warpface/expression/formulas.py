"""The expression model's formulas (SPEC §1, §6.2, §6.3), each written once as a Warp function.

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
    "linear_angular_factor",
    "linear_radial_factor",
    "sphincter_factor",
    "sphincter_ring_factor",
    "linear_muscle_weight",
    "sphincter_weight",
    "sliding_pull",
    "thickening_pull",
    "bunching_pull",
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


# ---------------------------------------------------------------- SPEC §1.1, §6.3: Waters muscle zones
# ``smooth = 0`` selects SPEC §1.1 exactly; ``smooth = 1`` the C¹ forms of §6.3 (docs/RIG.md §1), which reach zero
# with zero slope at every zone edge (angle Ω, radius Rf, the attachment, the sphincter rim), so the skin shows
# no crease where a muscle's influence ends: angular ``cos²(μ/Ω · π/2)``; radial ``sin²(D/Rs · π/2)`` below Rs,
# ``cos²((D − Rs)/(Rf − Rs) · π/2)`` from Rs to Rf; sphincter ``(1 − ρ²)²``.


@wp.func
def _half_pi_times(t: wp.Float):
    """``t · π/2`` in ``t``'s type."""
    return t * type(t)(1.5707963267948966)


@wp.func
def linear_angular_factor(mu: wp.Float, zone: wp.Float, smooth: int):
    """Angular factor at angle ``mu`` ∈ [0, zone] from the muscle axis (``zone`` = Ω) [rad]."""
    c = wp.cos(_half_pi_times(mu / zone))
    if smooth != 0:
        return c * c
    return c


@wp.func
def linear_radial_factor(distance: wp.Float, start: wp.Float, finish: wp.Float, smooth: int):
    """Radial factor at ``distance`` ∈ (0, finish] from the attachment, rising to 1 at ``start`` (Rs)."""
    if distance < start:
        if smooth != 0:
            s = wp.sin(_half_pi_times(distance / start))
            return s * s
        return wp.cos(_half_pi_times(type(distance)(1.0) - distance / start))
    c = wp.cos(_half_pi_times((distance - start) / (finish - start)))
    if smooth != 0:
        return c * c
    return c


@wp.func
def sphincter_factor(rho_squared: wp.Float, smooth: int):
    """Sphincter weight at elliptic radius² ``rho_squared`` (1 at the centre, 0 on and beyond the rim)."""
    one = type(rho_squared)(1.0)
    if rho_squared >= one:
        return type(rho_squared)(0.0)
    if smooth != 0:
        f = one - rho_squared
        return f * f
    return one - wp.sqrt(rho_squared)


@wp.func
def sphincter_ring_factor(rho_squared: wp.Float, ring: wp.Float):
    """Ring factor of a sphincter whose inner part does not move: ``sin²(ρ/ring · π/2)`` for ``ρ < ring``, else 1."""
    one = type(ring)(1.0)
    if ring <= type(ring)(0.0):
        return one
    rho = wp.sqrt(rho_squared)
    if rho >= ring:
        return one
    s = wp.sin(_half_pi_times(rho / ring))
    return s * s


@wp.func
def linear_muscle_weight(
    offset: vec3_any, axis: vec3_any, zone: wp.Float, start: wp.Float, finish: wp.Float, smooth: int
):
    """A linear muscle's displacement per unit K at ``offset = P − V1``: ``A·R·(V1 − P)/D``, 0 outside the zone
    (``μ > Ω``, ``D > Rf`` or ``D = 0``). ``axis`` is the unit ``V2 − V1``."""
    distance = wp.length(offset)
    zero = type(distance)(0.0)
    if distance == zero or distance > finish:
        return type(offset)(zero, zero, zero)
    # atan2 keeps μ accurate near 0 and π, where acos of a dot product loses digits.
    mu = wp.atan2(wp.length(wp.cross(axis, offset)), wp.dot(axis, offset))
    if mu > zone:
        return type(offset)(zero, zero, zero)
    factor = linear_angular_factor(mu, zone, smooth) * linear_radial_factor(distance, start, finish, smooth)
    return -(factor / distance) * offset


@wp.func
def sphincter_weight(
    offset: vec3_any,
    axis_x: vec3_any,
    axis_y: vec3_any,
    semi_x: wp.Float,
    semi_y: wp.Float,
    smooth: int,
    ring: wp.Float,
):
    """A sphincter's displacement per unit K at ``offset = P − C``: ``−f·(x·ex + y·ey)`` (toward the centre), with
    ``(x, y)`` the offset in the muscle's frame and ``f`` its falloff; 0 outside the ellipse."""
    x = wp.dot(offset, axis_x)
    y = wp.dot(offset, axis_y)
    rho_squared = x * x / (semi_x * semi_x) + y * y / (semi_y * semi_y)
    falloff = sphincter_factor(rho_squared, smooth) * sphincter_ring_factor(rho_squared, ring)
    zero = type(falloff)(0.0)
    if falloff > zero:
        return -falloff * (x * axis_x + y * axis_y)
    return type(offset)(zero, zero, zero)


# ---------------------------------------------------------------- the skin's answer to a pull (docs/RIG.md §2–3)
@wp.func
def sliding_pull(weight: vec3_any, normal: vec3_any, sliding: wp.Float):
    """``(1 − s)·w + s·(w − (w·N) N)``: the fraction ``s`` of the pull's normal part removed (the skin glides
    on the fascia, of unit normal ``N``)."""
    along = weight - wp.dot(weight, normal) * normal
    return (type(sliding)(1.0) - sliding) * weight + sliding * along


@wp.func
def thickening_pull(weight: vec3_any, pull: wp.Float, normal: vec3_any, thickening: wp.Float):
    """``w + τ·|w₀|·N``: a shortening belly thickens, lifting the skin in proportion to the zone's pull ``|w₀|``."""
    return weight + (thickening * pull) * normal


@wp.func
def bunching_pull(weight: vec3_any, height: wp.Float, cap: wp.Float, normal: vec3_any):
    """``w + c·tanh(b/c)·N``: the bunching height ``b = −β·h·ρ`` along ``N``, saturating smoothly at ``c``."""
    return weight + (cap * wp.tanh(height / cap)) * normal


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
