"""A contact sheet of every preset (ARKit skin-motion shapes and the paper's four) on a landmark-rigged face.

Each tile is the full-anatomy default rig evaluated at one preset, coloured by the displacement from
rest on one shared millimetre scale. The built-in face goes to ``docs/images/presets.png``; with
``--ict`` the ICT-FaceKit face from ``../shared/data`` (rigged from its 68 landmarks) goes to
``out/ict/presets.png`` (never into the repository).

    python examples/presets_sheet.py [--ict] [--out PATH] [--device cpu]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import warp as wp

import warpface as wf
from warpface import preview
from warpface.assets import PRESETS, default_rig, preset_controls
from warpface.data import ict_face_region, ict_landmark_indices

CENTIMETRE = 0.01
MAX_MM = 10.0
COLUMNS = 8


def contact_sheet(rig, device=None, tile=(220, 260)) -> np.ndarray:
    """All presets of :data:`~warpface.assets.PRESETS` on ``rig`` (metres), as one RGB image."""
    model = rig.model(device=device)
    points = rig.mesh.points
    camera = preview.Camera.for_face(points[rig.landmarks], yaw_deg=20.0, pitch_deg=5.0)
    names = list(PRESETS)
    frames = model.evaluate([preset_controls(name, rig) for name in names])
    colors = [
        preview.heat_colors(np.linalg.norm(frame - points, axis=1) * 1000.0, vmin=0.0, vmax=MAX_MM) for frame in frames
    ]
    rows = []
    for start in range(0, len(names), COLUMNS):
        views = [(name, frames[i]) for i, name in enumerate(names[start : start + COLUMNS], start=start)]
        views += [("", points)] * (COLUMNS - len(views))
        tile_colors = colors[start : start + COLUMNS] + [np.ones((len(points), 3))] * (
            COLUMNS - len(colors[start : start + COLUMNS])
        )
        rows.append(
            preview.render_comparison(
                views, rig.mesh.triangles, camera=camera, size=tile, colors=tile_colors, background=(0.12, 0.12, 0.14)
            )
        )
    return np.concatenate(rows, axis=0)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--ict", action="store_true", help="the ICT-FaceKit face instead of the built-in one")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)
    wp.config.quiet = True
    if args.ict:
        path, landmarks = ict_face_region(), ict_landmark_indices()
        if path is None or landmarks is None:
            print("ICT-FaceKit data not found in ../shared/data (set WARPFACE_SHARED_DATA); nothing to do")
            return 0
        source = wf.FaceMesh.from_obj(path)
        rig = default_rig(
            wf.FaceMesh(source.points * CENTIMETRE, source.triangles, name="ict_face"),
            landmarks,
            name="ICTFace",
            device=args.device,
        )
        out = args.out or Path("out/ict/presets.png")
    else:
        rig = default_rig(device=args.device)
        out = args.out or Path("docs/images/presets.png")
    out.parent.mkdir(parents=True, exist_ok=True)
    preview.save_image(out, contact_sheet(rig, args.device))
    print(f"{len(PRESETS)} presets; colour: displacement 0–{MAX_MM:g} mm; wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
