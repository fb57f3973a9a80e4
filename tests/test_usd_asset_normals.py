"""Baked normals (:class:`warpface.usd.asset_normals.SkinNormals`) against a float64 reference: area-weighted
(Newell) normals, the asset's interpolation and indexing kept, its hard edges kept hard."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pxr")

from pxr import Sdf, Usd, UsdGeom, Vt  # noqa: E402

from warpface.usd.asset_normals import SkinNormals  # noqa: E402


def _roof(n: int = 5):
    """A grid of (n−1)² quads folded 90° along its middle column: points (n², 3), counts, corner indices."""
    u, v = np.meshgrid(np.arange(n, dtype=np.float64), np.arange(n, dtype=np.float64), indexing="ij")
    middle = (n - 1) / 2
    height = middle - np.abs(u - middle)  # the ridge along u = middle
    points = np.stack([u, v, height], axis=-1).reshape(-1, 3)
    faces = [
        [i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1] for i in range(n - 1) for j in range(n - 1)
    ]
    return points, np.full(len(faces), 4), np.asarray(faces).ravel()


def _newell(points, counts, indices):
    starts = np.cumsum(counts) - counts
    area = np.zeros((len(counts), 3))
    for f, (s, c) in enumerate(zip(starts, counts)):
        ring = points[indices[s : s + c]]
        for k in range(c):
            area[f] += np.cross(ring[k], ring[(k + 1) % c])
    return area


def _reference(points, counts, indices, authored, interpolation):
    """Per value, float64, by loops: the area vectors of the faces sharing the value, normalised."""
    area = _newell(points, counts, indices)
    face = np.repeat(np.arange(len(counts)), counts)
    if interpolation == "uniform":
        sums = area
    elif interpolation == "vertex":
        sums = np.zeros_like(points)
        for c, v in enumerate(indices):
            sums[v] += area[face[c]]
    else:
        unit = authored / np.linalg.norm(authored, axis=1, keepdims=True)
        sums = np.zeros((len(indices), 3))
        for c, v in enumerate(indices):
            for d in np.flatnonzero(indices == v):
                if unit[c] @ unit[d] > 0.99:
                    sums[c] += area[face[d]]
    return sums / np.linalg.norm(sums, axis=1, keepdims=True)


def _mesh(points, counts, indices, normals, interpolation, *, indexed=False):
    stage = Usd.Stage.CreateInMemory()
    mesh = UsdGeom.Mesh.Define(stage, "/Skin")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(counts.astype(np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(indices.astype(np.int32)))
    primvar = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("normals", Sdf.ValueTypeNames.Normal3fArray, interpolation)
    if indexed:
        values, table = np.unique(normals.round(6), axis=0, return_inverse=True)
        primvar.Set(Vt.Vec3fArray.FromNumpy(values.astype(np.float32)))
        primvar.SetIndices(Vt.IntArray.FromNumpy(table.reshape(-1).astype(np.int32)))
    else:
        primvar.Set(Vt.Vec3fArray.FromNumpy(normals.astype(np.float32)))
    return stage, mesh.GetPrim()


def _deformed(points):
    rng = np.random.default_rng(3)
    return points + 0.15 * rng.normal(size=points.shape) + 0.2 * np.sin(points[:, [1, 2, 0]])


@pytest.mark.parametrize("indexed", [False, True])
def test_face_varying_hard_edges_stay_hard_and_match_the_float64_reference(indexed):
    points, counts, indices = _roof()
    flat = _newell(points, counts, indices)
    authored = np.repeat(flat / np.linalg.norm(flat, axis=1, keepdims=True), counts, axis=0)  # faceted: split
    authored = _reference(points, counts, indices, authored, "faceVarying")  # smooth on each side of the ridge
    stage, skin = _mesh(points, counts, indices, authored, "faceVarying", indexed=indexed)
    normals = SkinNormals.of(skin)
    moved = _deformed(points)
    expected = _reference(moved, counts, indices, authored, "faceVarying")
    got = normals.frame(moved)
    if indexed:
        primvar = UsdGeom.PrimvarsAPI(skin).GetPrimvar("normals")
        layer = stage.GetRootLayer()
        normals.prepare(layer, skin.GetPath(), 0.0, 0.0)
        normals.write(layer, 0.0, moved)
        got = np.asarray(primvar.ComputeFlattened(Usd.TimeCode(0.0)), dtype=np.float64)
        np.testing.assert_allclose(got, expected, atol=2e-6)
    else:
        np.testing.assert_allclose(got, expected, atol=1e-12)
    ridge = np.flatnonzero(points[indices][:, 0] == 2.0)  # corners on the ridge: two normals each, ~90° apart
    cosines = [expected[a] @ expected[b] for a in ridge for b in ridge if indices[a] == indices[b]]
    assert min(cosines) < 0.5


@pytest.mark.parametrize("interpolation", ["vertex", "uniform"])
def test_vertex_and_uniform_normals_and_an_inward_asset(interpolation):
    points, counts, indices = _roof()
    reference = _reference(points, counts, indices, None, interpolation)
    _, skin = _mesh(points, counts, indices, -reference, interpolation)  # authored pointing the other way
    moved = _deformed(points)
    got = SkinNormals.of(skin).frame(moved)
    np.testing.assert_allclose(got, -_reference(moved, counts, indices, None, interpolation), atol=1e-12)
