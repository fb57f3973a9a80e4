"""Capture pipelines: a landmark source → :class:`TrackingAdapter` → USD time samples.

Landmarks that drive a warpface face are named after the dense vertex they sit on, ``v01234``
(:func:`vertex_landmark_names`): a recording, an RGB-D folder or a live camera's fiducial layout
made for a face then maps onto it with no other bookkeeping. The sparse tracking mesh is the
Delaunay triangulation of those vertices at rest.
"""

from __future__ import annotations

import json
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from .transfer import TrackingAdapter

__all__ = [
    "vertex_landmark_names",
    "landmark_vertices",
    "adapter_for_face",
    "SyntheticCapture",
    "synthetic_capture",
    "open_source",
    "CaptureStats",
    "record",
]

_NAME = re.compile(r"^v(\d+)$")


def vertex_landmark_names(vertices) -> list[str]:
    """Landmark names for dense vertex indices: ``[12, 345] → ["v00012", "v00345"]``."""
    return [f"v{int(v):05d}" for v in np.asarray(vertices).ravel()]


def landmark_vertices(names: Sequence[str], vertex_count: int) -> np.ndarray:
    """Dense vertex indices from names made by :func:`vertex_landmark_names`.

    Raises:
        ValueError: a name that is not ``v<index>``, or an index outside the face.
    """
    indices = []
    for name in names:
        match = _NAME.match(str(name))
        if match is None:
            raise ValueError(f"landmark {name!r}: expected a dense-vertex name like 'v01234' (see vertex_landmark_names)")
        index = int(match.group(1))
        if index >= vertex_count:
            raise ValueError(f"landmark {name!r}: vertex {index} is outside the face ({vertex_count} vertices)")
        indices.append(index)
    return np.asarray(indices, dtype=np.int64)


def adapter_for_face(rest_points: np.ndarray, landmark_names: Sequence[str], *, camera_to_model=None,
                     stabilize=False, device=None) -> TrackingAdapter:
    """A :class:`TrackingAdapter` whose sparse mesh is the face's own landmark vertices, triangulated."""
    from .correspondence import triangulate_landmarks

    vertices = landmark_vertices(landmark_names, len(rest_points))
    sparse = np.asarray(rest_points, dtype=np.float64)[vertices]
    return TrackingAdapter(sparse, triangulate_landmarks(sparse), rest_points, landmark_names=list(landmark_names),
                           camera_to_model=camera_to_model, stabilize=stabilize, device=device)


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


def synthetic_capture(rig=None, *, expression: str = "smile", seconds: float = 2.0, fps: float = 30.0, dots: int = 60,
                      noise: bool = True, seed: int = 0, device=None) -> SyntheticCapture:
    """The built-in face (or ``rig``) performs ``expression``; a 640×480 Kinect-like camera at 0.6 m
    films it with painted dots (and, with ``noise``, depth noise and holes)."""
    from ..assets import default_rig, expression_timeline
    from .synthetic import KinectNoise, SyntheticRGBDCamera, default_model_to_camera, place_fiducials
    from .sources import RGBDLandmarks

    rig = default_rig() if rig is None else rig
    truth = rig.model(device=device).evaluate_batch(expression_timeline(expression, rig, seconds=seconds, fps=fps)).astype(np.float64)
    rest, triangles = truth[0], rig.mesh.triangles
    eye = np.linalg.inv(default_model_to_camera(rest))[:3, 3]
    fiducials = place_fiducials(rest, triangles, dots, spacing=0.014, camera_position=eye, device=device)
    camera = SyntheticRGBDCamera(truth, triangles, fiducials, names=vertex_landmark_names(fiducials), fps=fps,
                                 depth_noise=KinectNoise() if noise else None, seed=seed)
    source = RGBDLandmarks(camera, camera.dot_tracker(), device=device)
    return SyntheticCapture(camera=camera, source=source, truth=truth, triangles=triangles, fiducial_vertices=fiducials)


def open_source(spec: str, *, layout: str | None = None, device=None):
    """A landmark source from a command-line spec: a ``.npz`` recording, an RGB-D folder, or
    ``realsense`` / ``orbbec`` (which need ``layout``: a JSON file with ``names`` and
    ``initial_pixels`` of the painted dots, e.g. an RGB-D folder's ``fiducials``)."""
    from .detect import DotTracker
    from .sources import RecordedLandmarks, RGBDFolder, RGBDLandmarks

    if spec in ("realsense", "orbbec"):
        if layout is None:
            raise ValueError(f"a live {spec} capture needs --layout: a JSON file with the dots' 'names' and 'initial_pixels'")
        fiducials = json.loads(Path(layout).read_text())
        from .cameras import OrbbecCamera, RealSenseCamera

        camera = RealSenseCamera() if spec == "realsense" else OrbbecCamera()
        tracker = DotTracker(np.asarray(fiducials["initial_pixels"]), names=fiducials["names"])
        return RGBDLandmarks(camera, tracker, timestamp_policy="drop", device=device)
    path = Path(spec)
    if path.suffix == ".npz":
        return RecordedLandmarks(path)
    if path.is_dir():
        folder = RGBDFolder(path)
        fiducials = folder.fiducials
        if not fiducials:
            raise ValueError(f"{path}: meta.json has no 'fiducials' layout (names and initial pixels of the dots)")
        tracker = DotTracker(np.asarray(fiducials["initial_pixels"]), names=fiducials["names"])
        return RGBDLandmarks(folder, tracker, device=device)
    raise ValueError(f"unknown source {spec!r}: expected a .npz recording, an RGB-D folder, synthetic, realsense or orbbec")


@dataclass
class CaptureStats:
    """What a capture did."""

    frames: int
    seconds: float
    landmarks_found: float
    """Mean fraction of landmarks measured per frame."""

    @property
    def frames_per_second(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else float("nan")


def record(source, adapter: TrackingAdapter, writer, *, max_frames: int | None = None, progress: bool = True,
           on_frame=None) -> CaptureStats:
    """Run ``source`` through ``adapter`` into ``writer`` (a :class:`~warpface.usd.tracking_io.TrackingStageWriter`).

    Every frame received is kept: on any error (a camera that disappears, Ctrl-C) the writer is
    closed — flushing what it holds — before the error propagates. ``on_frame(frame, dense)`` is
    called for each frame before it is written (e.g. a :class:`~warpface.tracking.tissue_drive.TissueDrive`,
    or to collect errors); when it returns points, those are written instead. Landmarks are
    written in the face's model frame (the adapter's camera → model similarity), where the dense face is.
    """
    from tqdm import tqdm

    bar = tqdm(desc="track", unit="frame", disable=not progress, total=max_frames)
    found, count, started = 0.0, 0, time.perf_counter()
    try:
        for frame, dense in adapter.track(source):
            measured = np.all(np.isfinite(frame.points), axis=1) & (frame.confidence > 0)
            if on_frame is not None:
                replaced = on_frame(frame, dense)
                dense = dense if replaced is None else replaced
            writer.add(frame.timestamp, _to_model(adapter.camera_to_model, frame.points), frame.confidence, dense)
            count += 1
            found += measured.mean()
            elapsed = time.perf_counter() - started
            bar.set_postfix(fps=f"{count / elapsed:.0f}" if elapsed > 0 else "-", landmarks=f"{measured.sum()}/{len(measured)}")
            bar.update()
            if max_frames is not None and count >= max_frames:
                break
    finally:
        bar.close()
        writer.close()
    return CaptureStats(frames=count, seconds=time.perf_counter() - started, landmarks_found=found / max(count, 1))


def _to_model(camera_to_model, points: np.ndarray) -> np.ndarray:
    """Camera-frame points (N, 3) in the model frame (NaN rows stay NaN)."""
    if camera_to_model is None:
        return points
    return points @ camera_to_model[:3, :3].T + camera_to_model[:3, 3]
