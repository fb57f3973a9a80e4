"""Tracking drives the muscles: landmark frames → solved controls → the expression model → USD.

Per frame, :class:`SolvingTracker`

1. maps the source's landmarks into the face's model frame (``camera_to_model``, or a similarity
   fitted on the first frame with ≥ 4 landmarks, which should be neutral, as for the geometric
   :class:`~warpface.tracking.TrackingAdapter`);
2. solves the rig's controls (the muscles, and the jaw's opening, protrusion and slide when the rig
   has a jaw) with a :class:`warpface.solve.Solver` at the landmarks' vertices, warm-started from
   (and smoothed toward) the previous frame, with a rigid head pose;
3. evaluates the expression model (muscles → stretch → bulge → wrinkles) at those controls: the skin;
4. optionally (``residual_transfer``) adds what the solve could not explain: the landmarks' residual
   ``y − pose(x(c))``, taken back into the rig frame and relative to its value when each landmark was
   first measured (so a constant offset — a dot's painted height, a depth bias — does not move the
   face), carried to the dense skin by the geometric sparse → dense transfer.

A frame with fewer than ``min_points`` measured landmarks keeps the previous controls and is flagged
(``skipped``); nothing non-finite is ever returned or written.

On the stage (:class:`SolvedStageLayout`, written by :func:`solved_stage_writer` through the capture
writer's value clips, so Ctrl-C keeps every frame received, controls included)::

    /Capture/Landmarks                          the landmarks, model frame (as a geometric capture)
    /Capture/Rig                                the rig (warpface.usd.write_rig), contractions cleared
    /Capture/Rig/Muscles/<name>.contraction     solved control per frame (time samples)
    /Capture/Rig/<Jaw>.jawOpen, .jawForward,    the jaw's solved controls per frame (time samples; the
        .jawLeft                                jaw prim the rig stage links from the skin)
    /Capture/Rig/Skin.points, .extent           the skin per frame: the baked cache, rig frame
    /Capture/Rig/Skin.warpFace:track:residual   RMS landmark distance of the solve [m] (0 when skipped)
    /Capture/Rig/Skin.warpFace:track:skipped    True: too few landmarks, previous controls kept
    /Capture/Rig/Skin.warpFace:track:headPose   the solved head pose, matrix4d (row vectors:
                                                p_model = p_rig · M), when the pose is solved

:func:`read_solved_capture` reads it back; :func:`warpface.usd.read_animation` and ``read_rig`` work on
it as on any rig stage.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pxr import Sdf, Usd, UsdGeom, Vt

from ..tracking import LandmarkFrame, adapter_for_face, landmark_vertices
from ..tracking.alignment import similarity_fit
from ..usd.jaw_io import JAW_CONTROL_ATTRIBUTES, jaw_prim

__all__ = [
    "SolvedFrame",
    "SolvingTracker",
    "neutral_offsets",
    "SolvedStageLayout",
    "solved_stage_writer",
    "read_solved_capture",
    "RIG_ROOT",
]

RIG_ROOT = "/Capture/Rig"
"""Where a solved capture keeps its rig."""
_RESIDUAL, _SKIPPED, _POSE = "warpFace:track:residual", "warpFace:track:skipped", "warpFace:track:headPose"


@dataclass
class SolvedFrame:
    """One tracked frame's solve."""

    controls: np.ndarray
    """Controls in the solver's order, (C,) float64: the muscles (linear in mesh units, sphincters
    dimensionless), then the jaw's opening [rad], protrusion and slide [mesh units] when solved."""
    skin: np.ndarray
    """Skin points, rig frame [mesh units], (V, 3) float32 (with the residual motion when transferred)."""
    residual_motion: np.ndarray | None
    """The transferred residual motion included in :attr:`skin`, (V, 3) float32, or None."""
    residual: float
    """Weighted RMS distance between the posed model and the measured landmarks [mesh units]; 0 when skipped."""
    skipped: bool
    """Too few landmarks (or no model frame yet): the previous controls were kept."""
    converged: bool
    rotation: np.ndarray
    """Head rotation (3, 3): model-frame point = R (x − origin) + origin + t."""
    translation: np.ndarray
    origin: np.ndarray

    @property
    def head_pose(self) -> np.ndarray:
        """The head pose as a 4×4 matrix for row vectors (``p_model = [x, 1] · M``), USD's convention."""
        matrix = np.eye(4)
        matrix[:3, :3] = self.rotation.T
        matrix[3, :3] = self.origin + self.translation - self.origin @ self.rotation.T
        return matrix


class SolvingTracker:
    """Landmark frames → solved controls → skin with wrinkles, frame after frame (see the module docstring).

    Args:
        rig: a :class:`warpface.FaceRig` with muscles, in the units of the landmarks' model frame.
        landmark_names: the source's landmark names, ``v01234`` style (the vertex each one sits on).
        camera_to_model: 4×4 similarity from the camera frame to the rig's frame; fitted on the first
            frame with ≥ 4 measured landmarks when ``None``.
        residual_transfer: add the solve's residual motion through the geometric transfer.
        pose: solve a rigid head pose with the controls (default on for tracked data).
        smoothness: temporal weight of the solve (pull toward the previous frame's controls).
        min_confidence: landmarks at or below this confidence count as missing.
        neutral_offsets: take the first frame with ≥ 6 landmarks as neutral and subtract, from then on, each
            landmark's offset from its rig vertex there (rig frame, turned with the head pose): a detector whose
            landmarks sit a little off the rig's own (markerless) then does not read that offset as an expression.
        device: Warp device.
        **options: more :class:`warpface.solve.SolveOptions` fields (``l1``, ``symmetry``, ``min_points``,
            ``jaw=False`` to keep the jaw at rest …).
    """

    def __init__(
        self,
        rig,
        landmark_names,
        *,
        camera_to_model=None,
        residual_transfer: bool = False,
        pose: bool = True,
        smoothness: float = 1e-3,
        min_confidence: float = 0.0,
        neutral_offsets: bool = False,
        device=None,
        **options,
    ):
        from ..solve import Solver

        self.rig = rig
        self.names = [str(name) for name in landmark_names]
        self.vertices = landmark_vertices(self.names, rig.mesh.vertex_count)
        if len(np.unique(self.vertices)) != len(self.vertices):
            raise ValueError("landmark_names: two landmarks sit on the same vertex")
        self.solver = Solver(rig, self.vertices, pose=pose, smoothness=smoothness, device=device, **options)
        self.control_names = list(self.solver.names)
        _ = self.solver.model  # built now (≈ 0.2 s), not inside the first frame
        self.min_confidence = float(min_confidence)
        self.neutral_offsets = bool(neutral_offsets)
        self.offsets: np.ndarray | None = None
        """Per-landmark offsets from the neutral frame, (N, 3) rig frame, with ``neutral_offsets``."""
        self.camera_to_model = None if camera_to_model is None else np.array(camera_to_model, dtype=np.float64)
        if self.camera_to_model is not None and (
            self.camera_to_model.shape != (4, 4) or not np.all(np.isfinite(self.camera_to_model))
        ):
            raise ValueError("camera_to_model: expected a finite 4×4 matrix")
        self.rest = np.asarray(rig.mesh.points, dtype=np.float64)
        self.transfer = None
        if residual_transfer:
            self.transfer = adapter_for_face(self.rest, self.names, camera_to_model=np.eye(4), device=device)
            self.transfer.bind(self.names)
        self.last: SolvedFrame | None = None
        self._counts = {"frames": 0, "skipped": 0, "not_converged": 0, "residual": 0.0}
        self._skin = np.asarray(rig.mesh.points, dtype=np.float32)

    @property
    def model(self):
        """The rig's expression model that makes the skin."""
        return self.solver.model

    def track(self, source):
        """Yield ``(frame, skin (V, 3) float32)`` for every frame of ``source``; :attr:`last` holds the solve."""
        order = _selection(source.landmark_names, self.names)
        for frame in source.frames():
            yield frame, self.track_frame(frame, order).skin

    def track_frame(self, frame: LandmarkFrame, order: np.ndarray | None = None) -> SolvedFrame:
        """Solve one frame (landmarks in the camera frame, in :attr:`names` order unless ``order`` selects them)."""
        points = np.asarray(frame.points, dtype=np.float64)
        confidence = np.asarray(frame.confidence, dtype=np.float64)
        if order is not None:
            points, confidence = points[order], confidence[order]
        if points.shape != (len(self.names), 3) or confidence.shape != (len(self.names),):
            raise ValueError(f"frame {frame.index}: expected {len(self.names)} landmarks, got {points.shape}")
        with np.errstate(invalid="ignore"):
            valid = (
                np.all(np.isfinite(points), axis=1)
                & np.isfinite(confidence)
                & (confidence > self.min_confidence)
                & np.all(np.abs(points) < 1e6, axis=1)
            )
        if self.camera_to_model is None and valid.sum() >= 4:
            scale, rotation, translation, _ = similarity_fit(points[valid], self.rest[self.vertices][valid])
            self.camera_to_model = np.eye(4)
            self.camera_to_model[:3, :3], self.camera_to_model[:3, 3] = scale * rotation, translation
        if self.camera_to_model is None:
            targets = np.full_like(points, np.nan)  # no model frame yet: a skipped frame
        else:
            targets = np.where(
                valid[:, None], points @ self.camera_to_model[:3, :3].T + self.camera_to_model[:3, 3], np.nan
            )
        weights = np.where(valid, np.clip(confidence, 0.0, 1.0), 0.0)
        if self.neutral_offsets and self.offsets is None and valid.sum() >= 6:
            self.offsets = neutral_offsets(self.rest[self.vertices], targets, weights, self.solver.origin)
        if self.offsets is not None:
            targets = targets - self.offsets @ self.solver.rotation.T
        fit = self.solver.solve(targets, weights=weights if valid.any() else None)
        return self._finish(frame, fit, targets)

    def _finish(self, frame: LandmarkFrame, fit, targets: np.ndarray) -> SolvedFrame:
        """The skin, the residual motion and the counts of one solved frame (``targets``: rig frame)."""
        if not fit.skipped or self.last is None:
            self._skin = np.asarray(fit.points, dtype=np.float32)
        skin, motion = self._skin, None
        if self.transfer is not None:
            motion = self._residual_motion(frame, fit, targets)
            skin = skin + motion
        if not np.all(np.isfinite(skin)):
            raise ValueError(f"frame {frame.index}: the solved skin is not finite")
        self.last = SolvedFrame(
            controls=fit.vector.copy(),
            skin=skin,
            residual_motion=motion,
            residual=float(fit.residual),
            skipped=fit.skipped,
            converged=fit.converged,
            rotation=fit.rotation,
            translation=fit.translation,
            origin=fit.origin,
        )
        counts = self._counts
        counts["frames"] += 1
        counts["skipped"] += int(fit.skipped)
        counts["not_converged"] += int(not fit.skipped and not fit.converged)
        counts["residual"] += 0.0 if fit.skipped else float(fit.residual)
        return self.last

    @property
    def summary(self) -> dict:
        """Frames solved, ``skipped``, ``not_converged`` and the ``mean_residual`` [mesh units] of the solved ones."""
        counts = dict(self._counts)
        solved = counts["frames"] - counts["skipped"]
        counts["mean_residual"] = counts.pop("residual") / solved if solved else 0.0
        return counts

    def _residual_motion(self, frame: LandmarkFrame, fit, targets: np.ndarray) -> np.ndarray:
        """What the solve left at the landmarks, rig frame, carried to the skin: (V, 3) float32."""
        model = self._skin.astype(np.float64)[self.vertices]
        posed = (model - fit.origin) @ fit.rotation.T + fit.origin + fit.translation
        residual = (targets - posed) @ fit.rotation  # back into the rig frame (R⁻¹ = Rᵀ, row vectors)
        measured = np.all(np.isfinite(residual), axis=1)
        confidence = measured.astype(np.float64)
        local = LandmarkFrame(
            timestamp=frame.timestamp,
            points=np.where(measured[:, None], self.rest[self.vertices] + residual, np.nan),
            confidence=confidence,
            index=frame.index,
        )
        self.transfer.track_frame(local, copy=False)
        return self.transfer.displacements.numpy().copy()


def neutral_offsets(rest, targets, weights, origin) -> np.ndarray:
    """Each target's offset from its rest point under the best rigid fit (rest → targets), turned back into the
    rest frame: (N, 3), 0 for a target without weight (NaN rows)."""
    from ..solve.pose import rigid_alignment

    usable = np.all(np.isfinite(targets), axis=1) & (weights > 0)
    rotation, translation = rigid_alignment(
        rest, np.where(usable[:, None], targets, 0.0), np.where(usable, weights, 0.0), origin
    )
    posed = (rest - origin) @ rotation.T + origin + translation
    return np.where(usable[:, None], (np.where(usable[:, None], targets, posed) - posed) @ rotation, 0.0)


def _selection(source_names, names) -> np.ndarray:
    """Indices of ``names`` in the source's landmarks."""
    where = {str(name): i for i, name in enumerate(source_names)}
    missing = [name for name in names if name not in where]
    if missing:
        raise ValueError(f"the source lacks landmarks {missing[:5]}")
    return np.array([where[name] for name in names], dtype=np.int64)


@dataclass(frozen=True)
class SolvedStageLayout:
    """Attribute paths of a solved capture (see the module docstring)."""

    skin: Sdf.Path
    controls: tuple
    """Attribute paths in control order: each muscle's ``contraction``, the jaw prim's ``jawOpen`` … (a
    control without an attribute on the stage is refused when writing)."""
    pose: bool

    @property
    def channels(self) -> dict:
        """The capture writer's per-frame channels: ``{attribute path: Sdf.ValueTypeName}``."""
        types = Sdf.ValueTypeNames
        channels = {path: types.Double for path in self.controls}
        channels[self.skin.AppendProperty(UsdGeom.Tokens.points)] = types.Point3fArray
        channels[self.skin.AppendProperty(UsdGeom.Tokens.extent)] = types.Float3Array
        channels[self.skin.AppendProperty(_RESIDUAL)] = types.Double
        channels[self.skin.AppendProperty(_SKIPPED)] = types.Bool
        if self.pose:
            channels[self.skin.AppendProperty(_POSE)] = types.Matrix4d
        return channels

    def samples(self, solved: SolvedFrame, skin: np.ndarray) -> dict:
        """One frame's values of :attr:`channels` (``skin``: the points written, (V, 3))."""
        from ..usd.tracking_io import vec3f_array

        skin = np.ascontiguousarray(skin, dtype=np.float32)
        values = {path: float(value) for path, value in zip(self.controls, solved.controls)}
        values[self.skin.AppendProperty(UsdGeom.Tokens.points)] = vec3f_array(skin)
        values[self.skin.AppendProperty(UsdGeom.Tokens.extent)] = Vt.Vec3fArray.FromNumpy(
            np.stack([skin.min(axis=0), skin.max(axis=0)])
        )
        values[self.skin.AppendProperty(_RESIDUAL)] = float(solved.residual)
        values[self.skin.AppendProperty(_SKIPPED)] = bool(solved.skipped)
        if self.pose:
            values[self.skin.AppendProperty(_POSE)] = _matrix(solved.head_pose)
        return values


def _matrix(array: np.ndarray):
    from pxr import Gf

    return Gf.Matrix4d(*map(float, np.asarray(array, dtype=np.float64).ravel()))


def solved_stage_writer(
    path, tracker: SolvingTracker, fps: float, *, chunk_frames: int = 30, flush_seconds: float = 1.0
):
    """A :class:`~warpface.usd.tracking_io.TrackingStageWriter` for ``tracker``'s captures and its layout.

    Returns ``(writer, layout)``; write a frame with
    ``writer.add(t, landmarks, confidence, samples=layout.samples(tracker.last, skin))``
    (:func:`warpface.pipelines.capture.record` does, given ``samples=``).
    """
    from ..usd import write_rig
    from ..usd.tracking_io import TrackingStageWriter

    rig = tracker.rig
    root = Sdf.Path(RIG_ROOT)
    paths = _control_attributes(rig, root)
    unplaced = [name for name in tracker.control_names if name not in paths]
    if unplaced:  # every control must land on an attribute, or the stage would silently lose it
        raise ValueError(f"controls {unplaced[:5]} have no muscle or jaw prim on the stage; cannot write them")
    controls = tuple(paths[name] for name in tracker.control_names)
    layout = SolvedStageLayout(skin=root.AppendChild("Skin"), controls=controls, pose=tracker.solver.options.pose)
    writer = TrackingStageWriter(
        path,
        tracker.names,
        fps,
        chunk_frames=chunk_frames,
        flush_seconds=flush_seconds,
        extra_prims=lambda stage: write_rig(stage, rig, root_path=RIG_ROOT, fps=fps),
        channels=layout.channels,
    )
    return writer, layout


def _control_attributes(rig, root: Sdf.Path) -> dict:
    """``{control name: attribute path}`` as :func:`warpface.usd.write_rig` authors ``rig`` under ``root``:
    each muscle's ``contraction`` and, with a jaw, the jaw prim's control attributes."""
    from ..usd import rig_prims, write_rig

    stage = Usd.Stage.CreateInMemory()
    write_rig(stage, rig, root_path=str(root))
    prims = rig_prims(stage)
    paths = {
        name: prim.GetPath().AppendProperty("contraction") for name, prim in zip(prims.muscle_names, prims.muscles)
    }
    jaw = jaw_prim(stage, prims.skin)
    if jaw is not None:
        paths.update(
            {name: jaw.GetPath().AppendProperty(attribute) for name, attribute in JAW_CONTROL_ATTRIBUTES.items()}
        )
    return paths


def read_solved_capture(path) -> dict:
    """Read a solved capture: ``times`` (F,), ``controls`` (F, C), ``control_names`` (the muscles, then the
    jaw's when the capture solved them), ``skin`` (F, V, 3),
    ``residual`` (F,), ``skipped`` (F,) and, when solved, ``head_pose`` (F, 4, 4); plus what
    :func:`~warpface.usd.tracking_io.read_tracking` returns (``landmarks``, ``confidence``, ``fps`` …)."""
    from ..usd import open_stage, rig_prims
    from ..usd.tracking_io import read_tracking

    result = read_tracking(path)
    stage = open_stage(path)
    prims = rig_prims(stage)
    times = result["times"]
    contraction = [Usd.AttributeQuery(p.GetAttribute("contraction")) for p in prims.muscles]
    skin = prims.skin
    names = list(prims.muscle_names)
    jaw = jaw_prim(stage, skin)
    if jaw is not None:  # the jaw's controls, when the capture solved them (time samples)
        solved = [(name, jaw.GetAttribute(attribute)) for name, attribute in JAW_CONTROL_ATTRIBUTES.items()]
        if all(attribute and attribute.GetNumTimeSamples() > 0 for _, attribute in solved):
            names += [name for name, _ in solved]
            contraction += [Usd.AttributeQuery(attribute) for _, attribute in solved]
    result["control_names"] = names
    result["controls"] = np.array([[q.Get(t) for q in contraction] for t in times], dtype=np.float64).reshape(
        len(times), -1
    )
    points = skin.GetAttribute(UsdGeom.Tokens.points)
    result["skin"] = np.stack([np.asarray(points.Get(t)) for t in times]) if len(times) else np.zeros((0, 0, 3))
    result["residual"] = np.array([skin.GetAttribute(_RESIDUAL).Get(t) for t in times], dtype=np.float64)
    result["skipped"] = np.array([bool(skin.GetAttribute(_SKIPPED).Get(t)) for t in times], dtype=bool)
    pose = skin.GetAttribute(_POSE)
    if pose and pose.HasValue():
        result["head_pose"] = np.array([np.array(pose.Get(t)) for t in times]).reshape(len(times), 4, 4)
    return result
