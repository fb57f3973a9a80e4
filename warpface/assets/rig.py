"""The default, landmark-anchored face rig: muscles, a jaw, 21 wrinkles, thickness (docs/RIG.md).

``anatomy="classic"`` is thesis table 2.1: 20 linear muscles and 3 sphincters. The full anatomy (the
default) re-places some of them and adds the muscles of :mod:`~warpface.assets.anatomy` (44 linear,
4 sphincters) and the jaw.

Every muscle end and wrinkle curve is written in the :class:`~warpface.assets.frame.FaceFrame` of
the face (origin between the eyes, x toward the subject's left, y up, z out, unit = inter-ocular
distance) relative to the 68 iBUG landmarks, and put on the skin by casting rays at the mesh. Bone
attachments sit beneath the skin, along −normal. Nothing is an absolute length, so the same
function rigs the built-in face (metres) and the ICT-FaceKit face (centimetres).

Names end in ``_L``/``_R`` for the subject's left (+x) and right (−x) side, as in ICT-FaceKit and
FACS. Muscles follow thesis table 2.1 (SPEC §5); the wrinkles are the furrows those muscles make.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .._validate import expect_instance
from ..errors import RigError
from ..expression.muscles import LinearMuscle, SphincterMuscle
from ..expression.wrinkles import CylindricalProjection, PlanarProjection, Wrinkle, project_points
from ..landmarks import LEFT_SIDE, RIGHT_SIDE, check_layout
from ..mesh import FaceMesh
from ..rig import FaceRig
from .anatomy import (
    ANATOMY_LINEAR_MUSCLE_NAMES,
    ANATOMY_SPHINCTER_MUSCLE_NAMES,
    LINEAR_PULLS,
    SKIN_RESPONSE_OVERRIDES,
    anatomy_muscles,
    linear_muscles,
    revised_classic_muscles,
)
from .calibrated import apply_parameters, load_calibrated_anatomy
from .face import default_face, default_landmarks
from .frame import FaceFrame, SurfaceSampler, check_landmarks, head_cylinder
from .jaw import default_jaw
from .lids import default_lids
from .lip_roll import default_lip_rolls
from .lip_slide import LIP_HINGE_NAMES, default_lip_slides
from .lips import default_lip_seal, lip_margin_taper
from .mouth_corner import MOUTH_CORNER_NAMES, default_mouth_corners
from .thickness import default_thickness

__all__ = [
    "default_rig",
    "ANATOMIES",
    "CLASSIC_LINEAR_MUSCLE_NAMES",
    "CLASSIC_SPHINCTER_MUSCLE_NAMES",
    "rig_scale",
    "face_frame",
    "LINEAR_MUSCLE_NAMES",
    "SPHINCTER_MUSCLE_NAMES",
    "WRINKLE_NAMES",
    "BODY_CONTROL_NAMES",
]

_SIDES = ("L", "R")

CLASSIC_LINEAR_MUSCLE_NAMES: tuple[str, ...] = (
    *(f"frontalis_inner_{s}" for s in _SIDES),
    *(f"frontalis_outer_{s}" for s in _SIDES),
    *(f"corrugator_{s}" for s in _SIDES),
    "procerus",
    *(f"levator_labii_alaeque_nasi_{s}" for s in _SIDES),
    *(f"levator_labii_superioris_{s}" for s in _SIDES),
    *(f"zygomaticus_major_{s}" for s in _SIDES),
    *(f"risorius_{s}" for s in _SIDES),
    *(f"depressor_anguli_oris_{s}" for s in _SIDES),
    *(f"depressor_labii_inferioris_{s}" for s in _SIDES),
    "mentalis",
)
"""Linear (Waters) muscles of the ``"classic"`` rig (thesis table 2.1), in rig order. ``K`` is a length."""

CLASSIC_SPHINCTER_MUSCLE_NAMES: tuple[str, ...] = ("orbicularis_oris", "orbicularis_oculi_L", "orbicularis_oculi_R")
"""Sphincter muscles of the ``"classic"`` rig; their contraction ``K`` is dimensionless."""

LINEAR_MUSCLE_NAMES: tuple[str, ...] = CLASSIC_LINEAR_MUSCLE_NAMES + ANATOMY_LINEAR_MUSCLE_NAMES
"""Linear muscles of the default (``"full"``) rig, in rig order: the classic ones, then those of
:mod:`warpface.assets.anatomy`."""

SPHINCTER_MUSCLE_NAMES: tuple[str, ...] = CLASSIC_SPHINCTER_MUSCLE_NAMES + ANATOMY_SPHINCTER_MUSCLE_NAMES
"""Sphincter muscles of the default (``"full"``) rig."""

ANATOMIES = ("full", "classic")
"""``"full"``: the default — every muscle, C¹ zones, skin sliding and bunching, and the jaw
(docs/RIG.md). ``"classic"``: the 23 muscles of thesis table 2.1 with the SPEC §1.1 zones, no jaw."""

WRINKLE_NAMES: tuple[str, ...] = (
    "forehead_1",
    "forehead_2",
    "forehead_3",
    "forehead_4",
    "glabella_L",
    "glabella_R",
    "nasal_root_1",
    "nasal_root_2",
    "bunny_L",
    "bunny_R",
    *(f"crows_feet_{s}_{i}" for s in _SIDES for i in (1, 2, 3)),
    "nasolabial_L",
    "nasolabial_R",
    "under_eye_L",
    "under_eye_R",
    "chin",
)
"""Wrinkles of the default rig, in rig order."""


_LEFT, _RIGHT = LEFT_SIDE, RIGHT_SIDE  # the iBUG index sets of each side (warpface.landmarks)


def face_frame(mesh: FaceMesh, landmarks) -> FaceFrame:
    """The landmark frame of a face (see :class:`~warpface.assets.frame.FaceFrame`)."""
    expect_instance(mesh, FaceMesh, "mesh")
    landmarks = check_landmarks(mesh, landmarks)
    return FaceFrame.from_landmarks(mesh.points[landmarks])


def rig_scale(rig: FaceRig) -> float:
    """The face's size unit [mesh units]: its inter-ocular (eye-centre) distance, from the rig's landmarks.

    Raises:
        RigError: the rig has no 68 iBUG landmarks.
    """
    expect_instance(rig, FaceRig, "rig")
    if rig.landmarks is None:
        raise RigError(f"rig {rig.name!r}: has no landmarks; the 68 iBUG points are needed to measure the face")
    return face_frame(rig.mesh, rig.landmarks).scale


def default_rig(
    mesh: FaceMesh | None = None,
    landmarks=None,
    *,
    name: str = "Face",
    device=None,
    anatomy: str = "full",
    calibrated: bool = True,
) -> FaceRig:
    """The default rig on a face: muscles, wrinkles and thickness placed from its 68 iBUG landmarks.

    Args:
        mesh: the face's rest surface (any units; +z need not be the view axis — the landmark frame
            decides). Omit it for the built-in :func:`~warpface.assets.default_face`.
        landmarks: 68 iBUG-order vertex indices into ``mesh``; required with a custom mesh.
        name: rig name.
        device: Warp device for the vertex normals.
        anatomy: one of :data:`ANATOMIES`.
        calibrated: the full anatomy with the muscle geometry calibrated on ICT-FaceKit's shapes
            (:data:`~warpface.assets.calibrated.CALIBRATED_ANATOMY`, docs/RIG.md §13); False: as placed by hand.

    Returns:
        A :class:`~warpface.FaceRig` with the muscles of :data:`LINEAR_MUSCLE_NAMES` and
        :data:`SPHINCTER_MUSCLE_NAMES`, the wrinkles of :data:`WRINKLE_NAMES`, the painted and
        blurred thickness of :func:`~warpface.assets.default_thickness` (times
        :data:`MOBILE_TISSUE_FRACTION` in the full anatomy), and the landmarks.

    Raises:
        RigError: landmarks missing, malformed, not face-like (eyes coinciding, mouth not below) or not in
            iBUG order (:func:`warpface.landmarks.check_layout`), or the skin wound inward.
    """
    if mesh is None:
        mesh = default_face()
        landmarks = default_landmarks() if landmarks is None else landmarks
    elif landmarks is None:
        raise RigError(f"default_rig: mesh {mesh.name!r} needs its 68 iBUG landmark vertex indices")
    if not isinstance(mesh, FaceMesh):
        raise RigError(f"default_rig: mesh must be a FaceMesh, got {type(mesh).__name__}")
    if anatomy not in ANATOMIES:
        raise RigError(f"default_rig: anatomy must be one of {', '.join(ANATOMIES)}, got {anatomy!r}")
    landmarks = check_landmarks(mesh, landmarks)
    normals = mesh.vertex_normals(device=device)
    _check_layout_on(mesh, landmarks, normals)
    frame = FaceFrame.from_landmarks(mesh.points[landmarks])
    surface = SurfaceSampler(mesh, frame, normals)
    local = frame.to_local(mesh.points[landmarks])
    linear, sphincters = _linear_muscles(local, surface), _sphincters(local, frame)
    jaw, lids = None, []
    if anatomy == "full":
        extra_linear, sphincters = anatomy_muscles(local, surface, frame, sphincters)
        linear = [_with_skin_response(m) for m in revised_classic_muscles(local, surface, linear) + extra_linear]
        sphincters = [_with_skin_response(m) for m in sphincters]
        jaw = default_jaw(mesh, frame, landmarks)
        seal = default_lip_seal(mesh, frame, landmarks)
        # the lip hinges and slides and the mouth corners (docs/RIG.md §15–17) come before the eyelids', so the rig
        # still ends with the lids and the seal
        lids = default_lip_rolls(mesh, frame, landmarks) + default_lip_slides(mesh, frame, landmarks)
        lids += default_mouth_corners(mesh, frame, landmarks) + default_lids(mesh, frame, landmarks)
        lids += [] if seal is None else [seal]
    wrinkles = _wrinkles(local, surface, frame, head_cylinder(frame, local), _typical_edge(mesh) / frame.scale, device)
    thickness = default_thickness(mesh, landmarks, device=device)
    if anatomy == "full":
        thickness = MOBILE_TISSUE_FRACTION * thickness * lip_margin_taper(mesh, frame, landmarks)
    rig = FaceRig(
        mesh=mesh,
        muscles=linear + sphincters + lids,
        wrinkles=wrinkles,
        thickness=thickness,
        landmarks=landmarks,
        name=name,
        jaw=jaw,
    )
    if anatomy == "full" and calibrated:
        rig = apply_parameters(rig, load_calibrated_anatomy(), device=device)
    return rig


def _check_layout_on(mesh: FaceMesh, landmarks: np.ndarray, normals: np.ndarray) -> None:
    """The landmarks' iBUG layout (:func:`warpface.landmarks.check_layout`), the face's front read from the
    skin's normals under them; a layout that is right only seen from behind means inward-wound triangles."""
    front = np.asarray(normals, dtype=np.float64)[landmarks].sum(axis=0)
    label = f"default_rig: landmarks on mesh {mesh.name!r}"
    try:
        check_layout(mesh.points[landmarks], front, label=label)
    except RigError as error:
        try:
            check_layout(mesh.points[landmarks], -front, label=label)
        except RigError:
            raise error from None
        raise RigError(
            f"default_rig: mesh {mesh.name!r}: its triangles are wound inward (the normals under the landmarks point "
            "into the head); reverse the winding of every triangle"
        ) from None


BODY_CONTROL_NAMES: tuple[str, ...] = LIP_HINGE_NAMES + MOUTH_CORNER_NAMES
"""The full rig's controls that move a lip or a mouth corner as one body (docs/RIG.md §15–17): fitted, never mapped;
a :class:`~warpface.solve.Solver` holds them unless ``SolveOptions.lip_rolls`` frees them."""

MOBILE_TISSUE_FRACTION = 0.6
"""The full rig's ``h`` (the thickness that bulges, SPEC §1.3, and bunches, docs/RIG.md §3) as a fraction
of :func:`~warpface.assets.default_thickness`'s soft-tissue depth: the skin and superficial fat that move
over the deeper layers; the full depth bulges too much. Near the lips' contact line it tapers to 0
(:func:`~warpface.assets.lips.lip_margin_taper`). Calibrated on the ICT-FaceKit shapes with
``benchmarks/rig_reach.py`` (docs/RIG.md §3)."""

SKIN_SLIDING = 1.0
"""Sliding of every muscle of the full rig (docs/RIG.md §2; chosen by benchmarks/rig_reach.py)."""
SKIN_BUNCHING = 1.0
"""Bunching gain β of every muscle of the full rig (docs/RIG.md §3; chosen by benchmarks/rig_reach.py)."""


def _with_skin_response(muscle):
    """The full rig's form of a muscle: C¹ zone, sliding skin, bunching tissue (unless it sets its own or
    :data:`~warpface.assets.anatomy.SKIN_RESPONSE_OVERRIDES` names it)."""
    response = dict(sliding=muscle.sliding or SKIN_SLIDING, bunching=muscle.bunching or SKIN_BUNCHING)
    return replace(muscle, falloff="smooth", **{**response, **SKIN_RESPONSE_OVERRIDES.get(muscle.name, {})})


# ------------------------------------------------------------------------------------------------
# Muscles. Positions are local (x, y) in inter-ocular units; depths are along −normal, same units.


def _galea_muscle(name, surface: SurfaceSampler, x: float, brow_top: float, insertion_xy) -> LinearMuscle:
    """A frontalis belly: attachment 1.9 units above the brows and 0.45 behind the upper forehead."""
    upper = surface.frame.to_local(surface.point((x, brow_top + 0.9)))
    attachment = surface.frame.to_world([x, brow_top + 1.9, upper[2] - 0.45])
    insertion = surface.point(insertion_xy)
    length = float(np.linalg.norm(insertion - attachment))
    return LinearMuscle(name, attachment, insertion, 22.0, 0.95 * length, 1.15 * length)


def _linear_muscles(L: np.ndarray, surface: SurfaceSampler) -> list[LinearMuscle]:
    xy = L[:, :2]
    brow_top = float(xy[17:27, 1].max())
    muscles: dict[str, LinearMuscle] = {}
    for side, tag in ((_LEFT, "L"), (_RIGHT, "R")):
        s = side.sign
        _, second, middle, fourth, inner = (xy[i] for i in side.brow)
        eye_outer, eye_inner = xy[side.eye_outer], xy[side.eye_inner]
        eye = xy[list(side.eye)].mean(axis=0)
        corner, wing = xy[side.mouth_corner], xy[side.nose_wing]
        upper_lip, lower = xy[side.upper_lip], xy[side.lower_lip]
        cheek_side, chin_side = xy[side.jaw[3]], xy[side.jaw[6]]
        # Frontalis: from the galea aponeurotica over the crown down into the brow skin (AU1, AU2).
        # The attachment lies beyond the top of a typical face mesh, so the pull is nearly uniform
        # over the forehead instead of concentrated at a point on it.
        muscles[f"frontalis_inner_{tag}"] = _galea_muscle(
            f"frontalis_inner_{tag}", surface, inner[0] + 0.08 * s, brow_top, (inner[0] + 0.03 * s, inner[1] + 0.05)
        )
        muscles[f"frontalis_outer_{tag}"] = _galea_muscle(
            f"frontalis_outer_{tag}", surface, second[0] - 0.05 * s, brow_top, (second[0] + 0.02 * s, second[1] + 0.05)
        )
        ends = {
            # name: (origin (x, y), insertion (x, y))
            # Corrugator: from the medial end of the brow ridge into the skin above mid-brow; pulls the
            # brows together and down (AU4), squeezing the skin between them into vertical furrows.
            "corrugator": ((0.03 * s, inner[1] - 0.06), (0.5 * (middle[0] + fourth[0]), fourth[1] + 0.07)),
            # Levator labii superioris alaeque nasi: frontal process of the maxilla → nose wing (AU9).
            "levator_labii_alaeque_nasi": (
                (0.45 * eye_inner[0], eye_inner[1] + 0.05),
                (wing[0] + 0.02 * s, wing[1] + 0.04),
            ),
            # Levator labii superioris: infraorbital margin → upper lip (AU10).
            "levator_labii_superioris": (
                (eye[0] - 0.02 * s, eye[1] - 0.36),
                (upper_lip[0] + 0.02 * s, upper_lip[1] + 0.06),
            ),
            # Zygomaticus major: zygomatic bone → mouth corner, up and back (AU12, smile).
            "zygomaticus_major": ((eye_outer[0] + 0.40 * s, eye[1] - 0.30), (corner[0] + 0.07 * s, corner[1] + 0.01)),
            # Risorius: masseteric fascia → mouth corner, sideways (AU20).
            "risorius": ((0.85 * cheek_side[0], corner[1] + 0.02), (corner[0] + 0.07 * s, corner[1])),
            # Depressor anguli oris: mandible below the corner → mouth corner, down (AU15).
            "depressor_anguli_oris": (
                (corner[0] + 0.10 * s, 0.5 * (corner[1] + chin_side[1]) - 0.10),
                (corner[0] + 0.02 * s, corner[1] - 0.02),
            ),
            # Depressor labii inferioris: mandible → lower lip, down (AU16).
            "depressor_labii_inferioris": (
                (lower[0] + 0.12 * s, lower[1] - 0.42),
                (lower[0] + 0.03 * s, lower[1] - 0.02),
            ),
        }
        muscles.update(linear_muscles(surface, ends, LINEAR_PULLS, suffix=f"_{tag}"))
    ends = {
        # Procerus: nasal bone → skin between the brows, pulling it down (nasal-root lines).
        "procerus": ((0.0, xy[28, 1]), (0.0, 0.5 * (xy[21, 1] + xy[22, 1]) + 0.12)),
        # Mentalis: incisive fossa below the lower lip → chin skin, raising it (AU17).
        "mentalis": ((0.0, xy[57, 1] - 0.14), (0.0, 0.55 * xy[8, 1] + 0.45 * xy[57, 1])),
    }
    muscles.update(linear_muscles(surface, ends, LINEAR_PULLS))
    return [muscles[name] for name in CLASSIC_LINEAR_MUSCLE_NAMES]


def _sphincters(L: np.ndarray, frame: FaceFrame) -> list[SphincterMuscle]:
    world = frame.to_world
    up = frame.axes[1]
    mouth_centre = L[60:68].mean(axis=0)
    mouth_half_width = 0.5 * np.linalg.norm(L[54] - L[48])
    to_nose = mouth_centre[1] - L[33, 1]
    muscles = [
        SphincterMuscle(
            "orbicularis_oris",
            world(mouth_centre),
            world(L[54]) - world(L[48]),
            up,
            (1.45 * mouth_half_width * frame.scale, 1.15 * abs(to_nose) * frame.scale),
        )
    ]
    for side, tag in ((_LEFT, "L"), (_RIGHT, "R")):
        eye = L[list(side.eye)].mean(axis=0)
        across = world(L[side.eye_outer]) - world(L[side.eye_inner])
        # The orbital part is centred a little lateral to the eye: it reaches the brow above, the
        # cheek below and the temple laterally, so that its squeeze (AU6) gathers the crow's-feet
        # skin (compressed only within ~2/3 of the semi-axes) and lifts the cheek while it narrows
        # the eye.
        centre = eye + np.array([0.17 * side.sign, 0.0, 0.0])
        muscles.append(
            SphincterMuscle(
                f"orbicularis_oculi_{tag}", world(centre), across, up, (0.78 * frame.scale, 0.56 * frame.scale)
            )
        )
    return muscles


# ------------------------------------------------------------------------------------------------
# Wrinkles: cubic Bézier curves through surface points, in a frontal plane or the head cylinder.


def _typical_edge(mesh: FaceMesh) -> float:
    """Median edge length [mesh units]."""
    corners = mesh.points[mesh.triangles]
    return float(np.median(np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)))


def _wrinkles(
    L: np.ndarray, surface: SurfaceSampler, frame: FaceFrame, cylinder: CylindricalProjection, edge: float, device=None
) -> list[Wrinkle]:
    """The 21 furrows. Paths are local (x, y) through skin points; depth ``k_d`` and width ``k_w`` are in
    inter-ocular units (``k_d`` is large because a furrow shows ``k_d·(1 − r)``: a few percent of compression)."""
    xy = L[:, :2]
    plane = PlanarProjection(frame.origin, frame.axes[0], frame.axes[1])
    scale = frame.scale
    # A furrow narrower than ~2 edges cannot be drawn by the mesh: widen it where the mesh is coarse.
    min_width = 2.0 * edge

    def wrinkle(name, projection, path_xy, depth, width, kr=0.0):
        points = np.array([surface.point(p) for p in np.asarray(path_xy, dtype=np.float64)])
        control = project_points(projection, points, device=device)
        return Wrinkle(name, control, projection, depth * scale, max(width, min_width) * scale, kr)

    brow_top = float(xy[17:27, 1].max())
    brow_inner = 0.5 * (xy[21, 1] + xy[22, 1])
    wrinkles: dict[str, Wrinkle] = {}
    # Forehead: four horizontal furrows, gently following the brows' arch (frontalis, AU1+2).
    for index, (height, half_span) in enumerate(((0.20, 0.55), (0.38, 0.72), (0.56, 0.78), (0.74, 0.62)), start=1):
        y = brow_top + height
        wrinkles[f"forehead_{index}"] = wrinkle(
            f"forehead_{index}",
            plane,
            [
                (-half_span, y + 0.05),
                (-0.33 * half_span, y - 0.035),
                (0.33 * half_span, y - 0.035),
                (half_span, y + 0.05),
            ],
            0.15,
            0.060,
        )
    for side, tag in ((_LEFT, "L"), (_RIGHT, "R")):
        s = side.sign
        # Glabella: the vertical "11" lines between the brows (corrugator, AU4).
        x0 = 0.17 * s
        wrinkles[f"glabella_{tag}"] = wrinkle(
            f"glabella_{tag}",
            plane,
            [
                (x0, brow_inner - 0.10),
                (x0 + 0.005 * s, brow_inner + 0.0),
                (x0 + 0.015 * s, brow_inner + 0.10),
                (x0 + 0.04 * s, brow_inner + 0.20),
            ],
            0.10,
            0.050,
        )
    for index, offset in enumerate((0.02, -0.10), start=1):
        # Nasal root: horizontal lines across the top of the nose (procerus).
        y = xy[27, 1] + offset
        wrinkles[f"nasal_root_{index}"] = wrinkle(
            f"nasal_root_{index}",
            plane,
            [(-0.17, y + 0.015), (-0.06, y - 0.01), (0.06, y - 0.01), (0.17, y + 0.015)],
            0.16,
            0.045,
        )
    for side, tag in ((_LEFT, "L"), (_RIGHT, "R")):
        s = side.sign
        # Bunny lines: oblique furrows on the sides of the nose bridge (nose wrinkler, AU9).
        top = (0.08 * s, xy[28, 1] + 0.02)
        wrinkles[f"bunny_{tag}"] = wrinkle(
            f"bunny_{tag}",
            plane,
            [top, (0.12 * s, xy[28, 1] - 0.06), (0.16 * s, xy[29, 1] - 0.02), (0.20 * s, xy[29, 1] - 0.10)],
            0.10,
            0.045,
        )
    for side, tag in ((_LEFT, "L"), (_RIGHT, "R")):
        s = side.sign
        outer = xy[side.eye_outer]
        # Crow's feet: three furrows fanning out from the outer eye corner (orbicularis oculi, AU6).
        for index, (rise, angle) in enumerate(((0.09, 24.0), (0.0, 0.0), (-0.09, -24.0)), start=1):
            direction = np.array([np.cos(np.radians(angle)) * s, np.sin(np.radians(angle))])
            start = outer + np.array([0.09 * s, rise])
            path = [start + t * 0.24 * direction + (0.0, -0.012 * t * t) for t in (0.0, 1 / 3, 2 / 3, 1.0)]
            wrinkles[f"crows_feet_{tag}_{index}"] = wrinkle(f"crows_feet_{tag}_{index}", cylinder, path, 0.30, 0.040)
    for side, tag in ((_LEFT, "L"), (_RIGHT, "R")):
        s = side.sign
        wing, corner = xy[side.nose_wing], xy[side.mouth_corner]
        # Nasolabial fold: from above the nose wing, round the cheek, past the mouth corner (AU12, AU10).
        wrinkles[f"nasolabial_{tag}"] = wrinkle(
            f"nasolabial_{tag}",
            cylinder,
            [
                (wing[0] + 0.07 * s, wing[1] + 0.10),
                (wing[0] + 0.20 * s, wing[1] - 0.14),
                (corner[0] + 0.14 * s, corner[1] + 0.06),
                (corner[0] + 0.12 * s, corner[1] - 0.16),
            ],
            0.12,
            0.070,
        )
    for side, tag in ((_LEFT, "L"), (_RIGHT, "R")):
        s = side.sign
        inner, outer = xy[side.eye_inner], xy[side.eye_outer]
        lower = xy[list(side.eye)][:, 1].min()
        # Under-eye fold: below the lower lid, where the rising cheek bunches the skin (AU6).
        wrinkles[f"under_eye_{tag}"] = wrinkle(
            f"under_eye_{tag}",
            cylinder,
            [
                (inner[0] + 0.06 * s, lower - 0.13),
                (inner[0] + 0.20 * s, lower - 0.20),
                (outer[0] - 0.10 * s, lower - 0.20),
                (outer[0] + 0.04 * s, lower - 0.12),
            ],
            0.10,
            0.045,
        )
    # Chin: the mentolabial furrow, deepened when the mentalis raises the chin (AU17).
    y = xy[57, 1] - 0.13
    wrinkles["chin"] = wrinkle(
        "chin", plane, [(-0.26, y + 0.04), (-0.09, y - 0.02), (0.09, y - 0.02), (0.26, y + 0.04)], 0.12, 0.055
    )
    return [wrinkles[name] for name in WRINKLE_NAMES]
