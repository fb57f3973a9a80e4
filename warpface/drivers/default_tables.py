"""The default channel → control tables for ARKit's 52 weights and FACS action units.

Weights are in face units, so one table serves every landmark-rigged face: a linear muscle's
contraction (a length) per unit channel is given in inter-ocular distances and scaled by the face's
size (:func:`~warpface.assets.rig_scale`) when the table is made for a rig; sphincter contractions
``K`` and the jaw's opening angle [rad] are dimensionless; jaw slides are lengths like muscles.
ARKit's ``Left``/``Right`` is the subject's side, the side of the rig's ``_L``/``_R`` muscles (+x is
the subject's left). Full strength (ARKit 1, AU intensity 5) gives the contractions of the built-in
expression presets: a broad smile is ~0.22 inter-ocular distances of zygomaticus pull.

Channels with no skin motion (gaze, ``tongueOut``) and ``cheekPuff`` (air, not muscle) have no row.
Jaw channels drive the jaw controls ``jaw_open``, ``jaw_forward`` and ``jaw_left`` (a signed lateral slide:
``jawRight`` is a negative ``jaw_left``); they take effect on rigs that have them and are reported as
unmapped on rigs that do not.
"""

from __future__ import annotations

from .._validate import expect_instance, expect_iterable
from ..rig import FaceRig
from .mapping import Mapping

__all__ = [
    "ARKIT_TABLE",
    "FACS_TABLE",
    "JAW_CONTROLS",
    "LENGTH_CONTROLS",
    "default_table",
    "mapping_for_rig",
    "rig_control_names",
    "control_scales",
]

JAW_CONTROLS = ("jaw_open", "jaw_forward", "jaw_left")
"""Jaw controls the tables name (SPEC §6.2): opening angle [rad], protrusion and lateral slides [lengths]."""

LENGTH_CONTROLS = frozenset({"jaw_forward", "jaw_left"})
"""Non-muscle controls whose values are lengths (scaled by the face's size like linear muscles)."""


def _channel(channel: str, rows) -> list[tuple[str, str, float]]:
    """One channel's rows; ``rows`` = [(muscle, w)], a ``muscle_{s}`` standing for its ``_L`` and ``_R`` pair."""
    return [
        (channel, muscle.format(s=tag), weight)
        for muscle, weight in rows
        for tag in (("L", "R") if "{s}" in muscle else ("",))
    ]


def _sided(stem: str, rows) -> list[tuple[str, str, float]]:
    """``stemLeft`` → the ``_L`` muscles, ``stemRight`` → the ``_R`` ones; ``rows`` = [(muscle or muscle_{s}, w)]."""
    out = []
    for arkit_side, tag in (("Left", "L"), ("Right", "R")):
        for muscle, weight in rows:
            out.append((f"{stem}{arkit_side}", muscle.format(s=tag), weight))
    return out


_BLINK = (("lid_upper_close", 1.0), ("lid_lower_close", 1.0), ("orbicularis_oculi", 0.03))
"""A blink (eyeBlink, AU43/45) per side: both lid hinges to their meeting line (docs/RIG.md §11) and a light squeeze
of the orbital ring, which is all a rig without lid hinges (the classic anatomy) has."""

ARKIT_TABLE: tuple[tuple[str, str, float], ...] = tuple(
    _sided("browDown", [("corrugator_{s}", 0.09), ("procerus", 0.03)])
    + _channel("browInnerUp", [("frontalis_inner_{s}", 0.16), ("frontalis_middle_{s}", 0.06)])
    + _sided("browOuterUp", [("frontalis_outer_{s}", 0.14), ("frontalis_middle_{s}", 0.08)])
    + _sided("cheekSquint", [("orbicularis_oculi_{s}", 0.16)])
    + _sided("eyeBlink", [(f"{control}_{{s}}", weight) for control, weight in _BLINK])
    + _sided("eyeSquint", [("orbicularis_oculi_{s}", 0.10), ("orbicularis_oculi_lower_lid_{s}", 0.025)])
    + _sided("eyeWide", [("lid_upper_raise_{s}", 1.0), ("frontalis_outer_{s}", 0.02), ("frontalis_inner_{s}", 0.015)])
    + [
        ("jawOpen", "jaw_open", 0.35),
        ("jawForward", "jaw_forward", 0.08),
        ("jawLeft", "jaw_left", 0.08),
        ("jawRight", "jaw_left", -0.08),
    ]
    + [
        ("mouthClose", "orbicularis_oris", 0.10),
        ("mouthFunnel", "orbicularis_oris", 0.30),
        ("mouthPucker", "orbicularis_oris", 0.45),
        ("mouthRollLower", "orbicularis_oris", 0.15),
        ("mouthRollUpper", "orbicularis_oris", 0.15),
    ]
    + _channel("mouthRollLower", [("lip_lower_roll_in_{s}", 1.0)])  # the lip hinges (docs/RIG.md §15)
    + _channel("mouthRollUpper", [("lip_upper_roll_in_{s}", 1.0)])
    + [
        ("mouthLeft", "risorius_L", 0.06),
        ("mouthLeft", "zygomaticus_major_L", 0.03),
        ("mouthRight", "risorius_R", 0.06),
        ("mouthRight", "zygomaticus_major_R", 0.03),
    ]
    + _sided("mouthSmile", [("zygomaticus_major_{s}", 0.22)])
    + _sided("mouthFrown", [("depressor_anguli_oris_{s}", 0.06)])
    + _sided("mouthDimple", [("risorius_{s}", 0.04)])
    + _sided("mouthStretch", [("risorius_{s}", 0.05), ("depressor_labii_inferioris_{s}", 0.02)])
    + _sided("mouthPress", [("orbicularis_oris", 0.05)])
    + _sided("mouthLowerDown", [("depressor_labii_inferioris_{s}", 0.06)])
    + _sided("mouthUpperUp", [("levator_labii_superioris_{s}", 0.06)])
    + [("mouthShrugLower", "mentalis", 0.05)]
    + _channel("mouthShrugUpper", [("levator_labii_superioris_{s}", 0.025), ("mentalis", 0.02)])
    + _sided("noseSneer", [("levator_labii_alaeque_nasi_{s}", 0.11)])
)
"""(ARKit channel, control, weight per unit weight) rows."""

_FACS_AT_FULL: tuple[tuple[str, str, float], ...] = tuple(
    _channel("AU01", [("frontalis_inner_{s}", 0.16), ("frontalis_middle_{s}", 0.06)])
    + _channel("AU02", [("frontalis_outer_{s}", 0.14), ("frontalis_middle_{s}", 0.08)])
    + _channel("AU04", [("corrugator_{s}", 0.09), ("procerus", 0.06)])
    + _channel("AU05", [("lid_upper_raise_{s}", 1.0), ("frontalis_outer_{s}", 0.02), ("frontalis_inner_{s}", 0.015)])
    + _channel("AU06", [("orbicularis_oculi_{s}", 0.22)])
    + _channel("AU07", [("orbicularis_oculi_{s}", 0.10), ("orbicularis_oculi_lower_lid_{s}", 0.025)])
    + _channel("AU09", [("levator_labii_alaeque_nasi_{s}", 0.11)])
    + _channel("AU10", [("levator_labii_superioris_{s}", 0.06)])
    + _channel("AU12", [("zygomaticus_major_{s}", 0.22)])
    + _channel("AU14", [("risorius_{s}", 0.04)])
    + _channel("AU15", [("depressor_anguli_oris_{s}", 0.06)])
    + _channel("AU16", [("depressor_labii_inferioris_{s}", 0.06)])
    + [("AU17", "mentalis", 0.05), ("AU18", "orbicularis_oris", 0.45)]
    + _channel("AU20", [("risorius_{s}", 0.06)])
    + [("AU22", "orbicularis_oris", 0.30), ("AU23", "orbicularis_oris", 0.15), ("AU24", "orbicularis_oris", 0.10)]
    + _channel("AU25", [("depressor_labii_inferioris_{s}", 0.03)])
    + [("AU26", "jaw_open", 0.25), ("AU27", "jaw_open", 0.45), ("AU28", "orbicularis_oris", 0.15)]
    + _channel("AU28", [("lip_upper_roll_in_{s}", 1.0), ("lip_lower_roll_in_{s}", 1.0)])
    + [row for au in ("AU43", "AU45") for row in _channel(au, [(f"{c}_{{s}}", w) for c, w in _BLINK])]
)

FACS_TABLE: tuple[tuple[str, str, float], ...] = tuple((au, control, w / 5.0) for au, control, w in _FACS_AT_FULL)
"""(action unit, control, weight per intensity unit) rows; intensity 5 gives the full pattern."""


def default_table(kind: str = "all") -> Mapping:
    """The default table in face units: ``"arkit"``, ``"facs"`` or ``"all"`` (both; their channels differ)."""
    tables = {"arkit": ARKIT_TABLE, "facs": FACS_TABLE, "all": ARKIT_TABLE + FACS_TABLE}
    if not isinstance(kind, str):
        raise TypeError(f"kind: expected one of {', '.join(tables)}, got {type(kind).__name__}")
    if kind not in tables:
        raise ValueError(f"kind: default table {kind[:40]!r}: expected one of {', '.join(tables)}")
    return Mapping.from_entries(tables[kind], name="default")


def rig_control_names(rig) -> list[str]:
    """The controls a :class:`~warpface.FaceRig` has, by name: its muscles' contractions.

    This is the one place that decides which table rows a rig keeps: when rigs gain a jaw (SPEC §6.2),
    its controls (:data:`JAW_CONTROLS`) join this list and the jaw rows of the tables take effect.
    """
    expect_instance(rig, FaceRig, "rig")
    return list(rig.control_names)


def control_scales(rig, controls) -> dict[str, float]:
    """Factor from face units to the rig's units per control: the face size for lengths, else 1."""
    expect_instance(rig, FaceRig, "rig")
    from ..assets.rig import rig_scale  # the assets package knows how to measure a landmarked face
    from ..expression.muscles import LinearMuscle

    linear = {m.name for m in rig.muscles if isinstance(m, LinearMuscle)} | set(LENGTH_CONTROLS)
    controls = list(expect_iterable(controls, "controls", item_types=str))
    needs_scale = [c for c in controls if c in linear]
    scale = rig_scale(rig) if needs_scale else 1.0
    return {c: (scale if c in linear else 1.0) for c in controls}


def mapping_for_rig(rig, kind: str = "all", *, name: str = "default") -> tuple[Mapping, list[str], list[str]]:
    """The default table in ``rig``'s units, keeping only controls the rig has.

    Returns:
        (mapping, controls the rig lacks, channels left with no control on this rig).

    Raises:
        RigError: a linear muscle is mapped but the rig has no landmarks to measure its size.
    """
    expect_instance(rig, FaceRig, "rig")
    table = default_table(kind)
    mapping, dropped, orphaned = table.restricted_to(rig_control_names(rig))
    scales = control_scales(rig, mapping.controls)
    factors = [scales[c] for c in mapping.controls]
    return (
        Mapping(
            channels=mapping.channels,
            controls=mapping.controls,
            matrix=mapping.matrix * [[f] for f in factors],
            offsets=mapping.offsets * factors,
            name=name,
        ),
        dropped,
        orphaned,
    )
