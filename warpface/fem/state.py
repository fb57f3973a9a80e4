"""Time-varying data of the tissue FEM, kept apart from the model (mesh, matrices) and the solvers.

Like Newton's ``State``/``Control``: a :class:`TissueState` holds the displacement, velocity and
acceleration of every node; a :class:`TissueControl` the displacements imposed on the driven nodes
at the end of a step. Both are Warp arrays on the solver's device, so a step
``solver.step(state_in, state_out, control, dt)`` reads and writes device memory only. A batch of
B models on one mesh (``models=B``) has the model first in every array: (B, N) and (B, D).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .._validate import as_count, as_device

MAX_NODES = 1 << 25
"""Largest node count of a tissue state (33.5 M; a face tissue has thousands)."""

__all__ = ["ControlFeed", "TissueControl", "TissueState", "force_vectors"]

_VECTORS = {wp.float32: wp.vec3f, wp.float64: wp.vec3d}


def _vector_type(dtype):
    if dtype not in _VECTORS:
        raise ValueError(f"state dtype must be wp.float32 or wp.float64, got {dtype}")
    return _VECTORS[dtype]


class TissueState:
    """Displacement ``d`` [m], velocity ``v`` [m/s] and acceleration ``a`` [m/s²] of N nodes.

    Each is a Warp array of shape (N,) — (B, N) for a batch — of ``vec3d`` (or ``vec3f`` for a float32
    solver) on ``device``.

    Args:
        node_count: N.
        models: B, the models of a batch (:class:`~warpface.fem.solver_batch.BatchedCGSolver`); ``None``
            (default) for one model.
        dtype: ``wp.float64`` (default) or ``wp.float32``.
        device: Warp device; ``None`` uses Warp's preferred device.
    """

    def __init__(self, node_count: int, *, models: int | None = None, dtype=wp.float64, device=None):
        vec = _vector_type(dtype)
        device = as_device(device)
        shape = _shape(as_count(node_count, "TissueState: node_count", maximum=MAX_NODES), models)
        self.d = wp.zeros(shape, dtype=vec, device=device)
        """Displacement [m], shape (N,) or (B, N)."""
        self.v = wp.zeros(shape, dtype=vec, device=device)
        """Velocity [m/s], shape (N,) or (B, N)."""
        self.a = wp.zeros(shape, dtype=vec, device=device)
        """Acceleration [m/s^2], shape (N,) or (B, N)."""

    @property
    def node_count(self) -> int:
        """N."""
        return self.d.shape[-1]

    @property
    def model_count(self) -> int | None:
        """B of a batched state, else None."""
        return self.d.shape[0] if self.d.ndim == 2 else None

    @property
    def device(self):
        """The Warp device of the arrays."""
        return self.d.device

    def model(self, index: int) -> TissueState:
        """Model ``index`` of a batched state as a state of its own: views of its rows, no copy."""
        view = TissueState.__new__(TissueState)
        view.d, view.v, view.a = self.d[index], self.v[index], self.a[index]
        return view

    def assign(self, d, v, a) -> None:
        """Copy host values (each shape (N, 3), or (B, N, 3)) into the state (waits for the copy on non-CPU
        devices)."""
        host = np.float64 if self.d.dtype == wp.vec3d else np.float32
        for dest, src in ((self.d, d), (self.v, v), (self.a, a)):
            dest.assign(np.ascontiguousarray(src, dtype=host).reshape(*dest.shape, 3))

    def copy_from(self, other: TissueState) -> None:
        """Device copy of another state of the same size and type (no allocation, no sync)."""
        for dest, src in ((self.d, other.d), (self.v, other.v), (self.a, other.a)):
            wp.copy(dest, src)

    def numpy(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(d, v, a)`` as float64 host arrays of shape (N, 3) or (B, N, 3) (copies; synchronises)."""
        return tuple(x.numpy().astype(np.float64) for x in (self.d, self.v, self.a))


class TissueControl:
    """Displacements [m] of the D driven nodes at the end of the next step, shape (D,) — (B, D) for a batch — of vec3.

    Args:
        driven_count: D (may be 0: then ``driven`` holds one unused entry per model).
        models: B, the models of a batch; ``None`` (default) for one model.
        dtype: ``wp.float64`` (default) or ``wp.float32``.
        device: Warp device; ``None`` uses Warp's preferred device.
    """

    def __init__(self, driven_count: int, *, models: int | None = None, dtype=wp.float64, device=None):
        self.driven_count = as_count(driven_count, "TissueControl: driven_count", maximum=MAX_NODES)
        """D."""
        shape = _shape(max(self.driven_count, 1), models)
        self.driven = wp.zeros(shape, dtype=_vector_type(dtype), device=as_device(device))
        """Driven displacements [m], shape (max(D, 1),) or (B, max(D, 1)), in the solver's driven-node order."""

    def model(self, index: int) -> TissueControl:
        """Model ``index`` of a batched control as a control of its own: a view of its row, no copy."""
        view = TissueControl.__new__(TissueControl)
        view.driven_count, view.driven = self.driven_count, self.driven[index]
        return view


def force_vectors(force, node_count: int, vec, *, device, models: int | None = None):
    """An external nodal force [N] of a solver step as the solver's vec3 array: ``None`` stays None; a Warp array
    of ``vec`` (N,) — (B, N) for a batch — or of its scalar (N, 3) — (B, N, 3) —, contiguous, on ``device``, is
    returned as the (B,) N vec3 view of the same memory (no copy).

    Raises:
        TypeError: ``force`` is not a Warp array.
        ValueError: another shape, precision or device (naming what the solver needs).
    """
    if force is None:
        return None
    if not isinstance(force, wp.array):
        raise TypeError(f"force must be a Warp array of nodal forces [N], got {type(force).__name__}")
    shape = (node_count,) if models is None else (models, node_count)
    scalar = vec._wp_scalar_type_
    if force.dtype == scalar and force.shape == (*shape, 3) and force.is_contiguous:
        force = force.view(vec)
    if force.shape != shape or not wp.types.types_equal(force.dtype, vec) or force.device != device:
        raise ValueError(
            f"force must be {shape} {wp.types.type_repr(vec)} (or {(*shape, 3)} {wp.types.type_repr(scalar)}) "
            f"on {device}, got {force.shape} {wp.types.type_repr(force.dtype)} on {force.device}"
        )
    if not force.is_contiguous:
        raise ValueError("force must be a contiguous Warp array")
    return force


def _shape(count: int, models) -> tuple:
    """``(count,)``, or ``(models, count)`` for a batch (``models`` checked)."""
    if models is None:
        return (count,)
    return (as_count(models, "models", minimum=1, maximum=MAX_NODES), count)


class ControlFeed:
    """Host driven displacements into a :class:`TissueControl`, one step at a time, without waiting.

    On the CPU every launch is synchronous: values are written through a zero-copy view of the control. On a
    device they go through a (pinned) host ring of ``rows`` slots, each copied to the control by a queued copy,
    so a queued copy never reads a slot the host has overwritten since; the caller waits for the device once
    per ring (:attr:`wrapped`).

    Args:
        control: The control to fill (one model or a batch).
        rows: Slots of the host ring (the solver's chunk on a device).
    """

    def __init__(self, control: TissueControl, rows: int):
        self.control = control
        driven = control.driven
        self._count = control.driven_count
        self._view = driven.numpy()[..., : self._count, :] if driven.device.is_cpu else None
        self._staging = wp.zeros((rows, *driven.shape), dtype=driven.dtype, device="cpu", pinned=driven.device.is_cuda)
        self._slot = 0
        self.wrapped = False
        """The last :meth:`put` used the ring's last slot: wait for the device before the next."""

    def put(self, driven: np.ndarray) -> None:
        """Queue ``driven`` [m], shape (D, 3) — (B, D, 3) for a batch — into the control (no check)."""
        if self._count and self._view is not None:
            self._view[:] = driven
        elif self._count:
            slot, width = self._slot, self.control.driven.size
            self._staging.numpy()[slot, ..., : self._count, :] = driven
            wp.copy(self.control.driven, self._staging, src_offset=slot * width, count=width)
        self._slot = (self._slot + 1) % self._staging.shape[0]
        self.wrapped = self._slot == 0

    def rewind(self) -> None:
        """Start the ring again at its first slot (after the device has been waited for)."""
        self._slot = 0
        self.wrapped = False
