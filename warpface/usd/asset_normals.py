"""Per-frame normals of a skin whose asset authors them (a bake writes them beside the points).

:class:`SkinNormals` reads the asset's normals (attribute or primvar; vertex, varying, faceVarying or
uniform; indexed or not) once and gives, for deformed points, area-weighted normals laid out as the
asset's, with its hard edges kept.
"""

from __future__ import annotations

import numpy as np
from pxr import Sdf, Usd, UsdGeom, Vt

from ..mesh import fan_triangles

__all__ = ["SkinNormals", "NORMAL_PROPERTIES", "SMOOTH_COS"]

NORMAL_PROPERTIES = ("normals", "primvars:normals", "primvars:normals:indices")
"""Skin properties a bake may write besides points and extent (when the asset authors normals)."""
SMOOTH_COS = 0.99
"""Two corners of a vertex whose authored rest normals agree this closely share one normal (else: a hard edge)."""


def _smooth_groups(corners: np.ndarray, authored: np.ndarray, vertex_count: int) -> np.ndarray:
    """Per corner (C,), its smooth group 0 … G−1: the corners of one vertex whose authored normals agree
    (cos > :data:`SMOOTH_COS`) with the group's first corner; ``authored`` (C, 3)."""
    unit = authored / np.maximum(np.linalg.norm(authored, axis=1, keepdims=True), 1e-300)
    label = np.full(len(corners), -1, dtype=np.int64)
    pending = np.ones(len(corners), dtype=bool)
    next_label = 0
    while pending.any():  # each round, the first pending corner of every vertex opens a group of its like corners
        order = np.flatnonzero(pending)
        vertices, first = np.unique(corners[order], return_index=True)
        leader = np.full(vertex_count, -1, dtype=np.int64)
        leader[vertices] = order[first]
        lead = leader[corners[order]]
        joins = (np.sum(unit[order] * unit[lead], axis=1) > SMOOTH_COS) | (order == lead)
        ids = np.full(vertex_count, -1, dtype=np.int64)
        ids[vertices] = next_label + np.arange(len(vertices))
        label[order[joins]] = ids[corners[order[joins]]]
        pending[order[joins]] = False
        next_label += len(vertices)
    return np.unique(label, return_inverse=True)[1].reshape(-1)


class SkinNormals:
    """Per-frame normals of a skin whose asset authors them, written with the asset's interpolation.

    Normals are area-weighted: every polygon contributes its area vector (the sum of its fan triangles'
    cross products, in float64) to its corners. ``vertex``/``varying`` normals sum over all faces of a
    vertex; ``faceVarying`` ones only over the faces whose authored rest normals at that vertex agree
    (:data:`SMOOTH_COS`), so a hard edge of the asset (split normals) stays hard; ``uniform`` ones are the
    faces' own. All are turned to agree with the asset's rest normals. An indexed primvar gets one value
    per smooth group (vertex, face) and its corners (vertices, faces) index them. ``None`` from :meth:`of`
    when the asset has no normals.
    """

    def __init__(self, skin: Usd.Prim, name: str, interpolation: str, indexed: bool):
        mesh = UsdGeom.Mesh(skin)
        counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(), dtype=np.int64)
        self._corners = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), dtype=np.int64)
        self._face_of_corner = np.repeat(np.arange(len(counts)), counts)
        self._triangles = fan_triangles(counts, self._corners)
        self._face_of_triangle = np.repeat(np.arange(len(counts)), np.maximum(counts - 2, 0))
        self._faces = len(counts)
        self._name, self._interpolation, self._indexed = name, interpolation, indexed
        points = np.asarray(mesh.GetPointsAttr().Get(), dtype=np.float64)
        self._vertex_count = len(points)
        authored = UsdGeom.Primvar(skin.GetAttribute(name)).ComputeFlattened() if indexed else None
        authored = np.asarray(authored if authored is not None else skin.GetAttribute(name).Get(), dtype=np.float64)
        self._group = None
        if interpolation == UsdGeom.Tokens.faceVarying:
            if len(authored) == len(self._corners):
                self._group = _smooth_groups(self._corners, authored, len(points))
            else:
                self._group = np.unique(self._corners, return_inverse=True)[1].reshape(-1)
        self._sign = 1.0
        expected = self.frame(points)
        self._sign = -1.0 if len(authored) == len(expected) and np.sum(authored * expected) < 0.0 else 1.0

    @classmethod
    def of(cls, skin: Usd.Prim) -> SkinNormals | None:
        primvar = UsdGeom.PrimvarsAPI(skin).GetPrimvar("normals")
        if primvar and primvar.HasAuthoredValue():
            return cls(skin, "primvars:normals", primvar.GetInterpolation(), primvar.IsIndexed())
        attribute = UsdGeom.Mesh(skin).GetNormalsAttr()
        if attribute and attribute.HasAuthoredValue():
            return cls(skin, "normals", UsdGeom.Mesh(skin).GetNormalsInterpolation(), False)
        return None

    def _values(self, points: np.ndarray) -> np.ndarray:
        """Unit normals, one per value: per smooth group (faceVarying), per face (uniform) or per vertex."""
        corners = points[self._triangles]
        cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        areas = np.stack([np.bincount(self._face_of_triangle, cross[:, k], minlength=self._faces) for k in range(3)], 1)
        if self._interpolation == UsdGeom.Tokens.uniform:
            sums = areas
        else:
            owner = self._group if self._group is not None else self._corners
            size = int(owner.max()) + 1 if self._group is not None else self._vertex_count
            contribution = areas[self._face_of_corner]
            sums = np.stack([np.bincount(owner, contribution[:, k], minlength=size) for k in range(3)], 1)
        length = np.linalg.norm(sums, axis=1, keepdims=True)
        return np.divide(sums, length, out=np.zeros_like(sums), where=length > 0)

    def frame(self, positions: np.ndarray) -> np.ndarray:
        """The normals written for skin ``positions`` (V, 3), float64, laid out as the asset's (for an indexed
        primvar: the values its indices point into)."""
        values = self._sign * self._values(np.asarray(positions, dtype=np.float64))
        return values[self._group] if self._group is not None and not self._indexed else values

    def prepare(self, layer: Sdf.Layer, skin_path: Sdf.Path, low: float, high: float) -> None:
        """Create the specs in the cache ``layer`` and drop its samples in ``[low, high]``."""
        prim = layer.GetPrimAtPath(skin_path)
        spec = prim.attributes.get(self._name) or Sdf.AttributeSpec(prim, self._name, Sdf.ValueTypeNames.Normal3fArray)
        spec.SetInfo("interpolation", self._interpolation)
        for time in layer.ListTimeSamplesForPath(spec.path):
            if low <= time <= high:
                layer.EraseTimeSample(spec.path, time)
        if self._indexed:  # one value per smooth group (vertex, face): the corners (vertices, faces) index them
            if self._group is not None:
                table = self._group
            else:
                table = np.arange(self._faces if self._interpolation == UsdGeom.Tokens.uniform else self._vertex_count)
            indices = prim.attributes.get(self._name + ":indices") or Sdf.AttributeSpec(
                prim, self._name + ":indices", Sdf.ValueTypeNames.IntArray
            )
            indices.default = Vt.IntArray.FromNumpy(np.ascontiguousarray(table, dtype=np.int32))
        self._path = spec.path

    def write(self, layer: Sdf.Layer, time: float, positions: np.ndarray) -> None:
        values = np.ascontiguousarray(self.frame(positions), dtype=np.float32)
        layer.SetTimeSample(self._path, time, Vt.Vec3fArray.FromNumpy(values))
