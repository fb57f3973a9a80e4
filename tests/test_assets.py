"""The built-in face, its landmarks, thickness, default rig and expression presets (warpface.assets)."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pytest

from warpface import ExpressionModel, FaceMesh, LinearMuscle, RigError, SphincterMuscle
from warpface.assets import (
    EXPRESSIONS,
    LANDMARK_NAMES,
    LINEAR_MUSCLE_NAMES,
    SPHINCTER_MUSCLE_NAMES,
    WRINKLE_NAMES,
    default_face,
    default_landmarks,
    default_rig,
    default_thickness,
    expression_contractions,
    expression_envelope,
    expression_timeline,
    rig_scale,
)
from warpface.assets import face as face_module
from warpface.assets.lids import LID_CONTROL_NAMES
from warpface.assets.lips import LIP_SEAL_NAME, lip_margin_taper
from warpface.assets.rig import BODY_CONTROL_NAMES, MOBILE_TISSUE_FRACTION, face_frame
from warpface.data import ict_face_region, ict_landmark_indices
from warpface.expression.wrinkles import bezier_distances, project_points

DEVICE = "cpu"

# iBUG index of each landmark's mirror image (subject's left ↔ right).
IBUG_MIRROR = np.array(
    [
        *range(16, -1, -1),
        *range(26, 16, -1),
        27,
        28,
        29,
        30,
        35,
        34,
        33,
        32,
        31,
        45,
        44,
        43,
        42,
        47,
        46,
        39,
        38,
        37,
        36,
        41,
        40,
        54,
        53,
        52,
        51,
        50,
        49,
        48,
        59,
        58,
        57,
        56,
        55,
        64,
        63,
        62,
        61,
        60,
        67,
        66,
        65,
    ]
)
RIGHT_SIDE = [*range(0, 8), *range(17, 22), 31, 32, *range(36, 42), 48, 49, 50, 58, 59, 60, 61, 67]
REQUIRED_MUSCLES = {
    "frontalis_inner_L",
    "frontalis_inner_R",
    "frontalis_outer_L",
    "frontalis_outer_R",
    "corrugator_L",
    "corrugator_R",
    "procerus",
    "levator_labii_superioris_L",
    "levator_labii_superioris_R",
    "zygomaticus_major_L",
    "zygomaticus_major_R",
    "risorius_L",
    "risorius_R",
    "depressor_anguli_oris_L",
    "depressor_anguli_oris_R",
    "mentalis",
    "orbicularis_oris",
    "orbicularis_oculi_L",
    "orbicularis_oculi_R",
}


# ------------------------------------------------------------------------------------------------ helpers


def edges_with_counts(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    edges = np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(edges, axis=0, return_counts=True)


def boundary_loops(triangles: np.ndarray) -> list[set[int]]:
    """Vertex sets of the connected components of the boundary-edge graph."""
    edges, counts = edges_with_counts(triangles)
    neighbours = defaultdict(list)
    for a, b in edges[counts == 1]:
        neighbours[int(a)].append(int(b))
        neighbours[int(b)].append(int(a))
    loops, seen = [], set()
    for start in neighbours:
        if start in seen:
            continue
        loop, stack = set(), [start]
        while stack:
            vertex = stack.pop()
            if vertex not in loop:
                loop.add(vertex)
                stack.extend(neighbours[vertex])
        seen |= loop
        loops.append(loop)
    return loops


def median_edge(mesh: FaceMesh) -> float:
    edges, _ = edges_with_counts(mesh.triangles)
    return float(np.median(np.linalg.norm(mesh.points[edges[:, 0]] - mesh.points[edges[:, 1]], axis=1)))


class Regions:
    """Vertex masks of facial regions in the landmark frame (inter-ocular units)."""

    def __init__(self, rig):
        self.frame = face_frame(rig.mesh, rig.landmarks)
        self.local = self.frame.to_local(rig.mesh.points)
        self.landmarks = self.frame.to_local(rig.mesh.points[rig.landmarks])
        x, y, z = self.local.T
        front = z > self.landmarks[36:48, 2].min() - 0.3
        brow = self.landmarks[17:27, 1].max()
        self.forehead = front & (np.abs(x) < 0.8) & (y > brow + 0.1) & (y < brow + 0.6)
        self.mouth = front & (np.abs(x) < 0.6) & (y < self.landmarks[33, 1] - 0.1) & (y > self.landmarks[8, 1] + 0.2)
        self.glabella = front & (np.abs(x) < 0.25) & (y > self.landmarks[27, 1]) & (y < brow + 0.1)
        self.nose_wings = np.zeros(len(x), bool)
        for index in (31, 35):
            self.nose_wings |= np.linalg.norm(self.local[:, :2] - self.landmarks[index, :2], axis=1) < 0.12
        self.inner_brows = np.zeros(len(x), bool)
        for index in (20, 21, 22, 23):
            self.inner_brows |= front & (np.linalg.norm(self.local[:, :2] - self.landmarks[index, :2], axis=1) < 0.12)

    def displacement(self, positions: np.ndarray) -> np.ndarray:
        """Displacements in frame axes, inter-ocular units, shape (V, 3)."""
        return self.frame.to_local(positions) - self.local


@pytest.fixture(scope="module")
def rig():
    return default_rig(device=DEVICE)


@pytest.fixture(scope="module")
def classic_rig():
    """The paper's four presets were written for the classic rig (thesis table 2.1, SPEC §1.1 zones)."""
    return default_rig(device=DEVICE, anatomy="classic")


@pytest.fixture(scope="module")
def ict_rig():
    path, landmarks = ict_face_region(), ict_landmark_indices()
    if path is None or landmarks is None:
        pytest.skip("ICT-FaceKit data not found in ../shared/data (set WARPFACE_SHARED_DATA)")
    return default_rig(FaceMesh.from_obj(path), landmarks, name="ict", device=DEVICE, anatomy="classic")


def evaluate_expressions(rig):
    model = ExpressionModel(rig.mesh, rig.muscles, rig.wrinkles, rig.thickness, device=DEVICE)
    results = {}
    for name in EXPRESSIONS:
        # evaluate() hands back views of device buffers; copy before the next frame.
        stages = model.stages(expression_contractions(name, rig))
        results[name] = {key: np.array(stages[key], copy=True) for key in ("muscle", "stretch", "bulge", "final")}
    return results


# ------------------------------------------------------------------------------------------------ face


def test_face_is_about_ten_thousand_vertices_in_metres():
    mesh = default_face()
    assert 9_000 <= mesh.vertex_count <= 13_000
    lo, hi = mesh.bounding_box
    height, width = hi[1] - lo[1], hi[0] - lo[0]
    assert 0.18 < height < 0.25, "face ~0.2 m tall (SI units)"
    assert 0.12 < width < 0.17
    assert hi[2] - lo[2] > 0.08, "a head-like depth, not a flat sheet"
    assert mesh is default_face(), "cached"
    assert not mesh.points.flags.writeable


def test_face_is_deterministic():
    points, triangles, landmarks = face_module._build.__wrapped__()
    mesh = default_face()
    np.testing.assert_array_equal(points, mesh.points)
    np.testing.assert_array_equal(triangles, mesh.triangles)
    np.testing.assert_array_equal(landmarks, default_landmarks())


def test_face_is_a_consistently_oriented_manifold_with_eye_and_mouth_holes():
    mesh = default_face()
    edges, counts = edges_with_counts(mesh.triangles)
    assert counts.max() == 2, "every edge in at most two triangles"
    directed = mesh.triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    assert len(np.unique(directed, axis=0)) == len(directed), "consistent orientation: no directed edge twice"
    assert np.bincount(mesh.triangles.ravel(), minlength=mesh.vertex_count).min() > 0, "no unused vertices"
    boundary = edges[counts == 1]
    assert np.all(np.bincount(boundary.ravel())[np.unique(boundary)] == 2), "boundary vertices are not pinched"

    loops = boundary_loops(mesh.triangles)
    assert len(loops) == 4, "outline, two eyes, mouth"
    landmarks = default_landmarks()
    holes = {
        name: {int(v) for v in landmarks[span]}
        for name, span in (("right eye", slice(36, 42)), ("left eye", slice(42, 48)), ("mouth", slice(60, 68)))
    }
    for name, members in holes.items():
        assert sum(members <= loop for loop in loops) == 1, f"the {name} landmarks lie on one hole's margin"
    outer = max(loops, key=len)
    assert len(outer) > 3 * max(len(loop) for loop in loops if loop is not outer)
    normals = mesh.vertex_normals(device=DEVICE)
    assert normals[landmarks[30], 2] > 0.8 and normals[landmarks[8], 1] < 0.0, (
        "outward: nose tip faces +z, chin faces down"
    )


def test_face_has_the_features_of_a_face():
    mesh = default_face()
    p = mesh.points[default_landmarks()]
    nose_tip, nasion, cheek = p[30], p[27], mesh.points[default_landmarks()[[2, 14]]].mean(axis=0)
    assert nose_tip[2] - nasion[2] > 0.012, "the nose stands out"
    upper_lids, brows_above = p[[37, 38, 43, 44]], p[[19, 20, 23, 24]]
    assert brows_above[:, 2].mean() > upper_lids[:, 2].mean() + 0.006, "brow ridge in front of the eye openings"
    assert p[57, 2] > p[8, 2] and p[51, 2] > p[8, 2], "lips in front of the chin"
    assert nose_tip[2] > cheek[2] + 0.05


def test_landmarks_are_ibug_ordered_and_symmetric():
    mesh = default_face()
    landmarks = default_landmarks()
    assert landmarks.shape == (68,) and landmarks.dtype == np.int64 and len(LANDMARK_NAMES) == 68
    assert len(np.unique(landmarks)) == 68
    assert landmarks.min() >= 0 and landmarks.max() < mesh.vertex_count
    p = mesh.points[landmarks]
    np.testing.assert_allclose(p[IBUG_MIRROR] * [-1.0, 1.0, 1.0], p, atol=1e-9)
    assert np.all(p[RIGHT_SIDE, 0] < 0.0), "iBUG right-side points (0–7, 17–21, 36–41, …) at −x"
    assert np.all(np.diff(p[0:9, 1]) < 0.0), "jaw descends from the ear to the chin"
    eye_y = p[36:48, 1].mean()
    assert p[17:27, 1].min() > eye_y
    assert eye_y > p[30, 1] > p[33, 1] > p[51, 1] > p[62, 1] > p[66, 1] > p[57, 1] > p[8, 1]
    assert p[39, 0] > p[36, 0] and p[42, 0] < p[45, 0], "inner eye corners toward the midline"
    assert p[48, 0] < p[60, 0] < 0.0 < p[64, 0] < p[54, 0]


# ------------------------------------------------------------------------------------------------ thickness


def test_thickness_is_positive_thin_on_the_forehead_thick_on_the_cheeks_and_smooth(rig):
    thickness = default_thickness()
    taper = lip_margin_taper(rig.mesh, face_frame(rig.mesh, rig.landmarks), rig.landmarks)
    np.testing.assert_allclose(rig.thickness, MOBILE_TISSUE_FRACTION * thickness * taper, rtol=1e-15)
    assert np.mean(taper == 1.0) > 0.9
    assert thickness.shape == (default_face().vertex_count,)
    assert np.all(np.isfinite(thickness)) and thickness.min() > 0.0005 and thickness.max() < 0.012
    regions = Regions(rig)
    cheeks = np.zeros(len(thickness), bool)
    for sign in (-1.0, 1.0):
        cheeks |= np.linalg.norm(regions.local[:, :2] - [sign * 0.62, -0.6], axis=1) < 0.15
    forehead, cheek = thickness[regions.forehead].mean(), thickness[cheeks].mean()
    assert forehead < 0.0035 and cheek > 0.006 and cheek > 2.5 * forehead
    # Smooth where the map's projection is faithful (skin facing the viewer; under the chin the
    # cylinder squeezes a band of skin into a few pixels).
    facing = rig.mesh.vertex_normals(device=DEVICE) @ regions.frame.axes[2] > 0.5
    edges, _ = edges_with_counts(rig.mesh.triangles)
    edges = edges[facing[edges].all(axis=1)]
    jump = np.abs(thickness[edges[:, 0]] - thickness[edges[:, 1]])
    length = np.linalg.norm(rig.mesh.points[edges[:, 0]] - rig.mesh.points[edges[:, 1]], axis=1)
    assert np.max(jump / length) < 0.7, "blurred: no step edges in thickness (≤ 0.7 mm per mm)"


# ------------------------------------------------------------------------------------------------ rig


def test_rig_has_the_required_muscles_and_wrinkles(rig):
    names = set(rig.muscle_names)
    assert REQUIRED_MUSCLES <= names
    lips = [*BODY_CONTROL_NAMES]  # the lip hinges and slides, the mouth corners (docs/RIG.md §15–17)
    assert rig.muscle_names == [*LINEAR_MUSCLE_NAMES, *SPHINCTER_MUSCLE_NAMES, *lips, *LID_CONTROL_NAMES, LIP_SEAL_NAME]
    assert sum(isinstance(m, LinearMuscle) for m in rig.muscles) >= 16
    assert {m.name for m in rig.muscles if isinstance(m, SphincterMuscle)} == set(SPHINCTER_MUSCLE_NAMES)
    assert rig.wrinkle_names == list(WRINKLE_NAMES) and len(rig.wrinkles) >= 21
    np.testing.assert_array_equal(rig.landmarks, default_landmarks())
    assert all(w.width >= 1.9 * median_edge(rig.mesh) for w in rig.wrinkles), "furrows at least ~2 edges wide"


def assert_muscles_sit_on_the_face(rig):
    """Insertions on the skin; bone attachments behind it (further from the viewer than the skin in
    front of them, or than the nearest skin where they lie beyond the mesh, like the galea)."""
    mesh = rig.mesh
    frame = face_frame(mesh, rig.landmarks)
    local = frame.to_local(mesh.points)
    edge = median_edge(mesh)
    for muscle in rig.muscles:
        if not isinstance(muscle, LinearMuscle):
            continue
        gap = np.linalg.norm(mesh.points - muscle.insertion, axis=1).min()
        assert gap < 1.5 * edge, f"{muscle.name}: insertion on the skin"
        bone = frame.to_local(muscle.attachment)
        footprint = np.linalg.norm(local[:, :2] - bone[:2], axis=1)
        in_front = footprint < 0.05
        skin_z = local[in_front, 2].max() if in_front.any() else local[np.argmin(footprint), 2]
        assert bone[2] < skin_z - 0.04, f"{muscle.name}: bone attachment beneath the skin"


def test_muscles_sit_on_the_face(rig):
    assert_muscles_sit_on_the_face(rig)


def test_rig_is_mirror_symmetric_on_the_symmetric_face(rig):
    mirror = np.array([-1.0, 1.0, 1.0])
    muscles = {m.name: m for m in rig.muscles}
    for name, muscle in muscles.items():
        if name.endswith("_L") and isinstance(muscle, LinearMuscle):
            twin = muscles[name[:-1] + "R"]
            np.testing.assert_allclose(muscle.attachment * mirror, twin.attachment, atol=1e-9)
            np.testing.assert_allclose(muscle.insertion * mirror, twin.insertion, atol=1e-9)
    for name in ("procerus", "mentalis"):
        assert abs(muscles[name].insertion[0]) < 1e-9


def test_rig_does_not_depend_on_units(rig):
    """The same face in centimetres gets the same rig ×100 and, with the presets, the same motion ×100."""
    mesh_cm = FaceMesh(default_face().points * 100.0, default_face().triangles, name="face_cm")
    rig_cm = default_rig(mesh_cm, default_landmarks(), device=DEVICE)
    assert rig_scale(rig_cm) == pytest.approx(100.0 * rig_scale(rig), rel=1e-12)
    np.testing.assert_allclose(rig_cm.thickness, 100.0 * rig.thickness, rtol=1e-6, atol=1e-9)
    for muscle, muscle_cm in zip(rig.muscles, rig_cm.muscles):
        if isinstance(muscle, LinearMuscle):
            # Vertex normals are float32, so the bone points agree to float32 precision.
            np.testing.assert_allclose(muscle_cm.attachment, 100.0 * muscle.attachment, rtol=1e-5, atol=1e-5)
            assert muscle_cm.falloff_finish == pytest.approx(100.0 * muscle.falloff_finish)
    for wrinkle, wrinkle_cm in zip(rig.wrinkles, rig_cm.wrinkles):
        assert wrinkle_cm.depth == pytest.approx(100.0 * wrinkle.depth) and wrinkle_cm.width == pytest.approx(
            100.0 * wrinkle.width
        )
    smile, smile_cm = expression_contractions("smile", rig), expression_contractions("smile", rig_cm)
    assert smile_cm["zygomaticus_major_L"] == pytest.approx(100.0 * smile["zygomaticus_major_L"])
    assert smile_cm["orbicularis_oculi_L"] == pytest.approx(smile["orbicularis_oculi_L"])
    metres = rig.model(device=DEVICE).evaluate(smile).copy()
    centimetres = rig_cm.model(device=DEVICE).evaluate(smile_cm).copy()
    np.testing.assert_allclose(centimetres / 100.0, metres, atol=2e-6)


def test_rig_rejects_bad_landmarks():
    mesh = default_face()
    with pytest.raises(RigError, match="landmark"):
        default_rig(mesh, None)
    with pytest.raises(RigError, match="68"):
        default_rig(mesh, default_landmarks()[:60])
    with pytest.raises(RigError, match="outside"):
        default_rig(mesh, np.full(68, mesh.vertex_count))
    collapsed = default_landmarks().copy()
    collapsed[36:48] = collapsed[30]
    with pytest.raises(RigError, match="eye"):
        default_rig(mesh, collapsed)


# ------------------------------------------------------------------------------------------------ expressions


def assert_expressions_move_the_right_regions(rig):
    regions = Regions(rig)
    results = evaluate_expressions(rig)
    lm = rig.landmarks

    def moved(name, mask):
        return np.linalg.norm(regions.displacement(results[name]["muscle"])[mask], axis=1).mean()

    # thinking: the forehead goes up, the mouth stays.
    up = regions.displacement(results["thinking"]["muscle"])[:, 1]
    assert up[regions.forehead].mean() > 0.05
    assert moved("thinking", regions.forehead) > 10.0 * moved("thinking", regions.mouth)
    # puzzled: the inner brows come together and down; the glabella is squeezed.
    shift = regions.displacement(results["puzzled"]["muscle"])
    inner = regions.inner_brows
    toward_midline = -np.sign(regions.local[inner, 0]) * shift[inner, 0]
    assert toward_midline.mean() > 0.01 and shift[inner, 1].mean() < 0.0
    assert results["puzzled"]["stretch"][regions.glabella].min() < 0.8
    assert moved("puzzled", inner) > 5.0 * moved("puzzled", regions.mouth)
    # disgust: the nose wings rise, the inner brows come down.
    shift = regions.displacement(results["disgust"]["muscle"])
    assert shift[regions.nose_wings, 1].mean() > 0.03
    assert shift[inner, 1].mean() < 0.0
    assert moved("disgust", regions.nose_wings) > 3.0 * moved("disgust", regions.forehead)
    # smile: the mouth corners go up and out, the eyes narrow, the forehead barely moves.
    shift = regions.displacement(results["smile"]["muscle"])
    corners = shift[lm[[48, 54]]]
    assert np.all(corners[:, 1] > 0.08)
    assert corners[0, 0] < 0.0 < corners[1, 0]
    opening = lambda positions, upper, lower: np.linalg.norm(positions[lm[upper]] - positions[lm[lower]], axis=1).mean()  # noqa: E731
    rest = rig.mesh.points
    for upper, lower in (([37, 38], [41, 40]), ([43, 44], [47, 46])):
        assert opening(results["smile"]["muscle"], upper, lower) < 0.85 * opening(rest, upper, lower)
    assert moved("smile", regions.mouth) > 5.0 * moved("smile", regions.forehead)
    return results


def wrinkle_depth_under(rig, results, expression: str, wrinkle_name: str) -> float:
    """Mean depth of a furrow along its own curve, k_d·C(r) [inter-ocular units]."""
    wrinkle = next(w for w in rig.wrinkles if w.name == wrinkle_name)
    uv = project_points(wrinkle.projection, rig.mesh.points, device=DEVICE)
    on_curve = bezier_distances(uv, wrinkle.control_points, device=DEVICE) < 0.5 * wrinkle.width
    stretch = results[expression]["stretch"][on_curve]
    return float(np.mean(wrinkle.depth * np.clip(1.0 - stretch, 0.0, 1.0)) / rig_scale(rig))


EXPECTED_FURROWS = {
    "thinking": ["forehead_1", "forehead_2", "forehead_3"],
    "puzzled": ["glabella_L", "glabella_R"],
    "disgust": ["nasal_root_1", "bunny_L", "bunny_R"],
    "smile": ["crows_feet_L_3", "crows_feet_R_3", "nasolabial_L", "nasolabial_R"],
}


def assert_wrinkles_show(rig, results):
    for expression, names in EXPECTED_FURROWS.items():
        for name in names:
            assert wrinkle_depth_under(rig, results, expression, name) > 0.012, f"{name} visible in {expression}"
    # ...and not where they do not belong.
    assert wrinkle_depth_under(rig, results, "smile", "forehead_2") < 0.003
    assert wrinkle_depth_under(rig, results, "thinking", "nasolabial_L") < 0.003
    neutral = ExpressionModel(rig.mesh, rig.muscles, rig.wrinkles, rig.thickness, device=DEVICE).evaluate({})
    np.testing.assert_allclose(neutral, rig.mesh.points, atol=1e-6 * rig.mesh.size)


def test_expressions_move_the_right_regions_and_make_their_wrinkles(classic_rig):
    rig = classic_rig
    results = assert_expressions_move_the_right_regions(rig)
    assert_wrinkles_show(rig, results)
    for name, result in results.items():
        assert np.all(np.isfinite(result["final"])), name
        with_wrinkles = np.linalg.norm(result["final"] - result["bulge"], axis=1).max()
        assert with_wrinkles > 0.001, f"{name}: the wrinkled version differs visibly (> 1 mm somewhere)"


def test_expression_contractions_scale_linear_muscles_only(rig):
    scale = rig_scale(rig)
    smile = expression_contractions("smile", rig, intensity=0.5)
    assert smile.keys() == EXPRESSIONS["smile"].keys()
    assert smile["zygomaticus_major_L"] == pytest.approx(0.5 * EXPRESSIONS["smile"]["zygomaticus_major_L"] * scale)
    assert smile["orbicularis_oculi_R"] == pytest.approx(0.5 * EXPRESSIONS["smile"]["orbicularis_oculi_R"])
    with pytest.raises(ValueError, match="unknown expression"):
        expression_contractions("grin", rig)
    with pytest.raises(ValueError, match="finite"):
        expression_contractions("smile", rig, intensity=float("nan"))
    bare = type(rig)(mesh=rig.mesh, muscles=rig.muscles[:3], landmarks=rig.landmarks)
    with pytest.raises(RigError, match="zygomaticus_major"):
        expression_contractions("smile", bare)
    no_landmarks = type(rig)(mesh=rig.mesh, muscles=rig.muscles)
    with pytest.raises(RigError, match="landmarks"):
        expression_contractions("smile", no_landmarks)


def test_expression_timeline_goes_neutral_to_expression_to_neutral(rig):
    timeline = expression_timeline("disgust", rig, seconds=2.0, fps=30)
    assert timeline.shape == (61, len(rig.muscles))
    assert np.all(timeline[0] == 0.0) and np.all(timeline[-1] == 0.0)
    peak = expression_contractions("disgust", rig)
    index = {name: i for i, name in enumerate(rig.muscle_names)}
    middle = timeline[30]
    for name, value in peak.items():
        assert middle[index[name]] == pytest.approx(value)
    untouched = [i for name, i in index.items() if name not in peak]
    assert np.all(timeline[:, untouched] == 0.0)
    envelope = expression_envelope(61)
    assert np.all(np.diff(envelope[:31]) >= 0.0) and np.all(np.diff(envelope[30:]) <= 0.0)
    np.testing.assert_allclose(envelope, envelope[::-1], atol=1e-12)
    assert envelope[1] < 1e-3, "eases in: zero velocity at the start"
    np.testing.assert_allclose(
        timeline / np.maximum(middle, 1e-30)[None, :] * (middle > 0), envelope[:, None] * (middle > 0)
    )
    jaw_at_rest = np.zeros((len(timeline[::15]), len(rig.control_names) - len(rig.muscles)))
    frames = rig.model(device=DEVICE).evaluate(np.concatenate([timeline[::15], jaw_at_rest], axis=1))
    np.testing.assert_allclose(frames[0], rig.mesh.points, atol=1e-6)
    with pytest.raises(ValueError):
        expression_timeline("smile", rig, seconds=0.0)


# ------------------------------------------------------------------------------------------------ ICT face


def test_default_rig_fits_the_ict_face(ict_rig):
    assert set(ict_rig.muscle_names) >= REQUIRED_MUSCLES and len(ict_rig.wrinkles) >= 21
    assert 5.5 < rig_scale(ict_rig) < 7.5, "ICT is in centimetres: eye centres ~6.5 cm apart"
    assert_muscles_sit_on_the_face(ict_rig)
    thickness = ict_rig.thickness
    assert thickness.min() > 0.05 and thickness.max() < 1.2, "thickness in cm"
    results = assert_expressions_move_the_right_regions(ict_rig)
    assert_wrinkles_show(ict_rig, results)


def test_landmark_sets_and_mirror_pairs_agree_with_names_and_the_symmetric_face():
    """warpface.landmarks: every mirrored pair swaps "right"/"left" in its names (or is the jaw's i ↔ 16 − i),
    midline points have no side, and on the mirror-symmetric built-in face each pair mirrors x."""
    from warpface import landmarks as lm

    assert len(lm.IBUG_NAMES) == lm.IBUG_COUNT == 68
    sets = (lm.JAW, lm.RIGHT_BROW, lm.LEFT_BROW, lm.NOSE_BRIDGE, lm.NOSE_BASE, lm.RIGHT_EYE, lm.LEFT_EYE, lm.MOUTH)
    assert sorted(i for s in sets for i in s) == list(range(68))
    for right, left in lm.MIRROR_PAIRS:
        r, l = lm.IBUG_NAMES[right], lm.IBUG_NAMES[left]
        assert r.replace("right", "left") == l or (r.startswith("jaw_") and right + left == 16), (r, l)
        assert "left" not in r
    assert np.array_equal(lm.IBUG_MIRROR[lm.IBUG_MIRROR], np.arange(68))
    for i in np.flatnonzero(lm.IBUG_MIRROR == np.arange(68)):
        assert "right" not in lm.IBUG_NAMES[i] and "left" not in lm.IBUG_NAMES[i]
    points = default_face().points[default_landmarks()]
    np.testing.assert_allclose(points[lm.IBUG_MIRROR] * [-1, 1, 1], points, atol=1e-9)
    for side in (lm.LEFT_SIDE, lm.RIGHT_SIDE):
        for index in (side.eye_outer, side.eye_inner, side.nose_wing, side.mouth_corner, *side.brow, *side.eye):
            assert np.sign(points[index, 0]) == side.sign
    assert lm.IBUG_MIRROR[lm.LEFT_SIDE.mouth_corner] == lm.RIGHT_SIDE.mouth_corner


def test_kato_landmarks_live_in_landmarks_and_metrics_reexports_them():
    from warpface import landmarks as lm
    from warpface import metrics

    assert metrics.kato_landmarks is lm.kato_landmarks and metrics.KATO_LANDMARKS is lm.KATO_LANDMARKS
    points = default_face().points[default_landmarks()]
    kato = lm.kato_landmarks(points)
    np.testing.assert_array_equal(kato["ch_L"], points[54])
    np.testing.assert_allclose(kato["glabella"], 0.5 * (points[21] + points[22]))
    with pytest.raises(TypeError, match="kato_landmarks"):
        lm.kato_landmarks({"a": 1})
