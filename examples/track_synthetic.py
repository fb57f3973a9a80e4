"""The tracking loop closed on ground truth (Kato's system, SPEC §3, on a synthetic camera).

The built-in face performs an expression; a synthetic 640×480 Kinect-like RGB-D camera at 0.6 m
films it with painted dots and depth noise; the dots are detected, tracked and lifted to 3-D with
depth; the landmarks drive the dense face through the sparse → dense transfer; everything goes to
a USD stage as time samples. Prints landmark and dense-surface errors against the ground truth and
writes an overlay image and a trajectory plot.

    python examples/track_synthetic.py [--expression smile] [--out out/track] [--seconds 2] [--device cpu]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import warp as wp

from warpface.pipelines.capture import record, synthetic_capture
from warpface.tracking import adapter_for_face
from warpface.usd.tracking_io import TrackingStageWriter


def overlay(color: np.ndarray, detected: np.ndarray, truth: np.ndarray, zoom: int = 3) -> np.ndarray:
    """The face region of the camera image, enlarged, with true dot centres (red rings) and the
    tracked landmarks projected back into the image (green crosses)."""
    import cv2

    lo = np.maximum(np.floor(truth.min(axis=0)) - 30, 0).astype(int)
    hi = np.minimum(np.ceil(truth.max(axis=0)) + 30, [color.shape[1], color.shape[0]]).astype(int)
    crop = cv2.resize(color[lo[1]:hi[1], lo[0]:hi[0]], None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST)
    image = cv2.cvtColor(crop, cv2.COLOR_RGB2BGR)
    place = lambda uv: tuple(int(round(c)) for c in (np.asarray(uv) - lo + 0.5) * zoom)  # pixel centres
    for uv in truth:
        cv2.circle(image, place(uv), 4 * zoom, (0, 0, 255), 1, cv2.LINE_AA)
    for uv in detected[np.all(np.isfinite(detected), axis=1)]:
        cv2.drawMarker(image, place(uv), (0, 220, 0), cv2.MARKER_CROSS, 3 * zoom, 1, cv2.LINE_AA)
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--expression", default="smile", help="thinking, puzzled, disgust or smile")
    parser.add_argument("--seconds", type=float, default=2.0, help="length of neutral → expression → neutral")
    parser.add_argument("--out", type=Path, default=Path("out/track"), help="output folder")
    parser.add_argument("--device", default=None, help="Warp device")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    wp.config.log_level = wp.LOG_WARNING

    capture = synthetic_capture(expression=args.expression, seconds=args.seconds, device=args.device)
    camera, truth = capture.camera, capture.truth
    adapter = adapter_for_face(truth[0], camera.landmark_names, camera_to_model=np.linalg.inv(camera.model_to_camera),
                               device=args.device)
    driven = adapter.weights > 0.999
    landmark_errors, surface_errors, still_errors, tracked, actual = [], [], [], [], []

    def compare(frame, dense):
        i = frame.index
        true_landmarks = camera.landmark_positions(i)
        ok = np.all(np.isfinite(frame.points), axis=1)
        landmark_errors.append(np.linalg.norm(frame.points[ok] - true_landmarks[ok], axis=1))
        surface_errors.append(np.linalg.norm(dense - truth[i], axis=1)[driven])
        still_errors.append(np.linalg.norm(truth[0] - truth[i], axis=1)[driven])
        tracked.append(np.where(ok[:, None], frame.points, np.nan))
        actual.append(true_landmarks)

    writer = TrackingStageWriter(args.out / "capture.usda", camera.landmark_names, camera.fps,
                                 dense_rest=truth[0], triangles=capture.triangles)
    stats = record(capture.source, adapter, writer, on_frame=compare)

    landmark_mm = np.concatenate(landmark_errors) * 1e3
    surface_mm, still_mm = np.concatenate(surface_errors) * 1e3, np.concatenate(still_errors) * 1e3
    print(f"{stats.frames} frames, {len(camera.landmark_names)} dots, {100 * stats.landmarks_found:.0f}% found per frame")
    print(f"3-D landmark error: mean {landmark_mm.mean():.2f} mm, 95th percentile {np.percentile(landmark_mm, 95):.2f} mm, "
          f"max {landmark_mm.max():.2f} mm")
    print(f"dense surface error over {driven.sum()} driven vertices: mean {surface_mm.mean():.2f} mm "
          f"(a face that did not move would be off by {still_mm.mean():.2f} mm)")

    peak = int(np.argmax([np.nanmean(np.linalg.norm(a - actual[0], axis=1)) for a in actual]))
    color, _ = camera.render(peak)
    detected = camera.intrinsics.project(tracked[peak])  # where the tracked 3-D landmarks land in the image
    from warpface.preview import save_image

    save_image(args.out / "overlay.png", overlay(color, detected, camera.landmark_pixels(peak)))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tracked_mm, actual_mm = np.array(tracked) * 1e3, np.array(actual) * 1e3
    moving = np.argsort(-np.ptp(actual_mm[:, :, 1], axis=0))[:3]
    times = np.arange(len(actual_mm)) / camera.fps
    figure, axis = plt.subplots(figsize=(7, 4))
    for k, index in enumerate(moving):
        axis.plot(times, actual_mm[:, index, 1] - actual_mm[0, index, 1], color=f"C{k}", label=f"{camera.landmark_names[index]} truth")
        axis.plot(times, tracked_mm[:, index, 1] - actual_mm[0, index, 1], "o", color=f"C{k}", markersize=3, label="tracked")
    axis.set_xlabel("time [s]")
    axis.set_ylabel("vertical motion in the camera [mm] (y down)")
    axis.set_title(f"Synthetic capture, {args.expression}: the three most moving dots")
    axis.legend(fontsize=7, ncol=3)
    figure.tight_layout()
    figure.savefig(args.out / "trajectories.png", dpi=120)
    camera.close()
    print(f"wrote {args.out}/capture.usda, overlay.png, trajectories.png")


if __name__ == "__main__":
    main()
