"""Capture pipelines: a landmark source → :class:`~warpface.tracking.TrackingAdapter` → USD time samples.

:func:`open_source` turns a command-line spec into a landmark source, :func:`synthetic_capture`
films the built-in face with a synthetic RGB-D camera, :func:`record` runs a source through an
adapter into a :class:`~warpface.usd.tracking_io.TrackingStageWriter`, keeping every frame received.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass

import numpy as np

from ..tracking import PrefetchedSource, TrackingAdapter
from ..tracking.landmark_names import vertex_landmark_names

__all__ = [
    "SyntheticCapture",
    "synthetic_capture",
    "open_source",
    "CaptureStats",
    "record",
]


@dataclass
class SyntheticCapture:
    """A synthetic RGB-D capture of a rig performing an expression, with its ground truth."""

    camera: object
    """The :class:`~warpface.tracking.synthetic.SyntheticRGBDCamera`."""
    source: object
    """Landmarks detected (dots) and back-projected from the camera's frames."""
    truth: np.ndarray
    """Ground-truth dense points per frame [m], shape (F, V, 3), model frame."""
    triangles: np.ndarray
    """Dense face triangles, shape (T, 3)."""
    fiducial_vertices: np.ndarray
    """Dense vertex under each painted dot, shape (K,)."""
    controls: np.ndarray | None = None
    """Ground-truth contractions per frame in the rig's muscle order, shape (F, M)."""


def synthetic_capture(
    rig=None,
    *,
    expression: str = "smile",
    seconds: float = 2.0,
    fps: float = 30.0,
    dots: int = 60,
    noise: bool = True,
    seed: int = 0,
    device=None,
) -> SyntheticCapture:
    """The built-in face (or ``rig``) performs ``expression``; a 640×480 Kinect-like camera at 0.6 m
    films it with painted dots (and, with ``noise``, depth noise and holes)."""
    from ..assets import default_rig, expression_timeline
    from ..tracking import KinectNoise, RGBDLandmarks, SyntheticRGBDCamera, place_fiducials
    from ..tracking.synthetic import default_model_to_camera

    rig = default_rig() if rig is None else rig
    muscles = expression_timeline(expression, rig, seconds=seconds, fps=fps)
    controls = np.pad(muscles, ((0, 0), (0, len(rig.control_names) - len(rig.muscles))))  # a jaw stays at rest
    truth = rig.model(device=device).evaluate(controls).astype(np.float64)
    rest, triangles = truth[0], rig.mesh.triangles
    eye = np.linalg.inv(default_model_to_camera(rest))[:3, 3]
    fiducials = place_fiducials(rest, triangles, dots, spacing=0.014, camera_position=eye, device=device)
    camera = SyntheticRGBDCamera(
        truth,
        triangles,
        fiducials,
        names=vertex_landmark_names(fiducials),
        fps=fps,
        depth_noise=KinectNoise() if noise else None,
        seed=seed,
    )
    source = RGBDLandmarks(camera, camera.dot_tracker(), device=device)
    return SyntheticCapture(
        camera=camera, source=source, truth=truth, triangles=triangles, fiducial_vertices=fiducials, controls=controls
    )


def open_source(spec: str, *, layout: str | None = None, device=None):
    """A landmark source from a command-line spec: a ``.npz`` recording, an RGB-D folder, or
    ``realsense`` / ``orbbec`` (which need ``layout``: a JSON file with ``names`` and
    ``initial_pixels`` of the painted dots, e.g. an RGB-D folder's ``fiducials``)."""
    from .._files import read_text
    from .._validate import as_path
    from ..tracking import DotTracker, RecordedLandmarks, RGBDFolder, RGBDLandmarks

    path = as_path(spec, "source")
    if spec in ("realsense", "orbbec"):
        if layout is None:
            raise ValueError(
                f"a live {spec} capture needs --layout: a JSON file with the dots' 'names' and 'initial_pixels'"
            )
        fiducials = json.loads(read_text(as_path(layout, "layout")))
        if not isinstance(fiducials, dict) or not {"names", "initial_pixels"} <= set(fiducials):
            raise ValueError(f"layout {layout}: expected a JSON object with 'names' and 'initial_pixels'")
        from ..tracking import OrbbecCamera, RealSenseCamera

        camera = RealSenseCamera() if spec == "realsense" else OrbbecCamera()
        tracker = DotTracker(np.asarray(fiducials["initial_pixels"]), names=fiducials["names"])
        return RGBDLandmarks(camera, tracker, timestamp_policy="drop", device=device)
    if path.suffix == ".npz":
        return RecordedLandmarks(path)
    if path.is_dir():
        folder = RGBDFolder(path)
        fiducials = folder.fiducials
        if not fiducials:
            raise ValueError(f"{path}: meta.json has no 'fiducials' layout (names and initial pixels of the dots)")
        tracker = DotTracker(np.asarray(fiducials["initial_pixels"]), names=fiducials["names"])
        return RGBDLandmarks(folder, tracker, device=device)
    raise ValueError(
        f"unknown source {spec!r}: expected a .npz recording, an RGB-D folder, synthetic, realsense or orbbec"
    )


@dataclass
class CaptureStats:
    """What a capture did."""

    frames: int
    """Frames handed to the writer (all of them are on its stage once :func:`record` returns)."""
    seconds: float
    landmarks_found: float
    """Mean fraction of landmarks measured per frame."""
    interrupted: bool = False
    """True when Ctrl-C ended the capture (cleanly, between two frames)."""

    @property
    def frames_per_second(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else float("nan")


def record(
    source,
    adapter: TrackingAdapter,
    writer,
    *,
    max_frames: int | None = None,
    progress: bool = True,
    on_frame=None,
    samples=None,
    prefetch: int = 0,
) -> CaptureStats:
    """Run ``source`` through ``adapter`` into ``writer`` (a :class:`~warpface.usd.tracking_io.TrackingStageWriter`).

    Every frame handed to the writer is kept. Ctrl-C stops the capture between two frames: the
    writer is closed (flushing what it holds) and the stats come back with ``interrupted=True``; a
    second Ctrl-C raises :class:`KeyboardInterrupt` at once (for a source that blocks) — the writer is
    still closed first. On any other error (a camera that disappears) the writer is closed before the
    error propagates. ``on_frame(frame, dense)`` is called for each frame before it is written (e.g. a
    :class:`~warpface.pipelines.tissue_drive.TissueDrive`, or to collect errors); when it returns
    points, those are written instead. Landmarks are written in the face's model frame (the
    adapter's camera → model similarity), where the dense face is.

    ``adapter`` may also be a :class:`~warpface.pipelines.track_solve.SolvingTracker` (anything with
    ``track(source)`` and ``camera_to_model``). ``samples(frame, dense)`` returns the frame's values of
    the writer's extra channels (``writer.add(..., samples=)``); a writer without a dense face is
    given no dense points.

    ``prefetch`` > 0 reads that many frames ahead in a background thread
    (:class:`~warpface.tracking.PrefetchedSource`): the source's detection and back-projection of the
    next frame run on the second CPU core while this thread transfers and writes the current one. The
    frames and what is written are the same; the source must tolerate being read from another thread
    (files, recordings and the RGB-D cameras do).
    """
    from tqdm import tqdm

    from .._signals import InterruptRequest, deferred_interrupts
    from .._validate import as_count

    if max_frames is not None:
        max_frames = as_count(max_frames, "max_frames", minimum=1)
    if as_count(prefetch, "prefetch", minimum=0, maximum=1024):
        source = PrefetchedSource(source, depth=prefetch)

    bar = tqdm(desc="track", unit="frame", disable=not progress, total=max_frames)
    found, count, started = 0.0, 0, time.perf_counter()
    with InterruptRequest() as stop:
        try:
            for frame, dense in adapter.track(source):
                measured = np.all(np.isfinite(frame.points), axis=1) & (frame.confidence > 0)
                if on_frame is not None:
                    replaced = on_frame(frame, dense)
                    dense = dense if replaced is None else replaced
                extra = {} if samples is None else {"samples": samples(frame, dense)}
                if getattr(writer, "vertex_count", True) is None:
                    dense = None
                with deferred_interrupts():  # the frame is either fully queued and counted, or not at all
                    writer.add(
                        frame.timestamp,
                        _to_model(adapter.camera_to_model, frame.points),
                        frame.confidence,
                        dense,
                        **extra,
                    )
                    count += 1
                found += measured.mean()
                elapsed = time.perf_counter() - started
                bar.set_postfix(
                    fps=f"{count / elapsed:.0f}" if elapsed > 0 else "-", landmarks=f"{measured.sum()}/{len(measured)}"
                )
                bar.update()
                if stop or (max_frames is not None and count >= max_frames):
                    break
        finally:
            with deferred_interrupts():
                writer.close()
            bar.close()
    return CaptureStats(
        frames=count,
        seconds=time.perf_counter() - started,
        landmarks_found=found / max(count, 1),
        interrupted=stop.requested,
    )


def _to_model(camera_to_model, points: np.ndarray) -> np.ndarray:
    """Camera-frame points (N, 3) in the model frame (NaN rows stay NaN)."""
    if camera_to_model is None:
        return points
    return points @ camera_to_model[:3, :3].T + camera_to_model[:3, 3]
