"""Expressive wrinkles (SPEC §1.4): Bézier furrows in a 2-D projection of the rest mesh.

A wrinkle is a cubic Bézier curve in the (u, v) plane of a :class:`PlanarProjection` or a
:class:`CylindricalProjection`. Each rest vertex is projected, its true nearest-point distance
``d`` to the curve is found once (float64 kernel), and a frame displaces it along the normal by
``S(d)·C(r)``, ``S(d) = k_d·(d/k_w − 1)·exp(−d/k_w)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Union

import numpy as np
import warp as wp

from .._validate import (
    MAX_COORDINATE,
    as_bounded,
    as_device,
    as_finite_array,
    as_points,
    as_positive,
    as_vec3,
    orthogonal_unit_vector,
    unit_vector,
)
from ._sparse import vertex_csr
from .formulas import wrinkle_profile

__all__ = [
    "PlanarProjection",
    "CylindricalProjection",
    "Projection",
    "Wrinkle",
    "project_points",
    "bezier_distances",
    "wrinkle_shapes",
    "skin_wrinkle_shapes",
    "WrinkleShapes",
    "WRINKLE_SHAPE_CUTOFF",
]

WRINKLE_SHAPE_CUTOFF = 1e-7
"""Entries with ``|(d/k_w − 1)·exp(−d/k_w)| <`` this are dropped (beyond ``d ≈ 19.6·k_w``): their
contribution is below 1e-7·k_d, under float32 resolution of the positions, and skipping them makes a
frame's cost proportional to the skin a wrinkle actually touches."""


def _cutoff_distance(cutoff: float) -> float:
    """The scaled distance x = d/k_w beyond which |(x − 1)·e^(−x)| < ``cutoff`` (bisection on x > 2)."""
    lo, hi = 2.0, 200.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if (mid - 1.0) * math.exp(-mid) >= cutoff else (lo, mid)
    return hi


_CUTOFF_SCALED_DISTANCE = _cutoff_distance(WRINKLE_SHAPE_CUTOFF)

_PLANAR = wp.constant(0)
_CYLINDRICAL = wp.constant(1)


@dataclass(frozen=True, eq=False)
class PlanarProjection:
    """``(u, v) = ((p − o)·û, (p − o)·v̂)`` — lengths in mesh units.

    Args:
        origin: shape (3,) [mesh units].
        u_axis, v_axis: shape (3,) each; normalised on construction; must not be parallel.
    """

    origin: np.ndarray
    u_axis: np.ndarray
    v_axis: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "origin", as_vec3(self.origin, "planar projection: origin"))
        u = unit_vector(self.u_axis, "planar projection: u_axis")
        v = unit_vector(self.v_axis, "planar projection: v_axis")
        if abs(float(np.dot(u, v))) > 1.0 - 1e-6:
            raise ValueError("planar projection: u_axis and v_axis are parallel")
        object.__setattr__(self, "u_axis", u)
        object.__setattr__(self, "v_axis", v)

    def _frame(self):
        return _PLANAR, self.origin, self.u_axis, self.v_axis, np.zeros(3), 0.0


@dataclass(frozen=True, eq=False)
class CylindricalProjection:
    """``u = radius·θ``, ``v = (p − o)·â``: θ is the angle of ``p − o`` around ``axis``, measured from
    ``reference`` with the right-hand rule (θ = +90° toward ``axis × reference``), in (−180°, 180°].

    Args:
        origin: a point on the cylinder axis, shape (3,) [mesh units].
        axis: the cylinder axis (the head's vertical), shape (3,); normalised.
        reference: direction of θ = 0 (e.g. toward the face); its component along ``axis`` is
            removed and it is normalised. The seam θ = ±180° lies opposite it.
        radius: cylinder radius [mesh units], > 0; scales θ into a length.
    """

    origin: np.ndarray
    axis: np.ndarray
    reference: np.ndarray
    radius: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "origin", as_vec3(self.origin, "cylindrical projection: origin"))
        axis = unit_vector(self.axis, "cylindrical projection: axis")
        reference = orthogonal_unit_vector(self.reference, axis, "cylindrical projection: reference ⟂ axis")
        object.__setattr__(self, "axis", axis)
        object.__setattr__(self, "reference", reference)
        object.__setattr__(self, "radius", as_positive(self.radius, "cylindrical projection: radius"))

    def _frame(self):
        return _CYLINDRICAL, self.origin, self.reference, self.axis, np.cross(self.axis, self.reference), self.radius


Projection = Union[PlanarProjection, CylindricalProjection]


@dataclass(frozen=True, eq=False)
class Wrinkle:
    """One furrow: a cubic Bézier curve in a projection, with its shape parameters.

    Args:
        name: unique wrinkle name.
        control_points: Bézier control points in (u, v) [mesh units], shape (4, 2).
        projection: :class:`PlanarProjection` or :class:`CylindricalProjection`.
        depth: ``k_d`` [mesh units], furrow depth at the curve (animatable per frame); finite.
        width: ``k_w`` [mesh units], > 0.
        kr: ``k_r`` in [0, 1]: the fraction of the furrow that remains at rest stretch (r = 1).
    """

    name: str
    control_points: np.ndarray
    projection: Projection
    depth: float
    width: float
    kr: float = 0.0

    def __post_init__(self) -> None:
        label = f"wrinkle {self.name[:60]!r}" if isinstance(self.name, str) else "wrinkle"
        if not isinstance(self.name, str):
            raise TypeError(f"{label}: name must be a string, got {type(self.name).__name__}")
        if not self.name:
            raise ValueError(f"{label}: name must be a non-empty string")
        object.__setattr__(
            self,
            "control_points",
            # u of a cylindrical projection reaches radius·π: allow that beyond the coordinate bound
            as_finite_array(
                self.control_points, f"{label}: control_points", shape=(4, 2), max_abs=4.0 * MAX_COORDINATE
            ),
        )
        if not isinstance(self.projection, (PlanarProjection, CylindricalProjection)):
            raise TypeError(
                f"{label}: projection must be PlanarProjection or CylindricalProjection, "
                f"got {type(self.projection).__name__}"
            )
        object.__setattr__(self, "depth", as_bounded(self.depth, f"{label}: depth", -MAX_COORDINATE, MAX_COORDINATE))
        object.__setattr__(self, "width", as_positive(self.width, f"{label}: width (k_w)"))
        kr = float(as_finite_array(self.kr, f"{label}: kr", shape=()))
        if not 0.0 <= kr <= 1.0:
            raise ValueError(f"{label}: kr must be in [0, 1], got {kr}")
        object.__setattr__(self, "kr", kr)


# ---------------------------------------------------------------------------------------------- kernels


@wp.func
def _project(p: wp.vec3d, kind: int, origin: wp.vec3d, e1: wp.vec3d, e2: wp.vec3d, e3: wp.vec3d, radius: wp.float64):
    offset = p - origin
    if kind == _PLANAR:
        return wp.vec2d(wp.dot(offset, e1), wp.dot(offset, e2))
    theta = wp.atan2(wp.dot(offset, e3), wp.dot(offset, e1))
    return wp.vec2d(radius * theta, wp.dot(offset, e2))


@wp.kernel
def _project_kernel(
    points: wp.array(dtype=wp.vec3d),
    kind: int,
    origin: wp.vec3d,
    e1: wp.vec3d,
    e2: wp.vec3d,
    e3: wp.vec3d,
    radius: wp.float64,
    uv: wp.array(dtype=wp.vec2d),
):
    i = wp.tid()
    uv[i] = _project(points[i], kind, origin, e1, e2, e3, radius)


@wp.func
def bezier_point(c0: wp.vec2d, c1: wp.vec2d, c2: wp.vec2d, c3: wp.vec2d, t: wp.float64):
    """Cubic Bézier B(t) in Bernstein form."""
    s = wp.float64(1.0) - t
    return (s * s * s) * c0 + (wp.float64(3.0) * s * s * t) * c1 + (wp.float64(3.0) * s * t * t) * c2 + (t * t * t) * c3


@wp.func
def bezier_tangent(c0: wp.vec2d, c1: wp.vec2d, c2: wp.vec2d, c3: wp.vec2d, t: wp.float64):
    """B'(t)."""
    s = wp.float64(1.0) - t
    return wp.float64(3.0) * ((s * s) * (c1 - c0) + (wp.float64(2.0) * s * t) * (c2 - c1) + (t * t) * (c3 - c2))


@wp.func
def bezier_curvature(c0: wp.vec2d, c1: wp.vec2d, c2: wp.vec2d, c3: wp.vec2d, t: wp.float64):
    """B''(t)."""
    s = wp.float64(1.0) - t
    return wp.float64(6.0) * (s * (c2 - wp.float64(2.0) * c1 + c0) + t * (c3 - wp.float64(2.0) * c2 + c1))


@wp.func
def _refine_in_bracket(
    p: wp.vec2d, c0: wp.vec2d, c1: wp.vec2d, c2: wp.vec2d, c3: wp.vec2d, lo: wp.float64, hi: wp.float64, t: wp.float64
):
    """Safeguarded Newton on g(t) = (B(t) − p)·B'(t) inside [lo, hi]; returns the squared distance."""
    half = wp.float64(0.5)
    for _ in range(40):
        offset = bezier_point(c0, c1, c2, c3, t) - p
        tangent = bezier_tangent(c0, c1, c2, c3, t)
        g = wp.dot(offset, tangent)
        slope = wp.dot(tangent, tangent) + wp.dot(offset, bezier_curvature(c0, c1, c2, c3, t))
        # The bracket keeps a sign change of g (a minimum of |B − p|²) inside it.
        if g > wp.float64(0.0):
            hi = t
        else:
            lo = t
        step_to = half * (lo + hi)
        if slope > wp.float64(0.0):
            newton = t - g / slope
            if newton > lo and newton < hi:
                step_to = newton
        if wp.abs(step_to - t) <= wp.float64(1e-15):
            t = step_to
            break
        t = step_to
    offset = bezier_point(c0, c1, c2, c3, t) - p
    return wp.dot(offset, offset)


_SAMPLES = wp.constant(64)


@wp.kernel
def _bezier_distance_kernel(
    uv: wp.array(dtype=wp.vec2d),
    c0: wp.vec2d,
    c1: wp.vec2d,
    c2: wp.vec2d,
    c3: wp.vec2d,
    distance: wp.array(dtype=wp.float64),
):
    """True distance from each point to the curve: coarse samples, then every sampled local minimum
    (endpoints included) is refined, so the global minimum is found even when several compete."""
    i = wp.tid()
    p = uv[i]
    step = wp.float64(1.0) / wp.float64(_SAMPLES - 1)
    end0 = bezier_point(c0, c1, c2, c3, wp.float64(0.0)) - p
    end1 = bezier_point(c0, c1, c2, c3, wp.float64(1.0)) - p
    best = wp.min(wp.dot(end0, end0), wp.dot(end1, end1))
    previous = wp.float64(1e300)
    current = wp.dot(end0, end0)
    for k in range(_SAMPLES):
        following = wp.float64(1e300)
        if k + 1 < _SAMPLES:
            offset = bezier_point(c0, c1, c2, c3, wp.float64(k + 1) * step) - p
            following = wp.dot(offset, offset)
        if current <= previous and current <= following:
            t = wp.float64(k) * step
            lo = wp.max(t - step, wp.float64(0.0))
            hi = wp.min(t + step, wp.float64(1.0))
            best = wp.min(best, _refine_in_bracket(p, c0, c1, c2, c3, lo, hi, t))
        previous = current
        current = following
    distance[i] = wp.sqrt(best)


# ---------------------------------------------------------------------------------------------- API


def project_points(projection: Projection, points: np.ndarray, *, device=None) -> np.ndarray:
    """Project points into a projection's (u, v) plane [mesh units]: (V, 3) → (V, 2) float64."""
    if not isinstance(projection, (PlanarProjection, CylindricalProjection)):
        raise TypeError(
            f"projection: expected PlanarProjection or CylindricalProjection, got {type(projection).__name__}"
        )
    device = as_device(device)
    points = as_points(points, "points")
    if len(points) == 0:
        return np.zeros((0, 2), dtype=np.float64)
    kind, origin, e1, e2, e3, radius = projection._frame()
    uv = wp.empty(len(points), dtype=wp.vec2d, device=device)
    wp.launch(
        _project_kernel,
        dim=len(points),
        inputs=[
            wp.array(points, dtype=wp.vec3d, device=device),
            kind,
            wp.vec3d(*origin),
            wp.vec3d(*e1),
            wp.vec3d(*e2),
            wp.vec3d(*e3),
            float(radius),
        ],
        outputs=[uv],
        device=device,
    )
    return uv.numpy()


def bezier_distances(uv: np.ndarray, control_points: np.ndarray, *, device=None) -> np.ndarray:
    """Nearest-point distance from each 2-D point to a cubic Bézier curve: (V, 2), (4, 2) → (V,) float64."""
    device = as_device(device)
    uv = as_finite_array(uv, "uv", shape=(None, 2), max_abs=4.0 * MAX_COORDINATE)
    control_points = as_finite_array(control_points, "control_points", shape=(4, 2), max_abs=4.0 * MAX_COORDINATE)
    if len(uv) == 0:
        return np.zeros(0, dtype=np.float64)
    c = [wp.vec2d(*row) for row in control_points]
    out = wp.empty(len(uv), dtype=wp.float64, device=device)
    wp.launch(
        _bezier_distance_kernel,
        dim=len(uv),
        inputs=[wp.array(uv, dtype=wp.vec2d, device=device), *c],
        outputs=[out],
        device=device,
    )
    return out.numpy()


@wp.kernel
def _profile_kernel(distance: wp.array(dtype=wp.float64), width: wp.float64, shape: wp.array(dtype=wp.float64)):
    i = wp.tid()
    shape[i] = wrinkle_profile(distance[i], width)


def _profiles(distance: np.ndarray, width: float, *, device) -> np.ndarray:
    """:func:`~warpface.expression.formulas.wrinkle_profile` of each distance, float64."""
    if len(distance) == 0:
        return np.zeros(0, dtype=np.float64)
    shape = wp.empty(len(distance), dtype=wp.float64, device=device)
    values = wp.array(distance, dtype=wp.float64, device=device)
    wp.launch(_profile_kernel, dim=len(distance), inputs=[values, width], outputs=[shape], device=device)
    return shape.numpy()


@dataclass(frozen=True)
class WrinkleShapes:
    """Precomputed furrow profiles, vertex-major CSR.

    A frame adds ``Σ_k depth[wrinkle[k]] · shape[k] · C(r; kr[wrinkle[k]])`` along the normal.
    """

    offsets: np.ndarray
    """Row offsets, shape (V + 1,), int32."""
    wrinkle: np.ndarray
    """Wrinkle index per entry, shape (E,), int32."""
    shape: np.ndarray
    """``(d/k_w − 1)·exp(−d/k_w)`` per entry (dimensionless, in [−1, e⁻²]), shape (E,), float64."""


def wrinkle_shapes(rest_points: np.ndarray, wrinkles: list[Wrinkle], *, device=None) -> WrinkleShapes:
    """Distances of every rest vertex to every wrinkle's curve, turned into kept profile entries."""
    rest_points = as_points(rest_points, "rest_points")
    for index, wrinkle in enumerate(wrinkles):
        if not isinstance(wrinkle, Wrinkle):
            raise TypeError(f"wrinkles[{index}]: expected a Wrinkle, got {type(wrinkle).__name__}")
    rows, columns, values = [], [], []
    for index, wrinkle in enumerate(wrinkles):
        uv = project_points(wrinkle.projection, rest_points, device=device)
        # The curve lies in its control points' bounding box (convex hull property), so vertices
        # farther than the cutoff from that box have no kept entry: skip their distance queries.
        reach = _CUTOFF_SCALED_DISTANCE * wrinkle.width
        lo = wrinkle.control_points.min(axis=0) - reach
        hi = wrinkle.control_points.max(axis=0) + reach
        near = np.flatnonzero(np.all((uv >= lo) & (uv <= hi), axis=1))
        distance = bezier_distances(uv[near], wrinkle.control_points, device=device)
        shape = _profiles(distance, wrinkle.width, device=as_device(device))
        kept = np.abs(shape) >= WRINKLE_SHAPE_CUTOFF
        rows.append(near[kept])
        columns.append(np.full(int(kept.sum()), index, dtype=np.int32))
        values.append(shape[kept])
    offsets, column, value = vertex_csr(len(rest_points), rows, columns, values)
    return WrinkleShapes(offsets=offsets, wrinkle=column, shape=value)


def skin_wrinkle_shapes(mesh, wrinkles: list[Wrinkle], muscles, *, device=None) -> WrinkleShapes:
    """The profiles the expression model and the solver apply (docs/RIG.md §14): :func:`wrinkle_shapes` of the
    rest ``mesh``'s points times the hinges' :func:`~warpface.expression.lids.hinge_taper`; on a rig beyond the
    paper's model (:func:`~warpface.expression.tissue.has_tissue_model`) each wrinkle no narrower than the mesh can
    draw (:mod:`~warpface.expression.wrinkle_width`: wider by the local edge length, shallower in the same ratio)."""
    from .lids import hinge_taper
    from .tissue import has_tissue_model
    from .wrinkle_width import drawable_widths

    points = mesh.points
    wrinkles = list(wrinkles)
    factors = np.ones(len(wrinkles))
    if wrinkles and has_tissue_model(list(muscles)):
        triangles = mesh.triangles[~mesh.degenerate_triangles]
        widths = drawable_widths(points, triangles, wrinkles, device=device)
        wrinkles = [replace(w, width=width) for w, (width, _) in zip(wrinkles, widths)]
        factors = np.array([factor for _, factor in widths])
    shapes = wrinkle_shapes(points, wrinkles, device=device)
    row = np.repeat(np.arange(len(points)), np.diff(shapes.offsets))
    shape = shapes.shape * hinge_taper(len(points), list(muscles))[row] * factors[shapes.wrinkle]
    return WrinkleShapes(offsets=shapes.offsets, wrinkle=shapes.wrinkle, shape=shape)
