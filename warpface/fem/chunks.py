"""Chunks of device steps with the host's copy-out of one chunk overlapping the device's next.

The CG solvers' ``run`` paths step in chunks: upload a chunk's driven inputs, queue its steps, queue the copy of its
recorded displacements (and of the device's status flags) to pinned host memory. :func:`pipelined_chunks` queues
chunk ``i + 1`` before it waits for chunk ``i``, so while the caller converts or stores chunk ``i`` the device steps
on; two host buffers of each kind take turns (``parity``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np
import warp as wp

from .kernels_integrator import single_precision

__all__ = ["ChunkedRun", "DeviceMirror", "pipelined_chunks"]


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


class ChunkedRun:
    """A solver's ``run`` in pipelined chunks: its device rings, two pinned host buffers of each kind (driven inputs
    in, float32 displacements out, status flags) taking turns by parity, and the work of one chunk.

    Args:
        trajectory: The device ring of driven displacements, shape (chunk, ..., D) of vec3 (``...``: models).
        record: The device ring of recorded displacements, shape (chunk, ..., N) of vec3.
        ring: The device ring index (``ring[0]``, the slot a step reads), zeroed at each chunk's start.
        status: Device arrays read back after each chunk, as handed to :meth:`run`'s ``check``.
    """

    def __init__(self, trajectory: wp.array, record: wp.array, ring: wp.array, *status: wp.array):
        device, pinned = record.device, record.device.is_cuda
        self.trajectory, self.ring, self.chunk = trajectory, ring, record.shape[0]
        self._rows = record.reshape((record.size // record.shape[-1], record.shape[-1]))  # (chunk · models, N)
        self._record32 = wp.zeros(self._rows.shape, dtype=wp.vec3f, device=device)
        self._driven = wp.zeros((2, *trajectory.shape), dtype=trajectory.dtype, device="cpu", pinned=pinned)
        self._out = wp.zeros((2, *record.shape), dtype=wp.vec3f, device="cpu", pinned=pinned)
        self._status = DeviceMirror(*status)

    def run(self, driven: np.ndarray, step: Callable, check: Callable) -> Iterator:
        """Step through driven displacements (T, ..., D, 3) [m]; yields each chunk's displacements (k, ..., N, 3)
        float32, a view of a host buffer valid until the next chunk is yielded.

        Args:
            driven: One row per step (its ``...`` and D at most the rings').
            step: Queues one step reading ring slot ``ring[0]`` (and advancing it); never waits.
            check: ``check(*status)`` raises if the status read back after a chunk booked a failure.
        """
        models = self._rows.shape[0] // self.chunk
        width = self.trajectory.size // self.chunk

        def queue(start: int, stop: int, slot: int):
            k = stop - start
            self.ring.zero_()  # each chunk restarts the ring at slot 0
            if driven.shape[-2]:  # any driven nodes
                self._driven.numpy()[slot][tuple(slice(0, size) for size in (k, *driven.shape[1:]))] = driven[
                    start:stop
                ]
                wp.copy(self.trajectory, self._driven[slot], count=k * width)
            for _ in range(k):
                step()
            wp.launch(
                single_precision,
                dim=(k * models, self._rows.shape[1]),
                inputs=[self._rows],
                outputs=[self._record32],
                device=self._record32.device,
            )
            wp.copy(self._out[slot], self._record32, count=k * models * self._rows.shape[1])
            return slot, k, self._status.queue(slot)

        def finish(queued) -> np.ndarray:
            slot, k, done = queued
            check(*self._status.read(slot, done))
            return self._out.numpy()[slot, :k]

        return pipelined_chunks(driven.shape[0], self.chunk, queue, finish, device=self._record32.device)
