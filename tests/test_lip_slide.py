"""Lip slides (docs/RIG.md §16): each lip moves as one piece, up or down, forward and sideways."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import warp as wp
from helpers import assert_rigs_equal

import warpface as wf
from warpface.assets import default_rig
from warpface.assets.frame import FaceFrame
from warpface.assets.jaw import lip_sided
from warpface.assets.lip_roll import LIP_ROLL_NAMES
from warpface.assets.lip_slide import LIP_HINGE_NAMES, LIP_SLIDE_NAMES, SLIDE, default_lip_slides
from warpface.assets.lips import contact_line
from warpface.assets.quality import LIP_PAIRS, face_up, pair_heights
from warpface.data import ict_face_region, ict_landmark_indices
from warpface.expression.lids import LidMuscle, lid_field

DEVICE = "cpu"

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


def _direction(name: str):
    return next(value for way, value in DIRECTIONS.items() if f"_{way}" in name)


def test_the_rig_has_twelve_lip_slides_after_the_hinges(rig):
    names = [m.name for m in rig.muscles]
    assert [n for n in names if n in LIP_HINGE_NAMES] == list(LIP_ROLL_NAMES) + list(LIP_SLIDE_NAMES)
    assert len(LIP_SLIDE_NAMES) == 12 and names.index(LIP_SLIDE_NAMES[-1]) < names.index("lid_upper_close_L")
    assert all(isinstance(m, LidMuscle) and not np.any(m.angles) for m in _slides(rig).values())


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
    model = rig.model(device=DEVICE)
    up = face_up(rig.mesh, rig.landmarks)
    rest = pair_heights(model.evaluate({}), rig.landmarks, LIP_PAIRS, up, 1000.0)
    frames = [{name: 1.0} for name in LIP_SLIDE_NAMES]
    rng = np.random.default_rng(7)
    frames += [dict(zip(LIP_HINGE_NAMES, rng.uniform(0.0, 1.0, len(LIP_HINGE_NAMES)))) for _ in range(6)]
    for frame in frames:
        heights = pair_heights(model.evaluate(frame), rig.landmarks, LIP_PAIRS, up, 1000.0)
        # protrusion and sideways slides keep the heights up to the tilt of the check's up axis from the frame's
        assert np.all(heights >= rest - 1e-3), (frame, heights - rest)


def test_the_lip_slides_are_placed_relative_to_the_landmarks(rig):
    mesh, landmarks = rig.mesh, rig.landmarks
    angle = 0.4
    turn = np.array([[np.cos(angle), 0.0, np.sin(angle)], [0.0, 1.0, 0.0], [-np.sin(angle), 0.0, np.cos(angle)]])
    moved = wf.FaceMesh(2.5 * mesh.points @ turn.T + [0.3, -1.0, 2.0], mesh.triangles, name="moved")
    before = default_lip_slides(mesh, FaceFrame.from_landmarks(mesh.points[landmarks]), landmarks)
    after = default_lip_slides(moved, FaceFrame.from_landmarks(moved.points[landmarks]), landmarks)
    for a, b in zip(before, after):
        assert a.name == b.name and np.array_equal(a.vertices, b.vertices)
        np.testing.assert_allclose(b.slides, 2.5 * a.slides, rtol=1e-9)
        np.testing.assert_allclose(b.axis, turn @ a.axis, atol=1e-9)


def test_lip_slides_round_trip_through_a_stage(rig, tmp_path):
    path = tmp_path / "rig.usda"
    exact = wf.FaceRig(
        wf.FaceMesh(rig.mesh.points.astype(np.float32).astype(np.float64), rig.mesh.triangles, name=rig.mesh.name),
        list(_slides(rig).values()),
        [],
        0.0,
        name=rig.name,
    )
    wf.usd.write_rig(path, exact)
    back = wf.usd.read_rig(path)
    assert_rigs_equal(exact, back)
    frame = {"lip_upper_raise_L": 1.0, "lip_lower_slide_right": 0.5}
    np.testing.assert_allclose(
        back.model(device=DEVICE).evaluate(frame), exact.model(device=DEVICE).evaluate(frame), atol=1e-6
    )


@pytest.mark.slow
def test_the_slides_reach_ict_s_mouth_to_one_side():
    """ICT-FaceKit's mouthLeft, fitted densely: the slides take the reach from 37.5 % to about 50 % (docs/RIG.md
    §16); without them the rig stays below 40 %."""
    if ict_face_region("mouthLeft") is None or ict_landmark_indices() is None:
        pytest.skip("ICT-FaceKit data not in ../shared/data")
    from warpface.calibration import ExampleShape, reach

    source = wf.FaceMesh.from_obj(ict_face_region())
    mesh = wf.FaceMesh(source.points * 0.01, source.triangles, name="ict")
    rig = default_rig(mesh, ict_landmark_indices(), device=DEVICE)
    without = replace(rig, muscles=[m for m in rig.muscles if m.name not in LIP_SLIDE_NAMES])
    example = [ExampleShape("left", wf.FaceMesh.from_obj(ict_face_region("mouthLeft")).points * 0.01, "mouthLeft")]
    (slid,) = reach(rig, example, millimetre=1e-3, device=DEVICE)
    (held,) = reach(without, example, millimetre=1e-3, device=DEVICE)
    assert held["reduction"] < 0.40 and slid["reduction"] > 0.45, (held["reduction"], slid["reduction"])
    sideways = [slid["controls"][rig.control_names.index(f"lip_upper_slide_{way}")] for way in ("left", "right")]
    assert max(sideways) > 0.1, sideways
