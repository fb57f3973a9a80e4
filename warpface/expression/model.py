"""``ExpressionModel``: the per-vertex expression pipeline of SPEC §1 on a Warp device."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
import warp as wp

from ..kernels_surface import triangle_area_vectors
from ..mesh import FaceMesh
from .jaw import JAW_CONTROL_NAMES, Jaw
from .kernels import (MuscleEntry, WrinkleEntry, apply_jaw_and_muscles, apply_muscles, apply_wrinkles, stretch_and_bulge,
                      triangle_stretch)
from .muscles import LinearMuscle, Muscle, SphincterMuscle, muscle_weights
from .tissue import tissue_response
from .thickness import validate_thickness
from .wrinkles import Wrinkle, wrinkle_shapes

__all__ = ["ExpressionModel", "ExpressionStages"]

_MAX_LAUNCH_THREADS = (1 << 31) - 1
"""Kernels index flat frames × elements arrays with 32-bit thread indices."""

_MAX_BATCH_VERTICES = 1 << 22
"""On CUDA a batched call processes frames in chunks of at most this many frame·vertices (bounded
memory). On the CPU, where kernels run serially, a chunk is one frame: its working set stays in cache
(64 frames of the 9.4k-vertex face: 0.65 ms/frame one at a time, 0.74 in chunks of 2–8, 1.05 in one chunk)."""


@dataclass(frozen=True)
class ExpressionStages:
    """Intermediate results of one frame (all numpy, float32). Also indexable: ``stages["bulge"]``."""

    muscle: np.ndarray
    """After muscles, x1, shape (V, 3)."""
    stretch: np.ndarray
    """Stretch ratio r of x1 against rest, shape (V,)."""
    bulge: np.ndarray
    """After the volume-preserving bulge, x2, shape (V, 3)."""
    final: np.ndarray
    """After wrinkles, x3, shape (V, 3)."""

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in ("muscle", "stretch", "bulge", "final"):
            raise KeyError(name)
        return getattr(self, name)


class _FrameBuffers:
    """Device work arrays for ``frames`` frames at once, flat frame after frame (allocated once, reused)."""

    def __init__(self, frames: int, vertex_count: int, triangle_count: int, muscle_count: int, wrinkle_count: int, device):
        self.frames = frames
        self.device = device
        self.muscle_width = max(muscle_count, 1)
        self.wrinkle_width = max(wrinkle_count, 1)
        self.contraction = wp.zeros(frames * self.muscle_width, dtype=wp.float32, device=device)
        self.depth = wp.zeros(frames * self.wrinkle_width, dtype=wp.float32, device=device)
        self.muscle_points = wp.empty(frames * vertex_count, dtype=wp.vec3, device=device)
        self.area_vectors = wp.empty(frames * triangle_count, dtype=wp.vec3, device=device)
        self.stretch_terms = wp.empty(frames * triangle_count, dtype=wp.vec4, device=device)
        self.stretch = wp.empty(frames * vertex_count, dtype=wp.float32, device=device)
        self.bulge_points = wp.empty(frames * vertex_count, dtype=wp.vec3, device=device)
        self.final_points = wp.empty(frames * vertex_count, dtype=wp.vec3, device=device)
        self.launches: list[wp.Launch] = []
        """The frame's kernel launches, recorded once (CPU: replayed without re-packing arguments)."""
        self.graph = None
        """The same sequence captured as a CUDA graph (CUDA only)."""
        # Controls are written on the host: on the CPU straight into the kernels' arrays (numpy views
        # share their memory), on CUDA into pinned staging arrays copied up before each launch.
        staging = device.is_cuda
        self._control_pairs = [
            (array, wp.zeros(array.shape, dtype=wp.float32, device="cpu", pinned=True) if staging else array, width)
            for array, width in ((self.contraction, self.muscle_width), (self.depth, self.wrinkle_width))
        ]
        self._control_views = [host.numpy().reshape(frames, width) for _, host, width in self._control_pairs]
        self._host_views: dict[int, np.ndarray] = {}
        """Zero-copy numpy views of CPU buffers (the read-back copies out of them)."""

    def upload_controls(self, contraction: np.ndarray, depth: np.ndarray) -> None:
        """Write (count, M) contractions and (count, W) depths into the first frames; later frames get 0."""
        for view, values in zip(self._control_views, (contraction, depth)):
            view[: values.shape[0], : values.shape[1]] = values
            view[values.shape[0]:] = 0.0
        for array, host, _ in self._control_pairs:
            if host is not array:
                wp.copy(array, host)

    def read_frames(self, array: wp.array, count: int, out: np.ndarray | None = None) -> np.ndarray:
        """Copy the first ``count`` frames of a flat per-frame array to the host.

        Returns ``out`` (or a new array) of shape (count, elements) for float32 arrays or
        (count, elements, 3) for vec3 arrays. On CUDA the device-to-host copy lands in ``out``
        directly (no second copy).
        """
        per_frame = array.shape[0] // self.frames
        inner = (3,) if array.dtype == wp.vec3 else ()
        if out is None:
            out = np.empty((count, per_frame) + inner, dtype=np.float32)
        if self.device.is_cpu:
            view = self._host_views.get(id(array))
            if view is None:
                view = self._host_views[id(array)] = array.numpy()
            out[...] = view[: count * per_frame].reshape(out.shape)
        else:
            target = wp.array(out.reshape((count * per_frame,) + inner), dtype=array.dtype, device="cpu", copy=False)
            wp.copy(target, array, count=count * per_frame)
            wp.synchronize_device(self.device)
        return out


class ExpressionModel:
    """Muscles → stretch → bulge → wrinkles, per vertex, from the rest mesh every frame (never cumulative).

    Everything that depends only on the rig (muscle weight fields, wrinkle distances) is evaluated
    once here in float64; a frame is then five kernel launches over vertices and triangles. On CUDA
    the single-frame sequence is captured once as a graph and replayed.

    Args:
        mesh: the rest surface.
        muscles: linear and sphincter muscles; their order is the contraction order.
        wrinkles: wrinkle furrows; their order is the depth order.
        thickness: subcutaneous thickness ``h`` [mesh units]: a scalar or shape (V,), ≥ 0.
        device: Warp device (default: Warp's preferred device).
        jaw: optional :class:`~warpface.expression.Jaw`, applied before the muscles (SPEC §6.2); its
            controls :data:`~warpface.expression.JAW_CONTROL_NAMES` follow the muscles in the control
            vector (:attr:`control_names`).

    Raises:
        ValueError: duplicate muscle or wrinkle names, wrong thickness, wrong item types.
    """

    def __init__(
        self,
        mesh: FaceMesh,
        muscles: Sequence[Muscle] = (),
        wrinkles: Sequence[Wrinkle] = (),
        thickness: float | np.ndarray = 0.0,
        device=None,
        *,
        jaw: Jaw | None = None,
    ):
        if not isinstance(mesh, FaceMesh):
            raise ValueError(f"mesh: expected a FaceMesh, got {type(mesh).__name__}")
        self.mesh = mesh
        self.muscles = list(muscles)
        self.wrinkles = list(wrinkles)
        for index, muscle in enumerate(self.muscles):
            if not isinstance(muscle, (LinearMuscle, SphincterMuscle)):
                raise ValueError(f"muscles[{index}]: expected LinearMuscle or SphincterMuscle, got {type(muscle).__name__}")
        for index, wrinkle in enumerate(self.wrinkles):
            if not isinstance(wrinkle, Wrinkle):
                raise ValueError(f"wrinkles[{index}]: expected Wrinkle, got {type(wrinkle).__name__}")
        self.muscle_names = _unique_names([m.name for m in self.muscles], "muscle")
        self.wrinkle_names = _unique_names([w.name for w in self.wrinkles], "wrinkle")
        if jaw is not None:
            if not isinstance(jaw, Jaw):
                raise ValueError(f"jaw: expected a Jaw, got {type(jaw).__name__}")
            jaw.check_vertex_count(mesh.vertex_count)
        self.jaw = jaw
        self.control_names = _unique_names(self.muscle_names + (list(JAW_CONTROL_NAMES) if jaw is not None else []), "control")
        """Muscle names, then the jaw's controls when there is a jaw: the order of a control vector."""
        self.thickness = validate_thickness(thickness, mesh.vertex_count)
        self.device = wp.get_device(device)

        self._mesh_buffers = mesh.device_buffers(self.device)
        weights = muscle_weights(mesh.points, self.muscles, self.device)
        if any(m.sliding > 0.0 or m.bunching > 0.0 or m.thickening > 0.0 for m in self.muscles):
            normals = mesh.vertex_normals(device=self.device)
            weights = tissue_response(mesh.points, mesh.triangles, normals, self.thickness, self.muscles, weights)
        shapes = wrinkle_shapes(mesh.points, self.wrinkles, self.device)
        self.muscle_entry_count = int(len(weights.muscle))
        self.wrinkle_entry_count = int(len(shapes.wrinkle))
        device_ = self.device
        self._muscle_offsets = wp.array(weights.offsets, dtype=wp.int32, device=device_)
        self._muscle_entries = _entry_array(MuscleEntry, device_, muscle=weights.muscle, weight=weights.weight.reshape(-1, 3))
        self._wrinkle_offsets = wp.array(shapes.offsets, dtype=wp.int32, device=device_)
        wrinkle_kr = np.array([w.kr for w in self.wrinkles], dtype=np.float32)
        self._wrinkle_entries = _entry_array(WrinkleEntry, device_, wrinkle=shapes.wrinkle, shape=shapes.shape, kr=wrinkle_kr[shapes.wrinkle])
        counted = np.bincount(mesh.triangles[~mesh.degenerate_triangles].ravel(), minlength=mesh.vertex_count)
        self._counts = wp.array(counted.astype(np.float32), dtype=wp.float32, device=device_)
        self._thickness = wp.array(self.thickness.astype(np.float32), dtype=wp.float32, device=device_)
        self.default_depths = np.array([w.depth for w in self.wrinkles], dtype=np.float64)
        if jaw is not None:
            self._jaw_weight = wp.array(jaw.weights.astype(np.float32), dtype=wp.float32, device=device_)
        self._buffers: dict[int, _FrameBuffers] = {}
        self._single = self._frame_buffers(1)

    @classmethod
    def from_rig(cls, rig, device=None) -> "ExpressionModel":
        """Build from a :class:`warpface.FaceRig` (mesh, muscles, wrinkles, thickness)."""
        return cls(rig.mesh, rig.muscles, rig.wrinkles, rig.thickness, device=device, jaw=getattr(rig, "jaw", None))

    # ------------------------------------------------------------------ controls
    def contraction_vector(self, contractions) -> np.ndarray:
        """Controls as an array in :attr:`control_names` order, shape (M,) or (M + 3,) with a jaw, float64.

        ``contractions`` is a mapping ``{muscle or jaw control name: value}`` (absent ones are 0), a
        sequence in control order, or ``None`` (all zero). Unknown names and non-finite values raise
        ValueError.
        """
        return _control_vector(contractions, self.control_names, np.zeros(len(self.control_names)), "contraction", "control")

    def depth_vector(self, depths) -> np.ndarray:
        """Wrinkle depths ``k_d`` in wrinkle order, shape (W,); ``None`` or absent names keep each wrinkle's own depth."""
        return _control_vector(depths, self.wrinkle_names, self.default_depths, "wrinkle depth", "wrinkle")

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, contractions=None, *, wrinkle_depths=None, stages: bool = False):
        """Deformed positions for one frame.

        Args:
            contractions: ``{name: K}`` or an array in muscle order (see :meth:`contraction_vector`).
            wrinkle_depths: optional per-frame ``k_d`` overrides, ``{name: k_d}`` or an array.
            stages: return :class:`ExpressionStages` (muscle, stretch, bulge, final) instead.

        Returns:
            Final positions, shape (V, 3), float32 — or the stages.
        """
        buffers = self._single
        buffers.upload_controls(self.contraction_vector(contractions)[None], self.depth_vector(wrinkle_depths)[None])
        if self.device.is_cuda:
            if buffers.graph is None:
                with wp.ScopedCapture(device=self.device) as capture:
                    self._launch(buffers)
                buffers.graph = capture.graph
            wp.capture_launch(buffers.graph)
        else:
            self._launch(buffers)
        if stages:
            return ExpressionStages(
                muscle=buffers.read_frames(buffers.muscle_points, 1)[0],
                stretch=buffers.read_frames(buffers.stretch, 1)[0],
                bulge=buffers.read_frames(buffers.bulge_points, 1)[0],
                final=buffers.read_frames(buffers.final_points, 1)[0],
            )
        return buffers.read_frames(buffers.final_points, 1)[0]

    def evaluate_batch(
        self, contractions, *, wrinkle_depths=None, progress: bool = False, frames_per_launch: int | None = None
    ) -> np.ndarray:
        """Deformed positions for many frames at once.

        Args:
            contractions: shape (F, M) in muscle order, or a sequence of F mappings.
            wrinkle_depths: ``None``, shape (F, W), or a sequence of F mappings.
            progress: show a progress bar over the frames.
            frames_per_launch: frames evaluated by one launch of the kernels; default 1 on the CPU
                (cache-friendly) and as many as fit in 2²² frame·vertices on CUDA.

        Returns:
            Positions, shape (F, V, 3), float32.
        """
        elements = max(self.mesh.vertex_count, self.mesh.triangle_count, 1)
        if frames_per_launch is None:
            chunk = 1 if self.device.is_cpu else _MAX_BATCH_VERTICES // max(self.mesh.vertex_count, 1)
        elif isinstance(frames_per_launch, (int, np.integer)) and frames_per_launch >= 1:
            chunk = int(frames_per_launch)
            if chunk * elements > _MAX_LAUNCH_THREADS:
                raise ValueError(
                    f"frames_per_launch: {chunk} frames × {elements:,} elements exceeds one launch's "
                    f"{_MAX_LAUNCH_THREADS:,} threads; use at most {_MAX_LAUNCH_THREADS // elements}"
                )
        else:
            raise ValueError(f"frames_per_launch: expected a positive integer, got {frames_per_launch!r}")
        controls = self._frame_controls(contractions, self.contraction_vector, len(self.control_names), "contractions")
        frame_count = len(controls)
        if wrinkle_depths is None:
            depths = np.tile(self.default_depths, (frame_count, 1))
        else:
            depths = self._frame_controls(wrinkle_depths, self.depth_vector, len(self.wrinkles), "wrinkle_depths")
            if len(depths) != frame_count:
                raise ValueError(f"wrinkle_depths: {len(depths)} frames, contractions have {frame_count}")
        chunk = max(1, min(frame_count, chunk))
        buffers = self._frame_buffers(chunk)
        result = np.empty((frame_count, self.mesh.vertex_count, 3), dtype=np.float32)
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=frame_count, desc="expression frames", unit="frame")
        for start in range(0, frame_count, chunk):
            stop = min(start + chunk, frame_count)
            count = stop - start
            buffers.upload_controls(controls[start:stop], depths[start:stop])
            self._launch(buffers)
            buffers.read_frames(buffers.final_points, count, out=result[start:stop])
            if bar is not None:
                bar.update(count)
        if bar is not None:
            bar.close()
        return result

    # ------------------------------------------------------------------ internals
    def _frame_buffers(self, frames: int) -> _FrameBuffers:
        if frames not in self._buffers:
            self._buffers[frames] = _FrameBuffers(
                frames, self.mesh.vertex_count, self.mesh.triangle_count, len(self.control_names), len(self.wrinkles), self.device
            )
        return self._buffers[frames]

    def _launch(self, buffers: _FrameBuffers) -> None:
        """Run the frame's five kernels over all of ``buffers``' frames (recorded on first use)."""
        if not buffers.launches:
            buffers.launches = self._record_launches(buffers)
        for launch in buffers.launches:
            launch.launch()

    def _record_launches(self, buffers: _FrameBuffers) -> list:
        mesh = self._mesh_buffers
        frames, vertex_count, triangle_count = buffers.frames, self.mesh.vertex_count, self.mesh.triangle_count
        vertices, triangles = frames * vertex_count, frames * triangle_count
        counts = [vertex_count, triangle_count]
        device = self.device

        def record(kernel, dim, inputs, outputs):
            return wp.launch(kernel, dim=dim, inputs=inputs, outputs=outputs, device=device, record_cmd=True)

        if self.jaw is None:
            first = record(apply_muscles, vertices,
                           [mesh.rest_points, self._muscle_offsets, self._muscle_entries, buffers.contraction,
                            buffers.muscle_width, vertex_count],
                           [buffers.muscle_points])
        else:
            jaw = self.jaw
            first = record(apply_jaw_and_muscles, vertices,
                           [mesh.rest_points, self._jaw_weight, wp.vec3(*jaw.pivot), wp.vec3(*jaw.axis),
                            wp.vec3(*jaw.forward), self._muscle_offsets, self._muscle_entries, buffers.contraction,
                            buffers.muscle_width, len(self.muscles), vertex_count],
                           [buffers.muscle_points])
        return [
            first,
            record(triangle_stretch, triangles,
                   [buffers.muscle_points, mesh.triangles, mesh.triangle_weight, mesh.rest_area_lengths, *counts],
                   [buffers.stretch_terms]),
            record(stretch_and_bulge, vertices,
                   [buffers.muscle_points, buffers.stretch_terms, self._counts,
                    mesh.adjacency_offsets, mesh.adjacency_triangles, self._thickness, *counts],
                   [buffers.stretch, buffers.bulge_points]),
            record(triangle_area_vectors, triangles,
                   [buffers.bulge_points, mesh.triangles, mesh.triangle_weight, *counts], [buffers.area_vectors]),
            record(apply_wrinkles, vertices,
                   [buffers.bulge_points, buffers.area_vectors, mesh.adjacency_offsets, mesh.adjacency_triangles,
                    buffers.stretch, self._wrinkle_offsets, self._wrinkle_entries,
                    buffers.depth, buffers.wrinkle_width, *counts],
                   [buffers.final_points]),
        ]

    @staticmethod
    def _frame_controls(values, to_vector, width: int, label: str) -> np.ndarray:
        if isinstance(values, np.ndarray) or (isinstance(values, Sequence) and values and not isinstance(values[0], Mapping)):
            array = np.asarray(values, dtype=np.float64)
            if array.ndim != 2 or array.shape[1] != width:
                raise ValueError(f"{label}: expected shape (frames, {width}), got {array.shape}")
            return np.stack([to_vector(row) for row in array]) if len(array) else array
        if isinstance(values, Sequence):
            return np.stack([to_vector(row) for row in values]) if values else np.zeros((0, width))
        raise ValueError(f"{label}: expected an array (frames, {width}) or a sequence of mappings")


def _unique_names(names: list[str], kind: str) -> list[str]:
    seen = set()
    for name in names:
        if name in seen:
            raise ValueError(f"duplicate {kind} name {name!r}")
        seen.add(name)
    return names


def _control_vector(values, names: list[str], default: np.ndarray, label: str, kind: str) -> np.ndarray:
    vector = np.array(default, dtype=np.float64)
    if values is None:
        return vector
    if isinstance(values, Mapping):
        index = {name: i for i, name in enumerate(names)}
        for name, value in values.items():
            if name not in index:
                raise ValueError(f"{label}: unknown {kind} name {name!r} (known: {', '.join(names) or 'none'})")
            number = float(value)
            if not np.isfinite(number):
                raise ValueError(f"{label} for {kind} {name!r}: non-finite value {number}")
            vector[index[name]] = number
        return vector
    array = np.asarray(values, dtype=np.float64)
    if array.shape != (len(names),):
        raise ValueError(f"{label}s: expected {len(names)} values in {kind} order, got shape {array.shape}")
    bad = np.flatnonzero(~np.isfinite(array))
    if len(bad):
        raise ValueError(f"{label} for {kind} {names[bad[0]]!r}: non-finite value {array[bad[0]]}")
    return array


def _entry_array(struct, device, **fields: np.ndarray) -> wp.array:
    """A Warp array of ``struct`` entries from per-field numpy columns (one unused zero entry if empty)."""
    count = len(next(iter(fields.values())))
    packed = np.zeros(max(count, 1), dtype=struct.numpy_dtype())
    for name, values in fields.items():
        packed[name][:count] = values
    return wp.array(packed, dtype=struct, device=device)
