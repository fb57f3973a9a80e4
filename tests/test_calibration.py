"""Calibration of muscle geometry from examples (docs/RIG.md §13): parameters, closed loop, bad input, CLI."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from helpers import small_face_rig
from hypothesis import given, settings
from hypothesis import strategies as st

from warpface.assets import default_rig
from warpface.assets.calibrated import (
    CALIBRATED_ANATOMY,
    EVERY_MUSCLE,
    EYELIDS,
    PARAMETER_FIELDS,
    SHARED_FIELDS,
    apply_parameters,
    load_calibrated_anatomy,
    parameter_layout,
)
from warpface.assets.rig import face_frame
from warpface.calibration import ExampleShape, calibrate, read_shapes, write_report
from warpface.calibration.shapes import arkit_name
from warpface.drivers.channels import ARKIT_CHANNELS
from warpface.errors import RigError


@pytest.fixture(scope="module")
def hand_rig():
    return default_rig(device="cpu", calibrated=False)


def _muscle(rig, name):
    return next(m for m in rig.muscles if m.name == name)


def test_zero_parameters_leave_the_rig(hand_rig):
    assert apply_parameters(hand_rig, {}, device="cpu") is hand_rig
    assert apply_parameters(hand_rig, {("zygomaticus_major", "zone"): 0.0}, device="cpu") is hand_rig


def test_offsets_are_mirrored_in_the_landmark_frame(hand_rig):
    frame = face_frame(hand_rig.mesh, hand_rig.landmarks)
    moved = apply_parameters(
        hand_rig, {("zygomaticus_major", "attach_x"): 0.05, ("zygomaticus_major", "attach_y"): -0.02}, device="cpu"
    )
    for side, sign in (("L", 1.0), ("R", -1.0)):
        before, after = _muscle(hand_rig, f"zygomaticus_major_{side}"), _muscle(moved, f"zygomaticus_major_{side}")
        shift = (after.attachment - before.attachment) / frame.scale
        np.testing.assert_allclose(shift @ frame.axes.T, [0.05 * sign, -0.02, 0.0], atol=1e-12)
        np.testing.assert_array_equal(after.insertion, before.insertion)
        # the radii follow the length (fractions of it), the zone is untouched
        ratio = np.linalg.norm(after.insertion - after.attachment) / np.linalg.norm(
            before.insertion - before.attachment
        )
        assert after.falloff_finish == pytest.approx(before.falloff_finish * ratio)
        assert after.zone_angle_deg == before.zone_angle_deg
    others = [m.name for m in hand_rig.muscles if not m.name.startswith("zygomaticus_major")]
    assert all(_muscle(moved, n) is _muscle(hand_rig, n) for n in others)


def test_scales_and_response_fields(hand_rig):
    values = {
        ("orbicularis_oculi", "semi_x"): 0.1,
        ("orbicularis_oculi", "ring"): 0.05,
        ("risorius", "zone"): -0.2,
        ("risorius", "finish"): 0.3,
        ("risorius", "sliding"): -5.0,  # clamped to 0
        ("risorius", "bunching"): 0.25,
    }
    moved = apply_parameters(hand_rig, values, device="cpu")
    for side in ("L", "R"):
        a, b = _muscle(hand_rig, f"orbicularis_oculi_{side}"), _muscle(moved, f"orbicularis_oculi_{side}")
        assert b.semi_axes[0] == pytest.approx(a.semi_axes[0] * np.exp(0.1))
        assert b.semi_axes[1] == pytest.approx(a.semi_axes[1])
        assert b.ring == pytest.approx(a.ring + 0.05)
        a, b = _muscle(hand_rig, f"risorius_{side}"), _muscle(moved, f"risorius_{side}")
        assert b.zone_angle_deg == pytest.approx(a.zone_angle_deg * np.exp(-0.2))
        assert b.falloff_finish == pytest.approx(a.falloff_finish * np.exp(0.3))
        assert b.sliding == 0.0 and b.bunching == pytest.approx(a.bunching * np.exp(0.25))
    lid = apply_parameters(hand_rig, {("all", "bunching"): 1.0}, device="cpu")
    assert all(m.bunching == 0.0 for m in lid.muscles if m.name.startswith("orbicularis_oculi_lower_lid"))


def test_layout_keeps_midline_muscles_on_the_midline(hand_rig):
    layout = parameter_layout(hand_rig)
    keys = {p.key for p in layout}
    assert ("procerus", "attach_x") not in keys and ("procerus", "attach_y") in keys
    assert ("orbicularis_oris", "centre_x") not in keys and ("orbicularis_oris", "semi_x") in keys
    assert all(p.field in PARAMETER_FIELDS[p.kind] for p in layout if p.group != EVERY_MUSCLE)
    assert {p.field for p in layout if p.group == EVERY_MUSCLE} == set(SHARED_FIELDS)
    assert not any(p.group.endswith(("_L", "_R")) for p in layout)


def test_bad_parameters_name_the_group(hand_rig):
    with pytest.raises(RigError, match="no muscle group 'nope'"):
        apply_parameters(hand_rig, {("nope", "zone"): 0.1})
    with pytest.raises(RigError, match="no field 'ring'"):
        apply_parameters(hand_rig, {("risorius", "ring"): 0.1})
    with pytest.raises(RigError, match="landmarks"):
        apply_parameters(small_face_rig(), {("frontalis", "zone"): 0.1})


def test_default_rig_uses_the_calibrated_anatomy(hand_rig):
    values = load_calibrated_anatomy()
    if not values:
        pytest.skip(f"{CALIBRATED_ANATOMY.name} not present")
    calibrated = default_rig(device="cpu")
    expected = apply_parameters(hand_rig, values, device="cpu")
    changed = 0
    for a, b, c in zip(calibrated.muscles, expected.muscles, hand_rig.muscles):
        assert a.name == b.name
        for name in ("attachment", "insertion", "center"):
            if hasattr(a, name):
                np.testing.assert_allclose(getattr(a, name), getattr(b, name), atol=1e-12)
                changed += not np.allclose(getattr(a, name), getattr(c, name))
    assert changed > 0
    data = json.loads(CALIBRATED_ANATOMY.read_text())
    assert data["held_out"] and not set(data["held_out"]) & set(data["trained_on"])


@pytest.mark.slow
def test_closed_loop_recovers_a_known_geometry(hand_rig):
    """Examples made by a rig with known parameters: calibrating the hand-made rig on them moves its parameters
    toward the truth and raises the reach."""
    truth = {("zygomaticus_major", "insert_y"): 0.04, ("zygomaticus_major", "zone"): 0.25}
    # the default face with the calibrated pair and two of its neighbours only (no jaw, lids or wrinkles): the same
    # calibration on a rig that rebuilds and refits in a fraction of the full rig's time
    kept = ("zygomaticus_major", "levator_anguli_oris")
    hand_rig = replace(
        hand_rig, muscles=[m for m in hand_rig.muscles if m.name.startswith(kept)], wrinkles=[], jaw=None
    )
    true_rig = apply_parameters(hand_rig, truth, device="cpu")
    model = true_rig.model(device="cpu")
    scale = face_frame(hand_rig.mesh, hand_rig.landmarks).scale
    shapes = [
        ExampleShape(f"smile_{side}_{k}", np.asarray(model.evaluate({f"zygomaticus_major_{side}": k * scale})))
        for side in ("L", "R")
        for k in (0.08, 0.15)
    ]
    result = calibrate(
        hand_rig,
        shapes,
        holdout=["smile_R_0.15"],
        muscles=["zygomaticus_major"],
        fields=["insert_y", "zone"],
        iterations=3,
        prior_weight=1e-6,
        device="cpu",
    )
    assert result.improved, result.message
    train = result.reach["train"]
    assert np.mean([r["reduction"] for r in train["after"]]) > np.mean([r["reduction"] for r in train["before"]])
    held = result.reach["held_out"]
    assert held["after"][0]["after"] < held["before"][0]["after"]
    for key, value in truth.items():
        assert 0.3 * value < result.values[key] < 1.7 * value, (key, result.values)


def test_no_improvement_keeps_the_input_rig(hand_rig):
    shape = ExampleShape("rest", hand_rig.mesh.points + 1e-4)
    result = calibrate(hand_rig, [shape], iterations=0, device="cpu")
    assert not result.improved and result.rig is hand_rig and result.values == {}
    assert "input rig is kept" in result.message


def _write(path, points, triangles):
    lines = [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in points] + [
        f"f {a + 1} {b + 1} {c + 1}" for a, b, c in triangles
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_bad_examples_name_the_file(tmp_path, hand_rig):
    mesh = hand_rig.mesh
    good = _write(tmp_path / "jawOpen.obj", mesh.points, mesh.triangles)
    nan = mesh.points.copy()
    nan[5, 1] = np.nan
    cases = {
        "nanShape.obj": (nan, mesh.triangles, "non-finite"),
        "fewer.obj": (
            mesh.points[:-10],
            mesh.triangles[mesh.triangles.max(axis=1) < len(mesh.points) - 10],
            "vertices",
        ),
        "flipped.obj": (mesh.points, mesh.triangles[:, ::-1], "topology differs"),
    }
    for name, (points, triangles, message) in cases.items():
        path = _write(tmp_path / name, points, triangles)
        with pytest.raises(ValueError, match=rf"{name}.*{message}"):
            read_shapes([good, path], hand_rig)
    with pytest.raises(ValueError, match=r"nanShape\.obj.*not an ARKit"):
        read_shapes([good, tmp_path / "nanShape.obj"], hand_rig, names="arkit")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match="no example shapes"):
        read_shapes(empty, hand_rig)
    with pytest.raises(ValueError, match="no example shapes"):
        calibrate(hand_rig, [])
    with pytest.raises(ValueError, match="'smile' is not one of the examples"):
        calibrate(hand_rig, read_shapes([good], hand_rig), holdout=["smile"])
    with pytest.raises(ValueError, match="every example is held out"):
        calibrate(hand_rig, read_shapes([good], hand_rig), holdout=["jawOpen"])
    with pytest.raises(TypeError, match="rig"):
        calibrate("rig.usda", [])


@settings(max_examples=60, deadline=None)
@given(st.text(min_size=1, max_size=24))
def test_arkit_names_are_arkit_or_none(stem):
    name = arkit_name(stem)
    if name is not None:
        assert name in ARKIT_CHANNELS or (name[:-2] in ARKIT_CHANNELS and name[-2:] in ("_L", "_R"))


def test_arkit_spellings():
    assert arkit_name("browDown_L") == "browDownLeft"
    assert arkit_name("MouthSmileRight") == "mouthSmileRight"
    assert arkit_name("browInnerUp_R") == "browInnerUp_R"
    assert arkit_name("smile") is None


def test_report_round_trip(tmp_path, hand_rig):
    shape = ExampleShape("rest", hand_rig.mesh.points + 1e-4)
    result = calibrate(hand_rig, [shape], iterations=0, device="cpu")
    result = replace(result, message="m")
    data = write_report(result, tmp_path / "r.json", picture=tmp_path / "r.png")
    assert json.loads((tmp_path / "r.json").read_text()) == json.loads(json.dumps(data))
    assert (tmp_path / "r.png").stat().st_size > 1000
    assert data["reach"]["train"]["before"]["shapes"][0]["name"] == "rest"


def test_brow_lowerer_lowers_its_brow_only(hand_rig):
    """The orbital orbicularis oculi's upper fibres (added for browDown) move every point of their brow down and
    leave the other side alone, on both sides alike."""
    frame = face_frame(hand_rig.mesh, hand_rig.landmarks)
    model = hand_rig.model(device="cpu")
    brows = {"L": list(range(22, 27)), "R": list(range(17, 22))}
    for side, other in (("L", "R"), ("R", "L")):
        points = np.asarray(model.evaluate({f"orbicularis_oculi_brow_{side}": 0.05 * frame.scale}), dtype=np.float64)
        local = (points - hand_rig.mesh.points) @ frame.axes.T / frame.scale
        down = -local[hand_rig.landmarks[brows[side]], 1]
        assert np.all(down > 0.002) and down.max() > 0.02, down
        assert np.abs(local[hand_rig.landmarks[brows[other]]]).max() < 1e-4  # float32 rounding only


def test_eyelid_group_recovers_known_lid_shapes(hand_rig):
    """The ``eyelids`` group (docs/RIG.md §13) rebuilds the six hinges from the landmarks: blinks made by hinges of a
    known radial and lower-lid reach calibrate the hand-made rig's hinges back to them."""
    truth = {(EYELIDS, "radial_reach"): 0.15, (EYELIDS, "lower_reach"): -0.3}
    lids_only = replace(hand_rig, muscles=[m for m in hand_rig.muscles if m.name.startswith("lid_")], wrinkles=[])
    lids_only = replace(lids_only, jaw=None)
    model = apply_parameters(lids_only, truth, device="cpu").model(device="cpu")
    blinks = {
        f"blink_{side}_{k}": {f"lid_upper_close_{side}": k, f"lid_lower_close_{side}": k}
        for side in "LR"
        for k in (0.5, 1)
    }
    shapes = [ExampleShape(name, np.asarray(model.evaluate(controls))) for name, controls in blinks.items()]
    options = dict(muscles=[EYELIDS], fields=["radial_reach", "lower_reach"], iterations=3, prior_weight=1e-6)
    result = calibrate(lids_only, shapes, holdout=["blink_R_1"], device="cpu", **options)
    assert result.improved, result.message
    held = result.reach["held_out"]
    assert held["after"][0]["after"] < 0.1 * held["before"][0]["after"]
    for key, value in truth.items():
        assert result.values[key] == pytest.approx(value, rel=0.1), (key, result.values)


def test_eyelid_group_keeps_each_hinge_s_range_and_needs_the_default_hinges(hand_rig):
    layout = parameter_layout(hand_rig, [EYELIDS])
    assert [p.field for p in layout] == list(PARAMETER_FIELDS["lids"])
    limited = replace(
        hand_rig,
        muscles=[replace(m, fit_limit=3.0) if m.name == "lid_upper_raise_L" else m for m in hand_rig.muscles],
    )
    moved = apply_parameters(limited, {(EYELIDS, "meet"): 0.05}, device="cpu")
    before, after = _muscle(limited, "lid_upper_raise_L"), _muscle(moved, "lid_upper_raise_L")
    assert after.fit_limit == 3.0 and after.taper_share == before.taper_share
    # the meeting line rises: the upper lid turns less, the lower more
    for name, grows in (("lid_upper_close_L", False), ("lid_lower_close_L", True)):
        turn_before, turn_after = np.abs(_muscle(limited, name).angles).sum(), np.abs(_muscle(moved, name).angles).sum()
        assert (turn_after > turn_before) == grows, name
    without = replace(hand_rig, muscles=[m for m in hand_rig.muscles if not m.name.startswith("lid_")])
    assert not [p for p in parameter_layout(without) if p.group == EYELIDS]
    with pytest.raises(RigError, match="lid hinges"):
        apply_parameters(without, {(EYELIDS, "meet"): 0.05}, device="cpu")
