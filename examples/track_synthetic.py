"""The tracking loop closed on ground truth (Kato's system, SPEC §3, on a synthetic camera).

The built-in face performs an expression; a synthetic 640×480 Kinect-like RGB-D camera at 0.6 m
films it with painted dots and depth noise; the dots are detected, tracked and lifted to 3-D with
depth. The same landmark frames then drive the face two ways:

* geometric: the sparse → dense transfer moves the skin like the landmarks' triangles;
* solved: the rig's muscle controls are solved from the landmarks (warpface.solve, head pose on),
  the expression model makes the skin with wrinkles; optionally plus the residual motion the solve
  could not explain, through the geometric transfer.

Prints landmark, surface and control errors of both paths against the ground truth, writes both as
USD stages (``capture.usda``: landmarks and the transferred face; ``capture_solved.usda``: the rig
with the solved contractions, skin and residual per frame), an overlay image and a trajectory plot.

    python examples/track_synthetic.py [--expression smile] [--out out/track] [--seconds 2] [--device cpu]
                                       [--residual-transfer]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import warp as wp

from warpface.pipelines.capture import record, synthetic_capture
from warpface.pipelines.track_compare import compare_tracking_paths
from warpface.pipelines.track_solve import SolvingTracker, solved_stage_writer
from warpface.tracking import adapter_for_face
from warpface.usd.tracking_io import TrackingStageWriter


class Replay:
    """The landmark frames of one capture, played again (both paths see the identical frames)."""

    def __init__(self, frames, landmark_names, fps):
        self.landmark_frames, self.landmark_names, self.fps = frames, landmark_names, fps

    def frames(self):
        return iter(self.landmark_frames)


def overlay(color: np.ndarray, detected: np.ndarray, truth: np.ndarray, zoom: int = 3) -> np.ndarray:
    """The face region of the camera image, enlarged, with true dot centres (red rings) and the
    tracked landmarks projected back into the image (green crosses)."""
    import cv2

    lo = np.maximum(np.floor(truth.min(axis=0)) - 30, 0).astype(int)
    hi = np.minimum(np.ceil(truth.max(axis=0)) + 30, [color.shape[1], color.shape[0]]).astype(int)
    crop = cv2.resize(color[lo[1] : hi[1], lo[0] : hi[0]], None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST)
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
    parser.add_argument(
        "--residual-transfer",
        action="store_true",
        help="solved stage: add the residual motion through the geometric transfer",
    )
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    wp.config.log_level = wp.LOG_WARNING

    capture = synthetic_capture(expression=args.expression, seconds=args.seconds, device=args.device)
    camera, truth = capture.camera, capture.truth
    adapter = adapter_for_face(
        truth[0], camera.landmark_names, camera_to_model=np.linalg.inv(camera.model_to_camera), device=args.device
    )
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

    frames = list(capture.source.frames())  # detected and back-projected once; replayed for each path
    replay = Replay(frames, camera.landmark_names, camera.fps)
    writer = TrackingStageWriter(
        args.out / "capture.usda", camera.landmark_names, camera.fps, dense_rest=truth[0], triangles=capture.triangles
    )
    stats = record(replay, adapter, writer, on_frame=compare)

    tracker = SolvingTracker(
        capture_rig(),
        camera.landmark_names,
        camera_to_model=np.linalg.inv(camera.model_to_camera),
        residual_transfer=args.residual_transfer,
        device=args.device,
    )
    solved_writer, layout = solved_stage_writer(args.out / "capture_solved.usda", tracker, camera.fps)
    record(replay, tracker, solved_writer, samples=lambda frame, skin: layout.samples(tracker.last, skin))

    landmark_mm = np.concatenate(landmark_errors) * 1e3
    surface_mm, still_mm = np.concatenate(surface_errors) * 1e3, np.concatenate(still_errors) * 1e3
    print(
        f"{stats.frames} frames, {len(camera.landmark_names)} dots, {100 * stats.landmarks_found:.0f}% found per frame"
    )
    print(
        f"3-D landmark error: mean {landmark_mm.mean():.2f} mm, 95th percentile {np.percentile(landmark_mm, 95):.2f} "
        "mm, "
        f"max {landmark_mm.max():.2f} mm"
    )
    print(
        f"dense surface error over {driven.sum()} driven vertices: mean {surface_mm.mean():.2f} mm "
        f"(a face that did not move would be off by {still_mm.mean():.2f} mm)"
    )
    summary = tracker.summary
    print(
        f"solve: mean landmark residual {summary['mean_residual'] * 1e3:.2f} mm, {summary['skipped']} frames skipped, "
        f"{summary['not_converged']} not converged"
    )
    print("\nBoth paths on the same frames, errors against ground truth (controls: RMS of |Δc|·reach):")
    print(compare_tracking_paths(capture, frames=frames, device=args.device).table())

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
        axis.plot(
            times,
            actual_mm[:, index, 1] - actual_mm[0, index, 1],
            color=f"C{k}",
            label=f"{camera.landmark_names[index]} truth",
        )
        axis.plot(
            times, tracked_mm[:, index, 1] - actual_mm[0, index, 1], "o", color=f"C{k}", markersize=3, label="tracked"
        )
    axis.set_xlabel("time [s]")
    axis.set_ylabel("vertical motion in the camera [mm] (y down)")
    axis.set_title(f"Synthetic capture, {args.expression}: the three most moving dots")
    axis.legend(fontsize=7, ncol=3)
    figure.tight_layout()
    figure.savefig(args.out / "trajectories.png", dpi=120)
    camera.close()
    print(f"wrote {args.out}/capture.usda, capture_solved.usda, overlay.png, trajectories.png")


def capture_rig():
    from warpface.assets import default_rig

    return default_rig()


if __name__ == "__main__":
    main()
