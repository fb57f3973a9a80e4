"""Lip slides (docs/RIG.md §16): each lip moves as one piece, up or down, forward and sideways; mouth corners (§17):
the modiolus moved up, down, back and out as one piece."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import warp as wp
from lip_checks import assert_hinges_round_trip, assert_inner_lips_never_close, random_mixes, turned_face

import warpface as wf
from warpface.assets import default_rig
from warpface.assets.frame import FaceFrame
from warpface.assets.jaw import lip_sided
from warpface.assets.lip_roll import LIP_ROLL_NAMES
from warpface.assets.lip_slide import LIP_HINGE_NAMES, LIP_SLIDE_NAMES, SLIDE, default_lip_slides
from warpface.assets.lips import contact_line
from warpface.assets.mouth_corner import (
    CORNER_RADII,
    CORNER_SLIDE,
    MOUTH_CORNER_NAMES,
    corner_weight,
    default_mouth_corners,
)
from warpface.assets.rig import BODY_CONTROL_NAMES
from warpface.data import ict_face_region, ict_landmark_indices
from warpface.expression.lids import LidMuscle, lid_field
from warpface.expression.seal import LipSeal, seal_fields

DEVICE = "cpu"
CORNER = {"L": 54, "R": 48}

# (frame axis, sign) each slide moves along
DIRECTIONS = {
    "raise": (1, 1.0),
    "depress": (1, -1.0),
    "protrude": (2, 1.0),
    "slide_left": (0, 1.0),
    "slide_right": (0, -1.0),
}


@pytest.fixture(scope="module")
def rig():
    return default_rig(device=DEVICE)


@pytest.fixture(scope="module")
def frame(rig):
    return FaceFrame.from_landmarks(rig.mesh.points[rig.landmarks])


def _slides(rig) -> dict[str, LidMuscle]:
    return {m.name: m for m in rig.muscles if m.name in LIP_SLIDE_NAMES}


def _corners(rig) -> dict[str, LidMuscle]:
    return {m.name: m for m in rig.muscles if m.name in MOUTH_CORNER_NAMES}


def _direction(name: str):
    return next(value for way, value in DIRECTIONS.items() if f"_{way}" in name)


def test_the_rig_has_twelve_lip_slides_and_eight_corners_after_the_hinges(rig):
    names = [m.name for m in rig.muscles]
    assert [n for n in names if n in BODY_CONTROL_NAMES] == [*LIP_ROLL_NAMES, *LIP_SLIDE_NAMES, *MOUTH_CORNER_NAMES]
    assert (len(LIP_SLIDE_NAMES), len(MOUTH_CORNER_NAMES)) == (12, 8)
    assert names.index(MOUTH_CORNER_NAMES[-1]) < names.index("lid_upper_close_L")
    bodies = [*_slides(rig).values(), *_corners(rig).values()]
    assert len(bodies) == 20 and all(isinstance(m, LidMuscle) and not np.any(m.angles) for m in bodies)


def test_each_slide_moves_its_own_lip_along_its_axis(rig, frame):
    """The field (float64 reference: the slide along the frame axis) moves only that lip's side of the contact line,
    by at most SLIDE inter-ocular units, and as far as that at the lip's middle."""
    mesh = rig.mesh
    local, below, _, _ = contact_line(mesh, frame, rig.landmarks)
    sided = lip_sided(mesh, frame, local, rig.landmarks, below)
    points = wp.array(mesh.points, dtype=wp.vec3d, device=DEVICE)
    middle = rig.landmarks[[62, 66]]
    for name, muscle in _slides(rig).items():
        axis, sign = _direction(name)
        field = lid_field(points, muscle)
        moved = np.flatnonzero(np.linalg.norm(field, axis=1) > 0.0)
        assert len(moved) > 20, name
        on_own_lip = sided[moved] < 0.0 if "_upper_" in name else sided[moved] >= 0.0
        assert on_own_lip.all(), name
        expected = np.zeros_like(field)
        expected[muscle.vertices] = muscle.slides[:, None] * (sign * frame.axes[axis])
        np.testing.assert_allclose(field, expected, rtol=0.0, atol=1e-12 * frame.scale)
        along = field @ frame.axes[axis] * sign / frame.scale
        assert along.min() >= 0.0 and along.max() <= SLIDE + 1e-12, name
        lip_middle = middle[0] if "_upper_" in name else middle[1]
        share = 0.5 if name[-2:] in ("_L", "_R") else 1.0  # a side's slide moves the midline by half
        assert along[lip_middle] == pytest.approx(SLIDE * share, rel=1e-6), name


def test_the_two_sides_make_the_whole_lip(rig):
    for lip, way in (("upper", "raise"), ("lower", "depress"), ("upper", "protrude"), ("lower", "protrude")):
        sides = _slides(rig)
        left, right = sides[f"lip_{lip}_{way}_L"], sides[f"lip_{lip}_{way}_R"]
        whole = sides[f"lip_{lip}_slide_left"]  # the whole lip's profile, unsplit
        total = np.zeros(rig.mesh.vertex_count)
        total[left.vertices] += left.slides
        total[right.vertices] += right.slides
        profile = np.zeros(rig.mesh.vertex_count)
        profile[whole.vertices] = whole.slides
        np.testing.assert_allclose(total, profile, rtol=1e-12, atol=1e-15)


def test_no_slide_and_no_mix_of_slides_and_hinges_brings_the_inner_lips_together(rig):
    frames = [{name: 1.0} for name in LIP_SLIDE_NAMES] + random_mixes(LIP_HINGE_NAMES, 6, seed=7)
    # protrusion and sideways slides keep the heights up to the tilt of the check's up axis from the frame's
    assert_inner_lips_never_close(rig, frames, tolerance_mm=1e-3)


def test_the_lip_slides_are_placed_relative_to_the_landmarks(rig):
    mesh, landmarks = rig.mesh, rig.landmarks
    angle = 0.4
    turn = np.array([[np.cos(angle), 0.0, np.sin(angle)], [0.0, 1.0, 0.0], [-np.sin(angle), 0.0, np.cos(angle)]])
    moved = turned_face(mesh, 2.5, turn, [0.3, -1.0, 2.0])
    before = default_lip_slides(mesh, FaceFrame.from_landmarks(mesh.points[landmarks]), landmarks)
    after = default_lip_slides(moved, FaceFrame.from_landmarks(moved.points[landmarks]), landmarks)
    for a, b in zip(before, after):
        assert a.name == b.name and np.array_equal(a.vertices, b.vertices)
        np.testing.assert_allclose(b.slides, 2.5 * a.slides, rtol=1e-9)
        np.testing.assert_allclose(b.axis, turn @ a.axis, atol=1e-9)


def test_lip_slides_round_trip_through_a_stage(rig, tmp_path):
    frame = {"lip_upper_raise_L": 1.0, "lip_lower_slide_right": 0.5}
    assert_hinges_round_trip(rig, _slides(rig).values(), frame, tmp_path / "rig.usda")


# ------------------------------------------------------------------------------------------------ mouth corners


def test_each_corner_moves_the_skin_around_it_along_its_direction(rig, frame):
    """Float64 reference: the slide fades as cos² from the corner (iBUG 54 left, 48 right) over CORNER_RADII, along
    +y (up), −y (down), −z (back) or away from the midline (out)."""
    local = frame.to_local(rig.mesh.points)
    points = wp.array(rig.mesh.points, dtype=wp.vec3d, device=DEVICE)
    directions = {"up": (1, 1.0), "down": (1, -1.0), "back": (2, -1.0)}
    inner, fade = CORNER_RADII
    for name, muscle in _corners(rig).items():
        way, side = name.split("_")[2], name[-1]
        corner = local[rig.landmarks[CORNER[side]]]
        distance = np.linalg.norm(local - corner, axis=1)
        t = np.clip((distance - inner) / fade, 0.0, 1.0)
        weight = np.where(distance < inner + fade, np.cos(0.5 * np.pi * t) ** 2, 0.0)
        axis, sign = directions.get(way, (0, 1.0 if side == "L" else -1.0))  # out: away from the midline
        expected = CORNER_SLIDE * frame.scale * weight[:, None] * (sign * frame.axes[axis])
        field = lid_field(points, muscle)
        np.testing.assert_allclose(field, expected, rtol=0.0, atol=1e-12 * frame.scale)
        assert np.linalg.norm(field[rig.landmarks[CORNER[side]]]) == pytest.approx(CORNER_SLIDE * frame.scale)
        if way == "out":
            assert np.all(np.sign(corner[0]) * (field @ frame.axes[0]) >= 0.0), name


def test_the_seal_covers_hinges_that_only_slide(rig, frame):
    """A hinge that only slides is sealed like a Waters muscle (on ICT's face a raised corner lifts the lower lip
    beside it 0.42 mm more than the upper one): a slide pushing the lower lip's pair vertices up gets the seal's
    parting added, a hinge that turns is left as it is (docs/RIG.md §12, §17)."""
    seal = next(m for m in rig.muscles if isinstance(m, LipSeal))
    points = wp.array(rig.mesh.points, dtype=wp.vec3d, device=DEVICE)
    part = lid_field(points, seal)
    upper, lower = seal.pairs[:, 0], seal.pairs[:, 1]
    direction = (part[upper] - part[lower]) / np.linalg.norm(part[upper] - part[lower], axis=1)[:, None]
    lifted = np.unique(lower)
    push = LidMuscle(
        "push", frame.origin, frame.axes[1], lifted, np.zeros(len(lifted)), slides=np.full(len(lifted), 1e-3)
    )
    roll = next(m for m in rig.muscles if m.name == "lip_upper_roll_in_L")
    muscles = [push, roll, seal]
    fields = [lid_field(points, m) for m in muscles]

    def parting(field):
        return np.sum((field[upper] - field[lower]) * direction, axis=1)

    assert parting(fields[0]).min() < -5e-4  # the push alone closes the pairs
    sealed = seal_fields(muscles, fields)
    assert parting(sealed[0]).min() >= -1e-15
    assert np.array_equal(sealed[1], fields[1]) and np.array_equal(sealed[2], fields[2])


def test_no_corner_and_no_mix_with_the_lips_brings_the_inner_lips_together(rig):
    frames = [{name: 1.0} for name in MOUTH_CORNER_NAMES] + random_mixes(BODY_CONTROL_NAMES, 6, seed=9)
    assert_inner_lips_never_close(rig, frames, tolerance_mm=1e-3)


def test_the_corners_are_placed_relative_to_the_landmarks(rig):
    mesh, landmarks = rig.mesh, rig.landmarks
    angle = -0.3
    turn = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(angle), -np.sin(angle)], [0.0, np.sin(angle), np.cos(angle)]])
    moved = turned_face(mesh, 0.01, turn, [1.0, 2.0, -3.0])
    before = default_mouth_corners(mesh, FaceFrame.from_landmarks(mesh.points[landmarks]), landmarks)
    after = default_mouth_corners(moved, FaceFrame.from_landmarks(moved.points[landmarks]), landmarks)
    for a, b in zip(before, after):
        assert a.name == b.name and np.array_equal(a.vertices, b.vertices)
        np.testing.assert_allclose(b.slides, 0.01 * a.slides, rtol=1e-9, atol=1e-9 * 0.01 * a.slides.max())
        np.testing.assert_allclose(b.axis, turn @ a.axis, atol=1e-9)
    frame = FaceFrame.from_landmarks(mesh.points[landmarks])
    assert corner_weight(mesh, frame, landmarks, "L")[landmarks[54]] == 1.0


@pytest.fixture(scope="module")
def ict_rig():
    if ict_face_region("mouthLeft") is None or ict_landmark_indices() is None:
        pytest.skip("ICT-FaceKit data not in ../shared/data")
    source = wf.FaceMesh.from_obj(ict_face_region())
    mesh = wf.FaceMesh(source.points * 0.01, source.triangles, name="ict")
    return default_rig(mesh, ict_landmark_indices(), device=DEVICE)


@pytest.mark.slow
@pytest.mark.parametrize(
    "shape, names, used",
    [
        ("mouthLeft", LIP_SLIDE_NAMES, ("lip_upper_slide_left", "lip_upper_slide_right")),
        ("mouthStretch_L", MOUTH_CORNER_NAMES, ("mouth_corner_out_L",)),
    ],
)
def test_the_slides_and_corners_reach_more_of_ict_s_mouth(ict_rig, shape, names, used):
    """ICT-FaceKit's mouthLeft and mouthStretch_L, fitted densely: the lip slides and the corners each add at least 5
    points of reach (mouthLeft 41.7 → 50.5 %, mouthStretch 56.5 → 67.7 %; docs/RIG.md §16–17), and the fit uses them."""
    from warpface.calibration import ExampleShape, reach

    without = replace(ict_rig, muscles=[m for m in ict_rig.muscles if m.name not in names])
    example = [ExampleShape(shape, wf.FaceMesh.from_obj(ict_face_region(shape)).points * 0.01, shape)]
    (full,) = reach(ict_rig, example, millimetre=1e-3, device=DEVICE)
    (held,) = reach(without, example, millimetre=1e-3, device=DEVICE)
    assert full["reduction"] > held["reduction"] + 0.05, (held["reduction"], full["reduction"])
    assert max(full["controls"][ict_rig.control_names.index(name)] for name in used) > 0.05
