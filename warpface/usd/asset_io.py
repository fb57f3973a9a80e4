"""A rig stage on the user's own mesh: the skin references the asset's mesh prim instead of a copy.

Layout (docs/RIG.md §10): ``/<Face>/Skin`` is a Mesh with a reference to the asset's head mesh (a USD
file's prim, or the USD copy :func:`write_obj_asset` makes of an OBJ once, beside the rig). The rig
layer adds only the rig's opinions (WarpFaceSkinAPI, thickness, landmarks, muscle relationships, the
rigid shells); the asset's points, faces, UVs, normals, subsets and bindings compose through the
reference, and a bake overrides ``points``/``extent`` in its own cache layer. Nothing here edits the
asset file.

Extra shells (eyes, teeth, tongue: connected parts other than the skin) are listed on the skin as
``warpFace:rigidVertices``: no muscle or wrinkle moves them, only the jaw with its weights (1 on the
shells of ``warpFace:jawVertices``, 0 on those wholly above the lips). Shells that sit on the skin (lashes)
ride it instead (:mod:`~warpface.usd.skin_followers`). :class:`RigidShells` applies both to a model's
evaluated frames.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdShade, Vt

from .._validate import expect_instance
from ..errors import RigError
from ..expression.jaw import JAW_CONTROL_NAMES, jaw_points
from ..mesh import ObjPolygons
from ._files import LAYER_SUFFIXES, checked_prim_path, export_layer_atomically, writable_path
from .asset_normals import NORMAL_PROPERTIES, SkinNormals
from .skin_followers import (
    RIDING_VERTICES,
    SkinEmbedding,
    follow_skin,
    other_meshes,
    points_spec,
    read_skin_embedding,
    set_points,
    write_skin_embedding,
)

__all__ = [
    "AssetLink",
    "RigidShells",
    "asset_link",
    "attach_asset",
    "check_asset",
    "rigid_shell_vertices",
    "shells_of",
    "SkinNormals",
    "NORMAL_PROPERTIES",
    "write_obj_asset",
    "follower_jaw_weights",
    "jaw_followers",
    "write_jaw_followers",
    "JAW_WEIGHTS",
    "RIGID_VERTICES",
    "JAW_VERTICES",
]

RIGID_VERTICES = "warpFace:rigidVertices"
"""Skin attribute (uniform int[]): vertices of extra shells, which no muscle or wrinkle moves."""
JAW_VERTICES = "warpFace:jawVertices"
"""Skin attribute (uniform int[]): the rigid vertices of shells wholly with the jaw (lower teeth); the jaw
prim's weights, which the bake uses, are 1 there."""
RIDING_FRACTION = 0.05
"""A shell with this fraction of its vertices on skin vertices rides on the skin (it is not rigid)."""
ACROSS_REACH = 0.175
"""A rigid shell reaching farther than this both above and below the lips' line lies across it (gums and tongue in
one piece) [outer eye-corner distances, iBUG 36–45]. On ICT and 45 warped, posed copies of it rigged with found
landmarks the teeth reach at most 0.11 to both sides at once, the gums-tongue part at least 0.21."""
_COPIED = ("faceVertexCounts", "faceVertexIndices", "subdivisionScheme", "orientation")


@dataclass(frozen=True)
class AssetLink:
    """Where a rig's skin comes from, and what of it is rigid."""

    path: Path
    """The asset file (absolute)."""
    prim_path: str
    """The mesh prim in it ("" for its default prim)."""
    up_axis: str
    """The asset's up axis token (``"Y"`` or ``"Z"``)."""
    rigid_vertices: np.ndarray
    jaw_vertices: np.ndarray
    followers: dict = dataclasses.field(default_factory=dict)
    """Other meshes of a USD asset that move with the jaw: their prim path in the asset → per-vertex jaw
    weights (see :func:`follower_jaw_weights`); written on their prims under ``/<Face>/Asset``."""
    skin_followers: dict = dataclasses.field(default_factory=dict)
    """Other meshes of a USD asset that ride the skin (lashes): their prim path in the asset →
    :class:`~warpface.usd.skin_followers.SkinEmbedding`; written on their prims under ``/<Face>/Asset``."""
    riding_vertices: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """Vertices of the skin mesh's own extra shells that ride the skin (not rigid, not skin: lashes)."""
    riding: SkinEmbedding | None = None
    """Where :attr:`riding_vertices` sit on the skin (rows in their order)."""


def write_obj_asset(polygons: ObjPolygons, path, *, name: str, meters_per_unit: float, up_axis: str) -> str:
    """Write an OBJ's polygons as a USD mesh file (every face, UV, normal, group and material kept).

    The mesh is the default prim ``/<name>``; ``usemtl`` materials become ``materialBind`` GeomSubsets
    bound to Material prims under it, ``g``/``o`` groups ``objGroup`` subsets. Returns the prim path.
    """
    expect_instance(polygons, ObjPolygons, "polygons")
    path = writable_path(path, LAYER_SUFFIXES)
    stage = Usd.Stage.CreateInMemory(f"asset{path.suffix}")
    UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    UsdGeom.SetStageUpAxis(stage, up_axis)
    root = Sdf.Path("/" + (Sdf.Path.IsValidIdentifier(name) and name or "Asset"))
    mesh = UsdGeom.Mesh.Define(stage, root)
    stage.SetDefaultPrim(mesh.GetPrim())
    points = np.ascontiguousarray(polygons.points, dtype=np.float32)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points))
    mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([points.min(axis=0), points.max(axis=0)])))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(polygons.counts.astype(np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(polygons.indices.astype(np.int32)))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)  # an OBJ is a polygon mesh
    primvars = UsdGeom.PrimvarsAPI(mesh)
    for values, table, primvar_name, type_name in (
        (polygons.uvs, polygons.uv_indices, "st", Sdf.ValueTypeNames.TexCoord2fArray),
        (polygons.normals, polygons.normal_indices, "normals", Sdf.ValueTypeNames.Normal3fArray),
    ):
        if values is not None:
            primvar = primvars.CreatePrimvar(primvar_name, type_name, UsdGeom.Tokens.faceVarying)
            primvar.Set(np.ascontiguousarray(values, dtype=np.float32))
            primvar.SetIndices(Vt.IntArray.FromNumpy(table.astype(np.int32)))
    _subsets(stage, mesh, polygons.materials, polygons.face_materials, UsdShade.Tokens.materialBind, bind=True)
    _subsets(stage, mesh, polygons.groups, polygons.face_groups, "objGroup", bind=False)
    export_layer_atomically(stage.GetRootLayer(), path)
    return str(root)


def _subsets(stage, mesh, names, of_face, family: str, *, bind: bool) -> None:
    if of_face is None or len(names) == 0:
        return
    used = set()
    for k, name in enumerate(names):
        faces = np.flatnonzero(of_face == k).astype(np.int32)
        identifier = _unique(name, used)
        subset = UsdGeom.Subset.Define(stage, mesh.GetPath().AppendChild(identifier))
        subset.CreateElementTypeAttr(UsdGeom.Tokens.face)
        subset.CreateFamilyNameAttr(family)
        subset.CreateIndicesAttr(Vt.IntArray.FromNumpy(faces))
        if name != identifier:
            subset.GetPrim().SetDisplayName(name)
        if bind:
            material = UsdShade.Material.Define(stage, mesh.GetPath().AppendPath(Sdf.Path(f"Looks/{identifier}")))
            UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(material)
    UsdGeom.Subset.SetFamilyType(mesh, family, UsdGeom.Tokens.partition if bind else UsdGeom.Tokens.nonOverlapping)


def _unique(name: str, used: set) -> str:
    from pxr import Tf

    identifier = base = Tf.MakeValidIdentifier(name) if name else "_"
    suffix = 1
    while identifier in used or identifier == "Looks":
        identifier, suffix = f"{base}_{suffix}", suffix + 1
    used.add(identifier)
    return identifier


def rigid_shell_vertices(shell_of_vertex: np.ndarray, skin_label: int, points, landmarks) -> tuple:
    """``(rigid, jaw, head)`` vertex indices: the extra shells no muscle moves, those of them wholly with the
    jaw, and those wholly with the head.

    A shell other than the skin is rigid unless it rides on the skin: when at least ``RIDING_FRACTION`` of
    its vertices sit on a skin vertex (within 1e-3 of the skin's size: eyelashes rooted in the lid margin,
    a lacrimal or occlusion film), the muscles move it with the skin. A rigid shell reaching more than
    :data:`ACROSS_REACH` both above and below the lips' contact line (through iBUG 60–67; up along iBUG 8 → 27,
    square to the mouth's corners 48 → 54) lies across it (gums and tongue in one piece) and keeps the rig's
    smooth jaw weights; any other goes with the jaw when its centroid is below the line (lower teeth), else with
    the head (eyes, upper teeth), however far its tips overlap the other row's.
    """
    from scipy.spatial import cKDTree

    points = np.asarray(points, dtype=np.float64)
    on_skin = shell_of_vertex == skin_label
    rigid = np.flatnonzero(~on_skin)
    if len(rigid) == 0:
        return rigid, rigid, rigid
    labels = np.unique(shell_of_vertex[rigid], return_inverse=True)[1].reshape(-1)
    skin = points[on_skin]
    touching = cKDTree(skin).query(points[rigid])[0] <= 1e-3 * np.linalg.norm(np.ptp(skin, axis=0))
    riding = np.bincount(labels, weights=touching) >= RIDING_FRACTION * np.bincount(labels)
    rigid, labels = rigid[~riding[labels]], np.unique(labels[~riding[labels]], return_inverse=True)[1].reshape(-1)
    if len(rigid) == 0:
        return rigid, rigid, rigid
    corners = points[landmarks[54]] - points[landmarks[48]]
    corners /= np.linalg.norm(corners)
    up = points[landmarks[27]] - points[landmarks[8]]
    up -= (up @ corners) * corners
    up /= np.linalg.norm(up)
    eye_corners = np.linalg.norm(points[landmarks[45]] - points[landmarks[36]])
    height = (points[rigid] - points[landmarks[60:68]].mean(axis=0)) @ up / eye_corners
    above = np.full(labels.max() + 1, -np.inf)
    below = np.full(labels.max() + 1, -np.inf)
    np.maximum.at(above, labels, height)
    np.maximum.at(below, labels, -height)
    across = np.minimum(above, below) > ACROSS_REACH
    lower = np.bincount(labels, weights=height) < 0.0  # the centroid's height, times the count
    return rigid, rigid[(lower & ~across)[labels]], rigid[(~lower & ~across)[labels]]


def attach_asset(layer: Sdf.Layer, skin_path, link: AssetLink, *, anchor: Path | None = None) -> None:
    """Replace ``layer``'s copy of the skin's geometry by a reference to ``link``'s mesh (Sdf edits only).

    ``anchor``: the folder ``layer`` will be saved in (the reference is written relative to it); ``None``
    writes the absolute path (an in-memory stage). A left-handed ``orientation`` (a skin wound inside
    out) stays. Calling it again re-points the reference.
    """
    expect_instance(layer, Sdf.Layer, "layer")
    expect_instance(link, AssetLink, "link")
    spec = layer.GetPrimAtPath(checked_prim_path(skin_path, "skin_path"))
    if spec is None:
        raise ValueError(f"skin_path: no prim spec at {skin_path} in {layer.identifier}")
    for name in _COPIED + (UsdGeom.Tokens.points, UsdGeom.Tokens.extent):
        prop = spec.properties.get(name)
        if prop is not None and not (name == "orientation" and prop.default == UsdGeom.Tokens.leftHanded):
            spec.RemoveProperty(prop)
    for name in list(spec.variantSets.keys()):
        del spec.variantSets[name]
    spec.variantSetNameList.ClearEdits()
    spec.variantSelections.clear()
    asset = link.path.as_posix() if anchor is None else _relative(link.path, anchor)
    spec.referenceList.prependedItems = [
        Sdf.Reference(asset, Sdf.Path(link.prim_path) if link.prim_path else Sdf.Path())
    ]
    for name, values in ((RIGID_VERTICES, link.rigid_vertices), (JAW_VERTICES, link.jaw_vertices)):
        attribute = spec.properties.get(name) or Sdf.AttributeSpec(
            spec, name, Sdf.ValueTypeNames.IntArray, Sdf.VariabilityUniform
        )
        attribute.default = Vt.IntArray.FromNumpy(np.ascontiguousarray(values, dtype=np.int32))
    if link.riding is not None and len(link.riding_vertices):
        riding = spec.properties.get(RIDING_VERTICES) or Sdf.AttributeSpec(
            spec, RIDING_VERTICES, Sdf.ValueTypeNames.IntArray, Sdf.VariabilityUniform
        )
        riding.default = Vt.IntArray.FromNumpy(np.ascontiguousarray(link.riding_vertices, dtype=np.int32))
        write_skin_embedding(spec, link.riding)
    order = spec.properties.get(UsdGeom.Tokens.xformOpOrder) or Sdf.AttributeSpec(
        spec, UsdGeom.Tokens.xformOpOrder, Sdf.ValueTypeNames.TokenArray, Sdf.VariabilityUniform
    )
    order.default = Vt.TokenArray()  # the rig lives in the mesh's own space: a transform of the mesh prim is not kept
    layer.pseudoRoot.SetInfo(UsdGeom.Tokens.upAxis, link.up_axis)
    if link.prim_path:
        _keep_whole_asset(layer, Sdf.Path(str(skin_path)), link, asset)


ASSET_PRIM = "Asset"
"""Child of the rig's root prim that references the rest of a USD asset (eyes, teeth … as their own prims)."""


def _keep_whole_asset(layer: Sdf.Layer, skin_path: Sdf.Path, link: AssetLink, asset: str) -> None:
    """Reference every other root prim of a USD asset under ``/<Face>/Asset``, the skin's mesh deactivated there
    (it is the rig's skin): a head whose eyes and teeth are meshes of their own keeps them. Nothing when the
    asset has no mesh besides the skin."""
    source = Sdf.Layer.FindOrOpen(str(link.path))
    stage = Usd.Stage.Open(source, load=Usd.Stage.LoadAll)
    skin_prim = Sdf.Path(link.prim_path)
    if not any(p.IsA(UsdGeom.Mesh) and p.GetPath() != skin_prim for p in stage.Traverse()):
        return
    holder = Sdf.CreatePrimInLayer(layer, skin_path.GetParentPath().AppendChild(ASSET_PRIM))
    holder.specifier, holder.typeName = Sdf.SpecifierDef, "Xform"
    for root in stage.GetPseudoRoot().GetChildren():
        child = Sdf.CreatePrimInLayer(layer, holder.path.AppendChild(root.GetName()))
        child.specifier = Sdf.SpecifierDef
        child.referenceList.prependedItems = [Sdf.Reference(asset, root.GetPath())]
        if skin_prim.HasPrefix(root.GetPath()):
            hidden = Sdf.CreatePrimInLayer(layer, skin_prim.ReplacePrefix(root.GetPath(), child.path))
            hidden.active = False
        for path, weights in link.followers.items():
            if Sdf.Path(path).HasPrefix(root.GetPath()):
                spec = Sdf.CreatePrimInLayer(layer, Sdf.Path(path).ReplacePrefix(root.GetPath(), child.path))
                attribute = spec.attributes.get(JAW_WEIGHTS) or Sdf.AttributeSpec(
                    spec, JAW_WEIGHTS, Sdf.ValueTypeNames.FloatArray, Sdf.VariabilityUniform
                )
                attribute.default = Vt.FloatArray.FromNumpy(np.asarray(weights, dtype=np.float32))
        for path, embedding in link.skin_followers.items():
            if Sdf.Path(path).HasPrefix(root.GetPath()):
                write_skin_embedding(
                    Sdf.CreatePrimInLayer(layer, Sdf.Path(path).ReplacePrefix(root.GetPath(), child.path)), embedding
                )


JAW_WEIGHTS = "warpFace:jawWeights"
"""Attribute (uniform float[]) of another mesh of the asset that follows the jaw: its per-vertex jaw weights. A
bake writes that mesh's points (and extent) moved by the jaw alone."""


def follower_jaw_weights(asset: Usd.Stage, skin_prim: str, skin_points, landmarks, skin_weights) -> dict:
    """Per-vertex jaw weights of every mesh of ``asset`` other than the skin that has any (lower teeth, tongue).

    Each connected shell of such a mesh (its points taken in the skin's space) below the lips' contact line
    weighs 1, above it 0 (:func:`rigid_shell_vertices`' rule); a shell across it takes the jaw weight of the
    nearest skin vertex. Returns ``{prim path: weights (V,) float64}``.
    """
    from scipy.spatial import cKDTree

    skin_points = np.asarray(skin_points, dtype=np.float64)
    nearest = cKDTree(skin_points)
    found = {}
    for prim, points, _, shells in other_meshes(asset, skin_prim):
        shells = shells + 1  # 0 is the skin's label below
        combined = np.concatenate([skin_points, points])
        labels = np.concatenate([np.zeros(len(skin_points), dtype=np.int64), shells])
        _, jaw, still = rigid_shell_vertices(labels, 0, combined, landmarks)
        weights = np.asarray(skin_weights, dtype=np.float64)[nearest.query(points)[1]]
        weights[jaw - len(skin_points)] = 1.0
        weights[still - len(skin_points)] = 0.0
        if np.any(weights > 0.0):
            found[str(prim.GetPath())] = weights
    return found


def jaw_followers(stage: Usd.Stage) -> list[tuple[Usd.Prim, np.ndarray, np.ndarray]]:
    """``(prim, jaw weights (N,), rest points (N, 3))`` of every mesh on ``stage`` with :data:`JAW_WEIGHTS`."""
    found = []
    for prim in stage.Traverse():
        weights = prim.GetAttribute(JAW_WEIGHTS).Get() if prim.HasAttribute(JAW_WEIGHTS) else None
        rest = UsdGeom.Mesh(prim).GetPointsAttr().Get(Usd.TimeCode.Default()) if prim.IsA(UsdGeom.Mesh) else None
        if weights is not None and rest is not None and len(weights) == len(rest):
            found.append((prim, np.asarray(weights, dtype=np.float64), np.asarray(rest, dtype=np.float64)))
    return found


def write_jaw_followers(layer: Sdf.Layer, followers, model, times: np.ndarray, controls: np.ndarray) -> None:
    """Points and extent time samples, in ``layer``, of the meshes ``followers`` (:func:`jaw_followers`): their
    rest points moved by the jaw of ``model`` (stage units) at each frame's jaw controls (columns after the
    muscles of ``controls``, (F, C))."""
    if model.jaw is None:
        return
    columns = slice(len(model.muscle_names), len(model.muscle_names) + len(JAW_CONTROL_NAMES))
    for prim, weights, rest in followers:
        jaw = dataclasses.replace(model.jaw, weights=weights)
        spec = points_spec(layer, prim.GetPath())
        with Sdf.ChangeBlock():
            for time, values in zip(times.tolist(), np.asarray(controls, dtype=np.float64)[:, columns]):
                set_points(layer, spec, time, jaw_points(jaw, rest, values) if np.any(values != 0.0) else rest)


def _relative(path: Path, anchor: Path) -> str:
    import os

    relative = os.path.relpath(path, Path(anchor).resolve())
    return relative if relative.startswith("..") else "./" + relative


def _references(skin: Usd.Prim) -> list[tuple[Sdf.Layer, Sdf.Reference]]:
    found = []
    for spec in skin.GetPrimStack():
        for reference in spec.referenceList.GetAddedOrExplicitItems():
            if reference.assetPath:
                found.append((spec.layer, reference))
    return found


def check_asset(skin: Usd.Prim) -> None:
    """RigError (one line) when the skin references an asset file that is missing."""
    expect_instance(skin, Usd.Prim, "skin")
    for layer, reference in _references(skin):
        resolved = layer.ComputeAbsolutePath(reference.assetPath)
        if not Path(resolved).is_file():
            raise RigError(
                f"{skin.GetPath()}: the referenced asset {reference.assetPath} ({resolved}) is missing; "
                "put the head mesh back there or run `warpface rig` again"
            )


def asset_link(stage: Usd.Stage, skin: Usd.Prim) -> AssetLink | None:
    """The asset the rig's skin references (absolute path), or ``None`` for a rig with its own skin."""
    expect_instance(stage, Usd.Stage, "stage")
    expect_instance(skin, Usd.Prim, "skin")
    references = _references(skin)
    if not references:
        return None
    layer, reference = references[0]

    def indices(name: str) -> np.ndarray:
        attribute = skin.GetAttribute(name)
        value = attribute.Get() if attribute else None
        return np.zeros(0, dtype=np.int64) if value is None else np.asarray(value, dtype=np.int64)

    holder = skin.GetPath().GetParentPath().AppendChild(ASSET_PRIM)
    followers = (
        {
            str(prim.GetPath().ReplacePrefix(holder, Sdf.Path.absoluteRootPath)): np.asarray(
                prim.GetAttribute(JAW_WEIGHTS).Get(), dtype=np.float64
            )
            for prim in Usd.PrimRange(stage.GetPrimAtPath(holder))
            if prim.HasAttribute(JAW_WEIGHTS)
        }
        if stage.GetPrimAtPath(holder)
        else {}
    )
    riding = {}
    if stage.GetPrimAtPath(holder):
        for prim in Usd.PrimRange(stage.GetPrimAtPath(holder)):
            embedding = read_skin_embedding(prim)
            if embedding is not None:
                riding[str(prim.GetPath().ReplacePrefix(holder, Sdf.Path.absoluteRootPath))] = embedding
    own = read_skin_embedding(skin)
    on_skin = indices(RIDING_VERTICES)
    own = own if own is not None and len(own.weights) == len(on_skin) else None
    return AssetLink(
        Path(layer.ComputeAbsolutePath(reference.assetPath)),
        str(reference.primPath) if not reference.primPath.isEmpty else "",
        UsdGeom.GetStageUpAxis(stage),
        indices(RIGID_VERTICES),
        indices(JAW_VERTICES),
        followers,
        riding,
        on_skin if own is not None else np.zeros(0, dtype=np.int64),
        own,
    )


class RigidShells:
    """An expression model whose evaluated frames move the rigid shells only with the jaw.

    Wraps ``model`` (same interface): the rows of ``rigid`` vertices are replaced by the jaw's motion of
    their rest positions alone, with the jaw's weights (:func:`~warpface.expression.jaw_points`): no
    muscle or wrinkle moves them. The rows of ``riding`` vertices (shells that sit on the skin: lashes)
    become their rest positions plus the skin's displacement interpolated at ``on_skin`` (their
    :class:`~warpface.usd.skin_followers.SkinEmbedding`, rows in ``riding``'s order).
    """

    def __init__(
        self, model, rigid: np.ndarray, riding: np.ndarray | None = None, on_skin: SkinEmbedding | None = None
    ):
        self._model = model
        self._rigid = np.asarray(rigid, dtype=np.int64)
        rest = np.asarray(model.mesh.points, dtype=np.float64)
        self._skin_rest = rest
        self._riding = np.zeros(0, dtype=np.int64) if on_skin is None else np.asarray(riding, dtype=np.int64)
        self._on_skin = on_skin
        self._rest = rest[self._rigid]
        self._jaw = None
        if model.jaw is not None:
            self._jaw = dataclasses.replace(model.jaw, weights=np.asarray(model.jaw.weights)[self._rigid])
        self._jaw_columns = len(model.muscle_names)

    def __getattr__(self, name):
        return getattr(self._model, name)

    def evaluate(self, controls=None, out=None, **kwargs):
        positions = self._model.evaluate(controls, out, **kwargs)
        frames = positions if positions.ndim == 3 else positions[None]
        if controls is None:
            values = None
        elif isinstance(controls, np.ndarray):
            values = np.asarray(controls, dtype=np.float64).reshape(len(frames), -1)
        else:
            values = np.asarray(self._model.control_vector(controls), dtype=np.float64).reshape(len(frames), -1)
        for row in range(len(frames)):
            moved = self._rest
            if self._jaw is not None and values is not None:
                jaw = values[row, self._jaw_columns : self._jaw_columns + len(JAW_CONTROL_NAMES)]
                if np.any(jaw != 0.0):
                    moved = jaw_points(self._jaw, self._rest, jaw)
            frames[row, self._rigid] = moved
        if len(self._riding):  # after the rigid shells: the riding ones sit on skin vertices only
            frames[:, self._riding] = follow_skin(self._on_skin, self._skin_rest[self._riding], self._skin_rest, frames)
        return positions


def shells_of(stage: Usd.Stage, skin: Usd.Prim, model):
    """``model`` wrapped in :class:`RigidShells` when the skin lists rigid vertices, else ``model``."""
    link = asset_link(stage, skin)
    if link is None or len(link.rigid_vertices) + len(link.riding_vertices) == 0:
        return model
    return RigidShells(model, link.rigid_vertices, link.riding_vertices, link.riding)
