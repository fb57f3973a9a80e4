"""The rig stage on the user's own mesh: the asset is referenced, kept exactly and never edited."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from warpface.assets import default_face, default_landmarks
from warpface.cli import main
from warpface.data import shared_data_path
from warpface.drivers import ARKIT_CHANNELS

CM = 0.01


def _quads(triangles):
    """Neighbouring triangles (t, t + 1) that share an edge merged into one quad; the others kept."""
    faces, k = [], 0
    while k < len(triangles):
        a = [int(v) for v in triangles[k]]
        b = [int(v) for v in triangles[k + 1]] if k + 1 < len(triangles) else []
        shared = set(a) & set(b)
        if len(shared) == 2:
            apex = next(v for v in a if v not in shared)
            i = a.index(apex)
            faces.append([apex, a[(i + 1) % 3], next(v for v in b if v not in shared), a[(i + 2) % 3]])
            k += 2
        else:
            faces.append(a)
            k += 1
    return faces


def live_link_csv(path, rows: dict, frames: int):
    """A Live Link Face CSV at 30 fps, the named ARKit channels from ``rows``, the others 0."""
    header = "Timecode,BlendshapeCount," + ",".join(n[0].upper() + n[1:] for n in ARKIT_CHANNELS)
    lines = [header]
    for frame in range(frames):
        values = ",".join(f"{rows[n][frame]:.6f}" if n in rows else "0" for n in ARKIT_CHANNELS)
        lines.append(f"10:20:00:{frame:02d}.000,{len(ARKIT_CHANNELS)}," + values)
    path.write_text("\n".join(lines) + "\n")
    return path


def _shell(centre, radius):
    """A closed octahedron (6 points, 8 triangles) around ``centre``."""
    axes = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64)
    faces = [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]]
    return centre + radius * axes, faces


@pytest.fixture(scope="module")
def quad_head(tmp_path_factory):
    """The built-in face in cm as quads and triangles with per-corner UVs and two materials, plus an eye
    shell above the lips and a tooth shell below them."""
    face = default_face()
    marks = default_landmarks()
    points = 100.0 * face.points
    faces = _quads(face.triangles)
    lips = points[marks[60:68]].mean(axis=0)
    eye, eye_faces = _shell(points[marks[36:42]].mean(axis=0) - [0, 0, 1.0], 0.4)
    tooth, tooth_faces = _shell(lips - [0, 0.6, 1.0], 0.3)
    count = len(points)
    faces += [[v + count for v in f] for f in eye_faces] + [[v + count + 6 for v in f] for f in tooth_faces]
    points = np.concatenate([points, eye, tooth])
    normals = np.concatenate([face.vertex_normals(), _unit(eye - eye.mean(axis=0)), _unit(tooth - tooth.mean(axis=0))])
    lines = ["mtllib head.mtl"] + [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in points]
    lines += [f"vn {x:.6f} {y:.6f} {z:.6f}" for x, y, z in normals]
    corner = 0
    uv_lines, face_lines = [], []
    for k, f in enumerate(faces):
        if k in (0, len(faces) // 2):
            face_lines.append(f"usemtl {'skin' if k == 0 else 'back'}")
        refs = []
        for v in f:
            uv_lines.append(f"vt {(v % 97) / 97:.6f} {(corner % 89) / 89:.6f}")
            corner += 1
            refs.append(f"{v + 1}/{corner}/{v + 1}")
        face_lines.append("f " + " ".join(refs))
    path = tmp_path_factory.mktemp("asset") / "head.obj"
    path.write_text("\n".join(lines + uv_lines + face_lines) + "\n")
    landmarks = path.with_name("marks.json")
    landmarks.write_text(json.dumps(marks.tolist()))
    return path, landmarks, count


def _unit(vectors):
    return vectors / np.linalg.norm(vectors, axis=1, keepdims=True)


def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_the_rig_references_the_asset_and_a_bake_overrides_only_points(quad_head, tmp_path, capsys):
    from pxr import Sdf, Usd, UsdGeom

    from warpface.errors import RigError
    from warpface.mesh import read_obj_polygons
    from warpface.usd import read_rig

    head, marks, skin_count = quad_head
    out = tmp_path / "rig" / "rig.usda"
    assert main(["--quiet", "rig", str(head), "--out", str(out), "--landmarks", str(marks)]) == 0
    asset = out.with_name("head_asset.usdc")
    assert asset.is_file()
    obj = read_obj_polygons(head)
    stage = Usd.Stage.Open(str(out))
    skin = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Skin"))
    # The composed skin is the asset: faces (quads kept), vertex order, UVs and material subsets.
    np.testing.assert_array_equal(np.asarray(skin.GetFaceVertexCountsAttr().Get()), obj.counts)
    np.testing.assert_array_equal(np.asarray(skin.GetFaceVertexIndicesAttr().Get()), obj.indices)
    assert np.count_nonzero(obj.counts == 4) > 1000
    uv = UsdGeom.PrimvarsAPI(skin).GetPrimvar("st")
    assert uv.GetInterpolation() == UsdGeom.Tokens.faceVarying
    np.testing.assert_array_equal(np.asarray(uv.GetIndices()), obj.uv_indices)
    np.testing.assert_allclose(np.asarray(uv.Get()), obj.uvs, atol=1e-7)
    subsets = UsdGeom.Subset.GetGeomSubsets(skin, "face", "materialBind")
    assert sorted(s.GetPrim().GetName() for s in subsets) == ["back", "skin"]
    assert sum(len(s.GetIndicesAttr().Get()) for s in subsets) == len(obj.counts)
    # The rig layer holds no geometry of its own; the stage keeps the input's frame.
    spec = Sdf.Layer.FindOrOpen(str(out)).GetPrimAtPath("/Face/Skin")
    assert not {"points", "faceVertexIndices", "faceVertexCounts"} & set(spec.properties.keys())
    assert UsdGeom.GetStageUpAxis(stage) == "Y" and UsdGeom.GetStageMetersPerUnit(stage) == pytest.approx(CM)
    rig = read_rig(out)  # metres, same frame, landmarks index the asset's vertices
    np.testing.assert_allclose(rig.mesh.points, obj.points * CM, atol=1e-6)
    np.testing.assert_array_equal(rig.landmarks, default_landmarks())
    rigid = np.asarray(stage.GetPrimAtPath("/Face/Skin").GetAttribute("warpFace:rigidVertices").Get())
    jaw = np.asarray(stage.GetPrimAtPath("/Face/Skin").GetAttribute("warpFace:jawVertices").Get())
    np.testing.assert_array_equal(rigid, np.arange(skin_count, skin_count + 12))
    np.testing.assert_array_equal(jaw, np.arange(skin_count + 6, skin_count + 12))  # the tooth, not the eye

    before = {path: _digest(path) for path in (head, asset, out)}
    frames = 12
    driver = live_link_csv(
        tmp_path / "take.csv",
        {"jawOpen": np.linspace(0, 0.8, frames), "eyeBlinkLeft": np.linspace(0, 1, frames)},
        frames,
    )
    animated = tmp_path / "anim" / "shot.usda"
    animated.parent.mkdir()
    assert main(["--quiet", "animate", str(driver), "--rig", str(out), "--out", str(animated), "--no-video"]) == 0
    assert {path: _digest(path) for path in before} == before  # neither the asset nor the rig was edited
    shot = Usd.Stage.Open(str(animated))
    shot_skin = UsdGeom.Mesh(shot.GetPrimAtPath("/Face/Skin"))
    np.testing.assert_array_equal(np.asarray(shot_skin.GetFaceVertexCountsAttr().Get()), obj.counts)
    cache = Sdf.Layer.FindOrOpen(str(animated.with_name("shot_anim.usdc")))
    authored = []
    cache.Traverse(Sdf.Path.absoluteRootPath, lambda path: authored.append(path) if path.IsPropertyPath() else None)
    assert sorted(p.name for p in authored) == ["extent", "points", "primvars:normals", "primvars:normals:indices"]
    normals = UsdGeom.PrimvarsAPI(shot_skin).GetPrimvar("normals")
    at_rest = np.asarray(normals.ComputeFlattened(Usd.TimeCode(0)), dtype=np.float64)
    assert np.median(np.sum(at_rest * obj.normals[obj.normal_indices], axis=1)) > 0.95  # the asset's, same sign
    corner_normals = np.asarray(normals.ComputeFlattened(Usd.TimeCode(frames - 1)), dtype=np.float64)
    last = np.asarray(shot_skin.GetPointsAttr().Get(Usd.TimeCode(frames - 1)), dtype=np.float64)
    rest = obj.points
    eye, tooth = slice(skin_count, skin_count + 6), slice(skin_count + 6, skin_count + 12)
    np.testing.assert_allclose(last[eye], rest[eye], atol=1e-4)  # the eye moves with the head only
    moved = np.linalg.norm(last[tooth] - rest[tooth], axis=1)
    assert moved.min() > 0.05  # the lower tooth follows the opened jaw ...
    rest_gaps = np.linalg.norm(rest[tooth][:, None] - rest[tooth][None], axis=2)
    gaps = np.linalg.norm(last[tooth][:, None] - last[tooth][None], axis=2)
    np.testing.assert_allclose(gaps, rest_gaps, atol=1e-4)  # ... rigidly
    assert np.abs(last[:skin_count] - rest[:skin_count]).max() > 0.1  # while the skin's muscles move it
    starts = np.cumsum(obj.counts) - obj.counts
    newell = np.zeros((len(obj.counts), 3))
    for k in range(obj.counts.max()):  # each face's Newell normal on the deformed points, float64
        has = obj.counts > k
        here = last[obj.indices[starts[has] + k]]
        after = last[obj.indices[starts[has] + (k + 1) % obj.counts[has]]]
        newell[has] += np.cross(here, after)
    rest_newell = np.zeros((len(obj.counts), 3))
    for k in range(obj.counts.max()):
        has = obj.counts > k
        here = rest[obj.indices[starts[has] + k]]
        rest_newell[has] += np.cross(here, rest[obj.indices[starts[has] + (k + 1) % obj.counts[has]]])
    face_normal = np.repeat(_unit(newell), obj.counts, axis=0)
    facing = np.sum(corner_normals * face_normal, axis=1)
    assert np.mean(facing > 0.5) > 0.99  # the baked normals follow the deformed faces ...
    turned = np.repeat(np.sum(_unit(newell) * _unit(rest_newell), axis=1) < 0.95, obj.counts)
    assert turned.sum() > 50  # ... where they turned, better than the rest normals do
    assert facing[turned].mean() > np.sum(at_rest * face_normal, axis=1)[turned].mean() + 0.05
    capsys.readouterr()

    asset.rename(asset.with_suffix(".moved"))
    assert main(["animate", str(driver), "--rig", str(out), "--out", str(tmp_path / "again.usda"), "--no-video"]) == 2
    error = capsys.readouterr().err.strip()
    assert "head_asset.usdc" in error and "missing" in error and "\n" not in error
    with pytest.raises(RigError, match="head_asset.usdc .* is missing"):
        read_rig(out)
    assert main(["validate", str(out)]) == 2
    report = capsys.readouterr().err.strip()
    assert "is missing" in report and "\n" not in report


ICT = shared_data_path("ict_facekit")


@pytest.mark.skipif(ICT is None, reason="ICT-FaceKit not in ../shared/data (set WARPFACE_SHARED_DATA)")
def test_whole_ict_head_keeps_its_polygons_and_shells(tmp_path):
    from pxr import Usd, UsdGeom

    from warpface.mesh import read_obj_polygons
    from warpface.usd import read_rig

    head = ICT / "original" / "generic_neutral_mesh.obj"
    out = tmp_path / "ict.usda"
    assert main(["--quiet", "rig", str(head), "--out", str(out)]) == 0
    obj = read_obj_polygons(head)
    stage = Usd.Stage.Open(str(out))
    skin = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Skin"))
    np.testing.assert_array_equal(np.asarray(skin.GetFaceVertexCountsAttr().Get()), obj.counts)
    np.testing.assert_array_equal(np.asarray(skin.GetFaceVertexIndicesAttr().Get()), obj.indices)
    rigid = np.asarray(skin.GetPrim().GetAttribute("warpFace:rigidVertices").Get())
    assert 0 < len(rigid) < len(obj.points) // 2
    rig = read_rig(out, degenerate="ignore")
    np.testing.assert_allclose(rig.mesh.points, obj.points * CM, atol=1e-6)
    assert not np.isin(rig.landmarks, rigid).any()
    jaw = np.asarray(skin.GetPrim().GetAttribute("warpFace:jawVertices").Get())
    corner_material = np.repeat(obj.face_materials, obj.counts)

    def vertices(*names):
        chosen = [obj.materials.index(name) for name in names]
        return np.unique(obj.indices[np.isin(corner_material, chosen)])

    eyes = vertices("M_ScleraLeft", "M_ScleraRight", "M_IrisLeft", "M_IrisRight")
    assert np.isin(eyes, rigid).all() and not np.isin(eyes, jaw).any()  # the eyes stay with the head
    assert not np.isin(vertices("M_EyeLashes"), rigid).any()  # lashes ride on the lids
    teeth = vertices("M_Teeth")
    assert np.isin(teeth, rigid).all() and 0.3 < np.isin(teeth, jaw).mean() < 0.7  # the lower ones with the jaw


ICT_PRIMS = {"Head": (0, 14062), "GumsTongue": (14062, 17039), "Teeth": (17039, 21451), "Eyes": (21451, 24591)}
"""The whole ICT head's region ranges (../shared/data/README.md) as prims; the remaining vertices (lashes …) go
to a prim "Rest"."""


def _split_ict_usd(path):
    """The whole ICT head as a cm, Y-up USD stage with one Mesh prim per region (polygons and order kept)."""
    from pxr import Usd, UsdGeom, Vt

    from warpface.mesh import read_obj_polygons

    obj = read_obj_polygons(ICT / "original" / "generic_neutral_mesh.obj")
    ranges = dict(ICT_PRIMS, Rest=(ICT_PRIMS["Eyes"][1], len(obj.points)))
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, CM)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/Character").GetPrim())
    starts = np.cumsum(obj.counts) - obj.counts
    first = obj.indices[starts]
    for name, (low, high) in ranges.items():
        faces = (first >= low) & (first < high)
        corners = np.concatenate([obj.indices[s : s + c] for s, c in zip(starts[faces], obj.counts[faces])])
        assert corners.min() >= low and corners.max() < high  # no face crosses regions
        mesh = UsdGeom.Mesh.Define(stage, f"/Character/{name}")
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(obj.points[low:high].astype(np.float32)))
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(obj.counts[faces].astype(np.int32)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy((corners - low).astype(np.int32)))
    stage.GetRootLayer().Save()
    return obj, ranges


@pytest.mark.slow  # end to end, over 20 s on the 2-core CI machine
@pytest.mark.skipif(ICT is None, reason="ICT-FaceKit not in ../shared/data (set WARPFACE_SHARED_DATA)")
def test_a_usd_head_of_several_meshes_is_rigged_on_its_face_and_kept_whole(tmp_path):
    from pxr import Usd, UsdGeom

    from warpface.data import ict_landmark_indices
    from warpface.usd import read_rig

    head = tmp_path / "asset" / "ict.usda"
    head.parent.mkdir()
    obj, ranges = _split_ict_usd(head)
    before = _digest(head)
    out = tmp_path / "rig" / "rig.usda"
    assert main(["--quiet", "rig", str(head), "--out", str(out)]) == 0
    assert _digest(head) == before  # the asset is never edited
    rig = read_rig(out, degenerate="ignore")  # the skin is the Head prim, the mesh the face was found on
    low, high = ranges["Head"]
    np.testing.assert_allclose(rig.mesh.points, obj.points[low:high] * CM, atol=1e-6)
    error_mm = 1000.0 * np.linalg.norm(rig.mesh.points[rig.landmarks] - obj.points[ict_landmark_indices()] * CM, axis=1)
    assert error_mm.mean() < 1.0 and error_mm.max() < 5.0
    stage = Usd.Stage.Open(str(out))
    kept = stage.GetPrimAtPath("/Face/Asset/Character")
    assert kept.IsValid() and not stage.GetPrimAtPath("/Face/Asset/Character/Head").IsActive()
    for name in ("Eyes", "Teeth", "GumsTongue", "Rest"):  # every other mesh of the asset composes, unchanged
        mesh = UsdGeom.Mesh(stage.GetPrimAtPath(f"/Face/Asset/Character/{name}"))
        low, high = ranges[name]
        np.testing.assert_array_equal(np.asarray(mesh.GetPointsAttr().Get()), obj.points[low:high].astype(np.float32))
    skins = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh) and p.GetName() == "Head"]
    assert [str(p.GetPath()) for p in skins] == []  # the head composes once: as the rig's skin
    assert UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Skin")).GetPointsAttr().Get() is not None
    rig_digest = _digest(out)

    frames = 6
    take = live_link_csv(tmp_path / "take.csv", {"jawOpen": np.linspace(0.0, 0.9, frames)}, frames)
    animated = tmp_path / "anim" / "shot.usda"
    assert main(["--quiet", "animate", str(take), "--rig", str(out), "--out", str(animated), "--no-video"]) == 0
    assert _digest(head) == before and _digest(out) == rig_digest
    shot = Usd.Stage.Open(str(animated))

    def points(name, time):
        mesh = UsdGeom.Mesh(shot.GetPrimAtPath(f"/Face/Asset/Character/{name}"))
        return np.asarray(mesh.GetPointsAttr().Get(Usd.TimeCode(time)), dtype=np.float64)

    eyes_rest, eyes_open = points("Eyes", 0), points("Eyes", frames - 1)
    np.testing.assert_array_equal(eyes_open, eyes_rest)  # the eyes stay with the head
    teeth_rest, teeth_open = points("Teeth", 0), points("Teeth", frames - 1)
    moved = np.linalg.norm(teeth_open - teeth_rest, axis=1)
    lower, upper = moved > 0.05, moved < 1e-6  # cm: the lower teeth follow the opened jaw, the upper ones stay
    assert lower.sum() > 0.3 * len(moved) and upper.sum() > 0.3 * len(moved) and (lower | upper).all()
    # rigidly: the lower teeth keep their distances (a rotation about the jaw's pivot)
    sample = np.flatnonzero(lower)[:: max(1, lower.sum() // 200)]
    gaps = np.linalg.norm(teeth_open[sample][:, None] - teeth_open[sample][None], axis=2)
    rest_gaps = np.linalg.norm(teeth_rest[sample][:, None] - teeth_rest[sample][None], axis=2)
    np.testing.assert_allclose(gaps, rest_gaps, atol=1e-3)


@pytest.mark.slow  # end to end on the whole head, ~40 s on the 2-core CI machine
@pytest.mark.skipif(ICT is None, reason="ICT-FaceKit not in ../shared/data (set WARPFACE_SHARED_DATA)")
def test_a_head_split_along_a_uv_seam_is_rigged_as_one_skin_and_its_seam_stays_closed(tmp_path):
    """A game or glTF export splits the skin's vertices along its UV seams: here the face down its middle. The
    rig welds the copies for itself (the asset keeps them), finds the landmarks on the whole face, and a bake
    moves every copy with its twin."""
    from pxr import Usd, UsdGeom

    from warpface.data import ict_landmark_indices
    from warpface.mesh import read_obj_polygons
    from warpface.usd import read_rig

    obj = read_obj_polygons(ICT / "original" / "generic_neutral_mesh.obj")
    starts = np.concatenate([[0], np.cumsum(obj.counts)[:-1]])
    centre_x = np.add.reduceat(obj.points[obj.indices, 0], starts) / obj.counts
    skin = ICT_PRIMS["Head"][1]
    seam = np.flatnonzero((np.abs(obj.points[:skin, 0]) < 1e-6))
    copy_of = np.full(len(obj.points), -1)
    copy_of[seam] = len(obj.points) + np.arange(len(seam))
    indices = obj.indices.copy()
    right = np.repeat(centre_x < 0.0, obj.counts) & (copy_of[indices] >= 0)  # the right half's corners on the seam
    indices[right] = copy_of[indices[right]]
    points = np.vstack([obj.points, obj.points[seam]])
    head = tmp_path / "split_head.obj"
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in points]
    lines += ["f " + " ".join(str(i + 1) for i in indices[s : s + c]) for s, c in zip(starts, obj.counts)]
    head.write_text("\n".join(lines) + "\n")

    out = tmp_path / "rig" / "rig.usda"
    assert main(["--quiet", "rig", str(head), "--out", str(out)]) == 0
    rig = read_rig(out, degenerate="ignore")
    assert len(rig.mesh.points) == len(points)  # the asset's vertices, copies included
    truth = obj.points[ict_landmark_indices()] * CM
    error_mm = 1000.0 * np.linalg.norm(rig.mesh.points[rig.landmarks] - truth, axis=1)
    assert error_mm.mean() < 1.0 and error_mm.max() < 5.0

    frames = 4
    take = live_link_csv(tmp_path / "take.csv", {"jawOpen": np.linspace(0.0, 0.8, frames)}, frames)
    animated = tmp_path / "anim" / "shot.usda"
    assert main(["--quiet", "animate", str(take), "--rig", str(out), "--out", str(animated), "--no-video"]) == 0
    stage = Usd.Stage.Open(str(animated))
    shot = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Skin")).GetPointsAttr()
    opened = np.asarray(shot.Get(Usd.TimeCode(frames - 1)), dtype=np.float64)
    rest = np.asarray(shot.Get(Usd.TimeCode(0)), dtype=np.float64)
    np.testing.assert_array_equal(opened[copy_of[seam]], opened[seam])  # the seam stays closed
    chin = ict_landmark_indices()[8]
    assert np.linalg.norm(opened[chin] - rest[chin]) > 0.5  # cm: the jaw did open


def test_rigid_shells_go_with_the_side_of_their_centroid_unless_they_reach_far_across_the_lips():
    """Teeth overlap the lips' line (an overbite) and a warped head moves its lips against them: a lower tooth with
    45 % of its points above the line but its centroid below it goes wholly with the jaw, an upper tooth reaching below
    stays with the head, the gums-tongue part across the line keeps smooth weights, and a lash on the skin rides it.
    The mouth is rolled 15° against the chin-nasion line: measured along that line instead of square to the mouth's
    corners, the lower tooth, out at the corner, would sit above the lips."""
    from warpface.usd.asset_io import ACROSS_REACH, rigid_shell_vertices

    roll = np.radians(15.0)
    corners = np.array([np.cos(roll), -np.sin(roll), 0.0])  # 48 → 54
    up = np.array([np.sin(roll), np.cos(roll), 0.0])  # square to the corners, in the face's plane
    lips = np.array([0.0, -0.5, 0.0])
    grid = np.stack(np.meshgrid(np.linspace(-1, 1, 21), np.linspace(-1.5, 1.5, 31), [0.3]), axis=-1).reshape(-1, 3)
    marks = np.zeros((68, 3))
    marks[8], marks[27] = (0.0, -1.2, 0.3), (0.0, 0.8, 0.3)  # chin → nasion: straight up, not square to the mouth
    marks[36], marks[45] = (-0.5, 0.3, 0.3), (0.5, 0.3, 0.3)  # eye corners 1 apart: heights in these units
    marks[48], marks[54] = lips - 0.4 * corners, lips + 0.4 * corners
    marks[60:68] = lips + np.outer(np.linspace(-0.3, 0.3, 8), corners)
    skin = np.vstack([grid, marks])

    def bar(at: float, low: float, high: float, count: int = 20) -> np.ndarray:
        """Points along ``up`` from ``low`` to ``high`` above the lips, ``at`` along the mouth's corners."""
        return lips + at * corners + np.outer(np.linspace(low, high, count), up) - (0.0, 0.0, 0.1)

    reach = ACROSS_REACH - 0.02
    parts = {
        "lower tooth": bar(-0.35, -0.2, reach),  # 9 of its 20 points above the line, its centroid below
        "upper tooth": bar(0.1, -reach, 0.3),
        "gums": bar(0.0, -ACROSS_REACH - 0.05, ACROSS_REACH + 0.05, 30),
        "eye": bar(-0.5, 0.75, 0.85),
        "lash": np.vstack([skin[:5], skin[:5] + (0.0, 0.0, 0.05)]),  # half its points on skin vertices
    }
    points = np.vstack([skin, *parts.values()])
    shell = np.concatenate([np.zeros(len(skin), int)] + [np.full(len(p), k + 1) for k, p in enumerate(parts.values())])
    landmarks = len(grid) + np.arange(68)
    rigid, jaw, head = rigid_shell_vertices(shell, 0, points, landmarks)
    members = {name: np.flatnonzero(shell == k + 1) for k, name in enumerate(parts)}
    np.testing.assert_array_equal(jaw, members["lower tooth"])
    np.testing.assert_array_equal(np.sort(head), np.sort(np.concatenate([members["upper tooth"], members["eye"]])))
    assert set(members["gums"]) <= set(rigid) and not set(members["gums"]) & (set(jaw) | set(head))
    assert not set(members["lash"]) & set(rigid)
