"""Chunks of device steps with the host's copy-out of one chunk overlapping the device's next.

The CG solvers' ``run`` paths step in chunks: upload a chunk's driven inputs, queue its steps, queue the copy of its
recorded displacements (and of the device's status flags) to pinned host memory. :func:`pipelined_chunks` queues
chunk ``i + 1`` before it waits for chunk ``i``, so while the caller converts or stores chunk ``i`` the device steps
on; two host buffers of each kind take turns (``parity``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import warp as wp

__all__ = ["DeviceMirror", "pipelined_chunks"]


def pipelined_chunks(steps: int, chunk: int, queue: Callable, finish: Callable, *, device) -> Iterator:
    """Yield ``finish(queue(start, stop, parity))`` for the chunks ``[start, stop)`` of ``steps`` steps, in order.

    Args:
        steps: Steps in all.
        chunk: Steps per chunk (the last may be shorter).
        queue: ``queue(start, stop, parity)`` queues a chunk's work on ``device`` into the buffers of ``parity``
            (0 or 1) and returns what ``finish`` needs; it must not wait for the device.
        finish: ``finish(queued)`` waits for that chunk and returns its result (which may view the buffers of its
            parity: they are reused two chunks later, after the caller has moved on).
        device: The Warp device; it is synchronised when the iteration ends, early or not, so that nothing queued
            outlives the caller's loop.
    """
    pending = None
    try:
        for index, start in enumerate(range(0, steps, chunk)):
            queued = queue(start, min(start + chunk, steps), index % 2)
            if pending is not None:
                yield finish(pending)
            pending = queued
        if pending is not None:
            yield finish(pending)
    finally:
        wp.synchronize_device(device)


class DeviceMirror:
    """Pinned host copies of device arrays (a solver's status flags), two by parity, queued after each chunk.

    Args:
        arrays: The device arrays, all on one device.
    """

    def __init__(self, *arrays: wp.array):
        self.arrays = arrays
        pinned = arrays[0].device.is_cuda
        self.host = [wp.zeros((2, *array.shape), dtype=array.dtype, device="cpu", pinned=pinned) for array in arrays]

    def queue(self, parity: int):
        """Queue the copies into the host arrays of ``parity``; returns the CUDA event that marks them done (and
        everything queued before them), or ``None`` on the CPU, where the copies are done already."""
        for host, array in zip(self.host, self.arrays):
            wp.copy(host[parity], array)
        device = self.arrays[0].device
        return wp.get_stream(device).record_event() if device.is_cuda else None

    def read(self, parity: int, done) -> list:
        """Wait for ``done`` (from :meth:`queue`) and return the host copies of ``parity`` as NumPy views."""
        if done is not None:
            wp.synchronize_event(done)
        return [host.numpy()[parity] for host in self.host]
