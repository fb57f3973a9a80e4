"""The data term of the solve on the device: stages → misfit, ``JᵀWJ`` and ``JᵀWe`` per frame (Warp kernels).

Only per-frame sums leave the device (the misfit, and with a Jacobian the K×K system and K gradient),
so a batch of many frames on CUDA moves a few kilobytes per frame per iteration, not the Jacobian.
The products run over each target point's *active* variables (the controls whose muscles reach the
point, plus the 6 pose variables), which exploits the rig's sparsity: a point feels a few muscles.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import warp as wp

from . import kernels
from .local_kernels import LocalExpression
from .targets import Observation

__all__ = ["DeviceObjective"]


class _FrameData:
    def __init__(self, frames: int, points: int, variables: int, device, frame_on):
        self.frames = frames
        self.targets = wp.zeros(max(frames * points, 1), dtype=wp.vec3d, device=device)
        self.weights = wp.zeros(max(frames * points, 1), dtype=wp.float64, device=device)
        self.rotation = wp.zeros(frames, dtype=wp.mat33d, device=device)
        self.translation = wp.zeros(frames, dtype=wp.vec3d, device=device)
        self.frame_on = frame_on
        """Shared with the model's stages: a frame turned off is neither evaluated nor summed."""
        self.hessian = wp.zeros(frames * variables * variables, dtype=wp.float64, device=device)
        self.gradient = wp.zeros(frames * variables, dtype=wp.float64, device=device)
        self.misfit = wp.zeros(frames, dtype=wp.float64, device=device)
        self.commands: dict[bool, object] = {}
        """The normal-equation launch, recorded per mode (replayed without re-packing arguments)."""
        self.cpu = device.is_cpu
        self.graphs: dict[bool, object] = {}
        """CPU: the evaluation per mode as a captured Warp graph (see :meth:`DeviceObjective.launch`)."""
        if self.cpu:  # NumPy views sharing the arrays' memory: per-frame inputs are written in place
            self.views = [a.numpy() for a in (self.rotation, self.translation, self.frame_on)]
            self.target_view, self.weight_view = self.targets.numpy(), self.weights.numpy()

    def set_frame_inputs(self, rotation: np.ndarray, translation: np.ndarray, frame_on: np.ndarray) -> None:
        values = (
            np.asarray(rotation, dtype=np.float64),
            np.asarray(translation, dtype=np.float64),
            np.asarray(frame_on, dtype=np.int32),
        )
        if self.cpu:
            for view, value in zip(self.views, values):
                view[...] = value
            return
        for array, value, dtype in zip(
            (self.rotation, self.translation, self.frame_on), values, (wp.mat33d, wp.vec3d, wp.int32)
        ):
            array.assign(wp.array(np.ascontiguousarray(value), dtype=dtype, device="cpu"))


class DeviceObjective:
    """Evaluates the data term of fixed target locations for many frames at once.

    Args:
        model: the neighbourhood evaluation (its vertices are the observation's).
        observation: where the targets sit (``P``).
        pose: add the 6 rigid-pose variables (rotation vector, translation) after the controls.
        origin: the pose's rotation centre [mesh units]; unit: the face unit ℓ [mesh units].
    """

    def __init__(
        self, model: LocalExpression, observation: Observation, *, pose: bool, origin: np.ndarray, unit: float
    ):
        self.model = model
        self.device = model.device
        self.control_count = model.control_count
        self.variable_count = model.control_count + (6 if pose else 0)
        self.layout = kernels.layout_of(model.control_count, model.muscle_count, model.basis_count, self.variable_count)
        """The block sizes of the normal equations' kernel and the device iteration."""
        self.point_count = observation.count
        self.origin = wp.vec3d(*np.asarray(origin, dtype=np.float64))
        self.unit = float(unit)
        matrix = observation.matrix.tocsr()
        matrix.sort_indices()
        d = self.device
        self._points = kernels.PointRows()
        self._points.offsets = wp.array(matrix.indptr.astype(np.int32), dtype=wp.int32, device=d)
        self._points.vertex = wp.array(matrix.indices.astype(np.int32), dtype=wp.int32, device=d)
        self._points.weight = wp.array(matrix.data.astype(np.float64), dtype=wp.float64, device=d)
        # A point's active variables: the union of its vertices' active controls, then the pose.
        vertex_active = model.active_controls["s0"].astype(bool)
        point_active = (matrix.astype(bool) @ vertex_active).astype(bool).tocsr()
        if pose:
            point_active = sp.hstack([point_active, sp.csr_matrix(np.ones((self.point_count, 6), dtype=bool))]).tocsr()
        point_active.sort_indices()
        self._active_offsets = wp.array(point_active.indptr.astype(np.int32), dtype=wp.int32, device=d)
        self._active = wp.array(
            (point_active.indices if point_active.nnz else np.zeros(1)).astype(np.int32), dtype=wp.int32, device=d
        )
        self._data: dict[int, _FrameData] = {}
        self._bound: _FrameData | None = None

    def bind(self, targets: np.ndarray, weights: np.ndarray) -> None:
        """Upload a chunk's targets (F, N, 3) [face units] and normalised weights (F, N) (0 = missing)."""
        frames = len(targets)
        if frames not in self._data:
            self._data[frames] = _FrameData(
                frames, self.point_count, self.variable_count, self.device, self.model.buffers(frames).frame_on
            )
        data = self._bound = self._data[frames]
        if data.cpu:
            data.target_view[: targets.size // 3] = np.reshape(targets, (-1, 3))
            data.weight_view[: weights.size] = np.reshape(weights, -1)
            return
        data.targets.assign(
            wp.array(np.ascontiguousarray(targets, dtype=np.float64).reshape(-1, 3), dtype=wp.vec3d, device="cpu")
        )
        data.weights.assign(
            wp.array(np.ascontiguousarray(weights, dtype=np.float64).reshape(-1), dtype=wp.float64, device="cpu")
        )

    def evaluate(
        self,
        controls: np.ndarray,
        rotation: np.ndarray,
        translation: np.ndarray,
        frame_on: np.ndarray,
        *,
        jacobian: bool,
    ):
        """Misfit (F,), and with ``jacobian`` the systems ``JᵀWJ`` (F, K, K) and ``JᵀWe`` (F, K) [mesh-unit columns].

        Frames with ``frame_on`` False are skipped (zeros). Returns host arrays.
        """
        data = self._bound
        frames = data.frames
        self.model.upload(self.model.buffers(frames), controls)
        data.set_frame_inputs(rotation, translation, frame_on)
        self.launch(jacobian=jacobian)
        misfit = data.misfit.numpy().copy()
        if not jacobian:
            return misfit, None, None
        k = self.variable_count
        upper = data.hessian.numpy().reshape(frames, k, k)  # the kernel sums the upper triangle only
        hessian = np.triu(upper) + np.transpose(np.triu(upper, 1), (0, 2, 1))
        return misfit, hessian, data.gradient.numpy().reshape(frames, k).copy()

    def inputs(self):
        """The bound chunk's device inputs and outputs: ``(controls (F·M,), rotation (F,), translation (F,),
        frame_on (F,), hessian (F·K·K,; upper triangle summed), gradient (F·K,), misfit (F,))`` — written and
        read by the on-device iteration (:mod:`.device_steps`) between :meth:`launch` calls."""
        data = self._bound
        buffers = self.model.buffers(data.frames)
        return (
            buffers.controls,
            data.rotation,
            data.translation,
            data.frame_on,
            data.hessian,
            data.gradient,
            data.misfit,
        )

    def launch(self, *, jacobian: bool) -> None:
        """Evaluate the bound chunk at the device inputs already in place (see :meth:`inputs`); no readback.

        On the CPU the evaluation's launches and clears are captured once per mode into a Warp graph and
        replayed in one call (Warp's C++ loop): an evaluation is ~8 small launches, and packing each one's
        arguments in Python would be a large share of a landmark frame's value evaluation.
        """
        data = self._bound
        if data.cpu:
            graph = data.graphs.get(jacobian)
            if graph is None:
                with wp.ScopedCapture(device=self.device) as capture:
                    self._evaluation(data, jacobian)
                graph = data.graphs[jacobian] = capture.graph
            wp.capture_launch(graph)
            return
        self._evaluation(data, jacobian)

    def _evaluation(self, data: _FrameData, jacobian: bool) -> None:
        """The launches of one evaluation of ``data`` (see :meth:`launch`)."""
        frames = data.frames
        buffers = self.model.buffers(frames)
        self.model.launch(buffers, frames, jacobian, per_control=False)  # the jaw's chain rule is in the kernel below
        data.misfit.zero_()
        if jacobian:
            data.hessian.zero_()
            data.gradient.zero_()
        if jacobian not in data.commands:
            data.commands[jacobian] = wp.launch(
                kernels.normal_equations,
                dim=frames * self.point_count,
                device=self.device,
                record_cmd=True,
                inputs=[
                    buffers.x3,
                    buffers.dx3_basis,
                    buffers.controls,
                    self._points,
                    self._active_offsets,
                    self._active,
                    data.targets,
                    data.weights,
                    data.rotation,
                    data.translation,
                    data.frame_on,
                    self.origin,
                    wp.float64(self.unit),
                    self.layout,
                    self.model.count,
                    self.point_count,
                    1 if jacobian else 0,
                ],
                outputs=[data.hessian, data.gradient, data.misfit],
            )
        data.commands[jacobian].launch()
