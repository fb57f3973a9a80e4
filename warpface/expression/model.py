"""``ExpressionModel``: the per-vertex expression pipeline of SPEC §1 on a Warp device."""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import warp as wp

from .._validate import MAX_COORDINATE, as_count, as_device
from ..kernels_surface import triangle_area_vectors
from ..mesh import FaceMesh
from .batch_graph import BatchGraphs
from .controls import (
    as_device_array,
    check_rig_parts,
    contraction_limits,
    control_vector,
    frame_controls,
    is_device_array,
)
from .frame_buffers import FrameBuffers
from .jaw import JAW_CONTROL_NAMES, Jaw
from .kernels import (
    MuscleEntry,
    WrinkleEntry,
    apply_jaw_and_muscles,
    apply_muscles,
    apply_wrinkles,
    stretch_and_bulge,
    triangle_stretch,
)
from .kernels_fused import (
    MUSCLE_SLOTS,
    WRINKLE_SLOTS,
    bulge_from_ring,
    muscle_points_over_frames,
    muscles_and_bulge_from_ring,
    ring_table,
    slot_table,
    wrinkles_from_ring,
)
from .kernels_tiled import model_kernel
from .muscles import Muscle, muscle_weights
from .readback import PinnedReadback
from .tiling import mesh_tiles
from .tissue import tissue_response
from .wrinkles import Wrinkle, wrinkle_shapes

__all__ = ["ExpressionModel", "ExpressionStages", "LAUNCH_PLANS"]

LAUNCH_PLANS = (1, 2, 3, 5)
"""Kernel launches per frame an :class:`ExpressionModel` can run (its ``launches`` argument)."""

_MAX_LAUNCH_THREADS = (1 << 31) - 1
"""Kernels index flat frames × elements arrays with 32-bit thread indices."""

_MAX_BATCH_VERTICES = 1 << 22
"""On CUDA a batched call processes frames in chunks of at most this many frame·vertices (bounded
memory); a device-resident batch (:meth:`ExpressionModel.evaluate_batch_into`, no host copy to overlap)
in chunks of :data:`_MAX_DEVICE_BATCH_VERTICES`. On the CPU, where kernels run serially, a chunk is one
frame: its working set stays in cache, which measured fastest (see benchmarks/README.md)."""

_MAX_DEVICE_BATCH_VERTICES = 1 << 24
"""Larger chunks let a thread evaluate more frames of its vertex (see ``_frames_per_thread``): 16 % more
frames/s at 1M vertices on an H200 than chunks of 2²², for 0.6 GB of work buffers."""

_RECORDING = threading.Lock()
"""Held while a thread records its launches: recording loads the kernels' Warp modules, and two threads loading
at once crash the process (the demo's two-thread bake: ~60 % of runs). Recorded launches may then run at once."""

_MAX_FRAMES_PER_THREAD = 8
"""Most frames one CUDA thread evaluates for its vertex in the fused plans (see ``_frames_per_thread``)."""

_TILE_FRAMES_PER_PASS = 4
"""Frames each pass of the tiled plan evaluates at once (H200, 1M vertices, CUDA kernel: 4 gave 6–10 % more frames/s than 2)."""
_TILE_FRAMES_PER_BLOCK = 16
"""Frames one block of the tiled plan evaluates (H200, 1M vertices: 16 gave 4 % more frames/s than 8)."""


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


class ExpressionModel:
    """Muscles → stretch → bulge → wrinkles, per vertex, from the rest mesh every frame (never cumulative).

    Everything that depends only on the rig (muscle weight fields, wrinkle distances) is evaluated
    once here in float64. On CUDA a frame is then three fused kernel launches over vertices
    (:mod:`~warpface.expression.kernels_fused`), captured once as a graph and replayed; on the CPU
    it is the five-kernel sequence of :mod:`~warpface.expression.kernels` (see ``launches``). All
    plans give the same bits on the same device (on CUDA up to the compiler's FMA contraction).

    Two ways to get results, running the same kernels:

    * NumPy: :meth:`evaluate` (one frame) and :meth:`evaluate_batch` (many) return host arrays.
    * Device-resident: :meth:`evaluate_into` and :meth:`evaluate_batch_into` write into a caller's
      array on the model's device and return without waiting for the GPU, so the result can feed
      further kernels (an activation solver, a renderer) with no host round trip. The output may be
      a ``wp.array`` (``wp.vec3`` or float32 with a last axis of 3) or any DLPack tensor, e.g. a
      torch CUDA tensor — shared zero-copy, as are the controls when given as device arrays::

          out = torch.empty((V, 3), device="cuda")
          model.evaluate_into(out, torch_contractions)   # float32 (M,), same device; no sync
          warp_view = wp.from_torch(out, dtype=wp.vec3)  # or wp.from_dlpack(out); back: wp.to_torch(a)

      Synchronise (``wp.synchronize_device``) or use the same stream before reading on the host.

    On the CPU, :meth:`evaluate_batch` may run in several threads at once (each thread has its own
    work buffers, and Warp's CPU kernels release the GIL); the other methods are for one thread at a time.

    Controls given on the host are checked (names, types, finite, within range) and the call raises
    ``ValueError`` naming the item; device-resident controls are used as they are (checking them
    would need a host sync).

    Args:
        mesh: the rest surface.
        muscles: linear and sphincter muscles; their order is the contraction order.
        wrinkles: wrinkle furrows; their order is the depth order.
        thickness: subcutaneous thickness ``h`` [mesh units]: a scalar or shape (V,), in [0, 1e6].
        device: Warp device (default: Warp's preferred device).
        jaw: optional :class:`~warpface.expression.Jaw`, applied before the muscles (SPEC §6.2); its
            controls :data:`~warpface.expression.JAW_CONTROL_NAMES` follow the muscles in the control
            vector (:attr:`control_names`).
        launches: kernel launches per frame: 1 (vertex tiles with a two-ring halo in shared memory,
            :mod:`~warpface.expression.kernels_tiled`: each triangle once per tile, no intermediate in memory;
            the GPU's default: H200, 1.00–1.18× the frames/s of plan 3 batched from 10k to 1M vertices and the
            faster single frame; a mesh a tile cannot hold falls back to 3), 2 (fused kernels that recompute the one-ring's muscle points and
            triangle terms instead of storing them: fewest launches and bytes), 3 (muscle points stored, triangle
            terms computed in place) or 5 (every intermediate stored:
            fewest operations, the CPU's default). ``None``: by device (and by whether the mesh tiles).

    Raises:
        RigError: (a ``ValueError``) mesh not a FaceMesh, wrong item types, duplicate muscle or
            wrinkle names, wrong thickness — the same errors :class:`~warpface.FaceRig` raises.
    """

    def __init__(
        self,
        mesh: FaceMesh,
        muscles: Sequence[Muscle] = (),
        wrinkles: Sequence[Wrinkle] = (),
        thickness: float | np.ndarray = 0.0,
        *,
        device=None,
        jaw: Jaw | None = None,
        launches: int | None = None,
    ):
        self.muscles, self.wrinkles, self.thickness = check_rig_parts(
            mesh, muscles, wrinkles, thickness, owner="expression model"
        )
        self.mesh = mesh
        self.muscle_names = [m.name for m in self.muscles]
        self.wrinkle_names = [w.name for w in self.wrinkles]
        if jaw is not None:
            if not isinstance(jaw, Jaw):
                raise ValueError(f"jaw: expected a Jaw, got {type(jaw).__name__}")
            jaw.check_vertex_count(mesh.vertex_count)
            if set(JAW_CONTROL_NAMES) & set(self.muscle_names):
                raise ValueError(f"muscle names must not repeat the jaw's controls {', '.join(JAW_CONTROL_NAMES)}")
        self.jaw = jaw
        self.control_names = self.muscle_names + (list(JAW_CONTROL_NAMES) if jaw is not None else [])
        """Muscle names, then the jaw's controls when there is a jaw: the order of a control vector."""
        jaw_limits = np.full(len(self.control_names) - len(self.muscles), MAX_COORDINATE)
        self._contraction_limits = np.concatenate([contraction_limits(self.muscles), jaw_limits])
        self._depth_limits = np.full(len(self.wrinkles), MAX_COORDINATE)
        self.device = as_device(device)
        if launches is not None and (
            isinstance(launches, (bool, np.bool_))
            or not isinstance(launches, (int, np.integer))
            or launches not in LAUNCH_PLANS
        ):
            raise ValueError(f"launches: expected one of {LAUNCH_PLANS} or None, got {launches!r}")
        self.launches_per_frame = int(launches if launches is not None else 5 if self.device.is_cpu else 1)
        """Kernel launches per frame: 1 (tiled), 2 (fused), 3 or 5 (see ``launches``)."""

        self._mesh_buffers = mesh.device_buffers(device=self.device)
        weights = muscle_weights(mesh.points, self.muscles, device=self.device)
        if any(m.sliding > 0.0 or m.bunching > 0.0 or m.thickening > 0.0 for m in self.muscles):
            normals = mesh.vertex_normals(device=self.device)
            weights = tissue_response(mesh.points, mesh.triangles, normals, self.thickness, self.muscles, weights)
        shapes = wrinkle_shapes(mesh.points, self.wrinkles, device=self.device)
        self.muscle_entry_count = int(len(weights.muscle))
        self.wrinkle_entry_count = int(len(shapes.wrinkle))
        device_ = self.device
        self._muscle_offsets = wp.array(weights.offsets, dtype=wp.int32, device=device_)
        self._muscle_entries = _entry_array(
            MuscleEntry, device_, muscle=weights.muscle, weight=weights.weight.reshape(-1, 3)
        )
        self._wrinkle_offsets = wp.array(shapes.offsets, dtype=wp.int32, device=device_)
        wrinkle_kr = np.array([w.kr for w in self.wrinkles], dtype=np.float32)
        self._wrinkle_entries = _entry_array(
            WrinkleEntry, device_, wrinkle=shapes.wrinkle, shape=shapes.shape, kr=wrinkle_kr[shapes.wrinkle]
        )
        counted = np.bincount(mesh.triangles[~mesh.degenerate_triangles].ravel(), minlength=mesh.vertex_count)
        self._counts = wp.array(counted.astype(np.float32), dtype=wp.float32, device=device_)
        self._thickness = wp.array(self.thickness.astype(np.float32), dtype=wp.float32, device=device_)
        self.default_depths = np.array([w.depth for w in self.wrinkles], dtype=np.float64)
        if jaw is not None:
            self._jaw_weight = wp.array(jaw.weights.astype(np.float32), dtype=wp.float32, device=device_)
        if (
            self.launches_per_frame == 1
        ):  # the tiled plan's tiles; by default a mesh that cannot be tiled runs 3 launches
            self._tiles = mesh_tiles(mesh, self._mesh_buffers, device=device_, required=launches == 1)
            self.launches_per_frame = 3 if self._tiles is None else 1
        if self.launches_per_frame in (2, 3):  # the fused plans' fixed-width tables (kernels_fused)
            buffers = self._mesh_buffers
            self._ring = ring_table(
                mesh.triangles.astype(np.int32),
                buffers.triangle_weight.numpy(),
                buffers.rest_area_lengths.numpy(),
                mesh.adjacency.offsets,
                mesh.adjacency.triangles,
                device=device_,
            )
            self._muscle_slots = slot_table(
                MuscleEntry, weights.offsets, self._muscle_entries.numpy(), int(MUSCLE_SLOTS), device=device_
            )
            self._wrinkle_slots = slot_table(
                WrinkleEntry, shapes.offsets, self._wrinkle_entries.numpy(), int(WRINKLE_SLOTS), device=device_
            )
        self._block_dim = 256 if self.device.is_cuda else 1
        self._tile_frames_per_pass = _TILE_FRAMES_PER_PASS
        """Threads per block of every launch (the tiled plan's blocks are its third launch dimension)."""
        self._thread_buffers = threading.local()
        self._single = self._frame_buffers(1)
        self._batch_graphs = BatchGraphs(device=self.device)
        self._readbacks: dict[int, PinnedReadback] = {}

    @classmethod
    def from_rig(cls, rig, *, device=None) -> "ExpressionModel":
        """Build from a :class:`warpface.FaceRig` (mesh, muscles, wrinkles, thickness, jaw)."""
        if not all(
            hasattr(rig, field) for field in ("mesh", "muscles", "wrinkles", "thickness")
        ):  # warpface.rig imports this module
            raise TypeError(f"rig: expected a FaceRig, got {type(rig).__name__}")
        return cls(rig.mesh, rig.muscles, rig.wrinkles, rig.thickness, device=device, jaw=getattr(rig, "jaw", None))

    # ------------------------------------------------------------------ controls
    def contraction_vector(self, contractions) -> np.ndarray:
        """Controls in :attr:`control_names` order (muscles, then the jaw's), shape (M,) or (M + 3,), float64.

        ``contractions`` is a mapping ``{muscle or jaw control name: value}`` (absent ones are 0), a
        sequence in control order (with a jaw, M muscle values alone leave the jaw at rest), or ``None`` (all zero). Unknown names, non-numbers, non-finite values
        and values beyond ±1e6 (linear muscles and jaw, lengths and radians) or ±1e3 (sphincters) raise
        ValueError naming the control.
        """
        return control_vector(
            self._muscles_only_padded(contractions),
            self.control_names,
            np.zeros(len(self.control_names)),
            self._contraction_limits,
            "contraction",
            "muscle" if self.jaw is None else "control",
        )

    def depth_vector(self, depths) -> np.ndarray:
        """Wrinkle depths ``k_d`` in wrinkle order, shape (W,); ``None`` or absent names keep each wrinkle's own depth.

        Depths are lengths: beyond ±1e6 they are rejected like other bad values (ValueError naming the wrinkle).
        """
        return control_vector(
            depths, self.wrinkle_names, self.default_depths, self._depth_limits, "wrinkle depth", "wrinkle"
        )

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, contractions=None, *, wrinkle_depths=None, stages: bool = False):
        """Deformed positions for one frame, returned as NumPy.

        Args:
            contractions: ``{name: K}`` or an array in muscle order (see :meth:`contraction_vector`).
            wrinkle_depths: optional per-frame ``k_d`` overrides, ``{name: k_d}`` or an array.
            stages: return :class:`ExpressionStages` (muscle, stretch, bulge, final) instead.

        Returns:
            Final positions, shape (V, 3), float32 — or the stages.
        """
        if not isinstance(stages, (bool, np.bool_)):
            raise ValueError(f"stages: expected True or False, got {type(stages).__name__}")
        buffers = self._single
        buffers.upload_controls(self.contraction_vector(contractions)[None], self.depth_vector(wrinkle_depths)[None])
        if stages:
            self._launch_frames(buffers, frames=1, keep_muscle_points=True)
        else:
            self._run_single(buffers)
        if stages:
            return ExpressionStages(
                muscle=buffers.read_frames(buffers.muscle_points, 1)[0],
                stretch=buffers.read_frames(buffers.stretch, 1)[0],
                bulge=buffers.read_frames(buffers.bulge_points, 1)[0],
                final=buffers.read_frames(buffers.final_points, 1)[0],
            )
        return buffers.read_frames(buffers.final_points, 1)[0]

    def evaluate_into(self, out, contractions=None, *, wrinkle_depths=None):
        """Deformed positions for one frame, written into ``out`` on the device; no host sync.

        Args:
            out: a ``wp.array`` on the model's device — shape (V,) of ``wp.vec3`` or (V, 3) float32 —
                or a DLPack tensor of the latter (e.g. a torch tensor), written in place.
            contractions: as in :meth:`evaluate`, or a float32 device array (M,) in muscle order.
            wrinkle_depths: as in :meth:`evaluate`, or a float32 device array (W,).

        Returns:
            ``out``. Same kernels and bit-identical values as :meth:`evaluate`.
        """
        target = as_device_array(out, "out", device=self.device, shape=(self.mesh.vertex_count,), dtype=wp.vec3)
        buffers = self._single
        self._upload_frames(buffers, contractions, wrinkle_depths, frames=1, first=0, count=1)
        self._run_single(buffers)
        wp.copy(target, buffers.final_points, count=self.mesh.vertex_count)
        return out

    def evaluate_batch(
        self, contractions, *, wrinkle_depths=None, progress: bool = False, frames_per_launch: int | None = None
    ) -> np.ndarray:
        """Deformed positions for many frames at once, returned as NumPy.

        Args:
            contractions: shape (F, M) in muscle order, or a sequence of F mappings.
            wrinkle_depths: ``None``, shape (F, W), or a sequence of F mappings.
            progress: show a progress bar over the frames.
            frames_per_launch: frames evaluated by one launch of the kernels; default 1 on the CPU
                (cache-friendly) and as many as fit in 2²² frame·vertices on CUDA.

        Returns:
            Positions, shape (F, V, 3), float32. On CUDA each chunk comes back through a pinned
            double buffer: its copy to the host overlaps the next chunk's kernels.
        """
        controls, depths = self._host_frames(contractions, wrinkle_depths)
        frame_count = len(controls)
        vertex_count = self.mesh.vertex_count
        result = np.empty((frame_count, vertex_count, 3), dtype=np.float32)
        readback = None
        try:
            for buffers, start, count in self._chunks(frame_count, frames_per_launch, progress):
                buffers.upload_controls(controls[start : start + count], depths[start : start + count])
                self._launch(buffers)
                if self.device.is_cpu:
                    buffers.read_frames(buffers.final_points, count, out=result[start : start + count])
                    continue
                readback = self._readbacks.get(buffers.frames)
                if readback is None:
                    readback = self._readbacks[buffers.frames] = PinnedReadback(
                        buffers.frames * vertex_count, wp.vec3, device=self.device
                    )
                readback.submit(buffers.final_points, count * vertex_count, result[start : start + count])
        finally:
            if readback is not None:
                readback.finish()
        return result

    def evaluate_batch_into(
        self, out, contractions, *, wrinkle_depths=None, progress: bool = False, frames_per_launch: int | None = None
    ):
        """Deformed positions for many frames, written into ``out`` on the device; no host sync.

        Args:
            out: a ``wp.array`` on the model's device — shape (F, V) of ``wp.vec3`` or (F, V, 3)
                float32 — or a DLPack tensor of the latter, written in place.
            contractions: as in :meth:`evaluate_batch`, or a float32 device array (F, M).
            wrinkle_depths: as in :meth:`evaluate_batch`, or a float32 device array (F, W).
            progress, frames_per_launch: as in :meth:`evaluate_batch`, except that on CUDA the default
                chunk is as many frames as fit in 2²⁴ frame·vertices (no host copy to overlap).

        Returns:
            ``out``. Same kernels and bit-identical values as :meth:`evaluate_batch`. On CUDA (without a
            progress bar) the whole batch — every chunk's control copies, kernels and result copy — is
            one CUDA graph, captured on the first call with these arrays and sizes and replayed after.
        """
        frame_count = self._batch_frame_count(contractions, wrinkle_depths)
        target = as_device_array(
            out, "out", device=self.device, shape=(frame_count, self.mesh.vertex_count), dtype=wp.vec3
        )
        host, device_controls = self._split_controls(contractions, wrinkle_depths, frame_count)
        self._run_batch(target, host, device_controls, frame_count, frames_per_launch, progress)
        return out

    def _run_batch(
        self, target: wp.array, host, device_controls, frame_count: int, frames_per_launch, progress: bool
    ) -> None:
        """Chunk after chunk: copy its controls, run the kernels, the last one writing into ``target``.

        Host controls are staged once into device arrays kept for their shape; the kernels read each
        chunk's rows of the control arrays in place (no copy). On CUDA without a progress bar the whole
        sequence is one graph, replayed while the arrays and sizes stay the same.
        """
        if not isinstance(progress, (bool, np.bool_)):
            raise ValueError(f"progress: expected True or False, got {type(progress).__name__}")
        chunks = list(
            self._chunks(frame_count, frames_per_launch, False, device_resident=True)
        )  # checks frames_per_launch
        if not chunks:
            return
        sources = [
            self._batch_graphs.stage(values, slot) if given is None else given
            for values, given, slot in zip(host, device_controls, ("contraction", "depth"))
        ]
        vertex_count = self.mesh.vertex_count

        def write(buffers: FrameBuffers, start: int, count: int) -> None:
            controls, depths = (
                source[start * width : (start + count) * width] if width else fallback
                for source, width, fallback in (
                    (sources[0], len(self.control_names), buffers.contraction),
                    (sources[1], len(self.wrinkles), buffers.depth),
                )
            )
            self._launch_frames(
                buffers,
                frames=count,
                controls=controls,
                depths=depths,
                final_points=target[start * vertex_count : (start + count) * vertex_count],
            )

        if progress:
            for chunk in self._chunks(frame_count, frames_per_launch, True, device_resident=True):
                write(*chunk)
            return
        key = (target.ptr, frame_count, chunks[0][2], sources[0].ptr, sources[1].ptr)
        self._batch_graphs.run(key, lambda: [write(*chunk) for chunk in chunks])

    # ------------------------------------------------------------------ control plumbing
    def _muscles_only_padded(self, values):
        """With a jaw, a host array of muscle contractions only ((M,) or (F, M)) gets the jaw at rest appended."""
        if self.jaw is None or values is None or isinstance(values, (str, bytes, dict)) or is_device_array(values):
            return values
        if not isinstance(values, (np.ndarray, list, tuple)):
            return values
        try:
            array = np.asarray(values, dtype=np.float64)
        except (TypeError, ValueError):
            return values
        if array.ndim in (1, 2) and array.shape[-1] == len(self.muscles) != len(self.control_names):
            return np.concatenate(
                [array, np.zeros(array.shape[:-1] + (len(self.control_names) - len(self.muscles),))], axis=-1
            )
        return values

    def _host_frames(self, contractions, wrinkle_depths) -> tuple[np.ndarray, np.ndarray]:
        """Validated (F, M) contractions and (F, W) depths from host values."""
        controls = frame_controls(
            self._muscles_only_padded(contractions),
            self.contraction_vector,
            len(self.control_names),
            "contractions",
            self._contraction_limits,
        )
        frame_count = len(controls)
        if wrinkle_depths is None:
            return controls, np.tile(self.default_depths, (frame_count, 1))
        depths = frame_controls(
            wrinkle_depths, self.depth_vector, len(self.wrinkles), "wrinkle_depths", self._depth_limits
        )
        if len(depths) != frame_count:
            raise ValueError(f"wrinkle_depths: {len(depths)} frames, contractions have {frame_count}")
        return controls, depths

    def _device_controls(self, values, frames: int | None, width: int, name: str):
        """A device control array (flat float32, frames·width) or ``None`` for host values."""
        if not is_device_array(values):
            return None
        rows = values.shape[0] if frames is None else frames
        shape = (width,) if frames == 1 and len(values.shape) == 1 else (rows, width)
        return as_device_array(values, name, device=self.device, shape=shape, dtype=wp.float32)

    def _batch_frame_count(self, contractions, wrinkle_depths) -> int:
        for values in (contractions, wrinkle_depths):
            if is_device_array(values):
                return int(values.shape[0])
        return len(self._host_frames(contractions, wrinkle_depths)[0])

    def _split_controls(self, contractions, wrinkle_depths, frame_count: int):
        """Host (F, M)/(F, W) arrays for host controls and zeros/defaults under device ones; device arrays."""
        device_c = self._device_controls(contractions, frame_count, len(self.control_names), "contractions")
        device_d = self._device_controls(wrinkle_depths, frame_count, len(self.wrinkles), "wrinkle_depths")
        host_c = None if device_c is not None else contractions
        host_d = None if device_d is not None else wrinkle_depths
        if host_c is None:
            host_c = np.zeros((frame_count, len(self.control_names)))
        controls, depths = self._host_frames(host_c, host_d)
        if len(controls) != frame_count:
            raise ValueError(f"contractions: {len(controls)} frames, wrinkle_depths have {frame_count}")
        return (controls, depths), (device_c, device_d)

    def _upload_frames(self, buffers, contractions, wrinkle_depths, *, frames: int, first: int, count: int) -> None:
        device_c = self._device_controls(contractions, frames, len(self.control_names), "contractions")
        device_d = self._device_controls(wrinkle_depths, frames, len(self.wrinkles), "wrinkle_depths")
        host_c = self.contraction_vector(None if device_c is not None else contractions)
        host_d = self.depth_vector(None if device_d is not None else wrinkle_depths)
        buffers.upload_controls(host_c[None], host_d[None])
        buffers.copy_controls(device_c, device_d, first=first, count=count)

    def _chunks(self, frame_count: int, frames_per_launch, progress: bool, device_resident: bool = False):
        """``(buffers, first frame, frame count)`` per launch, with an optional progress bar."""
        elements = max(self.mesh.vertex_count, self.mesh.triangle_count, 1)
        if frames_per_launch is None:
            limit = _MAX_DEVICE_BATCH_VERTICES if device_resident else _MAX_BATCH_VERTICES
            chunk = 1 if self.device.is_cpu else limit // max(self.mesh.vertex_count, 1)
        else:
            chunk = as_count(frames_per_launch, "frames_per_launch", minimum=1)
            if chunk * elements > _MAX_LAUNCH_THREADS:
                raise ValueError(
                    f"frames_per_launch: {chunk} frames × {elements:,} elements exceeds one launch's "
                    f"{_MAX_LAUNCH_THREADS:,} threads; use at most {_MAX_LAUNCH_THREADS // elements}"
                )
        if not isinstance(progress, (bool, np.bool_)):
            raise ValueError(f"progress: expected True or False, got {type(progress).__name__}")
        chunk = max(1, min(frame_count, chunk))
        buffers = self._frame_buffers(chunk)
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=frame_count, desc="expression frames", unit="frame")
        for start in range(0, frame_count, chunk):
            count = min(chunk, frame_count - start)
            yield buffers, start, count
            if bar is not None:
                bar.update(count)
        if bar is not None:
            bar.close()

    # ------------------------------------------------------------------ internals
    @property
    def _buffers(self) -> dict[int, FrameBuffers]:
        """The calling thread's work buffers by frame count: on the CPU, where Warp's kernels release the
        GIL, several threads may run :meth:`evaluate_batch` at once (``warpface.usd.bake`` does)."""
        local = self._thread_buffers
        if not hasattr(local, "by_frames"):
            local.by_frames = {}
        return local.by_frames

    def _frame_buffers(self, frames: int) -> FrameBuffers:
        if frames not in self._buffers:
            self._buffers[frames] = FrameBuffers(
                frames,
                self.mesh.vertex_count,
                self.mesh.triangle_count,
                len(self.control_names),
                len(self.wrinkles),
                device=self.device,
                per_triangle=self.launches_per_frame == 5,
            )
        return self._buffers[frames]

    def _run_single(self, buffers: FrameBuffers) -> None:
        """One frame's kernels: replayed as a CUDA graph on CUDA, recorded launches on the CPU."""
        if self.device.is_cuda:
            if buffers.graph is None:
                with wp.ScopedCapture(device=self.device) as capture:
                    self._launch(buffers)
                buffers.graph = capture.graph
            wp.capture_launch(buffers.graph)
        else:
            self._launch(buffers)

    def _launch(self, buffers: FrameBuffers) -> None:
        """Run the frame's kernels over all of ``buffers``' frames (recorded on first use)."""
        if not buffers.launches:
            with _RECORDING:
                buffers.launches = self._record_launches(buffers)
        for launch in buffers.launches:
            launch.launch()

    def _frames_per_thread(self, frames: int) -> int:
        """Frames one thread evaluates for its vertex: 1 on the CPU and for small launches; on CUDA up to
        :data:`_MAX_FRAMES_PER_THREAD`, one more per 2²⁰ frame·vertices of the launch, so a vertex's rig
        data is read from memory once per G frames (H200, 1M vertices: G = 4 → 8, +8 % frames/s; 16: +1 %)."""
        if self.device.is_cpu:
            return 1
        return int(min(_MAX_FRAMES_PER_THREAD, max(1, frames * self.mesh.vertex_count // (1 << 20))))

    def _launch_args(
        self,
        buffers: FrameBuffers,
        frames: int,
        controls: wp.array,
        depths: wp.array,
        final_points: wp.array,
        keep_muscle_points: bool,
    ) -> list:
        """``(kernel, dim, inputs, outputs)`` of a frame's kernels over ``frames`` frames."""
        if self.launches_per_frame == 5:
            return self._staged_launch_args(buffers, frames, controls, depths, final_points)
        mesh = self._mesh_buffers
        vertex_count = self.mesh.vertex_count
        per_thread = self._frames_per_thread(frames)
        dim = -(-frames // per_thread) * vertex_count
        jaw = self.jaw
        if jaw is None:
            jaw_inputs = [self._counts, wp.vec3(), wp.vec3(), wp.vec3(), -1]  # jaw arrays unread
        else:
            jaw_inputs = [
                self._jaw_weight,
                wp.vec3(*jaw.pivot),
                wp.vec3(*jaw.axis),
                wp.vec3(*jaw.forward),
                len(self.muscles),
            ]
        if self.launches_per_frame == 1:  # blocks over (frame groups, tiles)
            per_block = min(_TILE_FRAMES_PER_BLOCK, frames)
            kernel = model_kernel(per_block, self._tile_frames_per_pass, len(self._tiles[0]), device=self.device)
            tiled = (
                kernel,
                (-(-frames // per_block), len(self._tiles[0]), self._block_dim),
                [
                    *self._tiles,
                    mesh.rest_points,
                    *jaw_inputs,
                    self._muscle_offsets,
                    self._muscle_entries,
                    controls,
                    buffers.muscle_width,
                    self._counts,
                    self._thickness,
                    self._wrinkle_offsets,
                    self._wrinkle_entries,
                    depths,
                    buffers.wrinkle_width,
                    vertex_count,
                    frames,
                    per_block,
                    int(keep_muscle_points),
                ],
                [buffers.muscle_points, buffers.stretch, buffers.bulge_points, final_points],
            )
            return [tiled]
        muscle_inputs = [
            mesh.rest_points,
            *jaw_inputs,
            self._muscle_offsets,
            self._muscle_entries,
            self._muscle_slots,
            controls,
            buffers.muscle_width,
        ]
        ring_inputs = [
            self._ring,
            mesh.triangles,
            mesh.triangle_weight,
            mesh.rest_area_lengths,
            mesh.adjacency_offsets,
            mesh.adjacency_triangles,
            self._counts,
            self._thickness,
            vertex_count,
            frames,
            per_thread,
        ]
        wrinkles = (
            wrinkles_from_ring,
            dim,
            [
                buffers.bulge_points,
                buffers.stretch,
                self._ring,
                mesh.triangles,
                mesh.triangle_weight,
                mesh.adjacency_offsets,
                mesh.adjacency_triangles,
                self._wrinkle_offsets,
                self._wrinkle_entries,
                self._wrinkle_slots,
                depths,
                buffers.wrinkle_width,
                vertex_count,
                frames,
                per_thread,
            ],
            [final_points],
        )
        if self.launches_per_frame == 3:
            muscles = (
                muscle_points_over_frames,
                dim,
                [
                    mesh.rest_points,
                    *jaw_inputs,
                    self._muscle_offsets,
                    self._muscle_entries,
                    controls,
                    buffers.muscle_width,
                    vertex_count,
                    frames,
                    per_thread,
                ],
                [buffers.muscle_points],
            )
            bulge = (
                bulge_from_ring,
                dim,
                [buffers.muscle_points, *ring_inputs],
                [buffers.stretch, buffers.bulge_points],
            )
            return [muscles, bulge, wrinkles]
        bulge = (
            muscles_and_bulge_from_ring,
            dim,
            [*muscle_inputs, *ring_inputs, int(keep_muscle_points)],
            [buffers.muscle_points, buffers.stretch, buffers.bulge_points],
        )
        return [bulge, wrinkles]

    def _staged_launch_args(
        self, buffers: FrameBuffers, frames: int, controls: wp.array, depths: wp.array, final_points: wp.array
    ) -> list:
        """The five-kernel sequence (muscles, triangle stretch, stretch and bulge, area vectors, wrinkles)."""
        mesh = self._mesh_buffers
        vertex_count, triangle_count = self.mesh.vertex_count, self.mesh.triangle_count
        vertices, triangles = frames * vertex_count, frames * triangle_count
        counts = [vertex_count, triangle_count]
        if self.jaw is None:
            first = (
                apply_muscles,
                vertices,
                [
                    mesh.rest_points,
                    self._muscle_offsets,
                    self._muscle_entries,
                    controls,
                    buffers.muscle_width,
                    vertex_count,
                ],
                [buffers.muscle_points],
            )
        else:
            jaw = self.jaw
            first = (
                apply_jaw_and_muscles,
                vertices,
                [
                    mesh.rest_points,
                    self._jaw_weight,
                    wp.vec3(*jaw.pivot),
                    wp.vec3(*jaw.axis),
                    wp.vec3(*jaw.forward),
                    self._muscle_offsets,
                    self._muscle_entries,
                    controls,
                    buffers.muscle_width,
                    len(self.muscles),
                    vertex_count,
                ],
                [buffers.muscle_points],
            )
        return [
            first,
            (
                triangle_stretch,
                triangles,
                [buffers.muscle_points, mesh.triangles, mesh.triangle_weight, mesh.rest_area_lengths, *counts],
                [buffers.stretch_terms],
            ),
            (
                stretch_and_bulge,
                vertices,
                [
                    buffers.muscle_points,
                    buffers.stretch_terms,
                    self._counts,
                    mesh.adjacency_offsets,
                    mesh.adjacency_triangles,
                    self._thickness,
                    *counts,
                ],
                [buffers.stretch, buffers.bulge_points],
            ),
            (
                triangle_area_vectors,
                triangles,
                [buffers.bulge_points, mesh.triangles, mesh.triangle_weight, *counts],
                [buffers.area_vectors],
            ),
            (
                apply_wrinkles,
                vertices,
                [
                    buffers.bulge_points,
                    buffers.area_vectors,
                    mesh.adjacency_offsets,
                    mesh.adjacency_triangles,
                    buffers.stretch,
                    self._wrinkle_offsets,
                    self._wrinkle_entries,
                    depths,
                    buffers.wrinkle_width,
                    *counts,
                ],
                [final_points],
            ),
        ]

    def _launch_frames(
        self,
        buffers: FrameBuffers,
        *,
        frames: int,
        controls: wp.array | None = None,
        depths: wp.array | None = None,
        final_points: wp.array | None = None,
        keep_muscle_points: bool = False,
    ) -> None:
        """The frame's kernels over the first ``frames`` frames, reading ``controls``/``depths`` (default: the
        buffers') and writing ``final_points`` (default: the buffers'); x1 is kept for the stages on request."""
        arguments = self._launch_args(
            buffers,
            frames,
            buffers.contraction if controls is None else controls,
            buffers.depth if depths is None else depths,
            buffers.final_points if final_points is None else final_points,
            keep_muscle_points,
        )
        for kernel, dim, inputs, outputs in arguments:
            wp.launch(kernel, dim=dim, inputs=inputs, outputs=outputs, device=self.device, block_dim=self._block_dim)

    def _record_launches(self, buffers: FrameBuffers) -> list:
        arguments = self._launch_args(
            buffers, buffers.frames, buffers.contraction, buffers.depth, buffers.final_points, False
        )
        return [
            wp.launch(
                kernel,
                dim=dim,
                inputs=inputs,
                outputs=outputs,
                device=self.device,
                block_dim=self._block_dim,
                record_cmd=True,
            )
            for kernel, dim, inputs, outputs in arguments
        ]


def _entry_array(struct, device, **fields: np.ndarray) -> wp.array:
    """A Warp array of ``struct`` entries from per-field numpy columns (one unused zero entry if empty)."""
    count = len(next(iter(fields.values())))
    packed = np.zeros(max(count, 1), dtype=struct.numpy_dtype())
    for name, values in fields.items():
        packed[name][:count] = values
    return wp.array(packed, dtype=struct, device=device)
