"""``validate``'s checks of a rig's face as a face: its landmarks in iBUG order, and a human size in the
stage's stated unit (a millimetre rig written without ``metersPerUnit`` reads as a head metres tall)."""

from __future__ import annotations

import math

import numpy as np

from ..errors import RigError
from ..landmarks import IBUG_COUNT, LEFT_EYE, RIGHT_EYE, check_layout
from ..rig import FaceRig
from ..rigging.units import PLAUSIBLE_RATIO, TYPICAL_EYE_DISTANCE, UNITS

__all__ = ["face_problems", "PLAUSIBLE_HEAD_EXTENT"]

PLAUSIBLE_HEAD_EXTENT = (0.03, 1.0)
"""Range [m] of the largest side of a skin's bounding box that passes when the rig has no 68 iBUG landmarks
(a patch of a face to a head with shoulders)."""

_LOG_PLAUSIBLE = math.log(PLAUSIBLE_RATIO)


def face_problems(rig: FaceRig, meters_per_unit: float, authored: bool, *, device=None) -> list[tuple[str, str]]:
    """(severity, message) findings about ``rig`` (read in metres) on a stage of ``meters_per_unit``.

    With 68 landmarks: their iBUG layout (error) and the inter-ocular distance against the human range
    (error, naming the unit that would fit); otherwise: the skin's extent (warning).
    """
    stated = f"metersPerUnit {meters_per_unit:g}" + ("" if authored else " (USD's fallback: not authored)")
    if rig.landmarks is None or len(rig.landmarks) != IBUG_COUNT:
        extent = float(np.ptp(rig.mesh.points, axis=0).max())
        low, high = PLAUSIBLE_HEAD_EXTENT
        if not low <= extent <= high:
            return [("warning", f"the skin is {extent:.3g} m across with {stated}: not a face's size")]
        return []
    problems = []
    marks = rig.mesh.points[rig.landmarks]
    front = np.asarray(rig.mesh.vertex_normals(device=device), dtype=np.float64)[rig.landmarks].sum(axis=0)
    try:
        check_layout(marks, front, label="landmarks")
    except RigError as exc:
        problems.append(("error", str(exc)))
    eyes = float(np.linalg.norm(marks[list(RIGHT_EYE)].mean(axis=0) - marks[list(LEFT_EYE)].mean(axis=0)))
    ratio = eyes / TYPICAL_EYE_DISTANCE
    if not (math.isfinite(ratio) and 1.0 / PLAUSIBLE_RATIO <= ratio <= PLAUSIBLE_RATIO):
        in_units = eyes / meters_per_unit
        fits = [n for n, v in UNITS.items() if abs(math.log(in_units * v / TYPICAL_EYE_DISTANCE)) <= _LOG_PLAUSIBLE]
        advice = (
            f"if the mesh is in {fits[0]}, author metersPerUnit = {UNITS[fits[0]]:g}"
            if fits
            else "rescale the mesh to m, cm or mm and author metersPerUnit"
        )
        problems.append(
            (
                "error",
                f"the eyes are {eyes:.3g} m apart with {stated}, so the head is ~{0.25 * ratio:.3g} m tall "
                f"(a human's is ~0.25 m); {advice}",
            )
        )
    return problems
