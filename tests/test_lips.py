"""The lip seal (docs/RIG.md §12): each muscle's field keeps the inner-lip pairs from closing; lips never cross."""

from __future__ import annotations

import numpy as np
import pytest

import warpface as wf
from benchmarks.face_quality import ROLLS, channel_frames, preset_frames, random_combinations
from warpface.assets import ARKIT_PRESET_NAMES, default_rig
from warpface.assets.quality import LIP_PAIRS, face_up, flipped_triangles, pair_heights
from warpface.data import ict_face_region, ict_landmark_indices
from warpface.expression.seal import LipSeal, seal_fields

DEVICE = "cpu"
ICT_FACE_VERTICES = 9409
"""The whole ICT head's face region is its vertices 0–9408 (../shared/data/README.md)."""


def test_seal_adds_the_least_share_that_keeps_every_pair_from_closing():
    rng = np.random.default_rng(5)
    pairs = np.array([[0, 1], [2, 3], [4, 5]])
    seal = LipSeal("seal", np.zeros(3), [1, 0, 0], np.arange(6), np.full(6, 0.1), pairs=pairs)
    part = np.zeros((12, 3))
    part[[0, 2, 4]], part[[1, 3, 5]] = [0.0, 1.0, 0.0], [0.0, -1.0, 0.0]  # parts each pair by 2 along y
    closing = rng.normal(size=(12, 3)) * 0.1
    closing[[0, 2, 4], 1] -= [0.3, 0.5, 0.1]  # the upper points move down
    parting = np.zeros((12, 3))
    parting[0, 1] = 0.2
    lid = wf.expression.LidMuscle("lid", np.zeros(3), [1, 0, 0], [7], [0.2])
    muscles = [seal, "closing", "parting", lid]
    out = seal_fields(muscles, [part, closing, parting, closing])
    assert out[0] is part and out[2] is parting and out[3] is closing  # the seal, a parting field and lids stay
    relative = (out[1][pairs[:, 0]] - out[1][pairs[:, 1]])[:, 1]
    assert relative.min() == pytest.approx(0.0, abs=1e-12)  # the binding pair just stays sealed
    before = (closing[pairs[:, 0]] - closing[pairs[:, 1]])[:, 1]
    share = max(0.0, (-before / 2.0).max())
    np.testing.assert_allclose(out[1], closing + share * part, atol=1e-15)
    with pytest.raises(ValueError, match="at most one"):
        seal_fields([seal, seal], [part, part])
    with pytest.raises(ValueError, match="does not part"):
        seal_fields([seal, "m"], [np.zeros((12, 3)), closing])
    with pytest.raises(ValueError, match="pairs"):
        LipSeal("seal", np.zeros(3), [1, 0, 0], [0], [0.1], pairs=np.zeros((0, 2), dtype=int))


def _lips(rig, frames):
    points = rig.model(device=DEVICE).evaluate(frames)
    return pair_heights(points, rig.landmarks, LIP_PAIRS, face_up(rig.mesh, rig.landmarks), 1000.0)


def test_lips_never_cross_on_the_built_in_face():
    rig = default_rig(device=DEVICE)
    assert _lips(rig, preset_frames(rig, ARKIT_PRESET_NAMES)).min() >= -0.2
    assert _lips(rig, random_combinations(rig, 100)).min() >= -0.2


def test_lips_never_cross_at_any_preset_on_the_ict_face():
    rig = _ict_rig()
    assert _lips(rig, preset_frames(rig, ARKIT_PRESET_NAMES)).min() >= -0.2


def test_no_triangle_turns_over_on_the_built_in_face():
    """Issue 25's surface check: flipped triangles summed over every ARKit and FACS channel at weight 1 (the
    lips' rolls excepted) stay within 10 (58 before the lid hinges and the jaw weights' diffusion)."""
    rig = default_rig(device=DEVICE)
    model = rig.model(device=DEVICE)
    total = 0
    for kind in ("arkit", "facs"):
        names, frames = channel_frames(rig, kind)
        keep = [i for i, name in enumerate(names) if name not in ROLLS]
        total += int(flipped_triangles(rig.mesh, model.evaluate(frames[keep])).sum())
    assert total <= 10


def _slit_pairs(mesh, landmarks, up):
    """Pairs (upper, lower) across a closed mouth's slit, found independently of the rig: in the mouth's central
    half, within 0.03 inter-ocular units of the landmarks' contact line, a vertex facing down and its nearest vertex
    facing up, closer than 0.03 units in space but three times farther over the surface."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra
    from scipy.spatial import cKDTree

    points, marks = mesh.points, mesh.points[landmarks]
    scale = np.linalg.norm(marks[36:42].mean(axis=0) - marks[42:48].mean(axis=0))
    contact = 0.5 * (marks[62] + marks[66])
    half = 0.25 * np.linalg.norm(marks[64] - marks[60])
    near = (np.linalg.norm(points - contact, axis=1) < 0.15 * scale) & (np.abs((points - contact) @ up) < 0.06 * scale)
    side = np.abs((points - contact) @ np.cross(up, mesh.vertex_normals()[landmarks[62]])) < half
    facing = mesh.vertex_normals() @ up
    upper = np.flatnonzero(near & side & (facing < -0.5))
    lower = np.flatnonzero(near & side & (facing > 0.5))
    distance, nearest = cKDTree(points[lower]).query(points[upper])
    edges = np.sort(mesh.triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    lengths = np.linalg.norm(points[edges[:, 0]] - points[edges[:, 1]], axis=1)
    graph = coo_matrix((lengths, (edges[:, 0], edges[:, 1])), shape=(len(points),) * 2).tocsr()
    close = distance < 0.03 * scale
    surface = dijkstra(graph, directed=False, indices=upper[close])[np.arange(close.sum()), lower[nearest[close]]]
    across = surface > 3.0 * distance[close]
    return upper[close][across], lower[nearest[close]][across]


def _ict_rig():
    path, landmarks = ict_face_region(), ict_landmark_indices()
    if path is None or landmarks is None:
        pytest.skip("ICT-FaceKit data not found in ../shared/data (set WARPFACE_SHARED_DATA)")
    source = wf.FaceMesh.from_obj(path)
    return default_rig(wf.FaceMesh(source.points * 0.01, source.triangles), landmarks, device=DEVICE)


@pytest.mark.slow
@pytest.mark.parametrize("face", ["builtin", "ict"])
def test_mouth_close_holds_the_lips_together_against_the_open_jaw(face):
    """ARKit's mouthClose: the jaw opens, the lips stay closed (docs/RIG.md §12). The preset's jaw alone parts the
    inner-lip midpoints by several mm; with the seal's closing share they end within 1 mm of contact, uncrossed."""
    rig = default_rig(device=DEVICE) if face == "builtin" else _ict_rig()
    frames = preset_frames(rig, ["mouthClose"])
    share = frames[0, rig.control_names.index("lips_part")]
    assert share < 0.0
    open_jaw = np.zeros_like(frames)
    open_jaw[0, rig.control_names.index("jaw_open")] = frames[0, rig.control_names.index("jaw_open")]
    jaw_only = frames.copy()
    jaw_only[0, rig.control_names.index("lips_part")] = 0.0
    assert _lips(rig, open_jaw).min() > 4.0 and _lips(rig, jaw_only).min() > 4.0
    closed = _lips(rig, frames)
    assert closed.min() >= -0.2 and closed.max() <= 1.0


@pytest.mark.slow
def test_a_closed_mouth_scan_s_lips_part_at_the_slit_and_never_cross(lee_perry_smith):
    """The Lee Perry-Smith scan's lips touch along a slit (no opening in the mesh; its found inner-lip landmarks lie
    1–2 mm off it). jawOpen and mouthFunnel part the slit (before the rig found the slit, the lips moved with the jaw
    as one sheet: jawOpen parted it by 0.7 mm, funnel by 0.03 mm); a press keeps it sealed."""
    mesh, landmarks, mm = lee_perry_smith
    rig = default_rig(mesh, landmarks, device=DEVICE)
    up = face_up(rig.mesh, rig.landmarks)
    upper, lower = _slit_pairs(rig.mesh, rig.landmarks, up)
    assert len(upper) >= 10
    names = ["jawOpen", "mouthFunnel", "mouthPressLeft", "mouthPressRight"]
    points = rig.model(device=DEVICE).evaluate(preset_frames(rig, names))
    opening = ((points[:, upper] - points[:, lower]) @ up - (rig.mesh.points[upper] - rig.mesh.points[lower]) @ up) * mm
    assert opening[0].min() > 0.0 and np.median(opening[0]) > 3.0  # jawOpen
    assert opening[1].min() > 0.0 and np.median(opening[1]) > 1.0  # mouthFunnel
    assert np.abs(opening[2:]).max() < 0.5  # the presses
    assert _lips(rig, preset_frames(rig, ARKIT_PRESET_NAMES)).min() >= -0.2
    assert _lips(rig, random_combinations(rig, 50)).min() >= -0.2


def test_a_live_link_take_s_mouth_close_seals_the_lips_through_animate(tmp_path):
    """ARKit's mouthClose over jawOpen, as a user drives it (a Live Link take through ``warpface animate``): the jaw
    opens, the lips stay together (docs/RIG.md §12), as the mouthClose preset holds them; alone, or above jawOpen,
    mouthClose never pushes them through each other; half of it leaves about half the opening (the built-in face's
    lips are 3 mm apart at rest: mouthClose closes that gap in proportion to its weight). Measured on the baked
    stage."""
    from pxr import Usd, UsdGeom

    from warpface.commands.animate import animate
    from warpface.drivers import Curves, write_live_link
    from warpface.usd import rig_prims

    poses = [(1.0, 0.0), (1.0, 1.0), (0.0, 0.6), (0.3, 1.0), (1.0, 0.5)]  # (jawOpen, mouthClose), 3 frames each
    values = np.repeat(np.array(poses), 3, axis=0)
    curves = Curves(times=np.arange(len(values)) / 30.0, names=["jawOpen", "mouthClose"], values=values, fps=30.0)
    result = animate(
        write_live_link(tmp_path / "take.csv", curves),
        tmp_path / "face.usda",
        video=False,
        device=DEVICE,
        progress=False,
    )
    stage = Usd.Stage.Open(str(result.stage))
    attribute = UsdGeom.Mesh(stage.GetPrimAtPath(rig_prims(stage).skin.GetPath())).GetPointsAttr()
    rig = default_rig(device=DEVICE)
    points = np.array([attribute.Get(float(3 * k + 1)) for k in range(len(poses))], dtype=np.float64)
    lips = pair_heights(points, rig.landmarks, LIP_PAIRS, face_up(rig.mesh, rig.landmarks), 1000.0)
    opened, closed, alone, above, half = lips
    assert opened.min() > 4.0
    assert closed.min() >= -0.2 and closed.max() <= 1.5
    assert alone.min() >= -0.2 and above.min() >= -0.2 and above.max() <= 1.5
    assert 0.3 * opened.max() < half.max() < 0.7 * opened.max()
    preset = _lips(rig, preset_frames(rig, ["mouthClose"]))
    assert preset.min() >= -0.2 and preset.max() <= 1.5  # the preset holds them as closely


def test_the_mouth_close_share_is_a_product_of_the_channels_and_the_jaw():
    from warpface.assets.lips import closing_share, mouth_close_shares

    rig = default_rig(device=DEVICE)
    jaw = np.array([[0.2, 0.0, 0.0], [0.2, 0.0, 0.0], [0.2, 0.0, 0.0], [0.0, 0.0, 0.0], [0.1, 0.0, 0.0]])
    shares = mouth_close_shares(rig, jaw, mouth_close=[0.0, 0.5, 2.0, 0.7, 0.25], jaw_open=[1.0, 1.0, 1.0, 0.0, 0.5])
    rest, full, half_open = (closing_share(rig, jaw[k]) for k in (3, 0, 4))
    assert full < rest < 0.0  # the built-in face's lips are 3 mm apart at rest: closing them is a share too
    expected = [
        0.0,
        max(full, 0.5 * (full - rest) + 0.5 * rest),
        full,
        0.7 * rest,
        max(half_open, 0.5 * (half_open - rest) + 0.25 * rest),
    ]
    np.testing.assert_allclose(shares, expected, rtol=1e-12)


@pytest.fixture(scope="module")
def whole_head():
    """The whole ICT head (skin, eyes, teeth, gums, mouth socket; metres), its landmarks, face frame and jaw."""
    from warpface.assets.jaw import default_jaw
    from warpface.assets.rig import face_frame
    from warpface.data import shared_data_path

    path = shared_data_path("ict_facekit", "original", "generic_neutral_mesh.obj")
    if path is None:
        pytest.skip("ICT-FaceKit data not found in ../shared/data (set WARPFACE_SHARED_DATA)")
    source = wf.FaceMesh.from_obj(path, degenerate="ignore")
    mesh, landmarks = wf.FaceMesh(source.points * 0.01, source.triangles, degenerate="ignore"), ict_landmark_indices()
    frame = face_frame(mesh, landmarks)
    return mesh, landmarks, frame, default_jaw(mesh, frame, landmarks)


def test_a_whole_head_s_lips_part_at_their_slit_not_at_the_mouth_socket_s_rim(whole_head):
    """The whole ICT head's lips touch along a slit, and its mouth socket, gums and teeth are shells of their own
    whose open rims lie in front of the mouth too. The jaw's lip-side term must come from the lips' own slit: when
    it took the socket's rim, the upper lip's slit face had the lower lip's jaw weight (0.77 against 0.81), and
    jawOpen parted the lips by 1 mm (docs/RIG.md §4)."""
    from warpface.assets.jaw import mouth_rim_arcs

    mesh, landmarks, frame, jaw = whole_head
    assert len(np.unique(mesh.shells)) == 56
    assert mouth_rim_arcs(mesh, frame.to_local(mesh.points), landmarks) is None
    upper, lower = _slit_pairs(mesh, landmarks, face_up(mesh, landmarks))
    assert len(upper) >= 10
    weights = jaw.weights
    assert np.median(weights[upper]) < 0.4 and np.median(weights[lower]) > 0.9
    assert np.all(weights[lower] > weights[upper])


def test_a_whole_head_s_jaw_opens_fully_without_turning_the_face_over(whole_head):
    """On the whole head the mouth socket joins the lips' inner corners and the neck the jaw's lower border, and the
    weights' equalizing rounds stalled with 76 of the face's triangles turned over at the full opening, at the inner
    mouth corners and under the jaw (docs/RIG.md §14). Longer rounds that hold the lips the seal reads clear them
    while each lip's slit keeps one weight: the lower lip's slit pairs all stay at the jaw's full weight."""
    from warpface.expression.jaw import jaw_points

    mesh, landmarks, frame, jaw = whole_head
    face = (mesh.triangles < ICT_FACE_VERTICES).all(axis=1)
    rest = mesh.points
    spacing = float(np.linalg.norm(rest[landmarks[36:42]].mean(axis=0) - rest[landmarks[42:48]].mean(axis=0)))
    slide = 0.08 * spacing  # the default mappings' full jawForward / jawLeft / jawRight
    for pose in ([0.35, 0.0, 0.0], [0.21, 0.0, 0.0], [0.0, slide, 0.0], [0.0, 0.0, slide], [0.0, 0.0, -slide]):
        moved = jaw_points(jaw, rest, np.array(pose))
        turned = _turned(rest, mesh.triangles[face], moved)
        assert turned == 0, pose
    upper, lower = _slit_pairs(mesh, landmarks, face_up(mesh, landmarks))
    assert np.median(jaw.weights[lower]) > 0.99


def _turned(rest: np.ndarray, triangles: np.ndarray, moved: np.ndarray) -> int:
    """Triangles whose normal turned over (rest · moved < 0), counted independently of the rig's guards."""

    def normals(points):
        a, b, c = (points[triangles[:, k]] for k in range(3))
        return np.cross(b - a, c - a)

    return int(np.count_nonzero(np.einsum("ij,ij->i", normals(rest), normals(moved)) < 0.0))
