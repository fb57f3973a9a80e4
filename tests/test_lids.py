"""Eyelid hinges (docs/RIG.md §11): the field against a float64 reference, blinks that close, I/O, the solver."""

from __future__ import annotations

import numpy as np
import pytest
import reference_expression as ref
from helpers import assert_rigs_equal

import warpface as wf
from warpface.assets import default_rig, preset_controls
from warpface.assets.lids import LID_CONTROL_NAMES
from warpface.assets.quality import LID_PAIRS, face_up, pair_distances, pair_heights
from warpface.assets.rig import BODY_CONTROL_NAMES
from warpface.data import ict_face_region, ict_landmark_indices
from warpface.drivers.default_tables import mapping_for_rig
from warpface.expression import muscle_weights
from warpface.expression.lids import LidMuscle, bulging_thickness, hinge_taper
from warpface.expression.seal import LipSeal
from warpface.solve import fit

DEVICE = "cpu"


@pytest.fixture(scope="module")
def rig():
    return default_rig(device=DEVICE)


def _dense(points, muscle):
    weights = muscle_weights(points, [muscle], device=DEVICE)
    out = np.zeros_like(points)
    rows = np.repeat(np.arange(len(points)), np.diff(weights.offsets))
    out[rows] = weights.weight
    return out


def test_lid_field_matches_the_float64_rodrigues_reference():
    rng = np.random.default_rng(3)
    points = rng.normal(size=(40, 3))
    vertices = np.array([1, 5, 7, 22, 39])
    angles, slides, lifts = rng.uniform(-1.2, 1.2, 5), rng.normal(size=5) * 0.1, rng.normal(size=5) * 0.1
    axis, centre = np.array([0.3, 1.0, -0.2]), np.array([0.1, -0.2, 0.4])
    lid = LidMuscle("lid", centre, axis, vertices, angles, slides, lifts)
    expected = ref.lid_hinge(points, centre, axis, vertices, angles, slides, lifts, 1.0)
    np.testing.assert_allclose(_dense(points, lid), expected, atol=1e-12)
    # a pure turn keeps each vertex's distance from the axis line and its position along it
    turn = _dense(points, LidMuscle("turn", centre, axis, vertices, angles)) + points
    unit = axis / np.linalg.norm(axis)
    for p, q in ((points[vertices], turn[vertices]),):
        along_p, along_q = (p - centre) @ unit, (q - centre) @ unit
        np.testing.assert_allclose(along_q, along_p, atol=1e-12)
        radial = np.linalg.norm(np.cross(p - centre, unit), axis=1)
        np.testing.assert_allclose(np.linalg.norm(np.cross(q - centre, unit), axis=1), radial, atol=1e-12)


def test_lid_muscle_rejects_bad_values():
    with pytest.raises(ValueError, match="angles"):
        LidMuscle("lid", np.zeros(3), [1, 0, 0], [0, 1], [0.1])
    with pytest.raises(ValueError, match="angles"):
        LidMuscle("lid", np.zeros(3), [1, 0, 0], [0], [2.0])
    with pytest.raises(ValueError, match="distinct"):
        LidMuscle("lid", np.zeros(3), [1, 0, 0], [0, 0], [0.1, 0.2])
    with pytest.raises(ValueError, match="slides"):
        LidMuscle("lid", np.zeros(3), [1, 0, 0], [0], [0.1], slides=[0.0, 1.0])
    with pytest.raises(TypeError, match="name"):
        LidMuscle(3, np.zeros(3), [1, 0, 0], [0], [0.1])
    mesh = wf.FaceMesh(np.eye(3), [[0, 1, 2]])
    with pytest.raises(wf.RigError, match="vertex 5"):
        wf.FaceRig(mesh, [LidMuscle("lid", np.zeros(3), [1, 0, 0], [5], [0.1])], [], 0.0)


def _blinks(rig, model):
    mapping, _, _ = mapping_for_rig(rig, "arkit")
    curves = wf.drivers.Curves(np.zeros(1), ["eyeBlinkLeft", "eyeBlinkRight"], np.ones((1, 2)))
    mapped = mapping.apply(curves)
    arkit = model.control_vector(dict(zip(mapped.names, mapped.values[0])))
    preset = {**preset_controls("eyeBlinkLeft", rig), **preset_controls("eyeBlinkRight", rig)}
    return model.evaluate(np.stack([arkit, model.control_vector(preset)]))


def _check_blink(rig, mm):
    model = rig.model(device=DEVICE)
    up = face_up(rig.mesh, rig.landmarks)
    assert pair_distances(rig.mesh.points, rig.landmarks, LID_PAIRS, mm).min() > 5.0  # a rest gap of several mm
    frames = _blinks(rig, model)
    assert pair_distances(frames, rig.landmarks, LID_PAIRS, mm).max() <= 0.5
    assert pair_heights(frames, rig.landmarks, LID_PAIRS, up, mm).min() >= -0.2


def test_a_blink_closes_the_built_in_face_s_lids(rig):
    assert rig.muscle_names[-7:-1] == list(LID_CONTROL_NAMES)
    _check_blink(rig, 1000.0)


def test_a_blink_closes_the_ict_face_s_lids():
    path, landmarks = ict_face_region(), ict_landmark_indices()
    if path is None or landmarks is None:
        pytest.skip("ICT-FaceKit data not found in ../shared/data (set WARPFACE_SHARED_DATA)")
    source = wf.FaceMesh.from_obj(path)
    _check_blink(default_rig(wf.FaceMesh(source.points * 0.01, source.triangles), landmarks, device=DEVICE), 1000.0)


def _ict_mesh(warped: bool = False):
    path, landmarks = ict_face_region(), ict_landmark_indices()
    if path is None or landmarks is None:
        pytest.skip("ICT-FaceKit data not found in ../shared/data (set WARPFACE_SHARED_DATA)")
    from benchmarks.face_quality import smooth_warp

    source = wf.FaceMesh.from_obj(path)
    points = smooth_warp(source.points) if warped else source.points
    return wf.FaceMesh(points * 0.01, source.triangles), landmarks


def test_a_blink_closes_a_warped_ict_face_s_lids():
    """Another identity rigged from its own landmarks: its margins meet along a meeting line that slopes."""
    _check_blink(default_rig(*_ict_mesh(warped=True), device=DEVICE), 1000.0)


@pytest.mark.slow
def test_a_blink_closes_a_scan_s_lids_from_found_landmarks(lee_perry_smith):
    """The Lee Perry-Smith scan (eyes closed over by skin) rigged from landmarks found on it: its lid gap narrows
    toward the midpoints, so the wrinkles kept a quarter of their lift there (0.9 mm open) and the upper midpoint
    passed the lower (−0.44 mm) before the taper saturated and the upper lid met its partner's x."""
    mesh, landmarks, mm = lee_perry_smith
    _check_blink(default_rig(mesh, landmarks, device=DEVICE), mm)


def test_the_hinge_taper_saturates_on_a_lid_and_not_on_the_lip_seal():
    angles = np.array([0.1, 0.2, 0.3, 0.4, 0.6, 0.8])
    share = 0.5
    lid = LidMuscle("lid", np.zeros(3), [1, 0, 0], np.arange(1, 7), -angles, taper_share=share)
    seal = LipSeal("seal", np.zeros(3), [1, 0, 0], np.arange(4, 10), angles, pairs=np.array([[4, 5]]))
    expected_lid = np.clip(1.0 - angles / (share * 0.8), 0.0, 1.0)  # 0 from half the largest turn on
    np.testing.assert_allclose(hinge_taper(12, [lid])[1:7], expected_lid, atol=1e-15)
    np.testing.assert_allclose(hinge_taper(12, [seal])[4:10], 1.0 - angles / 0.8, atol=1e-15)
    both = hinge_taper(12, [lid, seal, "not a hinge"])
    assert both[0] == 1.0 and both[11] == 1.0
    np.testing.assert_allclose(both[4:7], np.minimum(expected_lid[3:], 1.0 - angles[:3] / 0.8), atol=1e-15)
    # the bulge fades by the eyelids' taper only
    np.testing.assert_allclose(bulging_thickness(np.full(12, 2.0), [lid, seal]), 2.0 * hinge_taper(12, [lid]))
    for bad in (0.0, 1.5, np.nan):
        with pytest.raises(ValueError, match="taper_share"):
            LidMuscle("lid", np.zeros(3), [1, 0, 0], [1], [0.1], taper_share=bad)


def test_the_taper_share_round_trips_through_a_stage(tmp_path):
    mesh = wf.FaceMesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]), [[0, 1, 2], [1, 3, 2]])
    lids = [
        LidMuscle(name, [0, 0, -1], [1, 0, 0], [1, 2], [0.2, 0.1], taper_share=share)
        for name, share in (("half", 0.5), ("whole", 1.0))
    ]
    path = tmp_path / "lids.usda"
    wf.usd.write_rig(path, wf.FaceRig(mesh, lids, [], 0.0))
    assert [m.taper_share for m in wf.usd.read_rig(path).muscles] == [0.5, 1.0]
    from pxr import Usd

    stage = Usd.Stage.Open(str(path))
    prims = [p for p in stage.Traverse() if p.GetTypeName() == "WarpFaceLidMuscle"]
    prims[0].GetAttribute("taperShare").Clear()  # a stage written before the attribute
    prims[1].GetAttribute("taperShare").Set(2.0)
    stage.Save()
    with pytest.raises(wf.RigError, match="taperShare"):
        wf.usd.read_rig(path)
    prims[1].GetAttribute("taperShare").Clear()
    stage.Save()
    assert [m.taper_share for m in wf.usd.read_rig(path).muscles] == [1.0, 1.0]


def test_a_wide_eye_raises_the_upper_lid_and_closing_halfway_halves_the_gap(rig):
    model = rig.model(device=DEVICE)
    up = face_up(rig.mesh, rig.landmarks)
    rest = pair_heights(rig.mesh.points, rig.landmarks, LID_PAIRS, up, 1000.0)
    wide = model.evaluate(preset_controls("eyeWideLeft", rig))
    heights = pair_heights(wide, rig.landmarks, LID_PAIRS, up, 1000.0)
    assert np.all(heights[2:] > rest[2:] + 1.0) and np.allclose(heights[:2], rest[:2], atol=1e-3)
    half = model.evaluate({"lid_upper_close_R": 0.5, "lid_lower_close_R": 0.5})
    np.testing.assert_allclose(pair_heights(half, rig.landmarks, LID_PAIRS, up, 1000.0)[:2], 0.5 * rest[:2], rtol=0.15)


def test_lids_round_trip_through_a_stage(rig, tmp_path):
    path = tmp_path / "rig.usda"
    wf.usd.write_rig(path, rig)
    back = wf.usd.read_rig(path)
    lids = [
        m for m in back.muscles if isinstance(m, LidMuscle) and m.name not in BODY_CONTROL_NAMES
    ]  # lips, corners: §15–17
    assert [m.name for m in lids] == [*LID_CONTROL_NAMES, "lips_part"]
    assert isinstance(back.muscles[-1], LipSeal) and np.array_equal(back.muscles[-1].pairs, rig.muscles[-1].pairs)
    for m, n in zip(rig.muscles[-7:-1], lids):
        assert np.array_equal(m.vertices, n.vertices)
        for field in ("center", "axis", "angles", "slides", "lifts"):
            np.testing.assert_allclose(getattr(n, field), getattr(m, field), rtol=1e-12, atol=1e-15, err_msg=field)
    frame = {"lid_upper_close_L": 1.0, "lid_upper_raise_R": 0.5}
    np.testing.assert_allclose(
        back.model(device=DEVICE).evaluate(frame), rig.model(device=DEVICE).evaluate(frame), atol=1e-6
    )
    # a rig whose points are exact in float32 comes back equal in every part
    exact = wf.FaceRig(
        wf.FaceMesh(rig.mesh.points.astype(np.float32).astype(np.float64), rig.mesh.triangles, name=rig.mesh.name),
        rig.muscles[-7:],
        [],
        0.0,
        name=rig.name,
    )
    wf.usd.write_rig(path, exact)
    assert_rigs_equal(exact, wf.usd.read_rig(path))


@pytest.mark.slow  # end to end, over 20 s on the 2-core CI machine
def test_the_solver_fits_a_blink_with_the_lid_controls(rig):
    model = rig.model(device=DEVICE)
    target = model.evaluate({"lid_upper_close_L": 0.8, "lid_lower_close_L": 0.8})
    solved = fit(rig, target, device=DEVICE)
    values = dict(zip(model.control_names, solved.vector))
    assert values["lid_upper_close_L"] > 0.6
    assert np.abs(solved.points - target).max() < 0.05 * np.abs(target - rig.mesh.points).max()


def test_a_fit_raises_the_lower_lid_past_the_blink_up_to_its_limit(rig, tmp_path):
    from warpface.assets.lids import LOWER_FIT_LIMIT

    eyelids = [
        m for m in rig.muscles if isinstance(m, LidMuscle) and m.name not in BODY_CONTROL_NAMES
    ]  # lips, corners: §15–17
    limits = {m.name: m.fit_limit for m in eyelids if not isinstance(m, LipSeal)}
    assert limits == {n: (LOWER_FIT_LIMIT if "lower_close" in n else 1.0) for n in LID_CONTROL_NAMES}
    model = rig.model(device=DEVICE)
    # a squint: the lower lid 1.6 times its blink turn; a fit held at the full turn would stop at 1
    target = model.evaluate({"lid_lower_close_L": 1.6})
    solved = fit(rig, target, device=DEVICE)
    assert abs(solved.controls["lid_lower_close_L"] - 1.6) < 0.05, solved.controls["lid_lower_close_L"]
    held = fit(rig, target, device=DEVICE, bounds={"lid_lower_close_L": (0.0, 1.0)})
    assert held.controls["lid_lower_close_L"] <= 1.0 + 1e-12
    assert np.abs(held.points - target).max() > 2.0 * np.abs(solved.points - target).max()
    beyond = fit(rig, model.evaluate({"lid_lower_close_L": 3.0}), device=DEVICE)
    assert beyond.controls["lid_lower_close_L"] <= LOWER_FIT_LIMIT + 1e-12
    # the limit round-trips through a stage; one written before the attribute reads 1; a bad one is refused
    path = tmp_path / "rig.usda"
    wf.usd.write_rig(path, rig)
    back = {m.name: m.fit_limit for m in wf.usd.read_rig(path).muscles if m.name in limits}
    assert back == limits
    from pxr import Usd

    stage = Usd.Stage.Open(str(path))
    prims = [p for p in stage.Traverse() if p.GetTypeName() == "WarpFaceLidMuscle" and "lower_close" in p.GetName()]
    prims[0].GetAttribute("fitLimit").Clear()
    prims[1].GetAttribute("fitLimit").Set(-1.0)
    stage.Save()
    with pytest.raises(wf.RigError, match="fitLimit"):
        wf.usd.read_rig(path)
    prims[1].GetAttribute("fitLimit").Clear()
    stage.Save()
    back = wf.usd.read_rig(path).muscles
    assert {m.fit_limit for m in back if isinstance(m, LidMuscle) and m.name not in BODY_CONTROL_NAMES} == {1.0}
    for bad in (0.0, -1.0, 11.0, np.nan):
        with pytest.raises(ValueError, match="fit_limit"):
            LidMuscle("lid", np.zeros(3), [1, 0, 0], [1], [0.1], fit_limit=bad)
