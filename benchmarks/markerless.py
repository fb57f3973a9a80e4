"""Markerless capture against ground truth, in the same run as the painted-dot path, and its speed.

The built-in face performs each expression with brows, lips and nostrils painted on
(:func:`warpface.pipelines.markerless_loop.markerless_capture`); the synthetic 640×480 RGB-D camera (Kinect-like
depth noise, 2 % holes) films it. Paths, same performance:

* ``dots (RGB-D)`` — the existing path: 60 painted dots, :func:`warpface.pipelines.capture.synthetic_capture`;
* ``markerless RGB-D`` — face mesh → the rig's 68 iBUG vertices, lifted with depth, solved as 3-D points;
* ``markerless RGB-D rays`` — the same landmarks solved as rays with a depth term (λ = 0.05, docs/CAPTURE.md §2);
* ``… + dense`` — with the face mesh's ~260 other points on the rig's skin (``--dense``);
* ``markerless video`` — the colour frames written to an .mp4, read back, rays, point-to-ray solve
  (docs/CAPTURE.md §3), intrinsics given.

Columns: controls' error (RMS of |Δc|·reach, mm), surface error of the solved skin (mm, whole face), the
still face's error (rest pose against the truth: what doing nothing scores), frames/s of detection alone, of
detection + solve one after the other (detection, lifting or rays, solve and skin per frame; the rendering
excluded) and pipelined (detection a few frames ahead on the second core, as ``warpface track`` runs it).

    python -m benchmarks.markerless [--seconds 1] [--expressions smile disgust]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import warp as wp

from warpface.pipelines.markerless_loop import markerless_capture, solve_markerless, write_video

from ._timing import machine_info, print_table, write_results


def _dot_path(rig, expression: str, seconds: float, device):
    from warpface.pipelines.capture import synthetic_capture
    from warpface.pipelines.track_compare import compare_tracking_paths

    capture = synthetic_capture(rig, expression=expression, seconds=seconds, device=device)
    try:
        result = compare_tracking_paths(capture, rig, device=device)
    finally:
        capture.camera.close()
    solved = result.paths[1]
    return solved.control_mm, solved.surface_face_mm, solved.frames_per_second


def main() -> None:
    from warpface.assets import default_rig
    from warpface.solve import Solver

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default=None)
    parser.add_argument("--seconds", type=float, default=1.0)
    parser.add_argument("--expressions", nargs="+", default=["smile", "disgust"])
    args = parser.parse_args()
    wp.config.quiet = True
    wp.config.log_level = wp.LOG_WARNING
    device = wp.get_device(args.device)
    rig = default_rig()
    reach = Solver(rig, rig.landmarks, device=device).reach

    rows = []
    for expression in args.expressions:
        capture = markerless_capture(rig, expression=expression, seconds=args.seconds, device=device)
        still = float(np.linalg.norm(capture.truth - capture.truth[0], axis=2).mean() * 1e3)
        control, surface, fps = _dot_path(rig, expression, args.seconds, device)
        rows.append(
            dict(
                expression=expression,
                path="dots (RGB-D)",
                control_mm=control,
                surface_mm=surface,
                still_mm=still,
                detect_fps=float("nan"),
                fps=fps,
                piped_fps=float("nan"),
                skipped=0,
            )
        )
        with tempfile.TemporaryDirectory() as folder:
            video = Path(folder) / "performance.mp4"
            write_video(capture.camera, video)
            paths = (
                ("rgbd", "markerless RGB-D"),
                ("rgbd-rays", "markerless RGB-D rays λ=0.05"),
                ("video", "markerless video"),
                ("rgbd", "markerless RGB-D + dense"),
                ("video", "markerless video + dense"),
            )
            for mode, name in paths:
                dense = name.endswith("dense")
                run = solve_markerless(capture, rig, mode=mode, video=video, dense=dense, device=device)
                piped = solve_markerless(capture, rig, mode=mode, video=video, dense=dense, prefetch=4, device=device)
                frames = len(run.controls)
                rows.append(
                    dict(
                        expression=expression,
                        path=name,
                        control_mm=run.control_mm(capture.controls, reach),
                        surface_mm=run.surface_mm(capture.truth),
                        still_mm=still,
                        detect_fps=frames / run.detect_seconds,
                        fps=frames / (run.detect_seconds + run.solve_seconds),
                        piped_fps=frames / (piped.detect_seconds + piped.solve_seconds),
                        skipped=int(run.skipped.sum()),
                    )
                )
        capture.camera.close()
    keys = ("expression", "path", "control_mm", "surface_mm", "still_mm", "detect_fps", "fps", "piped_fps", "skipped")
    labels = "expression|path|controls mm|surface mm|still mm|detect fps|detect+solve fps|pipelined fps|skipped"
    formats = ("s", "s", ".3f", ".3f", ".3f", ".0f", ".0f", ".0f", "d")
    print_table(rows, list(zip(keys, labels.split("|"), formats)))
    suffix = "" if device.is_cpu else "_" + str(device).replace(":", "")
    info = dict(benchmark="markerless", seconds=args.seconds, machine=machine_info(device), rows=rows)
    print(f"wrote {write_results('markerless' + suffix, info)}")


if __name__ == "__main__":
    main()
