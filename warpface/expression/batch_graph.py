"""A device batch as one CUDA graph: staging of host controls and the captured graphs, reused across calls."""

from __future__ import annotations

from collections import OrderedDict
from typing import Callable

import numpy as np
import warp as wp

__all__ = ["BatchGraphs"]


class BatchGraphs:
    """Captured graphs of a chunked batched evaluation on CUDA, and the device copies of host controls.

    On the CPU nothing is captured (:meth:`run` runs the work) and host controls are written straight
    into the kernels' array.

    A batch of F frames runs in chunks of frames; the whole sequence — per chunk: copy the chunk's
    controls device to device, the kernels, copy the result into the caller's array — is captured
    once per key (output, control arrays, F, chunk size) and then replayed: one launch from the host
    per batch and no host sync. Graphs are kept for the ``capacity`` most recent keys.

    Args:
        device: the model's Warp device.
        capacity: number of graphs kept (least recently used dropped first).
    """

    def __init__(self, *, device, capacity: int = 8):
        self.device = device
        self.capacity = capacity
        self._graphs: OrderedDict = OrderedDict()
        self._staging: dict[tuple, object] = {}

    def stage(self, values: np.ndarray, slot: str) -> wp.array:
        """Host ``values`` (F, width) copied asynchronously to a device array kept for this slot and shape.

        Returns that flat float32 device array (stable across calls, so a graph reading it is reused).
        Two pinned host buffers alternate: writing one waits only for the copy issued two calls ago,
        so one batch can be in flight while the next is staged.
        """
        frames, width = values.shape
        key = (slot, frames, width)
        if self.device.is_cpu:  # kernels run synchronously: write the kernels' array directly
            array = self._staging.get(key)
            if array is None:
                array = self._staging[key] = wp.zeros(frames * width, dtype=wp.float32, device=self.device)
            array.numpy().reshape(frames, width)[...] = values
            return array
        entry = self._staging.get(key)
        if entry is None:
            device_array = wp.zeros(frames * width, dtype=wp.float32, device=self.device)
            pinned = [[wp.zeros(frames * width, dtype=wp.float32, device="cpu", pinned=True), None] for _ in range(2)]
            entry = self._staging[key] = (device_array, pinned)
        device_array, pinned = entry
        pinned.append(pinned.pop(0))
        host, copied = pinned[-1]
        if copied is not None:
            wp.synchronize_event(copied)
        host.numpy().reshape(frames, width)[...] = values
        if values.size:
            wp.copy(device_array, host)
        pinned[-1][1] = wp.get_stream(self.device).record_event()
        return device_array

    def run(self, key: tuple, capture: Callable[[], None]) -> None:
        """Replay the graph of ``key``, capturing ``capture()``'s device work first if it is new."""
        if not self.device.is_cuda:
            capture()
            return
        graph = self._graphs.get(key)
        if graph is None:
            with wp.ScopedCapture(device=self.device) as scope:
                capture()
            graph = self._graphs[key] = scope.graph
            while len(self._graphs) > self.capacity:
                self._graphs.popitem(last=False)
        else:
            self._graphs.move_to_end(key)
        wp.capture_launch(graph)

    def __len__(self) -> int:
        return len(self._graphs)
