"""Double-buffered, asynchronous device → host copies of per-frame results through pinned memory."""

from __future__ import annotations

import numpy as np
import warp as wp

__all__ = ["PinnedReadback"]


class PinnedReadback:
    """Copies chunks of frames to host memory while the device works on the next chunk.

    Each :meth:`submit` queues the chunk's device → pinned copy behind its kernels (asynchronous, at
    full transfer speed) and then moves the *previous* chunk out of the other pinned buffer into the
    caller's array — the host copy overlaps the device's next chunk. :meth:`finish` completes the last.

    Args:
        elements: capacity of one buffer in elements of ``dtype`` (a chunk's frames × vertices).
        dtype: Warp element type (e.g. ``wp.vec3``).
        device: the CUDA device the results live on.
    """

    def __init__(self, elements: int, dtype, *, device):
        self.device = device
        self._buffers = [wp.empty(elements, dtype=dtype, device="cpu", pinned=True) for _ in range(2)]
        self._views = [buffer.numpy() for buffer in self._buffers]
        self._slot = 0
        self._pending: tuple | None = None
        """(event after the copy, buffer index, element count, destination) of the copy in flight."""

    def submit(self, source: wp.array, count: int, out: np.ndarray) -> None:
        """Queue copying ``source[:count]`` to the host, to land in ``out`` (``count`` elements' worth)."""
        wp.copy(self._buffers[self._slot], source, count=count)
        event = wp.get_stream(self.device).record_event()
        self.finish()
        self._pending = (event, self._slot, count, out)
        self._slot ^= 1

    def finish(self) -> None:
        """Wait for the copy in flight, if any, and move it into its destination."""
        if self._pending is None:
            return
        event, slot, count, out = self._pending
        self._pending = None
        wp.synchronize_event(event)
        out[...] = self._views[slot][:count].reshape(out.shape)
