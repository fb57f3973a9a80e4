"""Time-varying data of the tissue FEM, kept apart from the model (mesh, matrices) and the solvers.

Like Newton's ``State``/``Control``: a :class:`TissueState` holds the displacement, velocity and
acceleration of every node; a :class:`TissueControl` the displacements imposed on the driven nodes
at the end of a step. Both are Warp arrays on the solver's device, so a step
``solver.step(state_in, state_out, control)`` reads and writes device memory only.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .._validate import as_count, as_device

MAX_NODES = 1 << 25
"""Largest node count of a tissue state (33.5 M; a face tissue has thousands)."""

__all__ = ["TissueControl", "TissueState"]

_VECTORS = {wp.float32: wp.vec3f, wp.float64: wp.vec3d}


def _vector_type(dtype):
    if dtype not in _VECTORS:
        raise ValueError(f"state dtype must be wp.float32 or wp.float64, got {dtype}")
    return _VECTORS[dtype]


class TissueState:
    """Displacement ``d`` [m], velocity ``v`` [m/s] and acceleration ``a`` [m/s²] of N nodes.

    Each is a Warp array of shape (N,) of ``vec3d`` (or ``vec3f`` for a float32 solver) on ``device``.

    Args:
        node_count: N.
        dtype: ``wp.float64`` (default) or ``wp.float32``.
        device: Warp device; ``None`` uses Warp's preferred device.
    """

    def __init__(self, node_count: int, *, dtype=wp.float64, device=None):
        vec = _vector_type(dtype)
        device = as_device(device)
        node_count = as_count(node_count, "TissueState: node_count", maximum=MAX_NODES)
        self.d = wp.zeros(int(node_count), dtype=vec, device=device)
        """Displacement [m], shape (N,)."""
        self.v = wp.zeros(int(node_count), dtype=vec, device=device)
        """Velocity [m/s], shape (N,)."""
        self.a = wp.zeros(int(node_count), dtype=vec, device=device)
        """Acceleration [m/s^2], shape (N,)."""

    @property
    def node_count(self) -> int:
        """N."""
        return self.d.shape[0]

    @property
    def device(self):
        """The Warp device of the arrays."""
        return self.d.device

    def assign(self, d, v, a) -> None:
        """Copy host values (each shape (N, 3)) into the state (waits for the copy on non-CPU devices)."""
        host = np.float64 if self.d.dtype == wp.vec3d else np.float32
        for dest, src in ((self.d, d), (self.v, v), (self.a, a)):
            dest.assign(np.ascontiguousarray(src, dtype=host).reshape(-1, 3))

    def copy_from(self, other: TissueState) -> None:
        """Device copy of another state of the same size and type (no allocation, no sync)."""
        for dest, src in ((self.d, other.d), (self.v, other.v), (self.a, other.a)):
            wp.copy(dest, src)

    def numpy(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(d, v, a)`` as float64 host arrays of shape (N, 3) (copies; synchronises)."""
        return tuple(x.numpy().astype(np.float64) for x in (self.d, self.v, self.a))


class TissueControl:
    """Displacements [m] of the D driven nodes at the end of the next step, shape (D,) of vec3.

    Args:
        driven_count: D (may be 0: then ``driven`` holds one unused entry).
        dtype: ``wp.float64`` (default) or ``wp.float32``.
        device: Warp device; ``None`` uses Warp's preferred device.
    """

    def __init__(self, driven_count: int, *, dtype=wp.float64, device=None):
        self.driven_count = as_count(driven_count, "TissueControl: driven_count", maximum=MAX_NODES)
        """D."""
        self.driven = wp.zeros(max(self.driven_count, 1), dtype=_vector_type(dtype), device=as_device(device))
        """Driven displacements [m], shape (max(D, 1),), in the solver's driven-node order."""
