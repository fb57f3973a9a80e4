"""The paper's four expressions on a real face: the ICT-FaceKit face region from ``../shared/data``.

The default rig is placed from the face's 68 iBUG landmarks (nothing in it is specific to the built-in
face), the face is converted from centimetres to metres, and thinking, puzzled, disgust and smile are
rendered without (top) and with (bottom) wrinkles, and a blink and a smile (``blink_smile.png``). The rig
is also written as a USD stage. The ICT
data stays where it is; when it is absent the example says so and exits.

    python examples/ict_expressions.py [--out out/ict] [--device cpu]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import warp as wp

import warpface as wf
from warpface import preview, usd
from warpface.assets import EXPRESSIONS, default_rig, expression_contractions
from warpface.data import ict_face_region, ict_landmark_indices
from warpface.demo import SIDED_PRESETS, both_sides

CENTIMETRE = 0.01


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("out/ict"), help="output folder")
    parser.add_argument("--device", default=None, help="Warp device")
    args = parser.parse_args(argv)
    wp.config.log_level = wp.LOG_WARNING
    path, landmarks = ict_face_region(), ict_landmark_indices()
    if path is None or landmarks is None:
        print("ICT-FaceKit data not found in ../shared/data (set WARPFACE_SHARED_DATA); nothing to do")
        return 0
    source = wf.FaceMesh.from_obj(path)
    mesh = wf.FaceMesh(source.points * CENTIMETRE, source.triangles, name="ict_face")
    rig = default_rig(mesh, landmarks, name="ICTFace", device=args.device)
    smooth = wf.ExpressionModel(rig.mesh, rig.muscles, [], rig.thickness, device=args.device)
    wrinkled = rig.model(device=args.device)

    args.out.mkdir(parents=True, exist_ok=True)
    usd.write_rig(args.out / "ict_face.usda", rig)
    camera = preview.Camera.for_face(mesh.points[landmarks], yaw_deg=25.0, pitch_deg=5.0)
    style = dict(camera=camera, size=(420, 500), background=(0.12, 0.12, 0.14))
    rows = []
    for model, label in ((smooth, "no wrinkles"), (wrinkled, "with wrinkles")):
        views = [(f"{name}: {label}", model.evaluate(expression_contractions(name, rig))) for name in EXPRESSIONS]
        rows.append(preview.render_comparison(views, rig.mesh.triangles, **style))
    preview.save_image(args.out / "expressions.png", np.concatenate(rows, axis=0))
    views = [("neutral", mesh.points)]
    views += [(title, wrinkled.evaluate(both_sides(rig, name))) for title, name in SIDED_PRESETS]
    preview.render_comparison(views, rig.mesh.triangles, args.out / "blink_smile.png", **style)
    print(f"{len(rig.muscles)} muscles and {len(rig.wrinkles)} wrinkles placed from the 68 landmarks of {path.name}")
    print(f"wrote {args.out}/ict_face.usda, {args.out}/expressions.png and {args.out}/blink_smile.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
