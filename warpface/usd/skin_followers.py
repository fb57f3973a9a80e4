"""Other meshes of a head that sit on the skin (eyelashes, tear and occlusion films) ride it (docs/RIG.md §10).

At rig time a connected shell of another mesh of the asset is a *skin follower* when at least
:data:`FOLLOWER_SHARE` of its vertices lie within :data:`FOLLOWER_DISTANCE` inter-ocular distances of the skin
surface. Each vertex of its mesh is then embedded on the skin: the three skin vertices of its closest skin
triangle and its barycentric coordinates there (:func:`~warpface.geometry.closest_points`); the vertices of
the mesh's other shells get zero weights (they stay with the head). A bake writes the mesh's points as
``rest + Σ_j w_j (x_j(t) − x_j(rest))``, the interpolated displacement of the skin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pxr import Sdf, Usd, UsdGeom, Vt

from ..geometry import closest_points
from ..geometry.triangles import vertex_shells
from ..mesh import fan_triangles

__all__ = [
    "FOLLOWER_DISTANCE",
    "FOLLOWER_SHARE",
    "RIDING_VERTICES",
    "SKIN_VERTICES",
    "SKIN_WEIGHTS",
    "SkinEmbedding",
    "embed_on_skin",
    "follow_skin",
    "other_meshes",
    "points_spec",
    "read_skin_embedding",
    "set_points",
    "skin_embeddings",
    "skin_followers",
    "write_skin_embedding",
    "write_skin_followers",
]

SKIN_VERTICES = "warpFace:skinVertices"
"""Attribute (uniform int3[]) of a mesh that rides the skin: per vertex, the skin vertices of its skin triangle."""
RIDING_VERTICES = "warpFace:ridingVertices"
"""Skin attribute (uniform int[]): vertices of the skin mesh's own extra shells that ride the skin (lashes of a
one-mesh head); its :data:`SKIN_VERTICES` and :data:`SKIN_WEIGHTS` rows are theirs, in this order."""
SKIN_WEIGHTS = "warpFace:skinWeights"
"""Attribute (uniform float3[]): per vertex, its barycentric weights on :data:`SKIN_VERTICES` (0 0 0: it stays)."""
FOLLOWER_DISTANCE = 1e-3
"""Inter-ocular distances: a vertex this close to the skin surface touches it (0.065 mm on ICT; roots of lashes
and films coincide with the lid)."""
FOLLOWER_SHARE = 0.10
"""A shell with this share of its vertices touching the skin rides it. On ICT: lashes 17 %, lacrimal films
42 %, occlusion films 30 %; eyeballs and irises (grazing the eye socket) 2–3 %, eye blend 4 %, gums and
tongue 1 %, teeth 0–1 %."""


@dataclass(frozen=True)
class SkinEmbedding:
    """Where each vertex of a mesh sits on the skin."""

    vertices: np.ndarray
    """Skin vertex indices, shape (N, 3), int64."""
    weights: np.ndarray
    """Barycentric weights on them, shape (N, 3), float64; rows of 0 for vertices that stay with the head."""


def other_meshes(asset: Usd.Stage, skin_prim: str):
    """``(prim, points (N, 3) float64, triangles (T, 3), shell label per vertex (N,))`` of every mesh of ``asset``
    other than ``skin_prim`` with faces (fan triangles over its polygons, shells = connected parts)."""
    for prim in asset.Traverse():
        if not prim.IsA(UsdGeom.Mesh) or str(prim.GetPath()) == skin_prim:
            continue
        mesh = UsdGeom.Mesh(prim)
        points, counts = mesh.GetPointsAttr().Get(), mesh.GetFaceVertexCountsAttr().Get()
        indices = mesh.GetFaceVertexIndicesAttr().Get()
        if not points or not counts or not indices or max(indices) >= len(points):
            continue
        points = np.asarray(points, dtype=np.float64)
        triangles = fan_triangles(np.asarray(counts), np.asarray(indices))
        yield prim, points, triangles, vertex_shells(triangles, len(points))


def skin_embeddings(asset: Usd.Stage, skin_prim: str, skin_points, skin_triangles, landmarks, *, device=None) -> dict:
    """``{prim path: SkinEmbedding}`` of every other mesh of ``asset`` with a shell that rides the skin.

    ``skin_points`` (V, 3) and ``skin_triangles`` (T, 3): the skin in the asset's units (the other meshes are
    taken in its space); ``landmarks``: its 68 iBUG vertex indices (the inter-ocular distance is the distance
    of the eye landmarks' centres, 36–41 and 42–47); ``device``: the Warp device of the closest-point query.
    """
    skin_points = np.asarray(skin_points, dtype=np.float64)
    landmarks = np.asarray(landmarks, dtype=np.int64)
    eyes = np.linalg.norm(skin_points[landmarks[36:42]].mean(axis=0) - skin_points[landmarks[42:48]].mean(axis=0))
    found = {}
    for prim, points, _, shells in other_meshes(asset, skin_prim):
        embedding, distance = embed_on_skin(points, skin_points, skin_triangles, device=device)
        touching = distance <= FOLLOWER_DISTANCE * eyes
        riding = np.bincount(shells, weights=touching) >= FOLLOWER_SHARE * np.bincount(shells)
        if np.any(riding):
            weights = np.where(riding[shells][:, None], embedding.weights, 0.0)
            found[str(prim.GetPath())] = SkinEmbedding(embedding.vertices, weights)
    return found


def embed_on_skin(points, skin_points, skin_triangles, *, device=None) -> tuple[SkinEmbedding, np.ndarray]:
    """``(embedding, distance (N,))``: each of ``points`` (N, 3) on its closest triangle of the skin
    (``skin_points`` (V, 3), ``skin_triangles`` (T, 3)) and its distance to it (same units); ``device``: the
    Warp device of the query (Warp's preferred one when ``None``)."""
    skin_triangles = np.asarray(skin_triangles, dtype=np.int64)
    triangle, weights, distance = closest_points(points, skin_points, skin_triangles, device=device)
    return SkinEmbedding(skin_triangles[triangle], weights.astype(np.float64)), distance.astype(np.float64)


def write_skin_embedding(spec: Sdf.PrimSpec, embedding: SkinEmbedding) -> None:
    """Author ``embedding`` on the prim spec ``spec`` (:data:`SKIN_VERTICES`, :data:`SKIN_WEIGHTS`)."""
    for name, type_name, values in (
        (SKIN_VERTICES, Sdf.ValueTypeNames.Int3Array, Vt.Vec3iArray.FromNumpy(embedding.vertices.astype(np.int32))),
        (SKIN_WEIGHTS, Sdf.ValueTypeNames.Float3Array, Vt.Vec3fArray.FromNumpy(embedding.weights.astype(np.float32))),
    ):
        attribute = spec.attributes.get(name) or Sdf.AttributeSpec(spec, name, type_name, Sdf.VariabilityUniform)
        attribute.default = values


def read_skin_embedding(prim: Usd.Prim) -> SkinEmbedding | None:
    """The prim's :class:`SkinEmbedding`, or ``None`` when it has none (or a malformed one)."""
    vertices = prim.GetAttribute(SKIN_VERTICES).Get() if prim.HasAttribute(SKIN_VERTICES) else None
    weights = prim.GetAttribute(SKIN_WEIGHTS).Get() if prim.HasAttribute(SKIN_WEIGHTS) else None
    if vertices is None or weights is None or len(vertices) != len(weights):
        return None
    return SkinEmbedding(np.asarray(vertices, dtype=np.int64).reshape(-1, 3), np.asarray(weights, dtype=np.float64))


def skin_followers(stage: Usd.Stage, skin_count: int) -> list[tuple[Usd.Prim, SkinEmbedding, np.ndarray]]:
    """``(prim, embedding, rest points (N, 3) float64)`` of every mesh on ``stage`` that rides a skin of
    ``skin_count`` vertices."""
    found = []
    for prim in stage.Traverse():
        embedding = read_skin_embedding(prim) if prim.IsA(UsdGeom.Mesh) else None
        rest = UsdGeom.Mesh(prim).GetPointsAttr().Get(Usd.TimeCode.Default()) if embedding is not None else None
        if rest is None or len(rest) == 0 or len(rest) != len(embedding.weights):
            continue
        if embedding.vertices.min() >= 0 and embedding.vertices.max() < skin_count:  # else another skin's
            found.append((prim, embedding, np.asarray(rest, dtype=np.float64)))
    return found


def follow_skin(embedding: SkinEmbedding, rest, skin_rest, skin_positions) -> np.ndarray:
    """Points of a mesh riding the skin: ``rest + Σ_j w_j (x_j − x_j(rest))``, shape (F, N, 3) float64.

    ``rest`` (N, 3): the mesh's rest points; ``skin_rest`` (V, 3) and ``skin_positions`` (F, V, 3): the skin's.
    """
    at = np.asarray(skin_positions)[:, embedding.vertices].astype(np.float64)  # (F, N, 3, 3): no copy of all V
    moved = at - np.asarray(skin_rest, dtype=np.float64)[embedding.vertices]
    return np.asarray(rest, dtype=np.float64) + np.einsum("fnkd,nk->fnd", moved, embedding.weights)


def points_spec(layer: Sdf.Layer, path) -> Sdf.PrimSpec:
    """The (over) prim spec at ``path`` in ``layer`` with ``points`` and ``extent`` attribute specs."""
    spec = Sdf.CreatePrimInLayer(layer, path)
    for name, type_name in (("points", Sdf.ValueTypeNames.Point3fArray), ("extent", Sdf.ValueTypeNames.Float3Array)):
        if spec.attributes.get(name) is None:
            Sdf.AttributeSpec(spec, name, type_name)
    return spec


def set_points(layer: Sdf.Layer, spec: Sdf.PrimSpec, time: float, points: np.ndarray) -> None:
    """``points`` (N, 3) and their extent as time samples at ``time`` of ``spec`` (:func:`points_spec`)."""
    points = np.asarray(points, dtype=np.float32)
    bounds = np.stack([points.min(axis=0), points.max(axis=0)])
    layer.SetTimeSample(spec.path.AppendProperty("points"), time, Vt.Vec3fArray.FromNumpy(points))
    layer.SetTimeSample(spec.path.AppendProperty("extent"), time, Vt.Vec3fArray.FromNumpy(bounds))


def write_skin_followers(layer: Sdf.Layer, followers, skin_rest, times, positions) -> None:
    """Points and extent time samples, in ``layer``, of the meshes ``followers`` (:func:`skin_followers`) at
    ``times`` (F,), from the skin's ``positions`` (F, V, 3) and rest points ``skin_rest`` (V, 3)."""
    for prim, embedding, rest in followers:
        spec = points_spec(layer, prim.GetPath())
        frames = follow_skin(embedding, rest, skin_rest, positions)
        with Sdf.ChangeBlock():
            for time, moved in zip(np.asarray(times).tolist(), frames):
                set_points(layer, spec, time, moved)
