"""Waters muscles (SPEC §1.1): linear and sphincter, as validated parameter records.

A muscle's displacement field is linear in its contraction ``K``: ``d_m(P) = K · w_m(P)`` with a
weight vector ``w_m`` that depends only on the rest position ``P``. :func:`muscle_weights`
evaluates ``w_m`` once per rig (float64 Warp kernels) and keeps only the vertices it moves, so a
frame costs one sparse gather instead of re-evaluating the trigonometry (see ``model.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Union

import numpy as np
import warp as wp

from .._validate import (
    MAX_COORDINATE,
    as_device,
    as_finite_array,
    as_points,
    as_positive,
    as_vec3,
    expect_iterable,
    orthogonal_unit_vector,
    unit_vector,
)
from ._sparse import vertex_csr
from .formulas import linear_muscle_weight, sphincter_weight
from .lids import LidMuscle, lid_field

__all__ = [
    "LinearMuscle",
    "MuscleLobe",
    "SphincterMuscle",
    "LidMuscle",
    "Muscle",
    "MUSCLE_TYPES",
    "muscle_weights",
    "MuscleWeights",
    "FALLOFFS",
]

FALLOFFS = ("waters", "smooth")
"""Zone shapes: ``"waters"`` is SPEC §1.1 (the default of the primitives), ``"smooth"`` the C¹ forms of
SPEC §6.3 / docs/RIG.md: angular ``cos²(μ/Ω·π/2)``, radial ``sin²(D/Rs·π/2)`` then
``cos²((D − Rs)/(Rf − Rs)·π/2)``, sphincter rim ``(1 − ρ²)²``; all vanish with zero slope."""


MAX_LOBES = 8
"""Most lobes one linear muscle drives."""
MAX_LOBE_GAIN = 1e3
"""Largest :attr:`MuscleLobe.gain`: beyond it the lobe, not the muscle, would be the control's field."""


def _check_zone(record, label: str) -> None:
    """Validate and normalise the Waters zone of a linear muscle or lobe (ends, angle, radii)."""
    set_ = object.__setattr__
    set_(record, "attachment", as_vec3(record.attachment, f"{label}: attachment"))
    set_(record, "insertion", as_vec3(record.insertion, f"{label}: insertion"))
    zone = float(as_finite_array(record.zone_angle_deg, f"{label}: zone_angle_deg", shape=()))
    if not 0.0 < zone < 180.0:
        raise ValueError(f"{label}: zone_angle_deg must be in (0, 180), got {zone}")
    set_(record, "zone_angle_deg", zone)
    start = float(as_finite_array(record.falloff_start, f"{label}: falloff_start", shape=()))
    if start < 0.0:
        raise ValueError(f"{label}: falloff_start must be ≥ 0, got {start}")
    finish = as_positive(record.falloff_finish, f"{label}: falloff_finish")
    if start >= finish:
        raise ValueError(f"{label}: falloff_start ({start}) must be < falloff_finish ({finish})")
    set_(record, "falloff_start", start)
    set_(record, "falloff_finish", finish)
    unit_vector(record.insertion - record.attachment, f"{label}: axis (insertion − attachment)")


class _WatersZone:
    """What a linear muscle and a lobe share beyond their validated zone (:func:`_check_zone`): its axis."""

    __slots__ = ()

    @property
    def axis(self) -> np.ndarray:
        """Unit vector from attachment to insertion, shape (3,)."""
        axis = self.insertion - self.attachment
        return axis / np.linalg.norm(axis)


@dataclass(frozen=True, eq=False)
class MuscleLobe(_WatersZone):
    """A second Waters zone that a linear muscle's contraction drives, scaled by ``gain``.

    A muscle whose fibres reach two regions moves both with one contraction: the frontalis, which has
    no bony origin, draws the brow up and the scalp's galea down toward its belly; the lower orbital
    fibres of the orbicularis oculi lift the cheek with the lower lid. The lobe's field is the §1.1 /
    §6.3 zone of its own ends and radii (same falloff form as its muscle), and the muscle's field is
    ``w = w_muscle + Σ gain · w_lobe`` before sliding and bunching (docs/RIG.md §5).

    Args:
        attachment, insertion, zone_angle_deg, falloff_start, falloff_finish: as for :class:`LinearMuscle`.
        gain: > 0 and ≤ :data:`MAX_LOBE_GAIN`, dimensionless: the lobe's pull per unit of the muscle's.
    """

    attachment: np.ndarray
    insertion: np.ndarray
    zone_angle_deg: float
    falloff_start: float
    falloff_finish: float
    gain: float = 1.0

    def __post_init__(self) -> None:
        _check_zone(self, "muscle lobe")
        gain = float(as_finite_array(self.gain, "muscle lobe: gain", shape=()))
        if not 0.0 < gain <= MAX_LOBE_GAIN:
            raise ValueError(f"muscle lobe: gain must be in (0, {MAX_LOBE_GAIN:g}], got {gain}")
        object.__setattr__(self, "gain", gain)


@dataclass(frozen=True, eq=False)
class LinearMuscle(_WatersZone):
    """A Waters linear muscle.

    For a rest vertex ``P``: ``D = |P − V1|``, ``μ`` the angle at ``V1`` between ``V2 − V1`` and
    ``P − V1``; unaffected when ``μ > Ω``, ``D > Rf`` or ``D = 0``; otherwise
    ``d = K · cos(μ/Ω · π/2) · R(D) · (V1 − P)/D`` with ``R = cos((1 − D/Rs)·π/2)`` for ``D < Rs``
    and ``R = cos((D − Rs)/(Rf − Rs)·π/2)`` for ``Rs ≤ D ≤ Rf``. Both factors vanish continuously
    at the zone edge, at ``V1`` and at ``Rf``.

    Args:
        name: unique muscle name (contractions are addressed by it).
        attachment: bone attachment point ``V1`` [mesh units], shape (3,).
        insertion: skin insertion point ``V2`` [mesh units], shape (3,); sets the axis ``V2 − V1``.
        zone_angle_deg: half-angle ``Ω`` of the zone of influence [degrees], in (0, 180).
        falloff_start: ``Rs`` [mesh units], ≥ 0 and < ``falloff_finish``.
        falloff_finish: ``Rf`` [mesh units].
        falloff: zone shape, one of :data:`FALLOFFS` (``"waters"``: the §1.1 factors above).
        sliding: in [0, 1]: the fraction of the pull's normal component removed, so the skin slides
            along its rest tangent plane instead of sinking toward the bone (docs/RIG.md §2).
        bunching: ≥ 0, dimensionless: tissue the muscle compresses moves out of the face by
            ``bunching · h · (−dr/dK)`` per unit contraction (docs/RIG.md §3); needs the mesh, so
            :class:`~warpface.ExpressionModel` adds it.
        thickening: ≥ 0, dimensionless: a shortening muscle thickens, lifting the skin over it by
            ``thickening · |w|`` along the normal per unit contraction (docs/RIG.md §3).
        lobes: :class:`MuscleLobe` s, further zones the same contraction moves (default none).

    Contraction ``K`` is a length [mesh units]: the largest displacement, reached at ``μ = 0``,
    ``D = Rs``.
    """

    name: str
    attachment: np.ndarray
    insertion: np.ndarray
    zone_angle_deg: float
    falloff_start: float
    falloff_finish: float
    falloff: str = "waters"
    sliding: float = 0.0
    bunching: float = 0.0
    thickening: float = 0.0
    lobes: tuple[MuscleLobe, ...] = ()

    def __post_init__(self) -> None:
        label = f"linear muscle {_quoted(self.name)}"
        _check_name(self.name, label)
        _check_zone(self, label)
        _check_response(self, label)
        if len(expect_iterable(self.lobes, f"{label}: lobes", sized=True)) > MAX_LOBES:
            raise ValueError(f"{label}: at most {MAX_LOBES} lobes, got {len(self.lobes)}")
        object.__setattr__(
            self, "lobes", tuple(expect_iterable(self.lobes, f"{label}: lobes", item_types=(MuscleLobe,)))
        )


@dataclass(frozen=True, eq=False)
class SphincterMuscle:
    """A sphincter muscle (orbicularis oris / oculi): an elliptic ring contracting toward its centre.

    In the local frame ``x = (P − C)·e_x``, ``y = (P − C)·e_y``: ``f = 1 − sqrt(x²/lx² + y²/ly²)``
    and, where ``f > 0``, ``d = −K · f · (x·e_x + y·e_y)``; zero outside the ellipse. The ellipse
    is a cylinder along ``e_x × e_y``: the out-of-plane offset does not enter.

    Args:
        name: unique muscle name.
        center: ellipse centre ``C`` [mesh units], shape (3,).
        axis_x, axis_y: in-plane axes, shape (3,) each. Both are normalised; ``axis_y`` is made
            orthogonal to ``axis_x`` (Gram–Schmidt) so ``(x, y)`` are true frame coordinates.
        semi_axes: ``(lx, ly)`` [mesh units], both > 0.
        falloff, sliding, bunching, thickening: as for :class:`LinearMuscle`; ``"smooth"`` replaces ``f`` by
            ``(1 − ρ²)²`` with ``ρ = sqrt(x²/lx² + y²/ly²)``.
        ring: in [0, 1): inside ``ρ < ring`` ``f`` is multiplied by ``sin²(ρ/ring · π/2)``, so the pull
            fades to zero toward the centre with zero slope at ``ρ = ring`` (an orbital ring that leaves
            the lids inside it to other muscles; docs/RIG.md §5). 0 (default): the whole ellipse.

    Contraction ``K`` is dimensionless: the displacement is ``K·f`` times the in-plane offset.
    """

    name: str
    center: np.ndarray
    axis_x: np.ndarray
    axis_y: np.ndarray
    semi_axes: tuple[float, float]
    falloff: str = "waters"
    sliding: float = 0.0
    bunching: float = 0.0
    thickening: float = 0.0
    ring: float = 0.0

    def __post_init__(self) -> None:
        label = f"sphincter muscle {_quoted(self.name)}"
        _check_name(self.name, label)
        set_ = object.__setattr__
        set_(self, "center", as_vec3(self.center, f"{label}: center"))
        ex = unit_vector(self.axis_x, f"{label}: axis_x")
        ey = unit_vector(self.axis_y, f"{label}: axis_y")
        if np.linalg.norm(ey - np.dot(ey, ex) * ex) < 1e-6:
            raise ValueError(f"{label}: axis_x and axis_y are parallel")
        set_(self, "axis_x", ex)
        set_(self, "axis_y", orthogonal_unit_vector(ey, ex, f"{label}: axis_y"))
        semi = as_finite_array(self.semi_axes, f"{label}: semi_axes", shape=(2,))
        if np.any(semi <= 0.0) or np.any(semi > MAX_COORDINATE):
            raise ValueError(f"{label}: semi_axes must be in (0, {MAX_COORDINATE:g}], got {semi.tolist()}")
        set_(self, "semi_axes", (float(semi[0]), float(semi[1])))
        ring = float(as_finite_array(self.ring, f"{label}: ring", shape=()))
        if not 0.0 <= ring < 1.0:
            raise ValueError(f"{label}: ring must be in [0, 1), got {ring}")
        set_(self, "ring", ring)
        _check_response(self, label)


Muscle = Union[LinearMuscle, SphincterMuscle, LidMuscle]
MUSCLE_TYPES = (LinearMuscle, SphincterMuscle, LidMuscle)
"""The control kinds a rig's muscle list holds: Waters linear and sphincter muscles, and lid hinges."""


def _quoted(name) -> str:
    """``name`` for a one-line message: quoted when a string (cut at 60 characters), else its type."""
    return repr(name[:60]) if isinstance(name, str) else f"(name of type {type(name).__name__})"


def _check_name(name, label: str) -> None:
    if not isinstance(name, str):
        raise TypeError(f"{label}: name must be a string, got {type(name).__name__}")
    if not name:
        raise ValueError(f"{label}: name must be a non-empty string")


def _check_response(muscle, label: str) -> None:
    """Validate and normalise the falloff form, sliding and bunching of a muscle."""
    if muscle.falloff not in FALLOFFS:
        raise ValueError(f"{label}: falloff must be one of {', '.join(FALLOFFS)}, got {muscle.falloff!r}")
    sliding = float(as_finite_array(muscle.sliding, f"{label}: sliding", shape=()))
    if not 0.0 <= sliding <= 1.0:
        raise ValueError(f"{label}: sliding must be in [0, 1], got {sliding}")
    bunching = float(as_finite_array(muscle.bunching, f"{label}: bunching", shape=()))
    if bunching < 0.0:
        raise ValueError(f"{label}: bunching must be ≥ 0, got {bunching}")
    thickening = float(as_finite_array(muscle.thickening, f"{label}: thickening", shape=()))
    if thickening < 0.0:
        raise ValueError(f"{label}: thickening must be ≥ 0, got {thickening}")
    object.__setattr__(muscle, "sliding", sliding)
    object.__setattr__(muscle, "bunching", bunching)
    object.__setattr__(muscle, "thickening", thickening)


# ---------------------------------------------------------------------------------------------- kernels


@wp.kernel
def _linear_muscle_weight_kernel(
    rest: wp.array(dtype=wp.vec3d),
    attachment: wp.vec3d,
    axis: wp.vec3d,
    zone: wp.float64,
    falloff_start: wp.float64,
    falloff_finish: wp.float64,
    smooth: int,
    weight: wp.array(dtype=wp.vec3d),
):
    i = wp.tid()
    weight[i] = linear_muscle_weight(rest[i] - attachment, axis, zone, falloff_start, falloff_finish, smooth)


@wp.kernel
def _sphincter_weight_kernel(
    rest: wp.array(dtype=wp.vec3d),
    center: wp.vec3d,
    axis_x: wp.vec3d,
    axis_y: wp.vec3d,
    semi_x: wp.float64,
    semi_y: wp.float64,
    smooth: int,
    ring: wp.float64,
    weight: wp.array(dtype=wp.vec3d),
):
    i = wp.tid()
    weight[i] = sphincter_weight(rest[i] - center, axis_x, axis_y, semi_x, semi_y, smooth, ring)


@wp.kernel
def _add_scaled_kernel(values: wp.array(dtype=wp.vec3d), scale: wp.float64, total: wp.array(dtype=wp.vec3d)):
    i = wp.tid()
    total[i] = total[i] + scale * values[i]


def _linear_zone_weights(rest: wp.array, zone, falloff: str, out: wp.array) -> None:
    """The §1.1 / §6.3 zone weights of a :class:`LinearMuscle` or :class:`MuscleLobe` into ``out`` (V,) vec3d."""
    inputs = [
        rest,
        wp.vec3d(*zone.attachment),
        wp.vec3d(*zone.axis),
        math.radians(zone.zone_angle_deg),
        zone.falloff_start,
        zone.falloff_finish,
        int(falloff == "smooth"),
    ]
    wp.launch(_linear_muscle_weight_kernel, dim=len(rest), inputs=inputs, outputs=[out], device=rest.device)


@dataclass(frozen=True)
class MuscleWeights:
    """Sparse per-vertex muscle weights, vertex-major CSR: ``x1[v] = x[v] + Σ_k K[muscle[k]]·weight[k]``.

    Entries of vertex ``v`` are ``offsets[v]:offsets[v + 1]``.
    """

    offsets: np.ndarray
    """Row offsets, shape (V + 1,), int32."""
    muscle: np.ndarray
    """Muscle index (position in the rig's muscle list) per entry, shape (E,), int32."""
    weight: np.ndarray
    """Displacement per unit contraction [mesh units per unit K], shape (E, 3), float64."""

    @classmethod
    def from_fields(cls, vertex_count: int, fields) -> MuscleWeights:
        """The entries of dense per-muscle fields (an iterable of (V, 3) arrays in muscle order) that move a vertex."""
        rows, columns, values = [], [], []
        for index, field in enumerate(fields):
            moved = np.flatnonzero(np.any(field != 0.0, axis=1))
            rows.append(moved)
            columns.append(np.full(len(moved), index, dtype=np.int32))
            values.append(field[moved])
        offsets, column, value = vertex_csr(vertex_count, rows, columns, values)
        return cls(offsets=offsets, muscle=column, weight=value)


def muscle_weights(rest_points: np.ndarray, muscles: list[Muscle], *, device=None) -> MuscleWeights:
    """Evaluate every muscle's weight field at the rest points and keep the non-zero entries.

    Args:
        rest_points: shape (V, 3), float64.
        muscles: linear and sphincter muscles and lid hinges, in contraction order.
        device: Warp device for the float64 kernels.
    """
    device = as_device(device)
    rest_points = as_points(rest_points, "rest_points")
    muscles = expect_iterable(muscles, "muscles", item_types=MUSCLE_TYPES)
    rest = wp.array(rest_points, dtype=wp.vec3d, device=device)
    return MuscleWeights.from_fields(len(rest_points), (_weight_field(rest, muscle) for muscle in muscles))


def _weight_field(rest: wp.array, muscle: Muscle) -> np.ndarray:
    """One muscle's weight ``w_m`` at every rest point, shape (V, 3) float64 (lobes added by their gain)."""
    vertex_count, device = len(rest), rest.device
    if isinstance(muscle, LidMuscle):
        return lid_field(rest, muscle)
    out = wp.empty(vertex_count, dtype=wp.vec3d, device=device)
    if isinstance(muscle, LinearMuscle):
        _linear_zone_weights(rest, muscle, muscle.falloff, out)
        lobe_weights = wp.empty_like(out) if muscle.lobes else None
        for lobe in muscle.lobes:
            _linear_zone_weights(rest, lobe, muscle.falloff, lobe_weights)
            wp.launch(
                _add_scaled_kernel, dim=vertex_count, inputs=[lobe_weights, lobe.gain], outputs=[out], device=device
            )
    else:
        inputs = [
            rest,
            wp.vec3d(*muscle.center),
            wp.vec3d(*muscle.axis_x),
            wp.vec3d(*muscle.axis_y),
            muscle.semi_axes[0],
            muscle.semi_axes[1],
            int(muscle.falloff == "smooth"),
            muscle.ring,
        ]
        wp.launch(_sphincter_weight_kernel, dim=vertex_count, inputs=inputs, outputs=[out], device=device)
    return out.numpy()
