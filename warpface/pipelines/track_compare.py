"""The synthetic-camera closed loop for both tracking paths, on the same frames: geometric transfer
versus solved controls (with and without the residual transfer), scored against ground truth.

Used by ``examples/track_synthetic.py``, ``benchmarks/track_solve.py`` and the tests: the capture's
landmark frames are taken once, then each path processes the identical frames (timed per frame,
excluding the camera, detection and back-projection that they share).
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field

import numpy as np

__all__ = ["PathScore", "PathComparison", "compare_tracking_paths"]


@dataclass
class PathScore:
    """One path's errors against ground truth [mm], means over frames (and vertices)."""

    name: str
    surface_driven_mm: float
    """Over the vertices the geometric transfer drives fully (blend weight ≥ 0.999)."""
    surface_face_mm: float
    """Over every vertex of the face."""
    landmark_mm: float
    """The path's face at the landmarks' vertices versus their true positions."""
    control_mm: float | None
    """RMS over muscles of |c − c_true| · reach (the displacement the error makes); None: no controls."""
    frames_per_second: float
    """Frames this path processes per second (landmarks in, dense face out)."""
    per_frame_surface_mm: np.ndarray = field(repr=False, default=None)
    """Mean error over the face per frame, (F,)."""


@dataclass
class PathComparison:
    frames: int
    measured_landmark_mm: float
    """The camera's 3-D landmarks (after depth back-projection) against the true dot positions."""
    still_driven_mm: float
    """A face that did not move, over the driven vertices (the scale of the motion)."""
    still_face_mm: float
    paths: list

    def table(self) -> str:
        """The comparison as aligned text."""
        header = ("surface (driven)", 18), ("surface (face)", 16), ("at landmarks", 14), ("controls", 12)
        lines = [f"{'path':<32}" + "".join(f"{name:>{width}}" for name, width in header) + f"{'frames/s':>10}"]
        for p in self.paths:
            control = "-" if p.control_mm is None else f"{p.control_mm:.3f} mm"
            lines.append(
                f"{p.name:<32}{p.surface_driven_mm:>15.3f} mm{p.surface_face_mm:>13.3f} mm{p.landmark_mm:>11.3f} mm"
                f"{control:>12}{p.frames_per_second:>10.0f}"
            )
        lines.append(f"{'(face that did not move)':<32}{self.still_driven_mm:>15.3f} mm{self.still_face_mm:>13.3f} mm")
        return "\n".join(lines)


def compare_tracking_paths(
    capture, rig=None, *, frames=None, device=None, max_frames: int | None = None, **solve_options
) -> PathComparison:
    """Run the geometric and the solved paths on the frames of a :func:`~warpface.pipelines.capture.synthetic_capture`.

    Args:
        capture: the synthetic capture (its ``truth`` and ``controls`` are the ground truth).
        rig: the rig that performed it (default: the built-in face).
        device: Warp device.
        frames: the capture's landmark frames when already taken (default: read from ``capture.source``).
        max_frames: use only the first frames.
        **solve_options: for :class:`~warpface.pipelines.track_solve.SolvingTracker`.
    """
    from ..assets import default_rig
    from ..tracking import adapter_for_face
    from .track_solve import SolvingTracker

    rig = default_rig() if rig is None else rig
    camera = capture.camera
    camera_to_model = capture.camera_to_rig
    if frames is None:
        frames = []
        for frame in capture.source.frames():
            frames.append(frame)
            if max_frames is not None and len(frames) >= max_frames:
                break
    frames = list(frames)[:max_frames]
    if not frames:
        raise ValueError("compare_tracking_paths: the capture has no frames")
    truth = capture.truth
    vertices = capture.fiducial_vertices
    geometric = adapter_for_face(rig.mesh.points, camera.landmark_names, camera_to_model=camera_to_model, device=device)
    geometric.bind(camera.landmark_names)
    geometric.track_frame(frames[0])  # compiles the kernels outside the timing; then start over
    geometric.reset()
    geometric.bind(camera.landmark_names)
    driven = geometric.weights >= 0.999

    def score(name, outputs, seconds, controls=None, reach=None) -> PathScore:
        errors = np.stack([np.linalg.norm(out - truth[f.index], axis=1) for f, out in zip(frames, outputs)]) * 1e3
        control = None
        if controls is not None:
            solved = np.asarray(controls)
            truth_controls = capture.controls[[f.index for f in frames]]
            # A muscles-only performance leaves the jaw at rest: its solved controls are compared with 0.
            truth_controls = np.pad(truth_controls, ((0, 0), (0, solved.shape[1] - truth_controls.shape[1])))
            wrong = (solved - truth_controls) * reach * 1e3
            control = float(np.sqrt(np.mean(wrong**2, axis=1)).mean())
        return PathScore(
            name=name,
            surface_driven_mm=float(errors[:, driven].mean()),
            surface_face_mm=float(errors.mean()),
            landmark_mm=float(errors[:, vertices].mean()),
            control_mm=control,
            frames_per_second=len(frames) / seconds if seconds > 0 else float("inf"),
            per_frame_surface_mm=errors.mean(axis=1),
        )

    outputs, started = [], time.perf_counter()
    for frame in frames:
        outputs.append(geometric.track_frame(frame))
    scores = [score("geometric transfer", outputs, time.perf_counter() - started)]
    for residual in (False, True):
        new_tracker = functools.partial(
            SolvingTracker,
            rig,
            camera.landmark_names,
            camera_to_model=camera_to_model,
            residual_transfer=residual,
            device=device,
            **solve_options,
        )
        new_tracker().track_frame(frames[0])  # compiles the kernels outside the timing; then start over
        tracker = new_tracker()
        outputs, controls, started = [], [], time.perf_counter()
        for frame in frames:
            solved = tracker.track_frame(frame)
            outputs.append(solved.skin)
            controls.append(solved.controls)
        name = "solved + residual transfer" if residual else "solved controls"
        scores.append(score(name, outputs, time.perf_counter() - started, controls, tracker.solver.reach))

    measured = []
    for frame in frames:
        ok = np.all(np.isfinite(frame.points), axis=1)
        measured.append(np.linalg.norm(frame.points[ok] - camera.landmark_positions(frame.index)[ok], axis=1))
    still = np.stack([np.linalg.norm(truth[0] - truth[f.index], axis=1) for f in frames]) * 1e3
    return PathComparison(
        frames=len(frames),
        measured_landmark_mm=float(np.concatenate(measured).mean() * 1e3),
        still_driven_mm=float(still[:, driven].mean()),
        still_face_mm=float(still.mean()),
        paths=scores,
    )
