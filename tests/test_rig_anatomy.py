"""The full default rig: C¹ zones (SPEC §6.3), skin sliding and bunching, the §1.1 forms still selectable,
the added muscles, and the rig with its jaw through USD."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import reference_expression as ref
from helpers import grid_surface

import warpface as wf
from warpface.assets import SPHINCTER_MUSCLE_NAMES, default_rig
from warpface.assets.anatomy import SKIN_RESPONSE_OVERRIDES
from warpface.assets.lids import LID_CONTROL_NAMES
from warpface.assets.lips import LIP_SEAL_NAME
from warpface.assets.rig import BODY_CONTROL_NAMES, CLASSIC_LINEAR_MUSCLE_NAMES, LINEAR_MUSCLE_NAMES, face_frame
from warpface.expression import muscle_weights
from warpface.expression.lids import LidMuscle
from warpface.expression.tissue import neighbourhood_mean, tissue_response

DEVICE = "cpu"


def dense(points, muscle):
    weights = muscle_weights(points, [muscle], device=DEVICE)
    out = np.zeros((len(points), 3))
    out[np.repeat(np.arange(len(points)), np.diff(weights.offsets))] = weights.weight
    return out


def smooth_linear_reference(points, v1, v2, zone_deg, rs, rf):
    """Independent float64 form of the C¹ linear zone: cos² angular, sin² / cos² radial (docs/RIG.md §1)."""
    offset = points - v1
    distance = np.linalg.norm(offset, axis=1)
    axis = (v2 - v1) / np.linalg.norm(v2 - v1)
    mu = np.arccos(np.clip(offset @ axis / distance, -1.0, 1.0))
    zone = np.radians(zone_deg)
    inside = (mu <= zone) & (distance <= rf) & (distance > 0)
    angular = np.cos(mu / zone * np.pi / 2) ** 2
    radial = np.where(
        distance < rs, np.sin(distance / rs * np.pi / 2) ** 2, np.cos((distance - rs) / (rf - rs) * np.pi / 2) ** 2
    )
    return np.where(inside[:, None], -(angular * radial / distance)[:, None] * offset, 0.0)


LINEAR = dict(
    attachment=np.array([0.0, 0.0, 0.0]),
    insertion=np.array([1.0, 0.0, 0.0]),
    zone_angle_deg=35.0,
    falloff_start=0.6,
    falloff_finish=1.5,
)


def edge_slope(falloff, path, parameter_at_edge):
    """|d|w|/dt| by a one-sided float64 difference of step h at the zone edge, for h = 1e-3 and 1e-4."""
    muscle = wf.LinearMuscle("m", falloff=falloff, **LINEAR)
    slopes = []
    for h in (1e-3, 1e-4):
        points = np.array([path(parameter_at_edge), path(parameter_at_edge - h)])
        magnitude = np.linalg.norm(dense(points, muscle), axis=1)
        slopes.append(abs(magnitude[1] - magnitude[0]) / h)
    return slopes


@pytest.mark.parametrize("edge", ["angle", "finish", "attachment"])
def test_smooth_linear_zone_vanishes_with_zero_slope_where_waters_does_not(edge):
    zone = np.radians(LINEAR["zone_angle_deg"])
    rs, rf = LINEAR["falloff_start"], LINEAR["falloff_finish"]
    if edge == "angle":
        path, at = (lambda mu: rs * np.array([np.cos(mu), np.sin(mu), 0.0])), zone
    elif edge == "finish":
        path, at = (lambda d: np.array([d, 0.0, 0.0])), rf
    else:  # approaching the attachment from inside: t = −D
        path, at = (lambda t: np.array([-t, 0.0, 0.0])), 0.0
    smooth = edge_slope("smooth", path, at)
    waters = edge_slope("waters", path, at)
    assert waters[1] > 0.5, "the §1.1 form meets its edge with a slope"
    assert smooth[1] < 2e-3 and smooth[1] < 0.2 * smooth[0], "C¹: the slope → 0 with the step"


def test_smooth_sphincter_rim_has_zero_slope():
    def rim_slopes(falloff):
        muscle = wf.SphincterMuscle("s", [0, 0, 0], [1, 0, 0], [0, 1, 0], (2.0, 1.0), falloff=falloff)
        out = []
        for h in (1e-3, 1e-4):
            points = np.array([[2.0, 0.0, 0.0], [2.0 - h, 0.0, 0.0]])
            out.append(np.linalg.norm(np.diff(np.linalg.norm(dense(points, muscle), axis=1))) / h)
        return out

    waters, smooth = rim_slopes("waters"), rim_slopes("smooth")
    assert waters[1] > 0.5
    assert smooth[1] < 2e-3 and smooth[1] < 0.2 * smooth[0]
    points = np.random.default_rng(0).uniform(-2.5, 2.5, (400, 3))
    rho2 = points[:, 0] ** 2 / 4.0 + points[:, 1] ** 2
    expected = np.where((rho2 < 1)[:, None], -((1 - rho2) ** 2)[:, None] * np.c_[points[:, :2], np.zeros(400)], 0.0)
    muscle = wf.SphincterMuscle("s", [0, 0, 0], [1, 0, 0], [0, 1, 0], (2.0, 1.0), falloff="smooth")
    np.testing.assert_allclose(dense(points, muscle), expected, atol=1e-12)


def test_sphincter_ring_matches_its_float64_formula_and_meets_the_ring_with_zero_slope():
    ring = 0.6
    points = np.random.default_rng(2).uniform(-2.5, 2.5, (400, 3))
    rho = np.sqrt(points[:, 0] ** 2 / 4.0 + points[:, 1] ** 2)
    fade = np.where(rho < ring, np.sin(rho / ring * np.pi / 2) ** 2, 1.0)
    expected = np.where(
        (rho < 1)[:, None], -(fade * (1 - rho**2) ** 2)[:, None] * np.c_[points[:, :2], np.zeros(400)], 0.0
    )
    muscle = wf.SphincterMuscle("s", [0, 0, 0], [1, 0, 0], [0, 1, 0], (2.0, 1.0), falloff="smooth", ring=ring)
    np.testing.assert_allclose(dense(points, muscle), expected, atol=1e-12)
    # Along the x axis (x = 2ρ) the fade's slope in ρ vanishes at the ring: compare one-sided differences of
    # |d| / ((1 − ρ²)² x), the fade alone, just inside the ring.
    slopes = []
    for h in (1e-3, 1e-4):
        rhos = np.array([ring, ring - h])
        points = np.c_[2.0 * rhos, np.zeros(2), np.zeros(2)]
        fade_values = np.linalg.norm(dense(points, muscle), axis=1) / ((1 - rhos**2) ** 2 * points[:, 0])
        slopes.append(abs(fade_values[0] - fade_values[1]) / h)
    assert slopes[1] < 5e-3 and slopes[1] < 0.2 * slopes[0]
    assert np.all(dense(np.zeros((1, 3)), muscle) == 0.0)
    for bad in (-0.1, 1.0, float("nan")):
        with pytest.raises(ValueError, match="ring"):
            wf.SphincterMuscle("s", [0, 0, 0], [1, 0, 0], [0, 1, 0], (2.0, 1.0), ring=bad)


def test_smooth_linear_zone_matches_its_float64_formula():
    points = np.random.default_rng(1).uniform(-0.5, 2.0, (2000, 3))
    muscle = wf.LinearMuscle("m", falloff="smooth", **LINEAR)
    expected = smooth_linear_reference(
        points, *(LINEAR[k] for k in ("attachment", "insertion", "zone_angle_deg", "falloff_start", "falloff_finish"))
    )
    np.testing.assert_allclose(dense(points, muscle), expected, atol=1e-10)


@pytest.fixture(scope="module")
def rig():
    return default_rig(device=DEVICE)


def _waters(rig):
    """The rig's Waters muscles (its lid hinges, docs/RIG.md §11, are tested in test_lids.py)."""
    return [m for m in rig.muscles if not isinstance(m, LidMuscle)]


def test_waters_forms_of_the_full_rig_still_match_the_section_1_reference(rig):
    points = rig.mesh.points
    for muscle in _waters(rig)[::5]:
        # §1.1 forms: Waters zones, no sliding, bunching, lobe or ring
        extra = {"lobes": ()} if isinstance(muscle, wf.LinearMuscle) else {"ring": 0.0}
        classic = replace(muscle, falloff="waters", sliding=0.0, bunching=0.0, thickening=0.0, **extra)
        if isinstance(muscle, wf.LinearMuscle):
            expected = ref.linear_muscle(
                points,
                muscle.attachment,
                muscle.insertion,
                muscle.zone_angle_deg,
                muscle.falloff_start,
                muscle.falloff_finish,
                1.0,
            )
        else:
            expected = ref.sphincter_muscle(points, muscle.center, muscle.axis_x, muscle.axis_y, *muscle.semi_axes, 1.0)
        np.testing.assert_allclose(dense(points, classic), expected, atol=1e-9 * rig.mesh.size, err_msg=muscle.name)


def test_a_lobe_adds_its_own_zone_scaled_by_its_gain(rig):
    points = rig.mesh.points
    lobed = [m for m in rig.muscles if isinstance(m, wf.LinearMuscle) and m.lobes]
    assert {m.name for m in lobed} >= {"frontalis_inner_L", "frontalis_middle_R", "orbicularis_oculi_lower_lid_L"}
    for muscle in lobed:
        classic = replace(muscle, falloff="waters", sliding=0.0, bunching=0.0, thickening=0.0)
        expected = ref.linear_muscle(
            points,
            muscle.attachment,
            muscle.insertion,
            muscle.zone_angle_deg,
            muscle.falloff_start,
            muscle.falloff_finish,
            1.0,
        )
        for lobe in muscle.lobes:
            expected += lobe.gain * ref.linear_muscle(
                points,
                lobe.attachment,
                lobe.insertion,
                lobe.zone_angle_deg,
                lobe.falloff_start,
                lobe.falloff_finish,
                1.0,
            )
        np.testing.assert_allclose(dense(points, classic), expected, atol=1e-9 * rig.mesh.size, err_msg=muscle.name)
    for bad in (dict(gain=0.0), dict(gain=float("inf")), dict(zone_angle_deg=180.0), dict(falloff_start=2.0)):
        fields = dict(
            attachment=[0, 0, 0], insertion=[1, 0, 0], zone_angle_deg=40.0, falloff_start=0.5, falloff_finish=1.5
        )
        with pytest.raises(ValueError, match="muscle lobe"):
            wf.MuscleLobe(**{**fields, **bad})
    with pytest.raises(TypeError, match="lobes"):
        wf.LinearMuscle("m", lobes=["frontalis"], **LINEAR)
    with pytest.raises(TypeError, match="lobes"):
        wf.LinearMuscle("m", lobes=5, **LINEAR)


def test_the_risorius_draws_the_lower_cheek_toward_the_ear(rig):
    """docs/RIG.md §5 masseteric lobe: the lower cheek between the mouth corner and the jaw outline moves with the
    risorius, laterally; without the lobe its narrow cone moves the corner only (that skin stays put)."""
    frame = face_frame(rig.mesh, rig.landmarks)
    local = frame.to_local(rig.mesh.points)
    marks = local[rig.landmarks]
    for tag, sign, corner, jaw in (("L", 1.0, 54, 12), ("R", -1.0, 48, 4)):
        muscle = next(m for m in rig.muscles if m.name == f"risorius_{tag}")
        (lobe,) = muscle.lobes
        fixed, insertion = frame.to_local(lobe.attachment), frame.to_local(lobe.insertion)
        assert sign * fixed[0] > abs(marks[jaw, 0])  # beyond the face's side, over the masseter
        assert abs(marks[corner, 0]) < sign * insertion[0] < abs(marks[jaw, 0])
        # skin points half-way from the corner to the jaw outline, below the mouth line
        way = marks[corner, :2] + 0.5 * (marks[jaw, :2] - marks[corner, :2])
        near = np.linalg.norm(local[:, :2] - way, axis=1) < 0.1
        near &= local[:, 2] > marks[jaw, 2]  # the face's front, not the back of the mesh
        assert near.sum() >= 3
        step = 1e-3 * frame.scale  # a small contraction, so the frame's scale does not enter
        lateral = []
        for lobes in (muscle.lobes, ()):
            moved = rig.mesh.points[near] + step * dense(rig.mesh.points, replace(muscle, lobes=lobes))[near]
            lateral.append(sign * (frame.to_local(moved)[:, 0] - local[near, 0]).mean() / step)
        assert lateral[0] > 0 and lateral[0] > 2.0 * abs(lateral[1])


def test_full_rig_has_every_muscle_with_c1_zones_and_a_jaw(rig):
    assert rig.muscle_names == [
        *LINEAR_MUSCLE_NAMES,
        *SPHINCTER_MUSCLE_NAMES,
        *BODY_CONTROL_NAMES,
        *LID_CONTROL_NAMES,
        LIP_SEAL_NAME,
    ]
    assert set(CLASSIC_LINEAR_MUSCLE_NAMES) < set(rig.muscle_names)
    for name in (
        "depressor_supercilii_L",
        "levator_anguli_oris_R",
        "zygomaticus_minor_L",
        "buccinator_R",
        "platysma_L",
        "nasalis_R",
        "orbicularis_oculi_upper_lid_L",
        "orbicularis_oculi_lower_lid_R",
        "orbicularis_oris_press",
        "orbicularis_oris_roll_upper",
    ):
        assert name in rig.muscle_names
    assert all(m.falloff == "smooth" and m.sliding > 0 for m in _waters(rig))
    assert all(m.bunching > 0 for m in _waters(rig) if m.name not in SKIN_RESPONSE_OVERRIDES)
    assert {m.name for m in _waters(rig) if m.bunching == 0} == set(SKIN_RESPONSE_OVERRIDES)
    assert "frontalis_middle_L" in rig.muscle_names
    assert next(m for m in rig.muscles if m.name == "orbicularis_oculi_L").ring > 0
    assert rig.jaw is not None and rig.control_names[-3:] == ["jaw_open", "jaw_forward", "jaw_left"]
    classic = default_rig(device=DEVICE, anatomy="classic")
    assert classic.jaw is None and all(m.falloff == "waters" and m.sliding == 0 for m in classic.muscles)
    with pytest.raises(wf.RigError, match="anatomy"):
        default_rig(device=DEVICE, anatomy="modern")


def test_sliding_removes_the_normal_pull_and_bunching_lifts_compressed_skin():
    points, triangles = grid_surface(30, size=2.0, height=0.0, seed=None)
    normals = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    muscle = wf.LinearMuscle("m", [0.0, -0.2, -0.3], [0.0, 0.8, 0.0], 40.0, 0.7, 1.4)
    weights = muscle_weights(points, [muscle], device=DEVICE)
    thickness = np.full(len(points), 0.1)
    plain = dense(points, muscle)
    assert np.abs(plain[:, 2]).max() > 0.05, "the Waters pull sinks toward the bone beneath the skin"
    slid = tissue_response(points, triangles, normals, thickness, [replace(muscle, sliding=1.0)], weights)
    field = np.zeros((len(points), 3))
    field[np.repeat(np.arange(len(points)), np.diff(slid.offsets))] = slid.weight
    np.testing.assert_allclose(field[:, 2], 0.0, atol=1e-12)
    # On a flat sheet the tangential part is the pull's in-plane part, untouched.
    np.testing.assert_allclose(field[:, :2], plain[:, :2], atol=1e-12)
    half = tissue_response(points, triangles, normals, thickness, [replace(muscle, sliding=0.5)], weights)
    halved = np.zeros((len(points), 3))
    halved[np.repeat(np.arange(len(points)), np.diff(half.offsets))] = half.weight
    np.testing.assert_allclose(halved, plain * [1.0, 1.0, 0.5], atol=1e-12)
    bunched = tissue_response(
        points, triangles, normals, thickness, [replace(muscle, sliding=1.0, bunching=2.0)], weights
    )
    lift = np.zeros(len(points))
    lift[np.repeat(np.arange(len(points)), np.diff(bunched.offsets))] = bunched.weight[:, 2]
    # Skin between the bone point and the zone converges (compresses): it rises out of the face.
    converging = np.linalg.norm(points[:, :2] - [0.0, 0.3], axis=1) < 0.25
    assert lift[converging].mean() > 0.0 and lift.max() > 0.01
    # Every term is per unit contraction: the muscle stage stays linear in K.
    mesh = wf.FaceMesh(points, triangles)
    model = wf.ExpressionModel(
        mesh, [replace(muscle, sliding=1.0, bunching=2.0, thickening=0.3)], thickness=thickness, device=DEVICE
    )
    one = model.stages([0.05]).muscle - points
    two = model.stages([0.10]).muscle - points
    np.testing.assert_allclose(two, 2.0 * one, atol=1e-6)


def test_neighbourhood_mean_is_a_weighted_average():
    points = np.random.default_rng(3).uniform(0, 1, (300, 3))
    constant = neighbourhood_mean(points, np.full(300, 2.5), 0.2)
    np.testing.assert_allclose(constant, 2.5)
    linear = neighbourhood_mean(points, points[:, 0], 0.2)
    assert np.all(linear >= points[:, 0].min()) and np.all(linear <= points[:, 0].max())


def test_full_rig_round_trips_through_usd_with_its_jaw(rig, tmp_path):
    from warpface.usd import read_rig, write_rig

    path = tmp_path / "face.usda"
    write_rig(path, rig)
    back = read_rig(path)
    assert back.control_names == rig.control_names
    np.testing.assert_allclose(back.jaw.weights, rig.jaw.weights)
    np.testing.assert_allclose(back.jaw.pivot, rig.jaw.pivot)
    for original, read in zip(rig.muscles, back.muscles):
        assert (read.falloff, read.sliding, read.bunching, read.thickening, getattr(read, "ring", None)) == (
            original.falloff,
            original.sliding,
            original.bunching,
            original.thickening,
            getattr(original, "ring", None),
        )
        lobes = [getattr(m, "lobes", ()) for m in (original, read)]
        assert len(lobes[0]) == len(lobes[1]), original.name
        for lobe, lobe_read in zip(*lobes):
            for field in ("attachment", "insertion", "zone_angle_deg", "falloff_start", "falloff_finish", "gain"):
                np.testing.assert_allclose(getattr(lobe_read, field), getattr(lobe, field), rtol=1e-12, atol=1e-15)
    controls = {"jaw_open": 0.2, "zygomaticus_major_L": 0.004, "orbicularis_oculi_R": 0.2}
    np.testing.assert_allclose(
        back.model(device=DEVICE).evaluate(controls), rig.model(device=DEVICE).evaluate(controls), atol=1e-6
    )


def test_a_broken_lobe_on_the_stage_is_one_clear_error(rig, tmp_path):
    import shutil

    from pxr import Usd

    from warpface.usd import read_rig, write_rig

    path = tmp_path / "face.usda"
    write_rig(path, rig)
    muscle = "/Face/Muscles/frontalis_inner_L"
    from pxr import Vt

    def with_first(name, value):  # the array with its first entry replaced
        def edit(prim):
            values = list(prim.GetAttribute(name).Get())
            prim.GetAttribute(name).Set(Vt.DoubleArray([value] + values[1:]))

        return edit

    def one_more(prim):
        gains = list(prim.GetAttribute("lobes:gain").Get())
        prim.GetAttribute("lobes:gain").Set(Vt.DoubleArray(gains + [0.4]))

    cases = (
        (lambda p: p.RemoveProperty("lobes:insertion"), "lobes:insertion: attribute is missing"),
        (with_first("lobes:gain", -1.0), "gain must be in"),
        (with_first("lobes:zoneAngle", float("nan")), "lobes:zoneAngle: non-finite"),
        (one_more, "one entry per lobe"),
    )
    for case, (edit, message) in enumerate(cases):
        copy = shutil.copy(path, tmp_path / f"case{case}.usda")  # each edit on its own layer
        stage = Usd.Stage.Open(str(copy))
        edit(stage.GetPrimAtPath(muscle))
        with pytest.raises(wf.RigError, match=message) as caught:
            read_rig(stage)
        assert "frontalis_inner_L" in str(caught.value)
    stage = Usd.Stage.Open(str(shutil.copy(path, tmp_path / "no_lobe.usda")))
    stage.GetPrimAtPath(muscle).GetAttribute("lobes:gain").Set(Vt.DoubleArray())  # empty: no lobes
    assert next(m for m in read_rig(stage).muscles if m.name == "frontalis_inner_L").lobes == ()


# ------------------------------------------------------------------------------------------------ presets


def region_centres(local_landmarks):
    """Local (|x|, y) of the regions preset names refer to (sided ones: the subject's left side)
    [inter-ocular units]."""
    xy = local_landmarks[:, :2]
    left_eye, mouth = xy[42:48].mean(axis=0), xy[48:68].mean(axis=0)
    return {
        "brow": xy[22:27].mean(axis=0),
        "eye": left_eye,
        "cheek": 0.7 * left_eye + 0.3 * xy[54],  # the malar cheek
        "nose": xy[[31, 35]].mean(axis=0) * [0.0, 1.0] + [abs(xy[35, 0]), 0.0],
        "mouth": mouth,
        "corner": xy[54],
        "jaw": xy[[7, 8, 9, 57]].mean(axis=0),
    }


@pytest.mark.parametrize("anatomy_face", ["builtin"])
def test_presets_move_the_regions_they_name(rig, anatomy_face):
    from warpface.assets import ARKIT_PRESET_NAMES, PRESETS, preset_controls
    from warpface.assets.rig import face_frame

    frame = face_frame(rig.mesh, rig.landmarks)
    local = frame.to_local(rig.mesh.points)
    centres = region_centres(local[rig.landmarks])
    model = rig.model(device=DEVICE)
    names = list(PRESETS)
    frames = model.evaluate([preset_controls(name, rig) for name in names])
    for name, frame_points in zip(names, frames):
        moved = np.linalg.norm(frame_points - rig.mesh.points, axis=1) / frame.scale
        assert moved.max() > 0.02, f"{name}: visibly moves the face (> 2 % of the eye distance)"
        if name not in ARKIT_PRESET_NAMES:
            continue
        weight = moved**2
        centroid = (local[:, :2] * weight[:, None]).sum(axis=0) / weight.sum()
        region = next(key for key in ("brow", "eye", "cheek", "nose", "jaw", "mouth") if name.lower().startswith(key))
        sided = name.endswith(("Left", "Right")) and region in ("brow", "eye", "cheek", "nose", "mouth")
        sided = sided and name not in ("mouthLeft", "mouthRight")
        x = abs(centroid[0]) if sided else centroid[0]
        target = centres["corner" if sided and region == "mouth" else region]
        target = target if sided else target * [0.0, 1.0]
        if name in ("mouthLeft", "mouthRight"):  # the named corner is drawn toward its side (muscle stage)
            pulled = model.stages(preset_controls(name, rig)).muscle - rig.mesh.points
            corner = rig.landmarks[54 if name == "mouthLeft" else 48]
            assert pulled[corner] @ frame.axes[0] * (1.0 if name == "mouthLeft" else -1.0) > 0.003 * frame.scale, name
            x = target[0]
        distance = np.hypot(x - target[0], centroid[1] - target[1])
        assert distance < 0.45, f"{name}: motion centred at {centroid.round(2)}, {region} is at {target.round(2)}"
        if name.endswith("Left") and not name.startswith(("jaw", "mouthLeft")):
            assert centroid[0] > 0.05, f"{name}: the subject's left side (+x) moves"
        if name.endswith("Right") and not name.startswith(("jaw", "mouthRight")):
            assert centroid[0] < -0.05, f"{name}: the subject's right side (−x) moves"
    opened = frames[names.index("jawOpen")]
    lm = rig.landmarks
    assert (
        np.linalg.norm(opened[lm[66]] - opened[lm[62]])
        > np.linalg.norm(rig.mesh.points[lm[66]] - rig.mesh.points[lm[62]]) + 0.1 * frame.scale
    )
    left = frames[names.index("jawLeft")][lm[8]] - rig.mesh.points[lm[8]]
    assert left @ frame.axes[0] > 0.03 * frame.scale
    with pytest.raises(ValueError, match="unknown preset"):
        preset_controls("mouthYawn", rig)
    with pytest.raises(wf.RigError, match="jaw_open"):
        preset_controls("jawOpen", default_rig(device=DEVICE, anatomy="classic"))
