"""Named control sets for ARKit's skin-motion blendshapes on any landmark-rigged face (full anatomy).

Values are relative to the face like :data:`~warpface.assets.EXPRESSIONS`: a linear muscle's value
is its contraction in inter-ocular units, a sphincter's its dimensionless ``K``, ``jaw_open`` an angle
in radians and ``jaw_forward`` / ``jaw_left`` lengths in inter-ocular units. ``Left``/``Right`` are the
subject's sides (``_L``/``_R``). :func:`preset_controls` turns a preset into ``{control: value}`` for a
rig; the paper's four expressions are included under their own names. The presets of :data:`SEALED_PRESETS`
also get the lip seal's control at the share that holds the lips together against their jaw
(:func:`~warpface.assets.lips.closing_share`, docs/RIG.md §12).
"""

from __future__ import annotations

from types import MappingProxyType

from ..errors import RigError
from ..expression.muscles import LinearMuscle
from ..rig import FaceRig
from .expressions import EXPRESSIONS, check_named_request
from .lips import LIP_SEAL_NAME, closing_share
from .rig import rig_scale

__all__ = ["PRESETS", "ARKIT_PRESET_NAMES", "SEALED_PRESETS", "preset_controls"]

_SIDE_NAMES = (("Left", "L"), ("Right", "R"))


def _sided(template: dict[str, float], side: str) -> dict[str, float]:
    return {name.replace("{s}", side): value for name, value in template.items()}


_PER_SIDE = {
    "browDown": {"corrugator_{s}": 0.07, "depressor_supercilii_{s}": 0.09, "orbicularis_oculi_{s}": 0.06},
    "browOuterUp": {"frontalis_outer_{s}": 0.14, "frontalis_middle_{s}": 0.08},
    "eyeBlink": {"lid_upper_close_{s}": 1.0, "lid_lower_close_{s}": 1.0},
    "eyeSquint": {"orbicularis_oculi_lower_lid_{s}": 0.03, "orbicularis_oculi_{s}": 0.12},
    "eyeWide": {"lid_upper_raise_{s}": 1.0},
    "cheekSquint": {"orbicularis_oculi_{s}": 0.20, "zygomaticus_minor_{s}": 0.02},
    "noseSneer": {"levator_labii_alaeque_nasi_{s}": 0.11, "nasalis_{s}": 0.06},
    "mouthSmile": {"zygomaticus_major_{s}": 0.14, "levator_anguli_oris_{s}": 0.04, "orbicularis_oculi_{s}": 0.08},
    "mouthFrown": {"depressor_anguli_oris_{s}": 0.12, "platysma_{s}": 0.03},
    "mouthDimple": {"buccinator_{s}": 0.10},
    "mouthStretch": {"platysma_{s}": 0.10, "risorius_{s}": 0.06},
    "mouthPress": {"orbicularis_oris_press": 0.08, "buccinator_{s}": 0.06, "mentalis": 0.02},
    "mouthLowerDown": {"depressor_labii_inferioris_{s}": 0.10},
    "mouthUpperUp": {"levator_labii_superioris_{s}": 0.09, "zygomaticus_minor_{s}": 0.03},
}

_PRESETS: dict[str, dict[str, float]] = {}
for _name, _template in _PER_SIDE.items():
    for _word, _side in _SIDE_NAMES:
        _PRESETS[f"{_name}{_word}"] = _sided(_template, _side)
_PRESETS.update(
    {
        "browInnerUp": {
            "frontalis_inner_L": 0.14,
            "frontalis_inner_R": 0.14,
            "frontalis_middle_L": 0.05,
            "frontalis_middle_R": 0.05,
        },
        # No muscle puffs the cheeks (air does): the closest the rig comes is cheek tissue bunched out by the
        # orbital orbicularis oculi and zygomaticus minor with the lips pressed.
        "cheekPuff": {
            "orbicularis_oculi_L": 0.12,
            "orbicularis_oculi_R": 0.12,
            "zygomaticus_minor_L": 0.05,
            "zygomaticus_minor_R": 0.05,
            "orbicularis_oris_press": 0.08,
        },
        "jawOpen": {"jaw_open": 0.25},
        "jawForward": {"jaw_forward": 0.08},
        "jawLeft": {"jaw_left": 0.08},
        "jawRight": {"jaw_left": -0.08},
        "mouthClose": {"jaw_open": 0.12, "orbicularis_oris_press": 0.30, "mentalis": 0.04},
        "mouthFunnel": {"orbicularis_oris": 0.18, "jaw_open": 0.08},
        "mouthPucker": {"orbicularis_oris": 0.25, "orbicularis_oris_press": 0.08},
        # The mouth moves toward the subject's side: that corner drawn out and back.
        "mouthLeft": {"risorius_L": 0.10, "buccinator_L": 0.04},
        "mouthRight": {"risorius_R": 0.10, "buccinator_R": 0.04},
        # the lip hinges roll each lip into the mouth (docs/RIG.md §15), the Waters roll presses it
        "mouthRollLower": {"orbicularis_oris_roll_lower": 0.05, "lip_lower_roll_in_L": 1.0, "lip_lower_roll_in_R": 1.0},
        "mouthRollUpper": {"orbicularis_oris_roll_upper": 0.05, "lip_upper_roll_in_L": 1.0, "lip_upper_roll_in_R": 1.0},
        "mouthShrugLower": {"mentalis": 0.10},
        "mouthShrugUpper": {"mentalis": 0.05, "levator_labii_superioris_L": 0.03, "levator_labii_superioris_R": 0.03},
    }
)

ARKIT_PRESET_NAMES: tuple[str, ...] = tuple(sorted(_PRESETS))
"""The ARKit skin-motion shapes with a preset (eye-gaze and tongue shapes move no skin)."""

PRESETS = MappingProxyType({**{k: MappingProxyType(v) for k, v in sorted(_PRESETS.items())}, **EXPRESSIONS})
"""Preset name → {control: relative value}: the ARKit shapes, then the paper's four expressions. Read-only."""

_JAW_LENGTHS = ("jaw_forward", "jaw_left")
SEALED_PRESETS = frozenset({"mouthClose"})
"""Presets whose lips stay closed while the jaw opens (ARKit's mouthClose: the lips stretch to stay together)."""


def preset_controls(name: str, rig: FaceRig, *, intensity: float = 1.0) -> dict[str, float]:
    """The controls ``{muscle or jaw control: value}`` of a named preset on ``rig``.

    Raises:
        ValueError: unknown preset or non-finite intensity.
        RigError: the rig lacks a control of the preset (e.g. a classic rig without a jaw), or landmarks.
    """
    intensity = check_named_request("preset", name, PRESETS, rig, intensity)
    known = set(rig.control_names)
    missing = [control for control in PRESETS[name] if control not in known]
    if missing:
        raise RigError(f"rig {rig.name!r}: preset {name!r} needs control(s) {', '.join(missing)}")
    scale = rig_scale(rig)
    linear = {m.name for m in rig.muscles if isinstance(m, LinearMuscle)}
    controls = {
        control: value * intensity * (scale if control in linear or control in _JAW_LENGTHS else 1.0)
        for control, value in PRESETS[name].items()
    }
    if name in SEALED_PRESETS and LIP_SEAL_NAME in known:
        jaw = [controls.get(control, 0.0) for control in ("jaw_open", *_JAW_LENGTHS)]
        controls[LIP_SEAL_NAME] = closing_share(rig, jaw)
    return controls
