"""The default rig's muscles beyond thesis table 2.1: FACS/ARKit skin motion the classic 23 cannot make.

Placed like the classic muscles (:mod:`warpface.assets.rig`): local ``(x, y)`` in the face frame,
inter-ocular units, relative to the 68 iBUG landmarks; bone attachments beneath the skin along
−normal. Each entry names its anatomy and the action units it serves.

Linear, per side:

- frontalis, middle belly: galea over the mid-forehead → skin above the brow's midpoint (AU1 + AU2,
  ``browInnerUp``, ``browOuterUp``), between the classic inner and outer bellies;
- depressor supercilii: medial orbital rim → skin of the brow head, down (AU4, ``browDown``);
- levator anguli oris: canine fossa → mouth corner, straight up (AU13, ``mouthSmile``, ``cheekPuff``);
- zygomaticus minor: zygomatic bone → lateral upper lip, up and out (AU11, ``mouthUpper``);
- buccinator: pterygomandibular raphe (deep, at mouth level) → mouth corner, back (AU14, dimple);
- platysma: fascia over the lower mandible → lip corner and lower lip, down and out (AU20/AU25,
  ``mouthStretch``, ``mouthLower``); its wide zone reaches the jaw line and lower cheek;
- nasalis: maxilla beside the nose wing → side of the nose, up and in (AU9, ``noseSneer``);
- orbicularis oculi palpebral part, per lid (upper: AU45 ``eyeBlink``; lower: AU7 ``eyeSquint``), and the
  levator palpebrae superioris that opens the upper lid (AU5, ``eyeWide``);
- orbicularis oris roll, upper and lower lip: a bone point behind the lips' contact line → the
  vermilion, rolling each lip in (AU28, ``mouthRollUpper/Lower``).

Sphincters (replacing the classic lateral orbicularis oculi):

- orbicularis oculi orbital part, per side: a ring (:data:`ORBITAL_RING`) centred between the eye and its
  medial canthus (the fibres arise from the medial orbital margin and the medial palpebral ligament, so
  the skin around the eye is drawn toward it: cheek up, brow tail down, temple skin medially — AU6,
  ``cheekSquint``); the lids inside the ring are left to the palpebral part;
- orbicularis oris press: a flat ellipse on the lips' contact line that presses the lips together
  (AU24, ``mouthPress``, ``mouthClose``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..expression.muscles import LinearMuscle, MuscleLobe, SphincterMuscle
from ..landmarks import IBUG_MIRROR
from .frame import FaceFrame, SurfaceSampler

__all__ = [
    "ANATOMY_LINEAR_MUSCLE_NAMES",
    "ANATOMY_SPHINCTER_MUSCLE_NAMES",
    "anatomy_muscles",
    "revised_classic_muscles",
]

_SIDES = (("L", +1.0), ("R", -1.0))
# iBUG indices per side: brow inner end, eye inner/outer corner, eye ring, nose wing, mouth corner,
# upper-lip border point, lower-lip border point, jaw outline at mouth level, jaw outline below the corner;
# the right side's are the left side's mirror twins.
_LEFT_LANDMARKS = dict(
    brow_inner=22,
    brow_middle=24,
    eye_inner=42,
    eye_outer=45,
    eye=tuple(range(42, 48)),
    wing=35,
    corner=54,
    upper=52,
    lower=56,
    jaw_mouth=12,
    jaw_low=10,
)


def _mirrored(index):
    """The mirror twin of an iBUG index, or the sorted twins of a tuple of them."""
    if isinstance(index, tuple):
        return tuple(sorted(int(IBUG_MIRROR[i]) for i in index))
    return int(IBUG_MIRROR[index])


_LANDMARKS = {"L": _LEFT_LANDMARKS, "R": {name: _mirrored(index) for name, index in _LEFT_LANDMARKS.items()}}

ANATOMY_LINEAR_MUSCLE_NAMES: tuple[str, ...] = (
    *(f"frontalis_middle_{s}" for s, _ in _SIDES),
    *(f"depressor_supercilii_{s}" for s, _ in _SIDES),
    *(f"levator_anguli_oris_{s}" for s, _ in _SIDES),
    *(f"zygomaticus_minor_{s}" for s, _ in _SIDES),
    *(f"buccinator_{s}" for s, _ in _SIDES),
    *(f"platysma_{s}" for s, _ in _SIDES),
    *(f"nasalis_{s}" for s, _ in _SIDES),
    *(f"orbicularis_oculi_upper_lid_{s}" for s, _ in _SIDES),
    *(f"orbicularis_oculi_lower_lid_{s}" for s, _ in _SIDES),
    *(f"levator_palpebrae_{s}" for s, _ in _SIDES),
    "orbicularis_oris_roll_upper",
    "orbicularis_oris_roll_lower",
    *(f"orbicularis_oculi_brow_{s}" for s, _ in _SIDES),
)
"""Linear muscles added by the full anatomy, in rig order."""

ANATOMY_SPHINCTER_MUSCLE_NAMES: tuple[str, ...] = ("orbicularis_oris_press",)
"""Sphincters added by the full anatomy (the orbital orbicularis oculi keeps its classic name)."""


def linear_muscle(
    name, surface: SurfaceSampler, origin_xy, depth, insertion_xy, zone_deg, start, finish
) -> LinearMuscle:
    """A Waters muscle from a bone point ``depth`` units beneath ``origin_xy`` to the skin at ``insertion_xy``;
    ``start`` and ``finish`` are the fall-off radii as fractions of the muscle's length."""
    attachment = surface.below(origin_xy, depth)
    insertion = surface.point(insertion_xy)
    length = float(np.linalg.norm(insertion - attachment))
    return LinearMuscle(name, attachment, insertion, zone_deg, start * length, finish * length)


def linear_muscles(surface: SurfaceSampler, ends: dict, pulls: dict, *, suffix: str = "") -> dict[str, LinearMuscle]:
    """:func:`linear_muscle` s by name (``name + suffix``), from two tables: ``ends``, name → (origin_xy,
    insertion_xy), and ``pulls``, name → (depth, zone_deg, start, finish)."""
    muscles = {}
    for name, (origin_xy, insertion_xy) in ends.items():
        depth, zone_deg, start, finish = pulls[name]
        muscles[name + suffix] = linear_muscle(
            name + suffix, surface, origin_xy, depth, insertion_xy, zone_deg, start, finish
        )
    return muscles


ORBITAL_SEMI_AXES = (0.95, 0.70)
"""Semi-axes (across, up) of the orbital orbicularis oculi [inter-ocular units]: its pull reaches the
upper cheek below and lateral of the eye, where a squint (AU6) moves the skin most (docs/RIG.md §5)."""
ORBITAL_CENTRE = 0.30
"""Where the orbital orbicularis oculi is centred, as a fraction of the way from the eye's centre to its
medial canthus: its fibres arise from the medial orbital margin and the medial palpebral ligament."""

FRONTALIS_BELLIES = {
    # belly: (height of the fixed point above the brow top, its depth beneath the skin, zone half-angle [deg],
    #         falloff start and finish as multiples of the belly's length)
    "inner": (0.60, 0.20, 36.0, 1.15, 2.00),
    "middle": (0.65, 0.06, 42.0, 1.25, 1.60),
    "outer": (0.90, 0.00, 48.0, 1.15, 1.60),
}
"""The full rig's frontalis bellies [inter-ocular units], fitted by coordinate search to the ICT-FaceKit
brow shapes with :func:`warpface.solve.fit`. The middle belly (above the brow's midpoint, its fixed
point 0.1 units medial) spreads the rise over the forehead's width. The falloff ends 0.4–1 lengths
beyond the brow, so the lids follow the brows only a little. Fit and measurements: docs/RIG.md §5."""

GALEA_LOBE = (0.30, 83.0, 0.90, 2.50, 0.40)
"""The frontalis' galea lobe [inter-ocular units]: (its insertion above the belly's fixed point, zone
half-angle [deg], falloff start and finish as multiples of its length, gain). The frontalis has no bony
origin: contracting, it draws the brow up and the scalp down toward its belly, and the forehead skin
between bunches out. Given to the inner and middle bellies rather than made a control of its own, which
landmarks (blind to the upper forehead) could not drive (docs/RIG.md §5)."""

NASAL_LOBE = (0.10, 0.00, 36.0, 1.00, 1.30, 0.05)
"""The inner frontalis' nasal lobe [inter-ocular units]: (its insertion beside the midline and above the
nose tip, iBUG 30; zone half-angle [deg]; falloff start and finish as multiples of its length; gain).
The inner belly's medial fibres continue into the procerus and the nasal skin, which a raised inner brow
lifts as one piece with the brow (docs/RIG.md §5)."""

CHEEK_LOBE = (0.30, 0.05, 0.15, 0.30, 0.45, 40.0, 0.80, 2.20, 1.45)
"""The lower lid's cheek lobe [inter-ocular units]: (fixed point medial of the inner canthus, and above it,
depth; insertion lateral of and below the eye's centre; zone half-angle [deg]; falloff start and finish
as multiples of its length; gain). The lower orbital fibres of the orbicularis oculi lift the cheek
medially and up with the lower lid in a squint (AU6 with AU7); it is part of the lower lid's control because
a landmark fit, which sees two lower-lid points, cannot drive a separate one (docs/RIG.md §5)."""

MASSETERIC_LOBE = (0.20, 0.10, 0.40, 0.04, 60.0, 1.20, 2.00, 2.00)
"""The risorius' masseteric lobe [inter-ocular units]: (its fixed point lateral of the jaw outline at mouth level,
iBUG 12/4, at that landmark's depth, and above the mouth corner; its insertion that fraction of the way from the
corner to the jaw outline, and below it; zone half-angle [deg]; falloff start and finish as multiples of its length;
gain). The risorius arises from the parotid-masseteric fascia, which glides with the skin over the masseter: a
stretched mouth (AU20) draws the whole lower cheek and jowl toward the ear, 2-3 mm in ICT's mouthStretch, where the
risorius' own narrow cone moves only the corner (docs/RIG.md §5)."""

ORBITAL_RING = 0.55
"""Ring of the orbital orbicularis oculi (:attr:`~warpface.SphincterMuscle.ring`): its pull fades out inside
0.55 of its ellipse, over the lids, which the palpebral muscles move (0.55 fits best with the lower lid's
cheek lobe; docs/RIG.md §5)."""

SKIN_RESPONSE_OVERRIDES: dict[str, dict] = {f"orbicularis_oculi_lower_lid_{s}": {"bunching": 0.0} for s, _ in _SIDES}
"""Muscles whose skin response differs from the rig's default (``{name: {field: value}}``). The lower lid's
skin is 1 mm thin over the eyeball's curve, where bunching would lift its margin out of the face
(docs/RIG.md §3)."""


def _side_of(muscle: LinearMuscle) -> tuple[str, float]:
    """``("L", +1)`` or ``("R", −1)`` from the muscle's name suffix."""
    return ("L", 1.0) if muscle.name.endswith("_L") else ("R", -1.0)


def _fixed_at(
    muscle: LinearMuscle, attachment: np.ndarray, zone_deg: float, start: float, finish: float
) -> LinearMuscle:
    """``muscle`` with a new fixed end; radii as fractions of the new length, the insertion kept."""
    length = float(np.linalg.norm(muscle.insertion - attachment))
    return LinearMuscle(muscle.name, attachment, muscle.insertion, zone_deg, start * length, finish * length)


def revised_classic_muscles(
    local: np.ndarray, surface: SurfaceSampler, classic: list[LinearMuscle]
) -> list[LinearMuscle]:
    """The classic linear muscles as the full rig places them: frontalis, risorius and the lip levator/depressor moved.

    Frontalis: each belly's fixed point in the forehead instead of beyond the hairline.

    The frontalis has no bony origin: it arises from the galea aponeurotica, which glides over the
    skull on loose areolar tissue, so the pull's fixed point lies in the upper forehead, close under
    the skin (:data:`FRONTALIS_BELLIES`); the zone reaches the brows and a short way below them.
    """
    brow_top = float(local[17:27, 1].max())
    out = []
    for muscle in classic:
        if muscle.name.startswith("risorius_"):
            # Risorius arises from the fascia over the masseter, at the side of the face. Its fixed end
            # lies 0.25 beneath that skin: a point just under the skin gathered the cheek side into a
            # lump in a smile, and sliding (docs/RIG.md §2) removes the pull's inward part anyway.
            origin = surface.frame.to_local(surface.below(surface.frame.to_local(muscle.attachment)[:2], 0.0))
            side_xy = (
                np.sign(origin[0]) * (max(abs(origin[0]), 0.9) - 0.1),
                surface.frame.to_local(muscle.insertion)[1] + 0.02,
            )
            fixed = _fixed_at(muscle, surface.below(side_xy, 0.25), 24.0, 0.90, 1.40)
            out.append(replace(fixed, lobes=(_masseteric_lobe(local, surface, *_side_of(muscle)),)))
            continue
        if muscle.name.startswith("depressor_labii_inferioris_"):
            # Depressor labii inferioris: from the mandible below the lip, 0.05 beneath the skin, into
            # the vermilion 0.02 above the lip border. The classic placement (0.20 deep, inserting
            # below the border) pulled the lip inward and, after sliding, lifted it 1 mm (mouthLowerDown).
            tag, sign = _side_of(muscle)
            lower = local[_LANDMARKS[tag]["lower"], :2]
            out.append(
                linear_muscle(
                    muscle.name,
                    surface,
                    (lower[0] + 0.12 * sign, lower[1] - 0.42),
                    0.05,
                    (lower[0] + 0.03 * sign, lower[1] + 0.02),
                    35.0,
                    0.85,
                    1.30,
                )
            )
            continue
        if muscle.name.startswith("levator_labii_superioris_"):
            # Levator labii superioris: from the infraorbital margin, 0.05 beneath the skin, into the
            # vermilion below the Cupid's-bow peak. The classic one (0.18 deep, inserting 0.06 above
            # the outer upper lip) pulled the lip into the face and, after sliding, raised the lip's
            # middle < 0.05 mm (mouthShrugUpper) and its side 0.2 mm (mouthUpperUp; now 0.8 and 1.8 mm).
            tag, sign = _side_of(muscle)
            eye = local[list(_LANDMARKS[tag]["eye"]), :2].mean(axis=0)
            peak = local[_LANDMARKS[tag]["upper"], :2]
            out.append(
                linear_muscle(
                    muscle.name,
                    surface,
                    (eye[0] - 0.02 * sign, eye[1] - 0.36),
                    0.05,
                    (peak[0] + 0.02 * sign, peak[1] - 0.02),
                    30.0,
                    0.88,
                    1.30,
                )
            )
            continue
        if not muscle.name.startswith("frontalis_"):
            out.append(muscle)
            continue
        out.append(_frontalis_belly(muscle.name, surface, brow_top, float(local[30, 1]), muscle.insertion))
    return out


def _masseteric_lobe(local: np.ndarray, surface: SurfaceSampler, tag: str, side: float) -> MuscleLobe:
    """The risorius' :data:`MASSETERIC_LOBE`, from the local landmarks (68, 3): the mouth corner and the jaw
    outline at mouth level (iBUG 54 and 12 on the left)."""
    out, up, insertion_at, below, *shape = MASSETERIC_LOBE
    corner, jaw = local[_LANDMARKS[tag]["corner"]], local[_LANDMARKS[tag]["jaw_mouth"]]
    fixed = surface.frame.to_world(np.array([jaw[0] + out * side, corner[1] + up, jaw[2]]))
    insertion = corner[:2] + insertion_at * (jaw[:2] - corner[:2]) - np.array([0.0, below])
    return _lobe(fixed, surface.point(insertion), *shape)


def _cheek_lobe(surface: SurfaceSampler, inner_canthus, eye, side: float) -> MuscleLobe:
    """The lower lid's :data:`CHEEK_LOBE`, from the local (x, y) of the inner canthus and the eye's centre."""
    medial, up, depth, across, down, *shape = CHEEK_LOBE
    return _lobe(
        surface.below((inner_canthus[0] - medial * side, inner_canthus[1] + up), depth),
        surface.point((eye[0] + across * side, eye[1] - down)),
        *shape,
    )


def _lobe(attachment, insertion, zone: float, start: float, finish: float, gain: float) -> MuscleLobe:
    """A lobe between two points; its radii as multiples of its length."""
    length = float(np.linalg.norm(insertion - attachment))
    return MuscleLobe(attachment, insertion, zone, start * length, finish * length, gain)


def _frontalis_belly(
    name, surface: SurfaceSampler, brow_top: float, nose_tip_y: float, insertion: np.ndarray, shift: float = 0.0
) -> LinearMuscle:
    """A frontalis belly of :data:`FRONTALIS_BELLIES` into the brow skin point ``insertion`` (3,), its fixed
    point ``shift`` units sideways of the insertion (local x), with its lobes (:data:`GALEA_LOBE`,
    :data:`NASAL_LOBE`); ``brow_top`` and ``nose_tip_y`` are local heights."""
    belly = name.split("_")[1]
    height, depth, zone, start, finish = FRONTALIS_BELLIES[belly]
    attachment = surface.below((surface.frame.to_local(insertion)[0] + shift, brow_top + height), depth)
    length = float(np.linalg.norm(insertion - attachment))
    lobes = []
    if belly in ("inner", "middle"):
        rise, *shape = GALEA_LOBE
        fixed = surface.frame.to_local(attachment)
        lobes.append(_lobe(attachment, surface.point((fixed[0], fixed[1] + rise)), *shape))
    if belly == "inner":
        across, up, *shape = NASAL_LOBE
        side = 1.0 if name.endswith("_L") else -1.0
        lobes.append(_lobe(attachment, surface.point((across * side, nose_tip_y + up)), *shape))
    return LinearMuscle(name, attachment, insertion, zone, start * length, finish * length, lobes=tuple(lobes))


LINEAR_PULLS = {
    # name: (origin depth, zone half-angle [deg], falloff start, falloff finish as fractions of the length)
    # the classic rig's (warpface.assets.rig)
    "corrugator": (0.06, 40.0, 0.75, 1.50),
    "levator_labii_alaeque_nasi": (0.22, 24.0, 0.85, 1.40),
    "levator_labii_superioris": (0.18, 20.0, 0.88, 1.30),
    "zygomaticus_major": (0.25, 30.0, 0.90, 1.45),
    "risorius": (0.30, 24.0, 0.90, 1.40),
    "depressor_anguli_oris": (0.18, 24.0, 0.88, 1.35),
    "depressor_labii_inferioris": (0.20, 22.0, 0.85, 1.30),
    "procerus": (0.10, 34.0, 0.80, 1.30),
    "mentalis": (0.20, 50.0, 0.90, 1.60),
    # the full rig's added muscles
    "depressor_supercilii": (0.10, 40.0, 0.75, 1.45),
    "levator_anguli_oris": (0.25, 30.0, 0.85, 1.45),
    "zygomaticus_minor": (0.22, 24.0, 0.85, 1.40),
    "buccinator": (0.12, 34.0, 0.90, 1.45),
    "platysma": (0.20, 38.0, 0.95, 1.55),
    "nasalis": (0.12, 30.0, 0.80, 1.45),
    "orbicularis_oculi_upper_lid": (0.06, 70.0, 0.90, 1.70),
    "orbicularis_oculi_lower_lid": (0.06, 70.0, 0.90, 2.20),
    "levator_palpebrae": (0.35, 40.0, 0.90, 1.30),
    "orbicularis_oris_roll_upper": (0.35, 60.0, 0.90, 1.45),
    "orbicularis_oris_roll_lower": (0.35, 60.0, 0.90, 1.45),
    "orbicularis_oculi_brow": (0.05, 75.0, 0.90, 1.80),
}
"""How each table-built :func:`linear_muscle` of the rigs pulls, by name (see :func:`linear_muscles`); the ends,
from the landmarks, are in :func:`anatomy_muscles` and in :mod:`warpface.assets.rig` for the classic muscles.
:func:`revised_classic_muscles` sets its own."""


def anatomy_muscles(
    local: np.ndarray, surface: SurfaceSampler, frame: FaceFrame, classic_sphincters: list[SphincterMuscle]
) -> tuple[list[LinearMuscle], list[SphincterMuscle]]:
    """The added linear muscles and the full rig's sphincters, from the local landmarks (68, 3)."""
    xy = local[:, :2]
    brow_top = float(xy[17:27, 1].max())
    linear: dict[str, LinearMuscle] = {}
    for tag, s in _SIDES:
        i = _LANDMARKS[tag]
        # Frontalis, middle belly: above the brow's midpoint, its fixed point a little medial, so the
        # three bellies together lift the whole brow and the forehead over it (AU1 + AU2).
        middle = xy[i["brow_middle"]]
        linear[f"frontalis_middle_{tag}"] = _frontalis_belly(
            f"frontalis_middle_{tag}",
            surface,
            brow_top,
            float(xy[30, 1]),
            surface.point((middle[0], middle[1] + 0.05)),
            shift=-0.10 * s,
        )
        brow_inner, eye_inner = xy[i["brow_inner"]], xy[i["eye_inner"]]
        eye = xy[list(i["eye"])].mean(axis=0)
        wing, corner, upper = xy[i["wing"]], xy[i["corner"]], xy[i["upper"]]
        jaw_mouth, jaw_low = xy[i["jaw_mouth"]], xy[i["jaw_low"]]
        ends = {
            # name: (origin (x, y), insertion (x, y))
            "depressor_supercilii": (
                (0.5 * (eye_inner[0] + 0.05 * s), eye_inner[1] - 0.02),
                (brow_inner[0] + 0.02 * s, brow_inner[1] + 0.04),
            ),
            "levator_anguli_oris": ((wing[0] + 0.12 * s, wing[1] - 0.02), (corner[0] + 0.02 * s, corner[1] + 0.02)),
            "zygomaticus_minor": ((eye[0] + 0.12 * s, eye[1] - 0.42), (0.5 * (upper[0] + corner[0]), upper[1] + 0.03)),
            "buccinator": ((0.80 * jaw_mouth[0], corner[1] - 0.02), (corner[0] + 0.05 * s, corner[1])),
            "platysma": ((jaw_low[0] + 0.05 * s, jaw_low[1] - 0.35), (corner[0] + 0.03 * s, corner[1] - 0.06)),
            "nasalis": ((wing[0] + 0.06 * s, wing[1] + 0.02), (0.45 * wing[0], xy[29, 1])),
        }
        linear.update(linear_muscles(surface, ends, LINEAR_PULLS, suffix=f"_{tag}"))
    for tag, s in _SIDES:
        # Palpebral part, one per lid: its fibres run round the lid between the palpebral ligaments,
        # so a contraction carries the lid (and the skin beyond it) toward the opposite lid margin
        # and a little medially, and nothing on the far side of that margin moves (a ring centred
        # there would also pull the brow down).
        ring = xy[list(_LANDMARKS[tag]["eye"])]
        eye, inner = ring.mean(axis=0), xy[_LANDMARKS[tag]["eye_inner"]]
        top, bottom = ring[:, 1].max(), ring[:, 1].min()
        medial = eye[0] + 0.75 * (inner[0] - eye[0])
        ends = {
            "orbicularis_oculi_upper_lid": ((medial, bottom), (eye[0], top + 0.10)),
            "orbicularis_oculi_lower_lid": ((medial, top), (eye[0], bottom - 0.12)),
            # Levator palpebrae superioris: from the orbit's roof, deep behind the brow, into the upper lid (eyeWide).
            "levator_palpebrae": ((eye[0], top + 0.30), (eye[0], top + 0.02)),
        }
        linear.update(linear_muscles(surface, ends, LINEAR_PULLS, suffix=f"_{tag}"))
        lid = linear[f"orbicularis_oculi_lower_lid_{tag}"]
        linear[lid.name] = replace(lid, lobes=(_cheek_lobe(surface, xy[_LANDMARKS[tag]["eye_inner"]], eye, s),))
    mouth_line = 0.5 * (xy[62, 1] + xy[66, 1])
    ends = {
        "orbicularis_oris_roll_upper": ((0.0, mouth_line + 0.02), (0.0, xy[51, 1])),
        "orbicularis_oris_roll_lower": ((0.0, mouth_line - 0.02), (0.0, xy[57, 1])),
    }
    linear.update(linear_muscles(surface, ends, LINEAR_PULLS))
    for tag, _sign in _SIDES:
        # Orbital orbicularis oculi, upper fibres: from the orbital rim above the eye into the skin over the
        # brow's middle; they lower the brow's middle and tail (AU4 with the corrugator and depressor supercilii,
        # which lower its head), which nothing else does without lifting the cheek.
        eye = xy[list(_LANDMARKS[tag]["eye"])].mean(axis=0)
        top = xy[list(_LANDMARKS[tag]["eye"]), 1].max()
        middle = xy[_LANDMARKS[tag]["brow_middle"]]
        ends = {"orbicularis_oculi_brow": ((eye[0], eye[1] - 0.05), (middle[0], middle[1] + 0.03))}
        linear.update(linear_muscles(surface, ends, LINEAR_PULLS, suffix=f"_{tag}"))

    world, up = frame.to_world, frame.axes[1]
    sphincters = {m.name: m for m in classic_sphincters}
    for tag, _sign in _SIDES:
        i = _LANDMARKS[tag]
        eye = local[list(i["eye"])].mean(axis=0)
        across = world(local[i["eye_outer"]]) - world(local[i["eye_inner"]])
        inner = local[i["eye_inner"]]
        centre = eye + ORBITAL_CENTRE * (inner - eye)
        sphincters[f"orbicularis_oculi_{tag}"] = SphincterMuscle(
            f"orbicularis_oculi_{tag}",
            world(centre),
            across,
            up,
            (ORBITAL_SEMI_AXES[0] * frame.scale, ORBITAL_SEMI_AXES[1] * frame.scale),
            ring=ORBITAL_RING,
        )
    mouth = local[60:68].mean(axis=0)
    half_width = 0.5 * np.linalg.norm(local[54] - local[48])
    sphincters["orbicularis_oris_press"] = SphincterMuscle(
        "orbicularis_oris_press",
        world(mouth),
        world(local[54]) - world(local[48]),
        up,
        (1.15 * half_width * frame.scale, 0.30 * frame.scale),
    )
    order = [m.name for m in classic_sphincters] + list(ANATOMY_SPHINCTER_MUSCLE_NAMES)
    return [linear[name] for name in ANATOMY_LINEAR_MUSCLE_NAMES], [sphincters[name] for name in order]
