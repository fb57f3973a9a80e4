"""``ExpressionEvaluator``: the evaluation state of an :class:`~warpface.expression.ExpressionModel`.

The model holds the rig's arrays and never changes; an evaluator owns what evaluating needs: work buffers
per frame count (per thread), recorded launches, CUDA graphs and pinned readbacks. Steps are allocation-free
after their first call (the launches are recorded once, on CUDA captured as a graph and replayed).
"""

from __future__ import annotations

import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import warp as wp

from .._validate import as_count
from .batch_graph import BatchGraphs
from .controls import as_device_array, is_device_array
from .frame_buffers import FrameBuffers
from .plans import plan_launches, staged_launches
from .readback import PinnedReadback

__all__ = ["ExpressionEvaluator", "ExpressionStages"]

_MAX_LAUNCH_THREADS = (1 << 31) - 1
"""Kernels index flat frames × elements arrays with 32-bit thread indices."""

_MAX_BATCH_VERTICES = 1 << 22
"""On CUDA a batch returned as NumPy is evaluated in chunks of at most this many frame·vertices (bounded
memory, each chunk's copy to the host overlapping the next chunk's kernels); a batch written to a device
array in chunks of :data:`_MAX_DEVICE_BATCH_VERTICES`. On the CPU, where kernels run serially, a chunk is
one frame: its working set stays in cache."""

_MAX_DEVICE_BATCH_VERTICES = 1 << 24
"""Larger chunks let a block of the tiled plan evaluate more frames of its tile (its rig data read once)."""

_RECORDING = threading.Lock()
"""Held while a thread records its launches: recording loads the kernels' Warp modules, and two threads loading
at once can crash the process. Recorded launches may then run at once."""


@dataclass(frozen=True)
class ExpressionStages:
    """Intermediate results of one frame (all numpy, float32), from the staged plan. Indexable: ``stages["bulge"]``."""

    muscle: np.ndarray
    """After the jaw and muscles, x1, shape (V, 3)."""
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


def _rank(values) -> int | None:
    """1 for one frame's values, 2 for a batch's, ``None`` for ``None``; anything else its number of axes."""
    if values is None:
        return None
    if isinstance(values, (Mapping, str, bytes)):
        return 1
    if is_device_array(values):
        return len(values.shape)
    if isinstance(values, Sequence) and len(values) and isinstance(values[0], Mapping):
        return 2
    try:
        return int(np.ndim(values))
    except (TypeError, ValueError):
        return 1  # the validation names the argument


class ExpressionEvaluator:
    """Evaluates an :class:`~warpface.expression.ExpressionModel`: one frame or a batch, to NumPy or a device array.

    Work buffers are per thread: on the CPU several threads may evaluate at once (Warp's CPU kernels release
    the GIL). Get one with :meth:`ExpressionModel.evaluator` (``model.evaluate`` uses the model's own).
    """

    def __init__(self, model):
        self.model = model
        self.device = model.device
        self._thread_buffers = threading.local()
        self._batch_graphs = BatchGraphs(device=self.device)
        self._readbacks: dict[int, PinnedReadback] = {}

    # ------------------------------------------------------------------ public
    def evaluate(self, controls=None, out=None, *, wrinkle_depths=None, progress: bool = False, frames_per_launch=None):
        """Deformed positions of one frame (``controls`` of shape (C,) or a mapping) or a batch ((F, C), F mappings).

        Args:
            controls: the rig's full control vector per frame (:attr:`ExpressionModel.control_names`: muscles,
                then the jaw's 3 controls when there is a jaw), as ``{name: value}`` (absent names are 0), an array,
                or a float32 device array (``wp.array`` or DLPack tensor) on the model's device; ``None``: all 0.
            out: optional device array on the model's device, written in place without a host sync: (V,) of
                ``wp.vec3`` or (V, 3) float32 for one frame, (F, V) or (F, V, 3) for a batch.
            wrinkle_depths: optional per-frame ``k_d`` overrides, shaped like ``controls`` (names, (W,), (F, W)).
            progress: show a progress bar over a batch's frames.
            frames_per_launch: frames per launch of a batch (default: 1 on the CPU, as many as fit on CUDA).

        Returns:
            ``out``, or float32 NumPy positions, shape (V, 3) or (F, V, 3).
        """
        if not isinstance(progress, (bool, np.bool_)):
            raise TypeError(f"progress: expected True or False, got {type(progress).__name__}")
        rank = _rank(controls)
        if isinstance(controls, (list, tuple)) and not controls and self.model.control_names:
            rank = 2  # no values for a rig with controls: a batch of no frames
        depth_rank = _rank(wrinkle_depths)
        if rank is None:
            rank = depth_rank or 1
        if rank not in (1, 2):
            raise ValueError(f"controls: expected one frame (C,) or a batch (frames, C), got {rank} axes")
        if rank == 1:
            return self._evaluate_frame(controls, wrinkle_depths, out)
        if controls is None:  # a batch given by its depths alone: every control at rest
            controls = np.zeros((self._batch_frame_count(wrinkle_depths, None), len(self.model.control_names)))
        frame_count = self._batch_frame_count(controls, wrinkle_depths)
        vertex_count = self.model.mesh.vertex_count
        if out is None and not (is_device_array(controls) or is_device_array(wrinkle_depths)):
            return self._batch_to_host(controls, wrinkle_depths, progress, frames_per_launch)
        target_shape = (frame_count, vertex_count)
        target = (
            wp.empty(target_shape, dtype=wp.vec3, device=self.device)
            if out is None
            else as_device_array(out, "out", device=self.device, shape=target_shape, dtype=wp.vec3)
        )
        host, device_controls = self._split_controls(controls, wrinkle_depths, frame_count)
        self._run_batch(target.flatten(), host, device_controls, frame_count, frames_per_launch, progress)
        return target.numpy().reshape(frame_count, vertex_count, 3) if out is None else out

    def stages(self, controls=None, *, wrinkle_depths=None) -> ExpressionStages:
        """One frame's intermediate results (x1, r, x2, x3) for inspection, from the staged plan's kernels
        (bit-identical to either plan on the CPU). Arguments as :meth:`evaluate`'s for one frame."""
        buffers = self._frame_buffers(1, stages=True)
        self._upload_frame(buffers, controls, wrinkle_depths)
        launches = staged_launches(self.model, buffers, 1, buffers.contraction, buffers.depth, buffers.final_points)
        self._launch_now(launches)
        return ExpressionStages(
            *(buffers.read_frames(a, 1)[0] for a in (buffers.muscle_points, buffers.stretch, buffers.bulge_points)),
            buffers.read_frames(buffers.final_points, 1)[0],
        )

    # ------------------------------------------------------------------ one frame
    def _evaluate_frame(self, controls, wrinkle_depths, out):
        buffers = self._frame_buffers(1)
        target = None
        if out is not None:
            target = as_device_array(
                out, "out", device=self.device, shape=(self.model.mesh.vertex_count,), dtype=wp.vec3
            )
        self._upload_frame(buffers, controls, wrinkle_depths)
        self._run_recorded(buffers)
        if target is None:
            return buffers.read_frames(buffers.final_points, 1)[0]
        wp.copy(target, buffers.final_points, count=self.model.mesh.vertex_count)
        return out

    def _upload_frame(self, buffers: FrameBuffers, controls, wrinkle_depths) -> None:
        """Validated host values into the buffers, then device values copied over them (device to device)."""
        model = self.model
        device_c = self._device_controls(controls, 1, len(model.control_names), "controls")
        device_d = self._device_controls(wrinkle_depths, 1, len(model.wrinkles), "wrinkle_depths")
        host_c = model.control_vector(None if device_c is not None else controls)
        host_d = model.depth_vector(None if device_d is not None else wrinkle_depths)
        buffers.upload_controls(host_c[None], host_d[None])
        buffers.copy_controls(device_c, device_d, first=0, count=1)

    # ------------------------------------------------------------------ batches
    def _batch_to_host(self, controls, wrinkle_depths, progress: bool, frames_per_launch) -> np.ndarray:
        """A host batch chunk by chunk; on CUDA each chunk comes back through a pinned double buffer."""
        controls, depths = self.model.host_frames(controls, wrinkle_depths)
        frame_count = len(controls)
        vertex_count = self.model.mesh.vertex_count
        result = np.empty((frame_count, vertex_count, 3), dtype=np.float32)
        readback = None
        try:
            for buffers, start, count in self._chunks(frame_count, frames_per_launch, progress):
                buffers.upload_controls(controls[start : start + count], depths[start : start + count])
                self._launch_recorded(buffers)
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

    def _run_batch(self, target: wp.array, host, device_controls, frame_count: int, frames_per_launch, progress):
        """Chunk after chunk into ``target``, reading each chunk's rows of the control arrays in place.

        Host controls are staged once into device arrays kept for their shape. On CUDA without a progress bar
        the whole sequence is one graph, replayed while the arrays and sizes stay the same.
        """
        chunks = list(self._chunks(frame_count, frames_per_launch, False, device_resident=True))
        if not chunks:
            return
        sources = [
            self._batch_graphs.stage(values, slot) if given is None else given
            for values, given, slot in zip(host, device_controls, ("contraction", "depth"))
        ]
        vertex_count = self.model.mesh.vertex_count
        widths = (len(self.model.control_names), len(self.model.wrinkles))

        def write(buffers: FrameBuffers, start: int, count: int) -> None:
            controls, depths = (
                source[start * width : (start + count) * width] if width else fallback
                for source, width, fallback in zip(sources, widths, (buffers.contraction, buffers.depth))
            )
            final = target[start * vertex_count : (start + count) * vertex_count]
            self._launch_now(plan_launches(self.model, buffers, count, controls, depths, final))

        if progress:
            for chunk in self._chunks(frame_count, frames_per_launch, True, device_resident=True):
                write(*chunk)
            return
        key = (target.ptr, frame_count, chunks[0][2], sources[0].ptr, sources[1].ptr)
        self._batch_graphs.run(key, lambda: [write(*chunk) for chunk in chunks])

    def _batch_frame_count(self, controls, wrinkle_depths) -> int:
        for values in (controls, wrinkle_depths):
            if is_device_array(values):
                return int(values.shape[0])
        if controls is None:  # host depths alone
            return len(self.model.host_depths(wrinkle_depths))
        return len(self.model.host_frames(controls, wrinkle_depths)[0])

    def _device_controls(self, values, frames: int | None, width: int, name: str):
        """A device control array (flat float32, frames·width) or ``None`` for host values."""
        if not is_device_array(values):
            return None
        rows = values.shape[0] if frames is None else frames
        shape = (width,) if frames == 1 and len(values.shape) == 1 else (rows, width)
        return as_device_array(values, name, device=self.device, shape=shape, dtype=wp.float32)

    def _split_controls(self, controls, wrinkle_depths, frame_count: int):
        """Host (F, C)/(F, W) arrays for host values and zeros/defaults under device ones; the device arrays."""
        model = self.model
        device_c = self._device_controls(controls, frame_count, len(model.control_names), "controls")
        device_d = self._device_controls(wrinkle_depths, frame_count, len(model.wrinkles), "wrinkle_depths")
        host_c = controls
        if device_c is not None or controls is None:
            host_c = np.zeros((frame_count, len(model.control_names)))
        host_values = model.host_frames(host_c, None if device_d is not None else wrinkle_depths)
        if len(host_values[0]) != frame_count:
            raise ValueError(f"controls: {len(host_values[0])} frames, wrinkle_depths have {frame_count}")
        return host_values, (device_c, device_d)

    def _chunks(self, frame_count: int, frames_per_launch, progress: bool, device_resident: bool = False):
        """``(buffers, first frame, frame count)`` per launch, with an optional progress bar."""
        mesh = self.model.mesh
        elements = max(mesh.vertex_count, mesh.triangle_count, 1)
        if frames_per_launch is None:
            limit = _MAX_DEVICE_BATCH_VERTICES if device_resident else _MAX_BATCH_VERTICES
            chunk = 1 if self.device.is_cpu else limit // max(mesh.vertex_count, 1)
        else:
            chunk = as_count(frames_per_launch, "frames_per_launch", minimum=1)
            if chunk * elements > _MAX_LAUNCH_THREADS:
                raise ValueError(
                    f"frames_per_launch: {chunk} frames × {elements:,} elements exceeds one launch's "
                    f"{_MAX_LAUNCH_THREADS:,} threads; use at most {_MAX_LAUNCH_THREADS // elements}"
                )
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

    # ------------------------------------------------------------------ buffers and launches
    def _frame_buffers(self, frames: int, *, stages: bool = False) -> FrameBuffers:
        """The calling thread's work buffers for ``frames`` frames (``stages``: with the staged intermediates)."""
        local = self._thread_buffers
        if not hasattr(local, "by_frames"):
            local.by_frames = {}
        per_triangle = stages or self.model.plan == "staged"
        key = (frames, per_triangle)
        if key not in local.by_frames:
            mesh = self.model.mesh
            local.by_frames[key] = FrameBuffers(
                frames,
                mesh.vertex_count,
                mesh.triangle_count,
                len(self.model.control_names),
                len(self.model.wrinkles),
                device=self.device,
                per_triangle=per_triangle,
            )
        return local.by_frames[key]

    def _run_recorded(self, buffers: FrameBuffers) -> None:
        """The plan over all of ``buffers``' frames: a replayed CUDA graph on CUDA, recorded launches on the CPU."""
        if self.device.is_cuda:
            if buffers.graph is None:
                with wp.ScopedCapture(device=self.device) as capture:
                    self._launch_recorded(buffers)
                buffers.graph = capture.graph
            wp.capture_launch(buffers.graph)
        else:
            self._launch_recorded(buffers)

    def _launch_recorded(self, buffers: FrameBuffers) -> None:
        """Run the plan over all of ``buffers``' frames, its launches recorded on first use."""
        if not buffers.launches:
            launches = plan_launches(
                self.model, buffers, buffers.frames, buffers.contraction, buffers.depth, buffers.final_points
            )
            with _RECORDING:
                buffers.launches = [self._launch(*launch, record=True) for launch in launches]
        for launch in buffers.launches:
            launch.launch()

    def _launch_now(self, launches: list) -> None:
        with _RECORDING:  # the first launch of a kernel loads its module
            for launch in launches:
                self._launch(*launch)

    def _launch(self, kernel, dim, inputs, outputs, *, record: bool = False):
        return wp.launch(
            kernel,
            dim=dim,
            inputs=inputs,
            outputs=outputs,
            device=self.device,
            block_dim=self.model.block_dim,
            record_cmd=record,
        )
