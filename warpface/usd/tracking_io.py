"""Tracked captures as USD: landmarks as time-sampled ``UsdGeom.Points``, the dense face as a
time-sampled ``Mesh``, at the camera's native rate (``timeCodesPerSecond`` = camera fps).

Layout of a capture written to ``capture.usda``::

    capture.usda                      root: stage metadata and the value-clip list on /Capture
    capture_track/static.usdc         sublayer: prims, topology, landmark ids and names, the dense
                                      rest points (``warpFace:restPoints``)
    capture_track/chunk_0000.usdc     time samples of frames 0..29   (value clip 0)
    capture_track/chunk_0001.usdc     time samples of frames 30..59  (value clip 1) ...

Value clips are USD's mechanism for caches split over files: each chunk is consulted for the time
codes it covers (sublayers would not do — the strongest layer with samples wins for *all* times).

Flushing and what an interruption can cost. Frames are queued in memory and flushed as a chunk
every ``chunk_frames`` frames (default 30) or once the oldest queued frame has waited
``flush_seconds`` (default 1 s, checked as each frame arrives), whichever comes first. A flush
writes the chunk through a temporary file and a rename, *then* rewrites the small root layer the
same way to list it; Ctrl-C (SIGINT) is held back until both are done, so the stage on disk always
lists every chunk beside it. Hence:

* Ctrl-C, a camera that disappears, an exception: :meth:`TrackingStageWriter.close` (called by
  the context manager and by :func:`warpface.pipelines.capture.record`) flushes what is queued —
  every frame received is on the stage.
* A hard kill (``kill -9``, power loss): the stage holds every frame up to the last flush; at most
  the frames of the last ``flush_seconds`` (and never more than ``chunk_frames``) are lost.

Nothing is written before the first flush, so a capture that fails before its first frame leaves
no files. Time code of a frame: ``(timestamp − first timestamp) · fps``.

More per-frame data (a solved rig's controls and skin, see :mod:`warpface.pipelines.track_solve`) rides
in the same chunks: ``extra_prims`` authors prims under ``/Capture`` in the static layer and ``channels``
declares the attributes sampled per frame (``add(..., samples=...)``), with the same guarantees.
"""

from __future__ import annotations

import ctypes
import time

import numpy as np
from pxr import Sdf, Usd, UsdGeom, Vt

from .._signals import deferred_interrupts
from .._validate import as_count
from ._files import export_layer_atomically, writable_path

__all__ = ["TrackingStageWriter", "read_tracking", "vec3f_array"]

ROOT = Sdf.Path("/Capture")
LANDMARKS = ROOT.AppendChild("Landmarks")
FACE = ROOT.AppendChild("Face")


def _writes_through_buffer() -> bool:
    """Whether a new ``Vt.Vec3fArray``'s exported buffer is its own storage (checked once, by value)."""
    probe = Vt.Vec3fArray(2)
    ctypes.memmove(np.asarray(probe).ctypes.data, np.arange(6, dtype=np.float32).ctypes.data, 24)
    return tuple(probe[1]) == (3.0, 4.0, 5.0)


_DIRECT_COPY = _writes_through_buffer()


def vec3f_array(points: np.ndarray) -> Vt.Vec3fArray:
    """A new ``Vt.Vec3fArray`` holding ``points`` (V, 3), C-contiguous float32, by one memory copy.

    ``Vt.Vec3fArray.FromNumpy`` converts element by element, an order of magnitude slower for a face
    (benchmarks/README.md, Tracking). A freshly constructed array owns its storage alone (no copy-on-write sharing yet),
    so filling it through the buffer it exports changes no other value; Vt marks that buffer
    read-only, hence the raw copy. Where a Vt build exports a copy instead (checked once at import),
    this falls back to ``FromNumpy``.
    """
    if points.dtype != np.float32 or points.ndim != 2 or points.shape[1] != 3 or not points.flags.c_contiguous:
        raise ValueError(f"points: expected C-contiguous float32 of shape (V, 3), got {points.dtype} {points.shape}")
    if not _DIRECT_COPY or len(points) == 0:
        return Vt.Vec3fArray.FromNumpy(points)
    out = Vt.Vec3fArray(len(points))
    ctypes.memmove(np.asarray(out).ctypes.data, points.ctypes.data, points.nbytes)
    return out


class TrackingStageWriter:
    """Write a landmark stream and the dense face it drives as USD time samples, incrementally.

    Args:
        path: the root stage (``.usda``); chunk and rest layers go to ``<stem>_track/`` beside it.
        landmark_names: names of the landmarks (N).
        fps: the source's native frame rate [1/s]; becomes ``timeCodesPerSecond``/``framesPerSecond``.
        dense_rest: rest points of the dense face [m], shape (V, 3), or ``None`` for landmarks only.
        triangles: dense face triangles, shape (T, 3) (required with ``dense_rest``).
        chunk_frames: flush after this many queued frames.
        flush_seconds: flush once the oldest queued frame has waited this long [s] (wall clock),
            bounding what a hard kill can lose for slow sources.
        extra_prims: optional ``callable(stage)`` authoring more prims under ``/Capture`` in the static
            layer (e.g. a rig with :func:`warpface.usd.write_rig`).
        channels: optional ``{attribute path: Sdf.ValueTypeName}`` of more time-sampled attributes under
            ``/Capture``; their prims must exist (``extra_prims``). A default value authored there is
            cleared (it would hide the chunks' samples).

    Raises:
        ValueError: bad path, shapes, fps or flush settings; non-finite data passed to :meth:`add`.
    """

    def __init__(
        self,
        path,
        landmark_names,
        fps: float,
        *,
        dense_rest=None,
        triangles=None,
        chunk_frames: int = 30,
        flush_seconds: float = 1.0,
        extra_prims=None,
        channels=None,
    ):
        self.path = writable_path(path, (".usda", ".usdc"))
        try:
            self.fps = float(fps)
            self.flush_seconds = float(flush_seconds)
        except (TypeError, ValueError):
            raise TypeError(f"fps and flush_seconds must be numbers, got {fps!r} and {flush_seconds!r}") from None
        if not np.isfinite(self.fps) or self.fps <= 0:
            raise ValueError(f"fps must be > 0, got {fps}")
        if not self.flush_seconds > 0:
            raise ValueError(f"flush_seconds must be > 0, got {flush_seconds}")
        self.names = [str(name) for name in landmark_names]
        if not self.names:
            raise ValueError("landmark_names: need at least one landmark")
        self.chunk_frames = as_count(chunk_frames, "chunk_frames", minimum=1)
        self.folder = self.path.with_name(self.path.stem + "_track")
        self.vertex_count = None
        if dense_rest is not None:
            dense_rest = np.asarray(dense_rest, dtype=np.float32)
            triangles = np.asarray(triangles)
            if dense_rest.ndim != 2 or dense_rest.shape[1] != 3 or not np.all(np.isfinite(dense_rest)):
                raise ValueError("dense_rest: expected finite points of shape (V, 3)")
            if (
                triangles.ndim != 2
                or triangles.shape[1] != 3
                or triangles.min() < 0
                or triangles.max() >= len(dense_rest)
            ):
                raise ValueError("triangles: expected (T, 3) indices into dense_rest")
            self.vertex_count = len(dense_rest)
        self._chunks: list[tuple[str, float]] = []  # (file name, first time code)
        # (time code, landmarks, confidence, (dense points, extent) or None)
        self._pending: list[tuple[float, np.ndarray, np.ndarray, tuple[Vt.Vec3fArray, Vt.Vec3fArray] | None]] = []
        self._first_timestamp: float | None = None
        self._last_time = -np.inf
        self._oldest_pending = 0.0  # time.monotonic() when the first queued frame arrived
        self._root_current = True  # False while a chunk on disk is not yet listed by the root layer
        self.frames_written = 0
        self.channels = {Sdf.Path(str(path)): type_name for path, type_name in (channels or {}).items()}
        for path in self.channels:
            if not path.IsPropertyPath() or not path.HasPrefix(ROOT):
                raise ValueError(f"channels: {path} is not an attribute path under {ROOT}")
        self._pending_samples: list[dict] = []  # per queued frame: {attribute path: value}
        self._static, self._root = self._author_layers(dense_rest, triangles, extra_prims)

    # ------------------------------------------------------------------ public
    def add(
        self,
        timestamp: float,
        landmarks: np.ndarray,
        confidence: np.ndarray,
        dense_points: np.ndarray | None = None,
        *,
        samples: dict | None = None,
    ) -> float:
        """Queue one frame; returns its time code. Missing landmarks (NaN rows, or beyond ±1e6 m) are
        written at their last known position with confidence 0 (USD points cannot be NaN), or at the
        origin until seen; confidences are clipped to [0, 1]. ``samples`` gives this frame's value of
        every declared channel (``{attribute path: value}``, numbers or arrays, all finite).

        Raises:
            ValueError: shapes differ from the first frame, time does not increase, dense points
                or samples are not finite, or samples miss a channel or name an undeclared one.
        """
        try:
            timestamp = float(timestamp)
            landmarks = np.asarray(landmarks, dtype=np.float64)
            confidence = np.asarray(confidence, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(
                f"frame at t={timestamp!r}: timestamp, landmarks and confidence must be numeric ({exc})"
            ) from None
        if not np.isfinite(timestamp):
            raise ValueError(f"frame at t={timestamp}: timestamp is not finite")
        if landmarks.shape != (len(self.names), 3) or confidence.shape != (len(self.names),):
            raise ValueError(f"frame at t={timestamp}: expected {len(self.names)} landmarks, got {landmarks.shape}")
        with np.errstate(invalid="ignore"):
            landmarks = np.where(np.abs(landmarks) <= 1e6, landmarks, np.nan)  # beyond float32 / any camera: missing
        if self._first_timestamp is None:
            self._first_timestamp = float(timestamp)
            self._held = np.zeros((len(self.names), 3))
        time_code = (float(timestamp) - self._first_timestamp) * self.fps
        if not time_code > self._last_time:
            raise ValueError(
                f"frame at t={timestamp}: time must increase (time code {time_code} after {self._last_time})"
            )
        seen = np.all(np.isfinite(landmarks), axis=1)
        self._held[seen] = landmarks[seen]
        confidence = np.where(seen & np.isfinite(confidence), np.clip(confidence, 0.0, 1.0), 0.0)
        if dense_points is not None:
            try:
                with np.errstate(over="ignore"):
                    dense_points = np.asarray(dense_points, dtype=np.float32)
            except (TypeError, ValueError):
                raise ValueError(f"frame at t={timestamp}: dense points must be numeric") from None
            if dense_points.shape != (self.vertex_count, 3):
                raise ValueError(f"frame at t={timestamp}: dense points must have shape ({self.vertex_count}, 3)")
            dense_points = np.ascontiguousarray(dense_points)
            # The extent doubles as the finiteness check: a NaN or ±inf anywhere reaches a min or a max.
            columns = np.ascontiguousarray(
                dense_points.T
            )  # min/max over contiguous rows beat a strided axis-0 reduction
            bounds = np.stack([columns.min(axis=1), columns.max(axis=1)])
            if not np.all(np.isfinite(bounds)):
                raise ValueError(f"frame at t={timestamp}: dense points are not finite; nothing written for it")
            # Copied now: the caller may reuse its buffer (``TrackingAdapter.track_frame(copy=False)``).
            dense_points = (vec3f_array(dense_points), Vt.Vec3fArray.FromNumpy(bounds))
        samples = self._checked_samples(samples, timestamp)
        if not self._pending:
            self._oldest_pending = time.monotonic()
        self._pending_samples.append(samples)
        self._pending.append((time_code, self._held.astype(np.float32), confidence.astype(np.float32), dense_points))
        self._last_time = time_code
        if len(self._pending) >= self.chunk_frames or time.monotonic() - self._oldest_pending >= self.flush_seconds:
            self.flush()
        return time_code

    def _checked_samples(self, samples, timestamp) -> dict:
        given = {Sdf.Path(str(path)): value for path, value in (samples or {}).items()}
        unknown = sorted(str(p) for p in set(given) - set(self.channels))
        missing = sorted(str(p) for p in set(self.channels) - set(given))
        if unknown or missing:
            raise ValueError(
                f"frame at t={timestamp}: samples "
                + (f"name undeclared channels {unknown}" if unknown else f"lack {missing}")
            )
        for path, value in given.items():
            try:
                finite = bool(np.all(np.isfinite(np.asarray(value, dtype=np.float64))))
            except (TypeError, ValueError):
                raise ValueError(f"frame at t={timestamp}: {path} must be numeric") from None
            if not finite:
                raise ValueError(f"frame at t={timestamp}: {path} is not finite; nothing written for the frame")
        return given

    @property
    def frames_queued(self) -> int:
        """Frames received but not yet on disk."""
        return len(self._pending)

    def flush(self) -> None:
        """Write the queued frames as a new chunk layer, then rewrite the root layer to list it.

        Ctrl-C is held until both files are in place. A flush that fails part way (a full disk)
        keeps its frames queued (or the root marked stale) for the next :meth:`flush` or :meth:`close`.
        """
        with deferred_interrupts():
            if self._pending:
                self._write_chunk()
            if not self._root_current:
                self._write_root()
                self._root_current = True
                if len(self._chunks) == 1:
                    self._remove_leftovers()

    def _write_chunk(self) -> None:
        if not self._chunks:
            # The first chunk: a failure (a full disk) must not leave a static layer no stage lists.
            created = not self.folder.exists()
            try:
                self.folder.mkdir(exist_ok=True)
                export_layer_atomically(self._static, self.folder / "static.usdc")
                self._write_chunk_layer()
            except BaseException:
                if not self.path.exists():
                    (self.folder / "static.usdc").unlink(missing_ok=True)
                if created and self.folder.is_dir() and not any(self.folder.iterdir()):
                    self.folder.rmdir()
                raise
            return
        self._write_chunk_layer()

    def _write_chunk_layer(self) -> None:
        layer = Sdf.Layer.CreateAnonymous(".usdc")
        positions = LANDMARKS.AppendProperty(UsdGeom.Tokens.points)
        confidence_path = LANDMARKS.AppendProperty("primvars:confidence")
        face_points = FACE.AppendProperty(UsdGeom.Tokens.points)
        face_extent = FACE.AppendProperty(UsdGeom.Tokens.extent)
        for prim_path in (LANDMARKS, FACE) if self.vertex_count else (LANDMARKS,):
            Sdf.CreatePrimInLayer(layer, prim_path).specifier = Sdf.SpecifierOver
        Sdf.AttributeSpec(layer.GetPrimAtPath(LANDMARKS), UsdGeom.Tokens.points, Sdf.ValueTypeNames.Point3fArray)
        Sdf.AttributeSpec(layer.GetPrimAtPath(LANDMARKS), "primvars:confidence", Sdf.ValueTypeNames.FloatArray)
        if self.vertex_count:
            Sdf.AttributeSpec(layer.GetPrimAtPath(FACE), UsdGeom.Tokens.points, Sdf.ValueTypeNames.Point3fArray)
            Sdf.AttributeSpec(layer.GetPrimAtPath(FACE), UsdGeom.Tokens.extent, Sdf.ValueTypeNames.Float3Array)
        with Sdf.ChangeBlock():
            for time_code, landmarks, confidence, dense in self._pending:
                layer.SetTimeSample(positions, time_code, Vt.Vec3fArray.FromNumpy(landmarks))
                layer.SetTimeSample(confidence_path, time_code, Vt.FloatArray.FromNumpy(confidence))
                if dense is not None:
                    layer.SetTimeSample(face_points, time_code, dense[0])
                    layer.SetTimeSample(face_extent, time_code, dense[1])
        self._write_channels(layer)
        name = f"chunk_{len(self._chunks):04d}.usdc"
        export_layer_atomically(layer, self.folder / name)
        self._root_current = False
        self._chunks.append((name, self._pending[0][0]))
        self.frames_written += len(self._pending)
        self._root.endTimeCode = max(self._pending[-1][0], self._root.startTimeCode)
        self._pending.clear()
        self._pending_samples.clear()

    def _write_channels(self, layer: Sdf.Layer) -> None:
        """The declared channels' samples of the queued frames, into the chunk ``layer``."""
        if not self.channels:
            return
        for path, type_name in self.channels.items():
            prim = Sdf.CreatePrimInLayer(layer, path.GetPrimPath())
            prim.specifier = Sdf.SpecifierOver
            Sdf.AttributeSpec(prim, path.name, type_name)
        with Sdf.ChangeBlock():
            for (time_code, *_), samples in zip(self._pending, self._pending_samples):
                for path, value in samples.items():
                    layer.SetTimeSample(path, time_code, value)

    def _remove_leftovers(self) -> None:
        """Chunks of an earlier capture to this path, which the new root no longer lists, and
        temporaries of a killed one (removed once the new root is in place)."""
        listed = {name for name, _ in self._chunks}
        for stale in [
            *self.folder.glob("chunk_*.usdc"),
            *self.folder.glob(".chunk_*.usdc.*"),
            *self.folder.glob(".static.usdc.*"),
        ]:
            if stale.name not in listed:
                stale.unlink(missing_ok=True)

    def close(self) -> None:
        """Flush what is queued. Safe to call twice. A writer that never received a frame leaves no files."""
        self.flush()

    def __enter__(self) -> "TrackingStageWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ internals
    def _author_layers(self, dense_rest, triangles, extra_prims=None) -> tuple[Sdf.Layer, Sdf.Layer]:
        """The static layer and the root layer, in memory (written at the first flush)."""
        stage = Usd.Stage.CreateInMemory("capture.usda")
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
        stage.SetTimeCodesPerSecond(self.fps)
        stage.SetFramesPerSecond(self.fps)
        stage.SetStartTimeCode(0.0)
        stage.SetEndTimeCode(0.0)
        stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, ROOT).GetPrim())
        points = UsdGeom.Points.Define(stage, LANDMARKS)
        points.CreateIdsAttr(Vt.Int64Array(list(range(len(self.names)))))
        points.CreateWidthsAttr(Vt.FloatArray([0.004]))
        points.SetWidthsInterpolation(UsdGeom.Tokens.constant)
        primvars = UsdGeom.PrimvarsAPI(points)
        primvars.CreatePrimvar("names", Sdf.ValueTypeNames.StringArray, UsdGeom.Tokens.constant).Set(
            Vt.StringArray(self.names)
        )
        primvars.CreatePrimvar("confidence", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex)
        UsdGeom.Imageable(points).CreatePurposeAttr(UsdGeom.Tokens.default_)
        if dense_rest is not None:
            mesh = UsdGeom.Mesh.Define(stage, FACE)
            mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(triangles)))
            mesh.CreateFaceVertexIndicesAttr(
                Vt.IntArray.FromNumpy(np.ascontiguousarray(triangles, dtype=np.int32).ravel())
            )
            mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
            mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
            rest = mesh.GetPrim().CreateAttribute("warpFace:restPoints", Sdf.ValueTypeNames.Point3fArray, custom=True)
            rest.Set(Vt.Vec3fArray.FromNumpy(dense_rest))
        if extra_prims is not None:
            extra_prims(stage)
        for path, type_name in self.channels.items():
            prim = stage.GetPrimAtPath(path.GetPrimPath())
            if not prim:
                raise ValueError(f"channels: no prim at {path.GetPrimPath()} (author it with extra_prims)")
            attribute = prim.GetAttribute(path.name) or prim.CreateAttribute(path.name, type_name, custom=True)
            attribute.ClearDefault()  # a default in this (stronger) layer would hide the chunks' samples
        # The heavy, static data (topology, rest points, names) goes once to a binary layer; the root
        # keeps only metadata and the clip list, so rewriting it after every chunk stays cheap. The
        # root is a stage-free layer: clip edits must not trigger composition (the relative clip
        # paths cannot resolve against an in-memory layer).
        root = Sdf.Layer.CreateAnonymous(".usda")
        for key in (
            "metersPerUnit",
            "upAxis",
            "timeCodesPerSecond",
            "framesPerSecond",
            "startTimeCode",
            "endTimeCode",
            "defaultPrim",
        ):
            root.pseudoRoot.SetInfo(key, stage.GetRootLayer().pseudoRoot.GetInfo(key))
        root.subLayerPaths = [f"./{self.folder.name}/static.usdc"]
        Sdf.CreatePrimInLayer(root, ROOT).specifier = Sdf.SpecifierOver
        static = Sdf.Layer.CreateAnonymous(".usdc")  # owned here: the stage's layer dies with the stage
        static.TransferContent(stage.GetRootLayer())
        return static, root

    def _write_root(self) -> None:
        if self._chunks:
            # Authored at the Sdf level: composing clips on the in-memory stage would try (and fail)
            # to resolve the relative clip paths against an anonymous layer.
            end = self._root.endTimeCode
            # Identity time mapping over the capture; a single pair for a one-frame capture (a
            # second pair at a later time would read back as an extra sample).
            self._root.GetPrimAtPath(ROOT).SetInfo(
                "clips",
                {
                    "default": {
                        "assetPaths": Sdf.AssetPathArray([f"./{self.folder.name}/{name}" for name, _ in self._chunks]),
                        "primPath": str(ROOT),
                        "active": Vt.Vec2dArray(
                            [(start, float(index)) for index, (_, start) in enumerate(self._chunks)]
                        ),
                        "times": Vt.Vec2dArray([(0.0, 0.0), (end, end)] if end > 0 else [(0.0, 0.0)]),
                    }
                },
            )
        export_layer_atomically(self._root, self.path)


def read_tracking(path) -> dict:
    """Read a capture back: ``times`` (F,), ``landmarks`` (F, N, 3), ``confidence`` (F, N), ``names``,
    ``fps`` and, when present, ``dense`` (F, V, 3) — all from the composed stage."""
    from ._files import open_stage

    stage = open_stage(path)
    points = UsdGeom.Points(stage.GetPrimAtPath(LANDMARKS))
    if not points:
        raise ValueError(f"{path}: no {LANDMARKS} points prim; not a warpface capture")
    attribute = points.GetPointsAttr()
    times = np.array(attribute.GetTimeSamples(), dtype=np.float64)
    confidence = UsdGeom.PrimvarsAPI(points).GetPrimvar("confidence")
    names = UsdGeom.PrimvarsAPI(points).GetPrimvar("names")
    if not names or not confidence or names.Get() is None:
        raise ValueError(f"{path}: {LANDMARKS} lacks its 'names' or 'confidence' primvar; not a warpface capture")
    result = {
        "times": times,
        "fps": stage.GetTimeCodesPerSecond(),
        "names": list(names.Get()),
        "landmarks": np.stack([np.asarray(attribute.Get(t)) for t in times]) if len(times) else np.zeros((0, 0, 3)),
        "confidence": np.stack([np.asarray(confidence.Get(t)) for t in times]) if len(times) else np.zeros((0, 0)),
    }
    face = UsdGeom.Mesh(stage.GetPrimAtPath(FACE))
    if face:
        face_points = face.GetPointsAttr()
        result["rest"] = np.asarray(face.GetPrim().GetAttribute("warpFace:restPoints").Get())
        result["dense"] = np.stack([np.asarray(face_points.Get(t)) for t in times]) if len(times) else None
    return result
