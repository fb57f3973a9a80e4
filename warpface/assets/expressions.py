"""The paper's four expressions as muscle-contraction presets, and smooth animations of them.

Presets are written relative to the face: a **linear** muscle's value is its contraction ``K``
(a displacement) in units of the face's inter-ocular distance, so a preset means the same on a
face in metres or centimetres; a **sphincter**'s value is its dimensionless ``K`` as is.
:func:`expression_contractions` turns a preset into ``{muscle: K}`` for a given rig.
"""

from __future__ import annotations

from types import MappingProxyType

import numpy as np

from .._validate import as_count, as_finite_array, as_positive, expect_instance
from ..errors import RigError
from ..expression.muscles import LinearMuscle
from ..rig import FaceRig
from .rig import rig_scale

__all__ = ["EXPRESSIONS", "expression_contractions", "expression_timeline", "expression_envelope"]

MAX_TIMELINE_FRAMES = 1_000_000
"""Most frames an expression timeline or envelope is made with (9 h at 30 fps)."""

EXPRESSIONS = MappingProxyType(
    {
        # Raise the brows (AU1 + AU2): frontalis, inner and outer.
        "thinking": MappingProxyType(
            {
                "frontalis_inner_L": 0.16,
                "frontalis_inner_R": 0.16,
                "frontalis_outer_L": 0.13,
                "frontalis_outer_R": 0.13,
            }
        ),
        # Knit the brows (AU4): corrugators pull them together and down, the procerus lowers the
        # glabella, the eyes narrow slightly.
        "puzzled": MappingProxyType(
            {
                "corrugator_L": 0.09,
                "corrugator_R": 0.09,
                "procerus": 0.07,
                "orbicularis_oculi_L": 0.10,
                "orbicularis_oculi_R": 0.10,
            }
        ),
        # Raise the nose and upper lip (AU9 + AU10), lower the brows (AU4), narrow the eyes.
        "disgust": MappingProxyType(
            {
                "levator_labii_alaeque_nasi_L": 0.11,
                "levator_labii_alaeque_nasi_R": 0.11,
                "levator_labii_superioris_L": 0.06,
                "levator_labii_superioris_R": 0.06,
                "corrugator_L": 0.08,
                "corrugator_R": 0.08,
                "procerus": 0.10,
                "orbicularis_oculi_L": 0.15,
                "orbicularis_oculi_R": 0.15,
                "depressor_anguli_oris_L": 0.04,
                "depressor_anguli_oris_R": 0.04,
                "mentalis": 0.035,
            }
        ),
        # Pull the mouth corners up and back (AU12), raise the cheeks and narrow the eyes (AU6).
        "smile": MappingProxyType(
            {
                "zygomaticus_major_L": 0.22,
                "zygomaticus_major_R": 0.22,
                "risorius_L": 0.04,
                "risorius_R": 0.04,
                "levator_labii_superioris_L": 0.03,
                "levator_labii_superioris_R": 0.03,
                "orbicularis_oculi_L": 0.26,
                "orbicularis_oculi_R": 0.26,
            }
        ),
    }
)
"""Expression name → {muscle name: relative contraction} (linear muscles in inter-ocular units,
sphincters dimensionless). Read-only."""


def check_named_request(kind: str, name, table, rig, intensity) -> float:
    """The checks of a named request (``kind``: "expression" or "preset") on ``rig``: ``rig`` a FaceRig,
    ``name`` a key of ``table``; returns ``intensity`` as a finite float."""
    expect_instance(rig, FaceRig, "rig")
    if not isinstance(name, str):
        raise TypeError(f"{kind} name: expected a str, got {type(name).__name__}")
    if name not in table:
        raise ValueError(f"unknown {kind} {name!r} (known: {', '.join(table)})")
    intensity = float(as_finite_array(intensity, f"{kind} {name!r}: intensity", shape=()))
    if not np.isfinite(intensity):
        raise ValueError(f"{kind} {name!r}: intensity must be finite, got {intensity}")
    return intensity


def expression_contractions(name: str, rig: FaceRig, *, intensity: float = 1.0) -> dict[str, float]:
    """The contractions ``{muscle: K}`` of a named expression on ``rig``.

    Args:
        name: one of :data:`EXPRESSIONS`.
        rig: a rig carrying the preset's muscles and its 68 landmarks (for the face's size).
        intensity: scales every contraction (1 = the preset, 0 = neutral).

    Raises:
        ValueError: unknown expression or non-finite intensity.
        RigError: the rig lacks one of the preset's muscles, or its landmarks.
    """
    intensity = check_named_request("expression", name, EXPRESSIONS, rig, intensity)
    muscles = {m.name: m for m in rig.muscles}
    missing = [muscle for muscle in EXPRESSIONS[name] if muscle not in muscles]
    if missing:
        raise RigError(f"rig {rig.name!r}: expression {name!r} needs muscle(s) {', '.join(missing)}")
    scale = rig_scale(rig)
    return {
        muscle: value * intensity * (scale if isinstance(muscles[muscle], LinearMuscle) else 1.0)
        for muscle, value in EXPRESSIONS[name].items()
    }


def expression_envelope(frames: int, hold: float = 0.2) -> np.ndarray:
    """Weights neutral → 1 → neutral over ``frames`` samples, shape (frames,), float64.

    The rise and fall are quintic smoothsteps (zero velocity and acceleration at both ends of each
    ramp); the peak is held for the fraction ``hold`` ∈ [0, 1) of the span. First and last are 0.
    """
    frames = as_count(frames, "expression envelope: frames", minimum=2, maximum=MAX_TIMELINE_FRAMES)
    hold = float(as_finite_array(hold, "expression envelope: hold", shape=()))
    if not 0.0 <= hold < 1.0:
        raise ValueError(f"expression envelope: hold must be in [0, 1), got {hold}")
    t = np.linspace(0.0, 1.0, frames)
    ramp = 0.5 * (1.0 - hold)
    s = np.clip(np.minimum(t, 1.0 - t) / ramp, 0.0, 1.0)
    return s * s * s * (s * (6.0 * s - 15.0) + 10.0)


def expression_timeline(
    name: str, rig: FaceRig, seconds: float = 2.0, fps: float = 30.0, *, hold: float = 0.2, intensity: float = 1.0
) -> np.ndarray:
    """Per-frame contractions for neutral → ``name`` → neutral, shape (F, M), in the rig's muscle order
    (the paper's expressions use muscles only; append zeros for a jaw's controls to evaluate them).

    ``F = round(seconds · fps) + 1`` frames: frame ``f`` is at time ``f / fps``, and both the first
    and the last frame are neutral. Feed it to :meth:`~warpface.ExpressionModel.evaluate`.
    """
    expect_instance(rig, FaceRig, "rig")
    seconds = as_positive(seconds, "expression timeline: seconds", maximum=1e6)
    fps = as_positive(fps, "expression timeline: fps", maximum=1e4)
    frames = int(round(seconds * fps)) + 1
    if frames > MAX_TIMELINE_FRAMES:
        raise ValueError(
            f"expression timeline: {seconds:g} s at {fps:g} fps is {frames} frames, more than {MAX_TIMELINE_FRAMES}"
        )
    peak = np.zeros(len(rig.muscles))
    index = {m.name: i for i, m in enumerate(rig.muscles)}
    for muscle, value in expression_contractions(name, rig, intensity=intensity).items():
        peak[index[muscle]] = value
    return expression_envelope(frames, hold)[:, None] * peak[None, :]
