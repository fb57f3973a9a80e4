"""``warpface rig``: rig a head mesh of one's own — landmarks (found or given), the default rig, a stage, a picture."""

from __future__ import annotations

import contextlib
import dataclasses
from pathlib import Path

__all__ = ["add_parser", "run", "read_head"]

HEAD_SUFFIXES = (".obj", ".usd", ".usda", ".usdc")
STAGE_SUFFIXES = (".usda", ".usdc", ".usd")


def add_parser(subparsers, common) -> None:
    rig = subparsers.add_parser(
        "rig",
        parents=[common],
        help="rig a head mesh: 68 landmarks (automatic or from a file), the default rig, a rig stage",
        description="Find the 68 iBUG landmarks of HEAD (any unit, up axis and facing; extra shells such as eyes "
        "and teeth are allowed) or read them from --landmarks, check their layout, build the default rig on "
        "them (muscles, wrinkles, jaw, thickness) and write it as a rig stage whose skin references HEAD's own mesh "
        "(an OBJ through a USD copy beside the stage), so its faces, UVs, normals and materials are kept and never "
        "edited. Errors are one line, exit 2, and nothing is written.",
    )
    rig.add_argument("head", help="head mesh (.obj, .usd, .usda, .usdc)")
    rig.add_argument("--out", required=True, help="rig stage to write (.usda, .usdc or .usd)")
    rig.add_argument(
        "--landmarks",
        default=None,
        metavar="FILE",
        help="68 iBUG landmarks: JSON vertex indices or points, menpo .ljson, or MeshLab/Wrap .pp (default: found)",
    )
    rig.add_argument("--up", default=None, help="the face's up axis in the mesh: x, y or z, signed (default: found)")
    rig.add_argument("--front", default=None, help="the direction the face looks: +z, -z, +x … (default: found)")
    rig.add_argument("--units", choices=("m", "cm", "mm"), default=None, help="mesh units (default: from its size)")
    rig.add_argument("--name", default="Face", help="rig name, the root prim (default Face)")
    rig.add_argument("--preview", default=None, metavar="PNG", help="also draw landmarks and muscles into this PNG")
    rig.add_argument(
        "--embed",
        action="store_true",
        help="copy the skin as triangles into the rig stage instead of referencing the head mesh (an OBJ head is "
        "referenced through a USD copy, <head>_asset.usdc, written beside the rig)",
    )
    rig.set_defaults(handler=run)


def _read_obj(path: Path):
    """``(points, triangles, the OBJ's polygons)``; a file of vertices alone gives no triangles and no polygons."""
    import numpy as np

    from ..mesh import read_obj_polygons

    with path.open("rb") as handle:
        head = handle.read(1 << 16)
    if not head.strip():
        raise ValueError(f"{path}: empty file; export the head mesh as OBJ or USD")
    try:
        polygons = read_obj_polygons(path)
        return polygons.points, polygons.triangles(), polygons
    except ValueError as exc:
        if "no vertices or faces" not in str(exc):
            raise
    text = path.read_text(encoding="utf-8", errors="replace")
    vertices = sum(1 for line in text.splitlines() if line.startswith("v "))
    if vertices == 0:
        raise ValueError(f"{path}: no vertices; export the head mesh as OBJ with its geometry") from None
    return np.zeros((vertices, 3)), np.zeros((0, 3), dtype=np.int64), None


def _skin_mesh(stage, path: Path):
    """The Mesh prim a USD head's face is on: of several (head, eyes, teeth as prims), the one of largest area."""
    import numpy as np
    from pxr import UsdGeom

    from ..rigging.surface import polygons_to_triangles

    meshes = [UsdGeom.Mesh(prim) for prim in stage.Traverse() if prim.IsA(UsdGeom.Mesh)]
    if not meshes:
        raise ValueError(f"{path}: no Mesh prim on the stage; export the head as a polygon mesh")

    def area(mesh) -> float:
        points, counts = mesh.GetPointsAttr().Get(), mesh.GetFaceVertexCountsAttr().Get()
        indices = mesh.GetFaceVertexIndicesAttr().Get()
        if not points or not counts or not indices or sum(counts) != len(indices) or max(indices) >= len(points):
            return -1.0  # no faces: chosen only when no mesh has any
        corners = np.asarray(points, dtype=np.float64)[polygons_to_triangles(np.asarray(counts), np.asarray(indices))]
        return float(
            np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1).sum()
        )

    return max(meshes, key=area)


def _read_usd(path: Path):
    """Points, triangles and metres per unit of the head's skin mesh on a USD stage (its local space: the stage's
    ``metersPerUnit`` times its ancestors' scale, :func:`_parents_scale`; None when the stage has none)."""
    import numpy as np
    from pxr import UsdGeom

    from ..rigging.surface import polygons_to_triangles
    from ..usd import open_stage

    stage = open_stage(path)
    mesh = _skin_mesh(stage, path)
    points = mesh.GetPointsAttr().Get()
    if points is None or len(points) == 0:
        sampled = mesh.GetPointsAttr().GetNumTimeSamples()
        raise ValueError(
            f"{path}: the mesh {mesh.GetPath()} has no points"
            + (
                f" at rest, only {sampled} time sample(s); export the neutral head with default points"
                if sampled
                else ""
            )
        )
    counts = mesh.GetFaceVertexCountsAttr().Get()
    indices = mesh.GetFaceVertexIndicesAttr().Get()
    points = np.asarray(points, dtype=np.float64)
    if counts is None or indices is None or len(counts) == 0:
        return points, np.zeros((0, 3), dtype=np.int64), None
    triangles = polygons_to_triangles(np.asarray(counts), np.asarray(indices))
    if not stage.HasAuthoredMetadata("metersPerUnit"):
        return points, triangles, None
    return points, triangles, UsdGeom.GetStageMetersPerUnit(stage) * _parents_scale(mesh)


def _parents_scale(mesh) -> float:
    """The uniform scale the mesh's ancestors apply to its points (|det|^⅓ of the parent-to-world matrix): a
    head kept in cm under a root scaled by 0.01 on a metre stage has points of 0.01 m, as the rig stage says.
    The rig's skin references the mesh prim alone, so its ancestors' transforms do not come along."""
    import numpy as np
    from pxr import Usd

    matrix = np.array(mesh.ComputeParentToWorldTransform(Usd.TimeCode.Default()), dtype=np.float64)[:3, :3]
    scale = abs(float(np.linalg.det(matrix))) ** (1.0 / 3.0)
    return scale if np.isfinite(scale) and scale > 0.0 else 1.0


def read_head(path) -> tuple:
    """``(points, triangles, metres per unit or None, the OBJ's polygons or None)`` of a head mesh file (OBJ or
    USD); the polygons (:class:`~warpface.mesh.ObjPolygons`) are what an OBJ head's USD copy is written from."""
    path = Path(path)
    if path.suffix.lower() not in HEAD_SUFFIXES:
        raise ValueError(f"{path}: head meshes must be {', '.join(HEAD_SUFFIXES)}, got {path.suffix or 'none'}")
    if not path.is_file():
        raise ValueError(f"{path}: file not found")
    if path.stat().st_size == 0:
        raise ValueError(f"{path}: empty file; export the head mesh as OBJ or USD")
    if path.suffix.lower() == ".obj":
        points, triangles, polygons = _read_obj(path)
        return points, triangles, None, polygons
    return (*_read_usd(path), None)


def _asset_link(head: Path, out: Path, points, triangles, landmarks, z_up: bool):
    """``(AssetLink, shells' vertices wholly with the head)``: the USD head's largest mesh, or the OBJ's USD copy
    beside ``out``."""
    import numpy as np

    from ..rigging.surface import HeadSurface
    from ..usd.asset_io import AssetLink, rigid_shell_vertices
    from ..usd.skin_followers import embed_on_skin

    surface = HeadSurface(points, triangles)
    rigid, jaw, still = rigid_shell_vertices(surface.shell_of_vertex, surface.skin_label, points, landmarks)
    riding = np.setdiff1d(np.flatnonzero(surface.shell_of_vertex != surface.skin_label), rigid)
    on_skin = embed_on_skin(points[riding], points, surface.skin_triangles)[0] if len(riding) else None
    extra = {"riding_vertices": riding, "riding": on_skin}  # the lashes of a one-mesh head ride its lids
    if head.suffix.lower() == ".obj":
        copy = out.with_name(f"{head.stem}_asset.usdc")
        if copy.resolve() == out.resolve():
            raise ValueError(f"--out {out}: is the name of the head's USD copy; choose another name")
        return AssetLink(copy.resolve(), "", "Z" if z_up else "Y", rigid, jaw, **extra), still
    from pxr import UsdGeom

    from ..usd import open_stage

    stage = open_stage(head)
    mesh = _skin_mesh(stage, head).GetPrim()
    link = AssetLink(head.resolve(), str(mesh.GetPath()), UsdGeom.GetStageUpAxis(stage), rigid, jaw, **extra)
    return link, still


def _unit_name(meters_per_unit: float) -> str | None:
    from ..rigging.units import UNITS

    for name, value in UNITS.items():
        if abs(value - meters_per_unit) <= 1e-9 * value:
            return name
    return None


@contextlib.contextmanager
def _stages(quiet: bool):
    """A progress bar over :func:`~warpface.rigging.find_landmarks`'s stages: yields its ``progress`` callback."""
    from tqdm import tqdm

    from ..rigging.detect import REGISTRATION_STEPS

    with tqdm(total=REGISTRATION_STEPS + 1, desc="landmarks", unit="stage", leave=False, disable=quiet) as bar:
        started = []

        def progress(stage: str) -> None:
            if started:  # a stage starts when the one before it ends
                bar.total = max(bar.total, bar.n + 2)  # a registration made again adds stages
                bar.set_postfix_str(stage, refresh=False)
                bar.update()
            else:
                bar.set_postfix_str(stage)
            started.append(stage)

        yield progress
        bar.update(bar.total - bar.n)


def run(args) -> int:
    import numpy as np

    from .._files import atomic_path
    from ..assets import default_rig
    from ..geometry.triangles import weld_seams
    from ..mesh import FaceMesh
    from ..rigging import check_layout, find_landmarks, read_landmark_file, rig_picture
    from ..rigging.surface import HeadSurface
    from ..rigging.units import infer_units, parse_axis, parse_units
    from ..usd import attach_asset, export_layer_atomically, rig_prims, write_obj_asset, write_rig

    out = Path(args.out)
    if out.suffix not in STAGE_SUFFIXES:
        raise ValueError(f"--out {out}: a rig stage must end in {', '.join(STAGE_SUFFIXES)}")
    if out.is_dir():
        raise ValueError(f"--out {out}: is a folder, not a file")
    preview = Path(args.preview) if args.preview else None
    if preview is not None and preview.suffix.lower() != ".png":
        raise ValueError(f"--preview {preview}: the picture must be a .png")
    up, front = parse_axis(args.up, "--up"), parse_axis(args.front, "--front")
    points, triangles, stage_unit, polygons = read_head(args.head)
    triangles = weld_seams(points, triangles)  # the rig sees one skin; the asset keeps its split vertices
    label = str(args.head)
    units = args.units or (_unit_name(stage_unit) if stage_unit else None)
    if args.landmarks is None:
        with _stages(quiet=args.quiet) as progress:
            found = find_landmarks(points, triangles, up=up, front=front, units=units, label=label, progress=progress)
        landmarks, meters_per_unit, front_dir = found.indices, found.meters_per_unit, found.front
        inside_out = found.inside_out
        low = np.flatnonzero(found.confidence < 0.2)
        summary = (
            f"{label}: landmarks found in {found.seconds:.1f} s ({found.units}, {found.shells} shell(s), "
            f"mean confidence {found.confidence.mean():.2f}"
            + (f"; low at iBUG {', '.join(map(str, low[:8]))}" if len(low) else "")
            + ")"
        )
    else:
        surface = HeadSurface(points, triangles, label)
        landmarks = read_landmark_file(args.landmarks, points)
        normals = np.zeros_like(surface.points)
        normals[surface.skin_vertices] = surface.skin_normals
        front_dir = front if front is not None else normals[landmarks].sum(axis=0)
        inside_out = surface.inside_out
        eye_distance = float(
            np.linalg.norm(points[landmarks[36:42]].mean(axis=0) - points[landmarks[42:48]].mean(axis=0))
        )
        meters_per_unit = parse_units(units) if units else infer_units(eye_distance, label)[1]
        summary = f"{label}: {args.landmarks}: 68 landmarks read"
        check_layout(points[landmarks], front_dir, label=f"{label}: landmarks")  # found ones pass it in the finder
    if inside_out:  # the rig puts bone attachments along −normal: wind the skin outward
        triangles = triangles[:, [0, 2, 1]]
    mesh = FaceMesh(points, triangles, name=Path(args.head).stem or "head", degenerate="ignore")
    rig = default_rig(mesh, landmarks, name=args.name, device=args.device)
    picture = rig_picture(rig, title=f"{Path(args.head).name}: {args.name}") if preview is not None else None

    from pxr import Sdf, Usd, UsdGeom, Vt

    up_axis = up if up is not None else (found.up if args.landmarks is None else None)
    z_up = up_axis is not None and abs(up_axis[2]) > max(abs(up_axis[0]), abs(up_axis[1]))
    link, still = None, None
    if not args.embed:
        link, still = _asset_link(Path(args.head), out, points, triangles, landmarks, z_up)
    if link is not None and rig.jaw is not None:  # rigid shells wholly below the lips with the jaw, above without
        weights = rig.jaw.weights.copy()
        weights[still] = 0.0
        weights[link.jaw_vertices] = 1.0
        rig = dataclasses.replace(rig, jaw=dataclasses.replace(rig.jaw, weights=weights))
    if link is not None and link.prim_path:  # a USD head: its other meshes below the lips follow the jaw ...
        from ..usd import open_stage
        from ..usd.asset_io import follower_jaw_weights
        from ..usd.skin_followers import skin_embeddings

        asset = open_stage(args.head)  # ... and those on the skin (lashes) ride it, leaving the jaw's followers
        riding = skin_embeddings(asset, link.prim_path, points, triangles, landmarks, device=args.device)
        followers = {}
        if rig.jaw is not None:
            followers = follower_jaw_weights(asset, link.prim_path, points, landmarks, rig.jaw.weights)
        followers = {path: w for path, w in followers.items() if path not in riding}
        link = dataclasses.replace(link, followers=followers, skin_followers=riding)
    stage = Usd.Stage.CreateInMemory(f"rig{out.suffix}")
    write_rig(stage, rig, meters_per_unit=meters_per_unit)
    skin = rig_prims(stage).skin
    if link is not None and inside_out:  # the rig's triangles were turned outward; say so, not rewinding the asset
        UsdGeom.Mesh(skin).GetOrientationAttr().Set(UsdGeom.Tokens.leftHanded)
    skin.SetCustomDataByKey("warpface:landmarkSource", "found" if args.landmarks is None else str(args.landmarks))
    if args.landmarks is None:
        skin.SetCustomDataByKey("warpface:landmarkConfidence", Vt.DoubleArray([float(c) for c in found.confidence]))
    if z_up:
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    out.parent.mkdir(parents=True, exist_ok=True)
    if link is not None and polygons is not None:
        write_obj_asset(
            polygons, link.path, name=Path(args.head).stem, meters_per_unit=meters_per_unit, up_axis=link.up_axis
        )
    layer = stage.GetRootLayer()
    if link is not None:  # on a copy: the in-memory stage would try to compose the relative reference
        layer = Sdf.Layer.CreateAnonymous(out.suffix)
        layer.TransferContent(stage.GetRootLayer())
        attach_asset(layer, skin.GetPath(), link, anchor=out.parent)
    export_layer_atomically(layer, out)
    if picture is not None:
        with atomic_path(preview, ".png") as temporary:
            temporary.write_bytes(picture)
    if not args.quiet:
        print(summary)
    counts = f"{len(rig.muscles)} muscles, {len(rig.wrinkles)} wrinkles"
    asset = f", skin from {link.path.name}" if link is not None else ""
    print(f"{out}: rig {args.name!r} with {counts}, {meters_per_unit:g} m/unit{asset}")
    return 0
