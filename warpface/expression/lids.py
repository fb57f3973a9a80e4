"""Eyelids as hinges (docs/RIG.md §11): lid vertices turn about the eyeball's centre.

A :class:`LidMuscle` is a control whose field is a rotation of each of its vertices about one axis
through the eye's centre, by that vertex's own angle: per unit contraction ``K``

``w(x_v) = R(θ_v, a)(x_v − c) + c + q_v·n_v + l_v·a − x_v``

(the jaw's hinge formulas, :func:`~warpface.expression.formulas.jaw_rotation`,
:func:`~warpface.expression.formulas.jaw_slide` with a per-vertex lateral slide ``l_v`` along the axis
and a radial lift ``q_v`` along ``n_v``, the unit normal from the axis to the turned point, as its
protrusion, and :func:`~warpface.expression.formulas.jaw_blend` with weight 1). The field is evaluated
once per rig like every muscle's, so the pipeline stays ``x1 = x + Σ K·w`` and the solver's Jacobian
of this stage is the weight matrix: ``K = 1`` puts each vertex exactly on its turned position over
the eyeball (the closed lid), ``0 < K < 1`` on the chord toward it. The angles are the rig's choice
(:mod:`warpface.assets.lids` builds them from the lid landmarks so the margins meet at ``K = 1``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from .._validate import as_bounded, as_finite_array, as_vec3, unit_vector
from .formulas import jaw_blend, jaw_rotation, jaw_slide, unit_or_zero

__all__ = ["LidMuscle", "MAX_LID_ANGLE", "MAX_FIT_LIMIT", "lid_field", "hinge_taper", "bulging_thickness"]

MAX_LID_ANGLE = np.pi / 2
"""Largest |θ_v| [rad] per unit contraction: a lid turns by less than a right angle over the eyeball."""
MAX_FIT_LIMIT = 10.0
"""Largest ``fit_limit``: a fit may turn a hinge at most ten times its full turn."""


@dataclass(frozen=True, eq=False)
class LidMuscle:
    """A lid's hinge: its vertices turn about ``axis`` through ``center`` by ``angles`` per unit contraction.

    Args:
        name: unique control name.
        center: the eyeball's centre ``c`` [mesh units], shape (3,).
        axis: unit rotation axis ``a``, shape (3,) (right-hand rule).
        vertices: the vertices it moves, shape (n,), distinct non-negative ints.
        angles: ``θ_v`` [rad per unit K] of each of ``vertices``, shape (n,), |θ| ≤ :data:`MAX_LID_ANGLE`.
        slides: ``l_v`` [mesh units per unit K] along ``axis`` of each of ``vertices``, shape (n,)
            (default 0: a pure turn), so a margin point can meet a partner that is not straight below it.
        lifts: ``q_v`` [mesh units per unit K] away from the axis, shape (n,) (default 0), so a margin can
            meet a partner at another distance from the axis.
        taper_share: ``q`` in (0, 1] of :func:`hinge_taper` (default 1): a vertex that turns by at least this
            share of the largest turn gets no wrinkle and no bulge (docs/RIG.md §11, §14).
        fit_limit: the largest ``K`` a fit may use (the solver's upper bound), > 0 (default 1: the full turn);
            presets and mappings stay within [0, 1] (docs/RIG.md §11, "Range in a fit").

    ``K`` is dimensionless (1: the full turn). The skin response of the Waters muscles does not apply:
    ``sliding``, ``bunching`` and ``thickening`` are 0 (the lid turns over the eyeball, on its surface).

    Raises:
        TypeError: a wrong name type. ValueError: non-finite, out-of-range or mismatched values.
    """

    name: str
    center: np.ndarray
    axis: np.ndarray
    vertices: np.ndarray
    angles: np.ndarray
    slides: np.ndarray | None = None
    lifts: np.ndarray | None = None
    taper_share: float = 1.0
    fit_limit: float = 1.0

    sliding = 0.0
    bunching = 0.0
    thickening = 0.0
    falloff = "smooth"

    def __post_init__(self) -> None:
        if not isinstance(self.name, str):
            raise TypeError(f"lid muscle: name must be a string, got {type(self.name).__name__}")
        label = f"lid muscle {self.name[:60]!r}"
        if not self.name:
            raise ValueError(f"{label}: name must be a non-empty string")
        set_ = object.__setattr__
        set_(self, "center", as_vec3(self.center, f"{label}: center"))
        set_(self, "axis", unit_vector(self.axis, f"{label}: axis"))
        vertices = np.asarray(self.vertices)
        if vertices.ndim != 1 or (vertices.size and not np.issubdtype(vertices.dtype, np.integer)):
            raise ValueError(f"{label}: vertices must be a 1-D array of ints, got {vertices.dtype} {vertices.shape}")
        vertices = vertices.astype(np.int64)
        if vertices.size and (vertices.min() < 0 or len(np.unique(vertices)) != len(vertices)):
            raise ValueError(f"{label}: vertices must be distinct and ≥ 0")
        angles = as_finite_array(self.angles, f"{label}: angles")
        if angles.shape != vertices.shape:
            raise ValueError(f"{label}: {angles.shape} angles for {vertices.shape} vertices")
        if angles.size and np.abs(angles).max() > MAX_LID_ANGLE:
            raise ValueError(f"{label}: angles must be within ±{MAX_LID_ANGLE:.4f} rad, got {np.abs(angles).max()}")
        set_(self, "vertices", vertices)
        set_(self, "angles", angles)
        for field in ("slides", "lifts"):
            value = getattr(self, field)
            value = np.zeros_like(angles) if value is None else as_finite_array(value, f"{label}: {field}")
            if value.shape != vertices.shape:
                raise ValueError(f"{label}: {value.shape} {field} for {vertices.shape} vertices")
            set_(self, field, value)
        set_(self, "taper_share", as_bounded(self.taper_share, f"{label}: taper_share", 0.0, 1.0))
        if self.taper_share == 0.0:
            raise ValueError(f"{label}: taper_share must be > 0")
        set_(self, "fit_limit", as_bounded(self.fit_limit, f"{label}: fit_limit", 0.0, MAX_FIT_LIMIT))
        if self.fit_limit == 0.0:
            raise ValueError(f"{label}: fit_limit must be > 0")

    @classmethod
    def pure_slide(cls, name: str, center, axis, amounts: np.ndarray) -> "LidMuscle":
        """A hinge that turns nothing: each vertex with ``amounts[v] > 0`` moves by ``amounts[v]`` along ``axis`` per
        unit ``K`` (``amounts``: (V,) [mesh units]; ``center`` plays no part in the field)."""
        amounts = np.asarray(amounts, dtype=np.float64)
        moved = np.flatnonzero(amounts > 0.0)
        return cls(name, center, axis, moved, np.zeros(len(moved)), slides=amounts[moved])

    @property
    def turns(self) -> bool:
        """Whether any vertex turns (False for :meth:`pure_slide` hinges)."""
        return bool(np.any(self.angles))

    def check_vertex_count(self, vertex_count: int) -> None:
        """Raise ValueError when a vertex index is outside a mesh of ``vertex_count`` points."""
        if self.vertices.size and self.vertices.max() >= vertex_count:
            raise ValueError(
                f"lid muscle {self.name!r}: vertex {int(self.vertices.max())} outside a mesh of {vertex_count} points"
            )


@wp.kernel
def _lid_field_kernel(
    rest: wp.array(dtype=wp.vec3d),
    vertices: wp.array(dtype=wp.int64),
    motion: wp.array(dtype=wp.vec3d),
    centre: wp.vec3d,
    axis: wp.vec3d,
    out: wp.array(dtype=wp.vec3d),
):
    k = wp.tid()  # motion[k] = (angle, slide, lift) of vertices[k]
    x = rest[vertices[k]]
    rotation = jaw_rotation(motion[k][0], axis)
    turned = wp.quat_rotate(rotation, x - centre)
    outward = unit_or_zero(turned - wp.dot(turned, axis) * axis)
    slide = jaw_slide(motion[k][2], motion[k][1], outward, axis)
    out[vertices[k]] = jaw_blend(x, wp.float64(1.0), centre, rotation, slide) - x


def lid_field(rest: wp.array, muscle: LidMuscle) -> np.ndarray:
    """The lid's weight field ``w`` at every rest point (``rest``: (V,) vec3d), shape (V, 3) float64."""
    out = wp.zeros(len(rest), dtype=wp.vec3d, device=rest.device)
    muscle.check_vertex_count(len(rest))
    if muscle.vertices.size:
        inputs = [
            rest,
            wp.array(muscle.vertices, dtype=wp.int64, device=rest.device),
            wp.array(
                np.stack([muscle.angles, muscle.slides, muscle.lifts], axis=1), dtype=wp.vec3d, device=rest.device
            ),
            wp.vec3d(*muscle.center),
            wp.vec3d(*muscle.axis),
        ]
        wp.launch(_lid_field_kernel, dim=len(muscle.vertices), inputs=inputs, outputs=[out], device=rest.device)
    return out.numpy()


def hinge_taper(vertex_count: int, muscles) -> np.ndarray:
    """Per vertex, ``1 − min(1, |θ_v| / (q · max |θ|))`` of the hinges (:class:`LidMuscle`, the lip seal too) among
    ``muscles`` that move it (the smallest where several do), 1 elsewhere, shape (V,); ``q`` is each hinge's
    ``taper_share``. It is 0 on a lid's margin (the default rig's lids: wherever the opening is at least ``q`` of
    its widest, as the margin turns by a share of the gap at its own x) and on the lips' contact line. The wrinkles
    fade by it (docs/RIG.md §14): a furrow's lift along the normal would otherwise open the lids a blink closes and
    push the lips through each other."""
    taper = np.ones(vertex_count)
    for muscle in muscles:
        if isinstance(muscle, LidMuscle) and len(muscle.vertices):
            turn = np.abs(muscle.angles)
            peak = float(turn.max()) * muscle.taper_share
            if peak > 0.0:
                taper[muscle.vertices] = np.minimum(taper[muscle.vertices], 1.0 - np.minimum(turn / peak, 1.0))
    return taper


def bulging_thickness(thickness: np.ndarray, muscles) -> np.ndarray:
    """The ``h`` the bulge (SPEC §1.3) applies, shape (V,) float64: ``thickness`` times the eyelid hinges'
    :func:`hinge_taper` (not the lip seal's: the lips have their own taper, docs/RIG.md §12–13), so the skin a
    blink gathers on a lid does not lift its margin off the other lid's."""
    from .seal import LipSeal

    thickness = np.asarray(thickness, dtype=np.float64)
    eyelids = [m for m in muscles if isinstance(m, LidMuscle) and not isinstance(m, LipSeal)]
    return thickness * hinge_taper(len(thickness), eyelids) if eyelids else thickness
