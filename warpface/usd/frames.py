"""Playing a stage back: the skin points of a rig stage or the dense face of a tracked capture, frame by frame.

Two kinds of stage hold a face that moves over time:

- a **rig** stage (:func:`~warpface.usd.write_rig`, usually baked): the skin mesh with ``WarpFaceSkinAPI``,
  rest shape in its variant, animated points from the cache sublayer;
- a **capture** written by ``warpface track`` (:class:`~warpface.usd.tracking_io.TrackingStageWriter`):
  ``/Capture/Face`` with its rest points in ``warpFace:restPoints`` and the tracked points in value
  clips under ``<stage>_track/``.

:func:`open_frames` gives both the same face: triangles, rest points, the time codes and the points at
any of them. :func:`capture_problems` checks a capture the way ``warpface validate`` reports it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pxr import Sdf, Usd, UsdGeom

from .._validate import expect_instance
from ..errors import RigError
from ._files import open_layer, open_stage
from .animation import MAX_FRAMES, frame_times
from .tracking_io import FACE, LANDMARKS, ROOT

__all__ = ["StageFrames", "open_frames", "is_capture", "capture_problems"]


@dataclass
class StageFrames:
    """A face on a stage over time (see the module docstring)."""

    stage: Usd.Stage
    kind: str
    """``"rig"`` or ``"capture"``."""
    triangles: np.ndarray
    """(T, 3) int64 vertex indices."""
    rest: np.ndarray
    """(V, 3) float64 rest points [stage units]."""
    times: np.ndarray
    """(F,) float64 time codes the animation plays at (empty: not animated)."""
    points_attribute: Usd.Attribute

    @property
    def time_range(self) -> tuple[float, float] | None:
        """(first, last) time code, or ``None`` when nothing is animated."""
        return (float(self.times[0]), float(self.times[-1])) if len(self.times) else None

    def check_time(self, time: float) -> float:
        """``time`` if it lies in :attr:`time_range` (any time for a still stage); ValueError otherwise."""
        time = float(time)
        span = self.time_range
        if not math.isfinite(time):
            raise ValueError(f"time {time}: must be finite")
        if span is None:
            return time
        if not span[0] <= time <= span[1]:
            raise ValueError(f"time {time:g} is outside the stage's time range [{span[0]:g}, {span[1]:g}]")
        return time

    def points_at(self, time: float | None = None) -> np.ndarray:
        """Points (V, 3) float64 at ``time`` (default: the first frame; the rest shape when still)."""
        if time is None:
            time = self.times[0] if len(self.times) else None
        value = self.points_attribute.Get(Usd.TimeCode.Default() if time is None else Usd.TimeCode(float(time)))
        points = self.rest if value is None else np.asarray(value, dtype=np.float64)
        if points.shape != self.rest.shape:
            raise ValueError(
                f"{self.points_attribute.GetPath()}: {len(points)} points at time {time}, "
                f"the rest shape has {len(self.rest)}"
            )
        if not np.isfinite(points).all():
            raise ValueError(f"{self.points_attribute.GetPath()}: non-finite points at time {time}")
        return points

    def __iter__(self):
        """The points (V, 3) at every time code in turn."""
        for time in self.times.tolist():
            yield self.points_at(time)


def is_capture(stage: Usd.Stage) -> bool:
    """True for a stage written by ``warpface track`` (a ``/Capture/Landmarks`` points prim)."""
    expect_instance(stage, Usd.Stage, "stage")
    return bool(stage.GetPrimAtPath(LANDMARKS)) and stage.GetPrimAtPath(LANDMARKS).IsA(UsdGeom.Points)


def open_frames(stage_or_path, *, max_frames: int | None = MAX_FRAMES) -> StageFrames:
    """The moving face of a rig stage or a capture (see the module docstring).

    Raises:
        ValueError, RigError: not a readable rig or capture; a capture without a dense face.
    """
    stage = open_stage(stage_or_path)
    if is_capture(stage):
        return _capture_frames(stage, max_frames)
    from .rig_io import read_rig, rig_prims, stage_meters_per_unit

    rig = read_rig(stage, meters_per_unit=stage_meters_per_unit(stage))
    attribute = rig_prims(stage).skin.GetAttribute(UsdGeom.Tokens.points)
    return StageFrames(
        stage, "rig", rig.mesh.triangles, rig.mesh.points, frame_times(stage, max_frames=max_frames), attribute
    )


def _capture_frames(stage: Usd.Stage, max_frames: int | None) -> StageFrames:
    label = stage.GetRootLayer().realPath or stage.GetRootLayer().identifier
    face = UsdGeom.Mesh(stage.GetPrimAtPath(FACE))
    if not face and stage.GetPrimAtPath(ROOT.AppendChild("Rig")):
        return _solved_capture_frames(stage, label, max_frames)
    if not face:
        raise ValueError(f"{label}: capture has landmarks only (no {FACE} mesh to render)")
    rest = face.GetPrim().GetAttribute("warpFace:restPoints").Get()
    if rest is None or len(rest) == 0:
        raise ValueError(f"{FACE}.warpFace:restPoints: missing")
    rest = np.asarray(rest, dtype=np.float64)
    if rest.ndim != 2 or rest.shape[1] != 3 or not np.isfinite(rest).all():
        raise ValueError(f"{FACE}.warpFace:restPoints: expected finite (V, 3) points")
    counts = np.asarray(face.GetFaceVertexCountsAttr().Get() or [], dtype=np.int64)
    indices = np.asarray(face.GetFaceVertexIndicesAttr().Get() or [], dtype=np.int64)
    if len(counts) == 0 or np.any(counts != 3) or len(indices) != 3 * len(counts):
        raise ValueError(f"{FACE}: expected a triangle mesh (faceVertexCounts all 3, matching faceVertexIndices)")
    if indices.min() < 0 or indices.max() >= len(rest):
        raise ValueError(f"{FACE}.faceVertexIndices: indices outside 0 … {len(rest) - 1}")
    attribute = face.GetPointsAttr()
    times = np.array(attribute.GetTimeSamples(), dtype=np.float64)
    if max_frames is not None and len(times) > max_frames:
        raise ValueError(f"{label}: {len(times)} frames, more than the limit of {max_frames}")
    return StageFrames(stage, "capture", indices.reshape(-1, 3), rest, times, attribute)


def _solved_capture_frames(stage: Usd.Stage, label: str, max_frames: int | None) -> StageFrames:
    """A capture solved by ``warpface track --solve``: its rig's skin moves (points in the value clips)."""
    from .rig_io import read_rig, rig_prims, stage_meters_per_unit

    rig = read_rig(stage, meters_per_unit=stage_meters_per_unit(stage))
    attribute = rig_prims(stage).skin.GetAttribute(UsdGeom.Tokens.points)
    times = np.array(attribute.GetTimeSamples(), dtype=np.float64)
    if max_frames is not None and len(times) > max_frames:
        raise ValueError(f"{label}: {len(times)} frames, more than the limit of {max_frames}")
    return StageFrames(stage, "capture", rig.mesh.triangles, rig.mesh.points, times, attribute)


def capture_problems(stage: Usd.Stage, *, progress: bool = False) -> list[tuple[str, str]]:
    """What is wrong with a capture written by ``warpface track``, as (path, message) pairs; empty if nothing.

    Checks: time metadata (positive rates, a finite range), every value-clip file exists and reads as a
    USD layer, the landmark names match the points, every frame's landmark and face points have the
    right count and are finite, the face's topology is valid.
    """
    expect_instance(stage, Usd.Stage, "stage")
    problems: list[tuple[str, str]] = []
    root = stage.GetRootLayer()
    label = root.realPath or root.identifier
    for name, value in (
        ("timeCodesPerSecond", stage.GetTimeCodesPerSecond()),
        ("framesPerSecond", stage.GetFramesPerSecond()),
    ):
        if not (math.isfinite(value) and value > 0):
            problems.append((label, f"{name} must be > 0, got {value}"))
    start, end = stage.GetStartTimeCode(), stage.GetEndTimeCode()
    if not (math.isfinite(start) and math.isfinite(end)) or end < start:
        problems.append((label, f"invalid time range [{start}, {end}]"))
    clips = Usd.ClipsAPI(stage.GetPrimAtPath(ROOT))
    for asset in clips.GetClipAssetPaths() or []:
        resolved = Sdf.ComputeAssetPathRelativeToLayer(root, asset.path) if not root.anonymous else asset.path
        try:
            open_layer(resolved or asset.path, referenced_by=label)
        except ValueError as exc:
            problems.append((str(ROOT), f"value clip {asset.path}: {exc}"))
    if problems:
        return problems
    landmarks = UsdGeom.Points(stage.GetPrimAtPath(LANDMARKS))
    names = UsdGeom.PrimvarsAPI(landmarks).GetPrimvar("names").Get()
    count = None if names is None else len(names)
    face = None
    try:
        face = _capture_frames(stage, None) if stage.GetPrimAtPath(FACE) else None
    except (ValueError, RigError) as exc:
        problems.append((str(FACE), str(exc)))
    points = landmarks.GetPointsAttr()
    times = points.GetTimeSamples()
    from tqdm import tqdm

    for time in tqdm(times, desc="validate", unit="frame", disable=not progress, leave=False):
        value = points.Get(time)
        if value is None or (count is not None and len(value) != count) or not np.isfinite(np.asarray(value)).all():
            problems.append((str(points.GetPath()), f"time {time:g}: expected {count} finite landmark points"))
            break
        if face is not None:
            try:
                face.points_at(time)
            except ValueError as exc:
                problems.append((str(FACE), str(exc)))
                break
    return problems
