"""The default rig's lip seal (docs/RIG.md §12), placed from the inner-lip landmarks.

In the :class:`~warpface.assets.frame.FaceFrame` (inter-ocular units): the *contact line* runs through
the mouth corners (iBUG 60, 64) and the midpoints of the inner-lip pairs 61/67, 62/66, 63/65; ``φ`` is a
point's height below it. The seal's field turns the upper lip up and the lower lip down by
:data:`PART_ANGLE` about the frame's x axis through a pivot :data:`PIVOT_DEPTH` behind the mouth, faded
(C¹, cos²) with ``|φ|`` over :data:`PART_BAND` and toward the corners over :data:`CORNER_BAND` (of the
mouth's half-width), and 0 beyond :data:`REACH` from the mouth's centre; which lip a point is on is the sign of
``φ`` with the jaw's lip-side term (:func:`~warpface.assets.jaw.lip_sided`: the mouth's rim, or a closed mouth's
slit, decides near the mouth). Its pairs are the inner-lip pairs the field parts (on a closed-mouth scan a pair
may share a vertex; that pair is left out) and, on a closed mouth's slit, the facing vertices across it in the
mouth's central half.
:func:`lip_margin_taper` is the share of the bulging thickness the rig keeps near the contact line;
:func:`closing_share` is the seal's (negative) share that holds the lips together against an open jaw (mouthClose).
"""

from __future__ import annotations

import numpy as np
import warp as wp
from scipy.spatial import cKDTree

from ..expression.jaw import Jaw, jaw_points
from ..expression.lids import lid_field
from ..expression.seal import LipSeal
from ..geometry.ramps import smooth_ramp
from ..mesh import FaceMesh
from .frame import FaceFrame
from .jaw import SLIT_GAP, lip_sided, mouth_rim_arcs, slit_faces

__all__ = [
    "band_fade",
    "contact_line",
    "closing_share",
    "closing_shares",
    "mouth_close_shares",
    "default_lip_seal",
    "lip_margin_taper",
    "LIP_SEAL_NAME",
    "PART_ANGLE",
    "PIVOT_DEPTH",
]

LIP_SEAL_NAME = "lips_part"
"""The seal's control: ``K = 1`` parts the lips by about :data:`PART_ANGLE` × :data:`PIVOT_DEPTH` each."""
PART_ANGLE = 0.05
"""Turn of each lip per unit K [rad]: ~0.03 inter-ocular units (2 mm) at the lip margin."""
PIVOT_DEPTH = 0.6
"""Depth of the parting axis behind the inner-lip landmarks [inter-ocular units]."""
PART_BAND = (0.03, 0.22)
"""``|φ|`` [inter-ocular units] over which a lip turns fully, then the height over which the turn fades."""
CORNER_BAND = (0.5, 0.5)
"""Distance from the mouth's centre [half-widths] turning fully, then the distance over which it fades."""
REACH = 0.6
"""Nothing farther than this from the mouth's centre turns [inter-ocular units] (a whole head's back)."""
MARGIN_BAND = 0.10
"""Distance from the lips' contact line [inter-ocular units] over which the bulging thickness returns."""
SLIT_PAIR_TURN = 1.0
"""A closed mouth's slit pairs are kept where the seal's corner fade is at least this share of its full turn."""
_PAIRS = ((61, 67), (62, 66), (63, 65))


def band_fade(t: np.ndarray, band: tuple[float, float]) -> np.ndarray:
    """1 for ``t ≤ band[0]``, ``cos²`` down to 0 at ``band[0] + band[1]``, 0 beyond (C¹), shape of ``t``."""
    s = np.clip((t - band[0]) / band[1], 0.0, 1.0)
    return np.cos(0.5 * np.pi * s) ** 2


def contact_line(mesh: FaceMesh, frame: FaceFrame, landmarks: np.ndarray):
    """In the face frame [inter-ocular units]: the local points (V, 3), their height φ below the lips' contact line
    (V,), the line's mean point (3,) and the mouth's half-width."""
    local = frame.to_local(mesh.points)
    marks = local[landmarks]
    contact = np.array([marks[60], *(0.5 * (marks[a] + marks[b]) for a, b in _PAIRS), marks[64]])
    order = np.argsort(contact[:, 0])
    below = np.interp(local[:, 0], contact[order, 0], contact[order, 1]) - local[:, 1]
    return local, below, contact.mean(axis=0), 0.5 * abs(marks[64, 0] - marks[60, 0])


def lip_margin_taper(mesh: FaceMesh, frame: FaceFrame, landmarks: np.ndarray) -> np.ndarray:
    """Per vertex (V,) in [0, 1]: the share of the bulging thickness the default rig keeps near the lips' contact
    line: a C¹ smoothstep of the distance from the line's segment between the corners over :data:`MARGIN_BAND`
    (0 on it, 1 beyond). The bulge moves skin along its normal, which at the lips' free margins points at the
    other lip: with the lips' full 3.6 mm it pushed them through each other by up to 7.7 mm (docs/RIG.md §12)."""
    local, below, middle, half_width = contact_line(mesh, frame, landmarks)
    beyond = np.maximum(np.abs(local[:, 0] - middle[0]) - half_width, 0.0)
    return smooth_ramp(0.0, MARGIN_BAND, np.hypot(below, beyond))


def _slit_pairs(mesh: FaceMesh, frame: FaceFrame, local: np.ndarray, landmarks: np.ndarray) -> list[tuple[int, int]]:
    """On a closed mouth's slit (:func:`~warpface.assets.jaw.slit_faces`; none where the mesh has a mouth opening):
    each vertex of the upper lip's facing surface with the nearest vertex of the lower lip's, both ways, within
    the slit's gap: the pairs that face each other across the contact line where the landmarks lie off it."""
    if mouth_rim_arcs(mesh, local, landmarks) is not None:
        return []
    faces = slit_faces(mesh, local, landmarks, frame.axes[1])
    if faces is None:
        return []
    upper, lower = faces
    found = []
    for mine, other, flip in ((upper, lower, False), (lower, upper, True)):
        distance, nearest = cKDTree(local[other]).query(local[mine])
        close = distance < SLIT_GAP
        a, b = np.asarray(mine)[close], np.asarray(other)[nearest][close]
        found.append(np.stack([b, a] if flip else [a, b], axis=1))
    return [(int(a), int(b)) for a, b in np.unique(np.concatenate(found), axis=0)]


def default_lip_seal(mesh: FaceMesh, frame: FaceFrame, landmarks: np.ndarray) -> LipSeal | None:
    """The default rig's :class:`~warpface.expression.LipSeal` on a face (module docstring), or None when no
    inner-lip pair can be parted (all of them share a vertex)."""
    local, below, middle, half_width = contact_line(mesh, frame, landmarks)
    lateral = band_fade(np.abs(local[:, 0] - middle[0]) / half_width, CORNER_BAND)
    near = np.linalg.norm(local - middle, axis=1) < REACH
    turn = PART_ANGLE * lateral * band_fade(np.abs(below), PART_BAND) * near
    # each lip turns its own way, also where a closed mouth's slit lies off the landmarks' line (docs/RIG.md §12)
    sided = lip_sided(mesh, frame, local, landmarks, below)
    angles = np.where(sided < 0.0, -turn, turn)  # a positive turn about +x moves a point in front down
    pairs = [(landmarks[a], landmarks[b]) for a, b in _PAIRS if angles[landmarks[a]] < 0.0 < angles[landmarks[b]]]
    full = lateral >= SLIT_PAIR_TURN  # a pair the seal hardly parts would ask for a large share of it
    slit = _slit_pairs(mesh, frame, local, landmarks)
    pairs += [(u, l) for u, l in slit if angles[u] < 0.0 < angles[l] and full[u] and full[l]]
    if not pairs:
        return None
    moved = np.flatnonzero(angles != 0.0)
    centre = frame.to_world([middle[0], middle[1], middle[2] - PIVOT_DEPTH])
    return LipSeal(LIP_SEAL_NAME, centre, frame.axes[0], moved, angles[moved], pairs=np.array(pairs))


def closing_share(rig, jaw_controls) -> float:
    """The seal's share ``a ≤ 0`` that holds the lips together against the jaw at ``jaw_controls`` (docs/RIG.md §12):
    with ``g_i`` the height of seal pair ``i``'s upper point above its lower one at the jaw's pose and ``δ_i`` the
    seal field's parting of the pair, both along the face's up axis, ``a = min(0, maxᵢ −g_i / δ_i)`` — the seal's
    field run backwards by the least share that brings a pair to contact, so none passes its partner. 0 without a
    seal or a jaw.

    Args:
        rig: a :class:`~warpface.rig.FaceRig`.
        jaw_controls: ``(jaw_open [rad], jaw_forward, jaw_left)`` [mesh units], shape (3,).
    """
    return float(closing_shares(rig, np.reshape(jaw_controls, (1, 3)))[0])


def closing_shares(rig, jaw_controls) -> np.ndarray:
    """:func:`closing_share` of each row of ``jaw_controls`` (F, 3), shape (F,); only the seal pairs' vertices are
    posed, so a take's every frame costs little."""
    jaw_controls = np.asarray(jaw_controls, dtype=np.float64).reshape(-1, 3)
    seal = next((m for m in rig.muscles if isinstance(m, LipSeal)), None)
    if seal is None or rig.jaw is None:
        return np.zeros(len(jaw_controls))
    rest = rig.mesh.points
    up = FaceFrame.from_landmarks(rest[rig.landmarks]).axes[1]
    parting = lid_field(wp.array(rest, dtype=wp.vec3d, device="cpu"), seal) @ up
    upper, lower = seal.pairs[:, 0], seal.pairs[:, 1]
    apart = parting[upper] - parting[lower]
    moved = apart > 0.0  # a slit pair the field parts mostly in depth bounds nothing here
    if not moved.any():
        return np.zeros(len(jaw_controls))
    ends = np.concatenate([upper[moved], lower[moved]])
    jaw = Jaw(rig.jaw.pivot, rig.jaw.axis, rig.jaw.forward, rig.jaw.weights[ends])
    count = int(moved.sum())
    shares = np.zeros(len(jaw_controls))
    for f, pose in enumerate(jaw_controls):
        posed = jaw_points(jaw, rest[ends], pose) @ up
        shares[f] = min(0.0, float(np.max(-(posed[:count] - posed[count:]) / apart[moved])))
    return shares


def mouth_close_shares(rig, jaw_controls, mouth_close, jaw_open) -> np.ndarray:
    """The seal's control per frame for ARKit's ``mouthClose`` ``c`` over ``jawOpen`` ``j`` (channel weights (F,)
    each; docs/RIG.md §12), shape (F,): with ``a(θ)`` the :func:`closing_share` at the frame's jaw pose ``θ`` (the
    jaw's controls (F, 3)) and ``a₀`` at rest,

    ``s = max(a(θ), min(1, c / j) · (a(θ) − a₀) + c · a₀)``,  ``c`` clipped to [0, 1] (``c / j`` = 1 where ``j`` = 0)

    — the jaw's parting closed in the ratio of the channels (all of it where ``c ≥ j``: the preset's seal) and a lip
    gap the face has at rest closed in proportion to ``c``, never beyond contact. 0 where ``c`` is 0."""
    close = np.clip(np.asarray(mouth_close, dtype=np.float64), 0.0, 1.0)
    opened = np.asarray(jaw_open, dtype=np.float64)
    ratio = np.divide(close, np.maximum(opened, close), out=np.zeros_like(close), where=close > 0.0)
    shares = np.zeros(len(ratio))
    on = np.flatnonzero(close > 0.0)
    if len(on):
        poses = np.asarray(jaw_controls, dtype=np.float64).reshape(-1, 3)[on]
        closing = closing_shares(rig, np.concatenate([np.zeros((1, 3)), poses]))
        rest, posed = closing[0], closing[1:]
        shares[on] = np.maximum(posed, ratio[on] * (posed - rest) + close[on] * rest)
    return shares
