"""Shells that sit on the skin (eyelashes, tear films) ride it: rest + the skin's interpolated displacement."""

from __future__ import annotations

import json

import numpy as np
import pytest

from warpface.data import shared_data_path

ICT = shared_data_path("ict_facekit")
CM = 0.01


def _octahedron(centre, radius):
    """A closed octahedron (6 points, 8 triangles); its vertex 3 is the lowest (−y), 5 the one at −z."""
    axes = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64)
    faces = [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]]
    return np.asarray(centre, dtype=np.float64) + radius * axes, np.array(faces)


def _define_mesh(stage, path, points, faces):
    from pxr import UsdGeom, Vt

    faces = np.asarray(faces, dtype=np.int32)
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(points, dtype=np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), faces.shape[1], dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.reshape(-1)))
    return mesh


def test_a_shell_touching_a_skin_sheet_bakes_as_rest_plus_the_interpolated_skin_displacement():
    from pxr import Sdf, Usd

    from warpface.usd.skin_followers import (
        skin_embeddings,
        skin_followers,
        write_skin_embedding,
        write_skin_followers,
    )

    n = 11  # a 10 × 10 cm sheet in the plane y = 0, two triangles per cell
    grid = np.stack(np.meshgrid(np.arange(n, dtype=np.float64), np.arange(n, dtype=np.float64)), axis=-1)
    sheet = np.column_stack([grid[..., 0].ravel(), np.zeros(n * n), grid[..., 1].ravel()])
    cell = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None]).ravel()
    triangles = np.concatenate(
        [np.column_stack([cell, cell + n, cell + 1]), np.column_stack([cell + 1, cell + n, cell + n + 1])]
    )
    landmarks = np.zeros(68, dtype=np.int64)
    landmarks[42:48] = n - 1  # inter-ocular distance 10 cm: touching is within 0.1 mm
    lash, faces = _octahedron([3.3, 0.45, 6.7], 0.45)  # its lowest vertex on the sheet: 1 of 6 touch
    eye, _ = _octahedron([6.2, 0.8, 2.4], 0.4)  # 4 mm above it: stays with the head
    stage = Usd.Stage.CreateInMemory("head.usda")
    _define_mesh(stage, "/Head/Skin", sheet, triangles)
    _define_mesh(stage, "/Head/Lash", np.concatenate([lash, eye]), np.concatenate([faces, faces + 6]))
    _define_mesh(stage, "/Head/Eye", eye, faces)
    found = skin_embeddings(stage, "/Head/Skin", sheet, triangles, landmarks, device="cpu")
    assert sorted(found) == ["/Head/Lash"]  # the eye is no follower, and the lash mesh's eye shell stays
    for path, embedding in found.items():
        write_skin_embedding(stage.GetRootLayer().GetPrimAtPath(path), embedding)
    followers = skin_followers(stage, len(sheet))
    assert [str(prim.GetPath()) for prim, _, _ in followers] == ["/Head/Lash"]

    rng = np.random.default_rng(7)
    frames = rng.normal(scale=0.3, size=(3, len(sheet), 3))
    frames[0] = 0.0
    positions = sheet + frames
    layer = Sdf.Layer.CreateAnonymous(".usda")
    write_skin_followers(layer, followers, sheet, np.array([0.0, 1.0, 2.0]), positions.astype(np.float32))

    # float64 reference: a point above the flat sheet is closest to its projection; its cell's triangle
    # and barycentric coordinates there from the plane's (x, z)
    rest = np.concatenate([lash, eye])
    expected = np.repeat(rest[None], 3, axis=0)
    for k, (x, _, z) in enumerate(lash):
        i, j = min(int(np.floor(x)), n - 2), min(int(np.floor(z)), n - 2)
        u, v = x - i, z - j  # u along x (index + 1), v along z (index + n)
        corner = j * n + i
        if u + v <= 1.0:
            vertices, weights = [corner, corner + n, corner + 1], [1 - u - v, v, u]
        else:
            vertices, weights = [corner + 1, corner + n, corner + n + 1], [1 - v, 1 - u, u + v - 1]
        expected[:, k] += np.einsum("fkd,k->fd", frames[:, vertices], weights)
    for time in range(3):
        baked = np.asarray(layer.QueryTimeSample(Sdf.Path("/Head/Lash.points"), time), dtype=np.float64)
        np.testing.assert_allclose(baked, expected[time], atol=2e-5)
        extent = np.asarray(layer.QueryTimeSample(Sdf.Path("/Head/Lash.extent"), time), dtype=np.float64)
        np.testing.assert_allclose(extent, [baked.min(axis=0), baked.max(axis=0)], atol=1e-6)
    assert np.abs(expected[1:, :6] - lash).max() > 0.1  # the lash did move


def _lashed_face():
    """The built-in face in cm and a lash strip on each upper lid: per margin landmark (37, 38, 43, 44) a
    triangle rooted on it, two tips 3 mm out."""
    from warpface.assets import default_face, default_landmarks

    face, marks = default_face(), default_landmarks()
    points = 100.0 * face.points
    normals = face.vertex_normals()
    roots = marks[[37, 38, 43, 44]]
    up = points[marks[27]] - points[marks[8]]
    up /= np.linalg.norm(up)
    lash = np.concatenate([[points[r], points[r] + 0.3 * normals[r] + 0.1 * up, points[r] + 0.3 * up] for r in roots])
    eye, faces = _octahedron(points[marks[36:42]].mean(axis=0) - [0, 0, 1.2], 0.4)
    return points, face.triangles, marks, lash, np.arange(len(lash)).reshape(-1, 3), eye, faces


@pytest.mark.parametrize("layout", ["one_mesh", "several_meshes"])
def test_rig_then_bake_keeps_the_lashes_on_the_blinking_lid(layout, tmp_path):
    from pxr import Usd, UsdGeom

    from benchmarks.lash_blink import live_link_take
    from warpface.cli import main

    points, triangles, marks, lash, lash_faces, eye, eye_faces = _lashed_face()
    marks_file = tmp_path / "marks.json"
    marks_file.write_text(json.dumps(marks.tolist()))
    count = len(points)
    if layout == "one_mesh":
        head = tmp_path / "head.obj"
        lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in np.concatenate([points, lash, eye])]
        faces = np.concatenate([triangles, lash_faces + count, eye_faces + count + len(lash)])
        head.write_text("\n".join(lines + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]) + "\n")
    else:
        head = tmp_path / "head.usda"
        stage = Usd.Stage.CreateNew(str(head))
        UsdGeom.SetStageMetersPerUnit(stage, CM)
        stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/Head").GetPrim())
        _define_mesh(stage, "/Head/Skin", points, triangles)
        _define_mesh(stage, "/Head/Lashes", lash, lash_faces)
        _define_mesh(stage, "/Head/Eye", eye, eye_faces)
        stage.GetRootLayer().Save()
    rig = tmp_path / "rig.usda"
    assert main(["--quiet", "rig", str(head), "--out", str(rig), "--landmarks", str(marks_file), "--units", "cm"]) == 0
    frames = 5
    take = live_link_take(tmp_path / "take.csv", {"eyeBlinkLeft": np.linspace(0, 1, frames)}, frames)
    animated = tmp_path / "shot.usda"
    assert main(["--quiet", "animate", str(take), "--rig", str(rig), "--out", str(animated), "--no-video"]) == 0
    shot = tmp_path / "again_shot.usda"
    command = ["--quiet", "bake", str(animated), "--cache", str(tmp_path / "again.usdc"), "--shot", str(shot)]
    assert main(command) == 0
    stage = Usd.Stage.Open(str(shot))

    def at(path, time):
        return np.asarray(UsdGeom.Mesh(stage.GetPrimAtPath(path)).GetPointsAttr().Get(time), dtype=np.float64)

    skin = at("/Face/Skin", Usd.TimeCode(frames - 1))
    if layout == "one_mesh":
        lash_now, eye_now = skin[count : count + len(lash)], skin[count + len(lash) :]
    else:
        lash_now, eye_now = at("/Face/Asset/Head/Lashes", frames - 1), at("/Face/Asset/Head/Eye", frames - 1)
    moved = skin[:count] - points
    roots = lash_faces[:, 0]
    np.testing.assert_allclose(lash_now[roots] - lash[roots], moved[marks[[37, 38, 43, 44]]], atol=1e-4)
    np.testing.assert_allclose(eye_now, eye, atol=1e-5)  # the eye stays with the head
    lid = np.linalg.norm(moved[marks[[37, 38, 43, 44]]], axis=1)
    assert lid.max() > 0.1  # cm: one upper lid closed ...
    tips = np.linalg.norm(lash_now - lash, axis=1).reshape(-1, 3)
    np.testing.assert_allclose(
        tips[:, 1:], np.repeat(lid[:, None], 2, axis=1), rtol=0.35, atol=0.02
    )  # ... lashes with it


@pytest.mark.skipif(ICT is None, reason="ICT-FaceKit not in ../shared/data (set WARPFACE_SHARED_DATA)")
def test_on_the_ict_head_the_lashes_and_films_ride_the_skin_and_the_eyes_do_not(tmp_path):
    from benchmarks.lash_blink import split_ict_usd
    from warpface.data import ict_landmark_indices
    from warpface.mesh import fan_triangles, read_obj_polygons
    from warpface.usd import open_stage
    from warpface.usd.skin_followers import skin_embeddings

    obj = read_obj_polygons(ICT / "original" / "generic_neutral_mesh.obj")
    ranges = split_ict_usd(obj, tmp_path / "ict.usda")
    low, high = ranges["Head"]
    triangles = fan_triangles(obj.counts, obj.indices)
    triangles = triangles[(triangles < high).all(axis=1)]
    found = skin_embeddings(
        open_stage(tmp_path / "ict.usda"),
        "/Character/Head",
        obj.points[:high],
        triangles,
        ict_landmark_indices(),
        device="cpu",
    )
    assert sorted(found) == ["/Character/Rest"]  # not the eyes, teeth, gums and tongue
    material = np.full(len(obj.points), -1)
    material[obj.indices] = np.repeat(obj.face_materials, obj.counts)
    first = ranges["Rest"][0]
    riding = np.abs(found["/Character/Rest"].weights).sum(axis=1) > 0.0
    names = {name: material[first:] == obj.materials.index(name) for name in obj.materials}
    for name in ("M_EyeLashes", "M_LacrimalFluid", "M_EyeOcclusion"):
        assert riding[names[name]].all(), name
    assert not riding[names["M_EyeBlend"]].any()  # 4 % of it touches: it stays with the eyes
    np.testing.assert_allclose(found["/Character/Rest"].weights[riding].sum(axis=1), 1.0, atol=1e-5)
