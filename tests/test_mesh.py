"""FaceMesh: validation, OBJ loading, adjacency, areas and normals."""

from __future__ import annotations

import numpy as np
import pytest
import reference_expression as ref
from helpers import grid_surface, icosphere_like

import warpface as wf
from warpface.data import ict_face_region


def test_normals_match_reference_and_point_outward_on_a_sphere():
    points, triangles = icosphere_like()
    mesh = wf.FaceMesh(points, triangles)
    normals = mesh.vertex_normals(device="cpu")
    np.testing.assert_allclose(normals, ref.vertex_normals(points, triangles), atol=1e-6)
    radial = points / np.linalg.norm(points, axis=1, keepdims=True)
    assert np.all(np.sum(normals * radial, axis=1) > 0.99)


def test_adjacency_and_areas(rng):
    points, triangles = grid_surface(9, seed=3)
    mesh = wf.FaceMesh(points, triangles)
    adjacency = mesh.adjacency
    for v in rng.integers(0, mesh.vertex_count, 20):
        expected = np.flatnonzero(np.any(triangles == v, axis=1))
        np.testing.assert_array_equal(
            np.sort(adjacency.triangles[adjacency.offsets[v] : adjacency.offsets[v + 1]]), expected
        )
    np.testing.assert_allclose(mesh.rest_areas, ref.triangle_areas(points, triangles), rtol=1e-12)
    assert mesh.rest_areas.sum() == pytest.approx(ref.triangle_areas(points, triangles).sum())
    assert len(mesh.boundary_vertices) == 4 * 8


def test_obj_with_quads_and_slashes(tmp_path):
    path = tmp_path / "quad.obj"
    path.write_text(
        "# quad + tri\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nvt 0 0\nf 1/1/1 2/1/1 3/1/1 4/1/1\nf -4 5 3\n"
    )
    mesh = wf.FaceMesh.from_obj(path)
    assert mesh.triangle_count == 3
    np.testing.assert_array_equal(mesh.triangles, [[0, 1, 2], [0, 2, 3], [1, 4, 2]])
    assert mesh.rest_areas.sum() == pytest.approx(1.5)


@pytest.mark.parametrize(
    "points, triangles, message",
    [
        ([[0, 0, 0], [1, 0, 0], [0, np.nan, 0]], [[0, 1, 2]], "non-finite"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 3]], "out of range"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, -1]], "out of range"),
        ([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]], "zero-area"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 1]], "repeats"),
        ([[0, 0, 0], [1, 0, 0]], [[0, 1]], "shape"),
    ],
)
def test_bad_meshes_raise_clear_errors(points, triangles, message):
    with pytest.raises(ValueError, match=message):
        wf.FaceMesh(points, triangles)


def test_degenerate_triangles_can_be_ignored_without_nan():
    points = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]]
    mesh = wf.FaceMesh(points, [[0, 1, 2], [0, 1, 3]], degenerate="ignore")
    model = wf.ExpressionModel(mesh, [wf.LinearMuscle("m", [0, -1, 0], [0, 0, 0], 60, 0.5, 3)], [], 0.2, device="cpu")
    stages = model.stages({"m": 0.1})
    assert np.all(np.isfinite(stages.final)) and np.all(np.isfinite(stages.stretch))


def test_real_ict_face_loads():
    path = ict_face_region()
    if path is None:
        pytest.skip("shared ICT face data not present (../shared/data)")
    mesh = wf.FaceMesh.from_obj(path)
    assert (mesh.vertex_count, mesh.triangle_count) == (9409, 18460)
    normals = mesh.vertex_normals(device="cpu")
    assert normals[:, 2].mean() > 0.3 and np.median(normals[:, 2]) > 0.5  # the face looks toward +z
