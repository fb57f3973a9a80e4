"""Device work arrays of the expression model for a fixed number of frames, and their host transfers."""

from __future__ import annotations

import numpy as np
import warp as wp

__all__ = ["FrameBuffers"]


class FrameBuffers:
    """Device work arrays for ``frames`` frames at once, flat frame after frame (allocated once, reused).

    Args:
        frames: frames evaluated by one launch of each kernel.
        vertex_count, triangle_count: sizes of the mesh.
        muscle_count, wrinkle_count: control widths (a zero width still gets one unused column).
        device: the model's Warp device.
        per_triangle: allocate the per-triangle intermediates of the staged plan (the tiled plan keeps
            them in shared memory).
    """

    def __init__(
        self,
        frames: int,
        vertex_count: int,
        triangle_count: int,
        muscle_count: int,
        wrinkle_count: int,
        *,
        device,
        per_triangle: bool = True,
    ):
        self.frames = frames
        self.device = device
        self.muscle_width = max(muscle_count, 1)
        self.wrinkle_width = max(wrinkle_count, 1)
        self.contraction = wp.zeros(frames * self.muscle_width, dtype=wp.float32, device=device)
        self.depth = wp.zeros(frames * self.wrinkle_width, dtype=wp.float32, device=device)
        self.muscle_points = wp.empty(frames * vertex_count, dtype=wp.vec3, device=device)
        self.area_vectors = wp.empty(frames * triangle_count if per_triangle else 0, dtype=wp.vec3, device=device)
        self.stretch_terms = wp.empty(frames * triangle_count if per_triangle else 0, dtype=wp.vec4, device=device)
        self.stretch = wp.empty(frames * vertex_count, dtype=wp.float32, device=device)
        self.bulge_points = wp.empty(frames * vertex_count, dtype=wp.vec3, device=device)
        self.final_points = wp.empty(frames * vertex_count, dtype=wp.vec3, device=device)
        self.launches: list[wp.Launch] = []
        """The frame's kernel launches, recorded once (CPU: replayed without re-packing arguments)."""
        self.graph = None
        """The same sequence captured as a CUDA graph (CUDA only)."""
        # Controls are written on the host: on the CPU straight into the kernels' arrays (numpy views
        # share their memory), on CUDA into pinned staging arrays copied up before each launch.
        staging = self._staging = bool(device.is_cuda)
        self._control_pairs = [
            (array, wp.zeros(array.shape, dtype=wp.float32, device="cpu", pinned=True) if staging else array, width)
            for array, width in ((self.contraction, self.muscle_width), (self.depth, self.wrinkle_width))
        ]
        self._control_views = [host.numpy().reshape(frames, width) for _, host, width in self._control_pairs]
        self._staged: wp.Event | None = None
        """Recorded after the last staging copy: the pinned arrays may be rewritten once it has passed."""
        self._host_views: dict[int, np.ndarray] = {}
        """Zero-copy numpy views of CPU buffers (the read-back copies out of them)."""

    def upload_controls(self, contraction: np.ndarray, depth: np.ndarray) -> None:
        """Write (count, M) contractions and (count, W) depths into the first frames; later frames get 0.

        On CUDA this only waits for the previous upload's copy (not for the kernels), so a caller that
        keeps its results on the device never blocks on them.
        """
        if self._staged is not None:
            wp.synchronize_event(self._staged)
        for view, values in zip(self._control_views, (contraction, depth)):
            view[: values.shape[0], : values.shape[1]] = values
            view[values.shape[0] :] = 0.0
        if self._staging:
            for array, host, _ in self._control_pairs:
                wp.copy(array, host)
        if self._staging:
            self._staged = wp.get_stream(self.device).record_event()

    def copy_controls(self, contraction: wp.array | None, depth: wp.array | None, first: int, count: int) -> None:
        """Copy ``count`` frames of device-resident controls, starting at frame ``first``, into the buffers.

        ``contraction`` is flat (F·M,) float32 and ``depth`` flat (F·W,) float32 on the model's device
        (``None``: zero contractions / the given default depths already uploaded). Device to device,
        no host involvement.
        """
        for array, source, width in (
            (self.contraction, contraction, self.muscle_width),
            (self.depth, depth, self.wrinkle_width),
        ):
            if source is not None and source.shape[0]:
                wp.copy(array, source, dest_offset=0, src_offset=first * width, count=count * width)

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
