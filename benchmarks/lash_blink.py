"""Lashes in a blink on the whole ICT head: how far they move against the lid they sit on [mm].

The whole ICT head (``../shared/data``, cm) is rigged twice with ``warpface rig`` (automatic landmarks):
as its OBJ (one mesh: the lashes are shells of the skin's mesh) and as a USD stage of five Mesh prims
(the face with sockets, gums and tongue, teeth, eyes, and the rest: lacrimal, blend and occlusion films and
lashes). A 4-frame Live Link take closes both eyes (``eyeBlinkLeft``/``Right`` 0 → 1, ``animate --rig``,
which bakes). At the last frame, per lash vertex: its displacement, that of its nearest skin vertex at rest
(the lid next to it), and the norm of their difference. Run it on two trees to compare them.

    python -m benchmarks.lash_blink
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

FRAMES = 4
PRIMS = {"Head": (0, 14062), "GumsTongue": (14062, 17039), "Teeth": (17039, 21451), "Eyes": (21451, 24591)}
"""The ICT regions as prims (../shared/data/README.md); the vertices after them go to a prim "Rest"."""


def split_ict_usd(obj, path: Path) -> dict:
    """The head as a cm USD stage with one Mesh per region (polygons and order kept); returns the ranges."""
    from pxr import Usd, UsdGeom, Vt

    ranges = dict(PRIMS, Rest=(PRIMS["Eyes"][1], len(obj.points)))
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/Character").GetPrim())
    face_of_corner = np.repeat(np.arange(len(obj.counts)), obj.counts)
    for name, (low, high) in ranges.items():  # a face belongs to the region of its vertices (none crosses)
        inside = (obj.indices >= low) & (obj.indices < high)
        mesh = UsdGeom.Mesh.Define(stage, f"/Character/{name}")
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(obj.points[low:high].astype(np.float32)))
        counts = obj.counts[np.unique(face_of_corner[inside])]
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(counts.astype(np.int32)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy((obj.indices[inside] - low).astype(np.int32)))
    stage.GetRootLayer().Save()
    return ranges


def live_link_take(path: Path, rows: dict, frames: int) -> Path:
    """A Live Link Face CSV at 30 fps at ``path``: the ARKit channels named in ``rows`` (name → (frames,)
    values), the others 0."""
    from warpface.drivers import ARKIT_CHANNELS

    lines = ["Timecode,BlendshapeCount," + ",".join(n[0].upper() + n[1:] for n in ARKIT_CHANNELS)]
    for frame in range(frames):
        values = ",".join(f"{rows[n][frame]:.6f}" if n in rows else "0" for n in ARKIT_CHANNELS)
        lines.append(f"10:20:00:{frame:02d}.000,{len(ARKIT_CHANNELS)}," + values)
    path.write_text("\n".join(lines) + "\n")
    return path


def _row(label: str, shot: Path, lash_prim: str, lashes: np.ndarray, skin_count: int) -> None:
    from pxr import Usd, UsdGeom
    from scipy.spatial import cKDTree

    stage = Usd.Stage.Open(str(shot))

    def points(path, frame):
        mesh = UsdGeom.Mesh(stage.GetPrimAtPath(path))
        return np.asarray(mesh.GetPointsAttr().Get(Usd.TimeCode(frame)), dtype=np.float64)

    skin_rest, skin_closed = points("/Face/Skin", 0)[:skin_count], points("/Face/Skin", FRAMES - 1)[:skin_count]
    rest, closed = points(lash_prim, 0)[lashes], points(lash_prim, FRAMES - 1)[lashes]
    near = cKDTree(skin_rest).query(rest)[1]
    lash, lid = 10.0 * (closed - rest), 10.0 * (skin_closed[near] - skin_rest[near])  # cm → mm
    gap = np.linalg.norm(lash - lid, axis=1)
    print(
        f"| {label} | {np.linalg.norm(lash, axis=1).mean():.2f} | {np.linalg.norm(lid, axis=1).mean():.2f} "
        f"| {gap.mean():.2f} / {gap.max():.2f} |"
    )


def main() -> None:
    from warpface.cli import main as cli
    from warpface.data import shared_data_path
    from warpface.mesh import read_obj_polygons

    ict = shared_data_path("ict_facekit")
    if ict is None:
        sys.exit("ICT-FaceKit not in ../shared/data (set WARPFACE_SHARED_DATA)")
    head = ict / "original" / "generic_neutral_mesh.obj"
    obj = read_obj_polygons(head)
    material = np.repeat(obj.face_materials, obj.counts)
    lashes = np.unique(obj.indices[material == obj.materials.index("M_EyeLashes")])
    print("| head | lashes [mm] | lid next to them [mm] | lash − lid, mean / max [mm] |\n|---|---|---|---|")
    with tempfile.TemporaryDirectory() as folder:
        work = Path(folder)
        closing = np.linspace(0.0, 1.0, FRAMES)
        take = live_link_take(work / "blink.csv", {"eyeBlinkLeft": closing, "eyeBlinkRight": closing}, FRAMES)
        ranges = split_ict_usd(obj, work / "ict.usda")
        for label, source, lash_prim, offset in (
            ("one mesh (OBJ)", head, "/Face/Skin", 0),
            ("five meshes (USD)", work / "ict.usda", "/Face/Asset/Character/Rest", ranges["Rest"][0]),
        ):
            rig, shot = work / f"{source.stem}_rig.usda", work / f"{source.stem}_shot.usda"
            assert cli(["--quiet", "rig", str(source), "--out", str(rig)]) == 0
            assert cli(["--quiet", "animate", str(take), "--rig", str(rig), "--out", str(shot), "--no-video"]) == 0
            _row(label, shot, lash_prim, lashes - offset, PRIMS["Head"][1])


if __name__ == "__main__":
    main()
