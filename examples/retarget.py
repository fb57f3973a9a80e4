"""Retargeting: a performance captured on the built-in face drives the ICT-FaceKit face through solved controls.

1. "Capture": the built-in face performs thinking → puzzled → disgust → smile; its 68 landmarks are
   sampled per frame with Kinect-like noise (default 0.5 mm) and a few dropped points (NaN).
2. Solve: ``warpface.solve.Solver`` recovers the 23 muscle contractions from the landmarks alone,
   frame after frame (warm-started, lightly smoothed in time).
3. Retarget: the ICT face (``../shared/data``), rigged from its own 68 landmarks with the same
   default rig, plays the solved controls. Linear contractions are lengths, so they are rescaled by
   the ratio of the two faces' inter-ocular distances; sphincters are dimensionless and carry over.

Writes ``out/retarget/retarget.png``: per expression peak, the captured face, the solved built-in
face, and the ICT face driven by the same controls.

    python examples/retarget.py [--out out/retarget] [--noise-mm 0.5] [--device cpu]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import warp as wp

import warpface as wf
from warpface import preview
from warpface.assets import EXPRESSIONS, default_rig, expression_timeline, rig_scale
from warpface.data import ict_face_region, ict_landmark_indices
from warpface.expression import LinearMuscle
from warpface.solve import Solver

CENTIMETRE = 0.01


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("out/retarget"), help="output folder")
    parser.add_argument("--noise-mm", type=float, default=0.5, help="landmark noise, standard deviation [mm]")
    parser.add_argument("--seconds", type=float, default=1.0, help="seconds per expression")
    parser.add_argument("--device", default=None, help="Warp device")
    args = parser.parse_args(argv)
    wp.config.quiet = True
    path, ict_landmarks = ict_face_region(), ict_landmark_indices()
    if path is None or ict_landmarks is None:
        print("ICT-FaceKit data not found in ../shared/data (set WARPFACE_SHARED_DATA); nothing to do")
        return 0

    # 1. The performance on the built-in face, seen as noisy landmarks.
    source = default_rig(device=args.device)
    source_model = source.model(device=args.device)
    timelines = [expression_timeline(name, source, seconds=args.seconds, fps=30.0) for name in EXPRESSIONS]
    truth = np.concatenate(timelines)
    truth = np.pad(truth, ((0, 0), (0, len(source.control_names) - len(source.muscles))))  # the jaw at rest
    captured = source_model.evaluate(truth, progress=True)
    rng = np.random.default_rng(0)
    landmarks = captured[:, source.landmarks].astype(np.float64)
    landmarks += rng.normal(scale=args.noise_mm * 1e-3, size=landmarks.shape)
    landmarks[rng.random(landmarks.shape[:2]) < 0.02] = np.nan  # occasional dropouts

    # 2. Solve controls from the landmarks, frame after frame.
    solver = Solver(source, source.landmarks, device=args.device, smoothness=1e-3, l1=1e-5)
    solved = np.stack([solver.solve(frame).vector for frame in landmarks])
    scale = rig_scale(source)
    jaw_count = len(source.control_names) - len(source.muscles)
    linear = np.array([isinstance(m, LinearMuscle) for m in source.muscles] + [False] * jaw_count)
    error = np.abs(solved - truth) / np.where(linear, scale, 1.0)
    solved_points = source_model.evaluate(solved)
    surface = np.linalg.norm(solved_points - captured, axis=2).mean(axis=1) / scale
    print(
        f"{len(truth)} frames: control error mean {error.mean():.4f}, max {error.max():.4f} "
        f"(linear in inter-ocular units, sphincters dimensionless); "
        f"surface error mean {surface.mean():.2e} IOD, worst frame {surface.max():.2e} IOD"
    )

    # 3. The ICT face plays the same controls.
    ict_source = wf.FaceMesh.from_obj(path)
    ict_mesh = wf.FaceMesh(ict_source.points * CENTIMETRE, ict_source.triangles, name="ict_face")
    target = default_rig(ict_mesh, ict_landmarks, name="ICTFace", device=args.device)
    if target.muscle_names != source.muscle_names:
        raise SystemExit("the two rigs' controls differ; retargeting needs the same control names")
    ratio = rig_scale(target) / scale
    retargeted = solved * np.where(linear, ratio, 1.0)
    target_model = target.model(device=args.device)

    peaks = np.cumsum([0] + [len(t) for t in timelines])[:-1] + np.array([len(t) // 2 for t in timelines])
    source_camera = preview.Camera.for_face(source.mesh.points[source.landmarks], yaw_deg=20.0, pitch_deg=5.0)
    target_camera = preview.Camera.for_face(ict_mesh.points[ict_landmarks], yaw_deg=20.0, pitch_deg=5.0)
    style = dict(size=(360, 420), background=(0.12, 0.12, 0.14))
    columns = []
    for name, frame in zip(EXPRESSIONS, peaks):
        rows = [
            preview.render_comparison(
                [(f"{name}: captured", captured[frame])], source.mesh.triangles, camera=source_camera, **style
            ),
            preview.render_comparison(
                [("solved from landmarks", solved_points[frame])], source.mesh.triangles, camera=source_camera, **style
            ),
            preview.render_comparison(
                [("ICT face, same controls", target_model.evaluate(retargeted[frame]))],
                target.mesh.triangles,
                camera=target_camera,
                **style,
            ),
        ]
        columns.append(np.concatenate(rows, axis=0))
    args.out.mkdir(parents=True, exist_ok=True)
    image = preview.save_image(args.out / "retarget.png", np.concatenate(columns, axis=1))
    print(f"wrote {image}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
