"""Landmark-relative changes to a rig's muscle geometry: the calibration's parameter vector (docs/RIG.md §13).

A :class:`Parameter` is one number of one muscle *group* (a muscle and its mirror twin share it: names
``x_L``/``x_R`` form group ``x``; the right side's local-x offsets are negated, so the rig stays
left/right symmetric). Values are in the :class:`~warpface.assets.frame.FaceFrame` of the rig's 68
landmarks (inter-ocular units) or are log-scales and additions, so a vector learnt on one face applies
to any face rigged from its landmarks. The zero vector leaves the rig unchanged.

    >>> layout = parameter_layout(rig)               # every parameter the rig's muscles offer
    >>> calibrated = apply_parameters(rig, {("zygomaticus_major", "insert_y"): 0.02})
"""

from __future__ import annotations

import json
import weakref
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..errors import RigError
from ..expression.muscles import LinearMuscle, SphincterMuscle
from ..rig import FaceRig
from .frame import FaceFrame, SurfaceSampler, check_landmarks
from .lids import LID_CONTROL_NAMES, LidShape, default_lids

__all__ = [
    "PARAMETER_FIELDS",
    "PRIOR_SIGMA",
    "Parameter",
    "parameter_layout",
    "apply_parameters",
    "muscle_group",
    "EVERY_MUSCLE",
    "EYELIDS",
    "WHOLE_RIG_KINDS",
    "SHARED_FIELDS",
    "CALIBRATED_ANATOMY",
    "load_calibrated_anatomy",
]

PARAMETER_FIELDS: dict[str, tuple[str, ...]] = {
    "linear": (
        "attach_x",
        "attach_y",
        "attach_z",
        "insert_x",
        "insert_y",
        "zone",
        "start",
        "finish",
        "sliding",
        "bunching",
    ),
    "sphincter": ("centre_x", "centre_y", "semi_x", "semi_y", "ring", "sliding", "bunching"),
    "lids": ("meet", "lower_reach", "raise", "radial_reach"),
}
"""The fields of each group kind (a new mechanism adds its kind, its fields and an ``_apply_*``)."""

EYELIDS = "eyelids"
"""The group of the default rig's six lid hinges (kind ``lids``): their shape constants, rebuilt from the landmarks
(:class:`~warpface.assets.lids.LidShape`); both eyes share it."""

WHOLE_RIG_KINDS = ("shared", "lids")
"""Kinds whose parameters move more than one muscle group's field (the grouped Jacobians give them whole-rig
columns)."""

EVERY_MUSCLE = "all"
"""The group whose values every muscle adds to its own (the fields of :data:`SHARED_FIELDS` it has): learnt from
every example, it carries to the muscles no example uses."""
SHARED_FIELDS = ("zone", "start", "finish", "sliding", "bunching", "semi_x", "semi_y")

PRIOR_SIGMA: dict[str, float] = {
    "attach_x": 0.06,
    "attach_y": 0.06,
    "attach_z": 0.06,
    "insert_x": 0.04,
    "insert_y": 0.04,
    "zone": 0.25,
    "start": 0.25,
    "finish": 0.25,
    "sliding": 0.25,
    "bunching": 0.5,
    "centre_x": 0.06,
    "centre_y": 0.06,
    "semi_x": 0.25,
    "semi_y": 0.25,
    "ring": 0.15,
    "meet": 0.05,
    "lower_reach": 0.25,
    "raise": 0.25,
    "radial_reach": 0.10,
}
"""Prior standard deviation of each field (inter-ocular units, log-scale or added value): the Gaussian prior
``(θ/σ)²`` that keeps the anatomy near the hand-placed one."""

CALIBRATED_ANATOMY = Path(__file__).with_name("calibrated_anatomy.json")
"""The default anatomy's calibrated parameters (docs/RIG.md §13), applied by ``default_rig``."""

_ZONE_DEG = (5.0, 170.0)
_SLIDING = (0.0, 1.0)
_BUNCHING = (0.0, 3.0)
_RING = (0.0, 0.9)
_MEET = (0.0, 0.5)


@dataclass(frozen=True)
class Parameter:
    """One calibration parameter: the muscle ``group`` (a name without ``_L``/``_R``), its ``kind`` and ``field``."""

    group: str
    kind: str
    field: str

    @property
    def key(self) -> tuple[str, str]:
        return (self.group, self.field)

    @property
    def sigma(self) -> float:
        return PRIOR_SIGMA[self.field]


def muscle_group(name: str) -> tuple[str, float]:
    """A muscle's group and side sign: ``("zygomaticus_major", +1)`` for ``zygomaticus_major_L``, −1 for
    ``_R``, 0 for a midline muscle."""
    if name.endswith("_L"):
        return name[:-2], 1.0
    if name.endswith("_R"):
        return name[:-2], -1.0
    return name, 0.0


def _kind(muscle) -> str | None:
    """The parameter kind of a Waters muscle; None for the lid hinges and the lip seal (not calibrated)."""
    if isinstance(muscle, LinearMuscle):
        return "linear"
    return "sphincter" if isinstance(muscle, SphincterMuscle) else None


def parameter_layout(rig: FaceRig, muscles=None, fields=None) -> list[Parameter]:
    """Every parameter of the rig's muscle groups (or of those named in ``muscles``; only ``fields`` when given),
    in rig order. Midline groups have no x offsets (they stay on the midline)."""
    wanted = None if muscles is None else set(muscles)
    chosen = None if fields is None else set(fields)
    layout, seen = [], set()
    if wanted is None or EVERY_MUSCLE in wanted:
        layout += [Parameter(EVERY_MUSCLE, "shared", f) for f in SHARED_FIELDS if not chosen or f in chosen]
    for muscle in rig.muscles:
        group, side = muscle_group(muscle.name)
        kind = _kind(muscle)
        if kind is None or group in seen or (wanted is not None and muscle.name not in wanted and group not in wanted):
            continue
        seen.add(group)
        for field in PARAMETER_FIELDS[kind]:
            if (side == 0.0 and field.endswith("_x") and field != "semi_x") or (chosen and field not in chosen):
                continue
            layout.append(Parameter(group, kind, field))
    if _has_default_lids(rig) and (wanted is None or EYELIDS in wanted or wanted & set(LID_CONTROL_NAMES)):
        layout += [Parameter(EYELIDS, "lids", f) for f in PARAMETER_FIELDS["lids"] if not chosen or f in chosen]
    return layout


def _has_default_lids(rig: FaceRig) -> bool:
    return set(LID_CONTROL_NAMES) <= set(rig.muscle_names)


_SAMPLERS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
"""mesh → (landmark bytes, frame, sampler): a calibration applies thousands of vectors to one rig's mesh."""


def _frame_of(rig: FaceRig, device) -> tuple[FaceFrame, SurfaceSampler]:
    if rig.landmarks is None or len(rig.landmarks) != 68:
        raise RigError(f"rig {rig.name!r}: calibration needs the 68 iBUG landmarks (the rig has none)")
    landmarks = check_landmarks(rig.mesh, rig.landmarks, label=f"rig {rig.name!r}: landmarks")
    cached = _SAMPLERS.get(rig.mesh)
    if cached is not None and cached[0] == landmarks.tobytes():
        return cached[1], cached[2]
    frame = FaceFrame.from_landmarks(rig.mesh.points[landmarks])
    sampler = SurfaceSampler(rig.mesh, frame, rig.mesh.vertex_normals(device=device))
    _SAMPLERS[rig.mesh] = (landmarks.tobytes(), frame, sampler)
    return frame, sampler


def _response(muscle, values: dict) -> dict:
    return dict(
        sliding=float(np.clip(muscle.sliding + values.get("sliding", 0.0), *_SLIDING)),
        # a scale, so a muscle whose skin must not bunch (bunching 0 by design) keeps 0
        bunching=float(np.clip(muscle.bunching * np.exp(values.get("bunching", 0.0)), *_BUNCHING)),
    )


def _apply_linear(muscle: LinearMuscle, side: float, values: dict, frame: FaceFrame, surface: SurfaceSampler):
    sign = 1.0 if side == 0.0 else side
    attachment = muscle.attachment
    shift = np.array([sign * values.get("attach_x", 0.0), values.get("attach_y", 0.0), values.get("attach_z", 0.0)])
    if np.any(shift):
        attachment = frame.to_world(frame.to_local(attachment) + shift)
    insertion = muscle.insertion
    move = np.array([sign * values.get("insert_x", 0.0), values.get("insert_y", 0.0)])
    if np.any(move):
        insertion = surface.point(frame.to_local(insertion)[:2] + move)
    stretch = float(np.linalg.norm(insertion - attachment) / np.linalg.norm(muscle.insertion - muscle.attachment))
    finish = muscle.falloff_finish * stretch * float(np.exp(values.get("finish", 0.0)))
    start = min(muscle.falloff_start * stretch * float(np.exp(values.get("start", 0.0))), 0.95 * finish)
    zone = float(np.clip(muscle.zone_angle_deg * np.exp(values.get("zone", 0.0)), *_ZONE_DEG))
    return replace(
        muscle,
        attachment=attachment,
        insertion=insertion,
        zone_angle_deg=zone,
        falloff_start=start,
        falloff_finish=finish,
        **_response(muscle, values),
    )


def _apply_sphincter(muscle: SphincterMuscle, side: float, values: dict, frame: FaceFrame, surface: SurfaceSampler):
    sign = 1.0 if side == 0.0 else side
    shift = np.array([sign * values.get("centre_x", 0.0), values.get("centre_y", 0.0), 0.0])
    centre = frame.to_world(frame.to_local(muscle.center) + shift) if np.any(shift) else muscle.center
    semi = (
        muscle.semi_axes[0] * float(np.exp(values.get("semi_x", 0.0))),
        muscle.semi_axes[1] * float(np.exp(values.get("semi_y", 0.0))),
    )
    ring = float(np.clip(muscle.ring + values.get("ring", 0.0), *_RING))
    return replace(muscle, center=centre, semi_axes=semi, ring=ring, **_response(muscle, values))


_APPLY = {"linear": _apply_linear, "sphincter": _apply_sphincter}


def apply_parameters(rig: FaceRig, values, *, device=None) -> FaceRig:
    """``rig`` with its muscles changed by ``values``: ``{(group, field): value}`` (missing = 0); ``device``: Warp
    device of the vertex normals.

    Raises:
        RigError: the rig has no 68 landmarks; a group no muscle of the rig has; an unknown field.
    """
    values = {tuple(key): float(value) for key, value in dict(values).items() if float(value) != 0.0}
    if not values:
        return rig
    groups = {muscle_group(m.name)[0]: _kind(m) for m in rig.muscles if _kind(m) is not None}
    if _has_default_lids(rig):
        groups[EYELIDS] = "lids"
    shared = {field: value for (group, field), value in values.items() if group == EVERY_MUSCLE}
    unknown = [field for field in shared if field not in SHARED_FIELDS]
    if unknown:
        raise RigError(f"calibrated parameters: the group {EVERY_MUSCLE!r} has no field {unknown[0]!r}")
    by_group: dict[str, dict[str, float]] = {}
    for (group, field), value in values.items():
        if group == EVERY_MUSCLE:
            continue
        if group not in groups:
            if group == EYELIDS:
                raise RigError(f"calibrated parameters: rig {rig.name!r} has not the default rig's lid hinges")
            raise RigError(f"calibrated parameters: rig {rig.name!r} has no muscle group {group!r}")
        if field not in PARAMETER_FIELDS[groups[group]]:
            raise RigError(f"calibrated parameters: {groups[group]} muscle {group!r} has no field {field!r}")
        if not np.isfinite(value):
            raise RigError(f"calibrated parameters: {group}.{field} is not finite")
        by_group.setdefault(group, {})[field] = value
    frame, surface = _frame_of(rig, device)
    muscles = []
    for muscle in rig.muscles:
        group, side = muscle_group(muscle.name)
        kind = _kind(muscle)
        if kind is None:
            muscles.append(muscle)
            continue
        changes = {f: v for f, v in shared.items() if f in PARAMETER_FIELDS[kind]}
        for field, value in by_group.get(group, {}).items():
            changes[field] = changes.get(field, 0.0) + value
        muscles.append(_APPLY[kind](muscle, side, changes, frame, surface) if changes else muscle)
    if EYELIDS in by_group:
        muscles = _rebuilt_lids(rig, muscles, by_group[EYELIDS], frame)
    return replace(rig, muscles=muscles)


def _rebuilt_lids(rig: FaceRig, muscles: list, values: dict, frame: FaceFrame) -> list:
    """``muscles`` with the six lid hinges rebuilt from the landmarks with the ``eyelids`` values (docs/RIG.md §13);
    each keeps the ``fit_limit`` and ``taper_share`` of the hinge it replaces."""
    base = LidShape()
    lower, radial = (float(np.exp(values.get(name, 0.0))) for name in ("lower_reach", "radial_reach"))
    shape = replace(
        base,
        lower_share=float(np.clip(base.lower_share + values.get("meet", 0.0), *_MEET)),
        raise_share=float(min(base.raise_share * np.exp(values.get("raise", 0.0)), 1.0)),
        lower_band=(base.lower_band[0] * lower, base.lower_band[1] * lower),
        radial_band=(base.radial_band[0] * radial, base.radial_band[1] * radial),
    )
    rebuilt = {m.name: m for m in default_lids(rig.mesh, frame, rig.landmarks, shape)}
    return [
        replace(rebuilt[m.name], fit_limit=m.fit_limit, taper_share=m.taper_share) if m.name in rebuilt else m
        for m in muscles
    ]


def load_calibrated_anatomy(path=CALIBRATED_ANATOMY) -> dict[tuple[str, str], float]:
    """The parameters stored in a calibration file (``{"parameters": {group: {field: value}}}``); {} if absent."""
    path = Path(path)
    if not path.is_file():
        return {}
    data = json.loads(path.read_text())
    return {
        (group, field): float(v) for group, fields in data.get("parameters", {}).items() for field, v in fields.items()
    }
