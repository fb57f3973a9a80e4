"""Tracking drives the muscles: geometric transfer versus solved controls on the same synthetic capture.

The built-in face performs each expression; the synthetic 640×480 Kinect-like RGB-D camera (depth noise
and holes) films its 60 painted dots, which are detected and back-projected once; then every path
processes the identical landmark frames (:func:`warpface.pipelines.track_compare.compare_tracking_paths`):

* ``geometric transfer`` — the sparse → dense transfer (the peer, measured in the same run);
* ``solved controls`` — warm-started :class:`warpface.solve.Solver` with head pose, then the expression
  model with wrinkles over the whole face;
* ``solved + residual transfer`` — plus the landmark motion the solve cannot explain, transferred.

Columns: mean surface error against ground truth over the vertices the transfer drives fully and over
the whole face, at the landmarks' vertices, the controls' error as RMS of |Δc|·reach, and frames/s of the
path alone (landmarks in, dense face out; camera, detection and depth shared and excluded), with the
ratio of each path's surface error to the geometric transfer's.

    python -m benchmarks.track_solve [--device cpu] [--seconds 2] [--expressions smile disgust]
"""

from __future__ import annotations

import argparse

import warp as wp

from warpface.pipelines.capture import synthetic_capture
from warpface.pipelines.track_compare import compare_tracking_paths

from ._timing import machine_info, print_table, write_results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default=None)
    parser.add_argument("--seconds", type=float, default=2.0)
    parser.add_argument("--expressions", nargs="+", default=["smile", "disgust", "thinking", "puzzled"])
    args = parser.parse_args()
    wp.config.quiet = True
    wp.config.log_level = wp.LOG_WARNING
    device = wp.get_device(args.device)

    rows = []
    for expression in args.expressions:
        capture = synthetic_capture(expression=expression, seconds=args.seconds, device=device)
        try:
            result = compare_tracking_paths(capture, device=device)
        finally:
            capture.camera.close()
        geometric = result.paths[0]
        for path in result.paths:
            rows.append(
                {
                    "expression": expression,
                    "path": path.name,
                    "frames": result.frames,
                    "measured_landmark_mm": result.measured_landmark_mm,
                    "surface_driven_mm": path.surface_driven_mm,
                    "surface_face_mm": path.surface_face_mm,
                    "landmark_mm": path.landmark_mm,
                    "control_mm": path.control_mm,
                    "fps": path.frames_per_second,
                    "face_error_ratio": path.surface_face_mm / geometric.surface_face_mm,
                    "still_face_mm": result.still_face_mm,
                }
            )
    print_table(
        rows,
        [
            ("expression", "expression", "s"),
            ("path", "path", "s"),
            ("measured_landmark_mm", "camera landmarks mm", ".2f"),
            ("surface_driven_mm", "surface (driven) mm", ".3f"),
            ("surface_face_mm", "surface (face) mm", ".3f"),
            ("landmark_mm", "at landmarks mm", ".3f"),
            ("control_mm", "controls mm", ".3f"),
            ("fps", "frames/s", ".0f"),
            ("face_error_ratio", "face error × geometric", ".2f"),
            ("still_face_mm", "no motion mm", ".3f"),
        ],
    )
    name = "track_solve" if device.is_cpu else f"track_solve_{str(device).replace(':', '')}"
    path = write_results(
        name, {"benchmark": "track_solve", "seconds": args.seconds, "machine": machine_info(device), "rows": rows}
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
