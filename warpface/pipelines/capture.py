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
    "upright_turn",
    "TurnedAdapter",
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
    camera_to_rig: np.ndarray | None = None
    """4×4 transform from the camera frame to the rig's own frame (the camera films the face turned upright:
    the rig's axes nearest its face's up and front become +y and +z); default: the inverse of the camera's
    ``model_to_camera``."""

    def __post_init__(self) -> None:
        if self.camera_to_rig is None:
            self.camera_to_rig = np.linalg.inv(self.camera.model_to_camera)


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
    """The built-in face (or ``rig``, e.g. a head rigged by ``warpface rig``, in metres) performs ``expression``;
    a 640×480 Kinect-like camera films it from the front, its face centred and its nose 0.6 m away, with painted
    dots (and, with ``noise``, depth noise and holes).

    A rig whose face looks along another axis, or is Z-up, is turned by the signed axis permutation nearest its
    landmark frame before it is filmed (:func:`upright_turn`); the capture's ``camera_to_rig`` undoes it."""
    from ..assets import default_rig, expression_timeline
    from ..tracking import KinectNoise, RGBDLandmarks, SyntheticRGBDCamera, place_fiducials
    from ..tracking.synthetic import default_model_to_camera

    rig = default_rig() if rig is None else rig
    muscles = expression_timeline(expression, rig, seconds=seconds, fps=fps)
    controls = np.pad(muscles, ((0, 0), (0, len(rig.control_names) - len(rig.muscles))))  # a jaw stays at rest
    truth = rig.model(device=device).evaluate(controls).astype(np.float64)
    turn = upright_turn(rig)
    shown = truth @ turn.T  # the model frame the camera expects: +y up, +z toward the camera
    rest, triangles = shown[0], rig.mesh.triangles
    model_to_camera = default_model_to_camera(rest[_face_vertices(rest, rig.landmarks)])
    eye = np.linalg.inv(model_to_camera)[:3, 3]
    fiducials = place_fiducials(rest, triangles, dots, spacing=0.014, camera_position=eye, device=device)
    camera = SyntheticRGBDCamera(
        shown,
        triangles,
        fiducials,
        names=vertex_landmark_names(fiducials),
        fps=fps,
        model_to_camera=model_to_camera,
        depth_noise=KinectNoise() if noise else None,
        seed=seed,
    )
    source = RGBDLandmarks(camera, camera.dot_tracker(), device=device)
    model_to_rig = np.eye(4)
    model_to_rig[:3, :3] = turn.T
    return SyntheticCapture(
        camera=camera,
        source=source,
        truth=truth,
        triangles=triangles,
        fiducial_vertices=fiducials,
        controls=controls,
        camera_to_rig=model_to_rig @ np.linalg.inv(model_to_camera),
    )


def upright_turn(rig) -> np.ndarray:
    """The signed axis permutation (3, 3) taking ``rig``'s coordinates to an upright, frontal model frame: its
    rows are the rig's axes nearest the face's up (→ +y) and front (→ +z), and their cross product (→ +x).
    The identity for a rig without 68 landmarks or one already upright and frontal (the built-in face)."""
    from ..assets.rig import face_frame
    from ..landmarks import IBUG_COUNT

    if rig.landmarks is None or len(rig.landmarks) != IBUG_COUNT:
        return np.eye(3)
    axes = face_frame(rig.mesh, rig.landmarks).axes
    up_axis = int(np.argmax(np.abs(axes[1])))
    front_scores = np.abs(axes[2]).copy()
    front_scores[up_axis] = -1.0
    front_axis = int(np.argmax(front_scores))
    up, front = np.zeros(3), np.zeros(3)
    up[up_axis], front[front_axis] = np.sign(axes[1][up_axis]), np.sign(axes[2][front_axis])
    return np.stack([np.cross(up, front), up, front])


class TurnedAdapter:
    """A tracking adapter that works in a rig's upright frame (:func:`upright_turn`: its sparse mesh is
    triangulated in the front view, which the adapter takes as its x-y plane) and hands out the dense face and
    its camera → model transform in the rig's own frame."""

    def __init__(self, rest_points, landmark_names, turn: np.ndarray, *, camera_to_rig=None, device=None):
        from ..tracking import adapter_for_face

        self.turn = np.asarray(turn, dtype=np.float64)
        self._to_upright = np.eye(4)
        self._to_upright[:3, :3] = self.turn
        self.adapter = adapter_for_face(
            np.asarray(rest_points, dtype=np.float64) @ self.turn.T,
            landmark_names,
            camera_to_model=None if camera_to_rig is None else self._to_upright @ camera_to_rig,
            device=device,
        )

    @property
    def camera_to_model(self) -> np.ndarray | None:
        """Camera → the rig's own frame (None until the adapter has fitted it on the first frame)."""
        upright = self.adapter.camera_to_model
        return None if upright is None else self._to_upright.T @ upright

    @property
    def weights(self) -> np.ndarray:
        """The adapter's per-vertex weights (frame-free)."""
        return self.adapter.weights

    @property
    def dense_rest(self) -> np.ndarray:
        """The dense rest points in the rig's frame."""
        return self.adapter.dense_rest @ self.turn

    def driven_vertices(self) -> np.ndarray:
        """The vertices the landmarks drive (frame-free)."""
        return self.adapter.driven_vertices()

    def track(self, source):
        """``(frame, dense points in the rig's frame)`` per frame of ``source``."""
        for frame, dense in self.adapter.track(source):
            yield frame, dense @ self.turn


def _face_vertices(points: np.ndarray, landmarks) -> np.ndarray:
    """Vertices the camera is aimed at: those over the landmarks' front-view box grown by half its size (forehead
    to chin, cheek to cheek, not the neck and shoulders of a bust); all of them without 68 landmarks."""
    from ..landmarks import IBUG_COUNT

    if landmarks is None or len(landmarks) != IBUG_COUNT:
        return np.arange(len(points))
    marks = points[landmarks, :2]
    low, high = marks.min(axis=0), marks.max(axis=0)
    grow = 0.5 * (high - low)
    inside = np.all((points[:, :2] >= low - grow) & (points[:, :2] <= high + grow), axis=1)
    return np.flatnonzero(inside)


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
