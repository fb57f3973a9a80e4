"""What the device CG solvers share: the step contract, graphs per binding, chunked runs, status and reset.

A device solver (:class:`~warpface.fem.solver_cg.CGSolver`, :class:`~warpface.fem.solver_batch.BatchedCGSolver`)
advances a state under a control with ``step(state_in, state_out, control, dt)``, like the direct solver. Its
step kernels see every per-model array with the model first (a single model is a batch of one), so one
*binding* — the arrays of a step: input and output state, the driven displacements as a ring of slots
``(chunk, B, D)`` and the ring of recorded displacements ``(chunk, B, N)`` — serves both. A binding is made once
per combination of arrays and, on CUDA, captured once as a graph: a step is then one ``wp.capture_launch``, no
allocation and no host read-back. Convergence is booked on the device and raised by :meth:`synchronize`.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import warp as wp

from ..errors import ConvergenceError
from .chunks import ChunkedRun
from .newmark import check_step_dt, step_key
from .state import TissueControl, TissueState, force_vectors

__all__ = ["DeviceSolver"]


class DeviceSolver:
    """Base of the device CG solvers (module docstring).

    A subclass sets, before its first step: ``device``, ``coefficients``, ``options``
    (:class:`~warpface.fem.options.CGOptions`), ``node_count``, ``free_nodes``, ``driven_nodes``, ``model_count``
    (``None`` for a single model, whose states are (N,)), ``_vec`` (the state's vector type), the rings
    ``_trajectory`` (chunk, B, max(D, 1)), ``_record`` (chunk, B, N) and ``_ring`` / ``_step_ring`` (2,), the
    extrapolation arrays ``_history`` (2, B, F) and ``_guess``, the device status ``_barrier`` (B, 3), ``_status``
    (B, 5), ``_failure`` (B, 2), ``_step_count`` (B,) and ``_cg_iter``; and implements ``_launch_sequence``.
    """

    kind = "cg"
    """Solver family, as ``TissueSimulation(solver=...)`` names it."""

    def _init_bindings(self) -> None:
        self._free_nodes_device = wp.array(self.free_nodes.astype(np.int32), dtype=wp.int32, device=self.device)
        self._no_force = wp.zeros((1, 0), dtype=self._vec, device=self.device)  # kernels skip an empty force
        self._no_force_one = wp.zeros(0, dtype=self._vec, device=self.device)
        self._use_graph = self.options.graph_on(device=self.device)
        self._graphs: dict = {}
        self._bindings: dict = {}
        self._chunked = None  # run_chunks' host buffers, allocated on its first call

    # ------------------------------------------------------------------ bindings
    def _batch_view(self, array: wp.array) -> wp.array:
        """``array`` with the model first: a single model's (N,) array as (1, N)."""
        return array.reshape((1, *array.shape)) if self.model_count is None else array

    def _check_state(self, name: str, state) -> None:
        if not isinstance(state, TissueState):
            raise TypeError(f"{name} must be a TissueState, got {type(state).__name__}")
        shape = (self.node_count,) if self.model_count is None else (self.model_count, self.node_count)
        if state.d.shape != shape or not wp.types.types_equal(state.d.dtype, self._vec) or state.device != self.device:
            precision = wp.types.type_repr(self._vec._wp_scalar_type_)
            models = "" if self.model_count is None else f" of {self.model_count} models"
            raise ValueError(f"{name} must hold {self.node_count} nodes{models} of {precision} vec3 on {self.device}")

    def _binding(self, state_in, state_out, trajectory, ring, record, key, force=None) -> SimpleNamespace:
        """The arrays of one step, per model first: the states, ``trajectory`` (chunk, B, D), ``record``
        (chunk, B, N) and ``force`` (B, N), or (1, 0) without one; for a single model also ``state`` (d, v, a of
        ``state_in``), ``driven`` (chunk, D) and ``force_one`` (N,) or (0,) for the launched loop's kernels."""
        view = self._batch_view
        binding = SimpleNamespace(
            d_in=view(state_in.d),
            v_in=view(state_in.v),
            a_in=view(state_in.a),
            d_out=view(state_out.d),
            v_out=view(state_out.v),
            a_out=view(state_out.a),
            trajectory=trajectory,
            ring=ring,
            record=record,
            chunk=trajectory.shape[0],
            force=self._no_force if force is None else view(force),
            key=key,
            arrays=(state_in, state_out),  # keeps the bound pointers valid
        )
        if self.model_count is None:
            binding.state = (state_in.d, state_in.v, state_in.a)
            binding.driven = trajectory.reshape((trajectory.shape[0], trajectory.shape[2]))
            binding.force_one = self._no_force_one if force is None else force
        return binding

    def _binding_for_step(self, state_in, state_out, control, force=None) -> SimpleNamespace:
        forced = None if force is None else (getattr(force, "ptr", id(force)), getattr(force, "shape", None))
        key = ("step", *step_key(state_in, state_out, control), forced)
        binding = self._bindings.get(key)
        if binding is None:
            force = force_vectors(force, self.node_count, self._vec, device=self.device, models=self.model_count)
            self._check_state("state_in", state_in)
            self._check_state("state_out", state_out)
            if not isinstance(control, TissueControl):
                raise TypeError(f"control must be a TissueControl, got {type(control).__name__}")
            driven = self._batch_view(control.driven)
            if driven.shape != self._trajectory.shape[1:] or not wp.types.types_equal(driven.dtype, self._vec):
                raise ValueError(
                    f"control must hold {self.driven_nodes.size} driven displacements"
                    f"{'' if self.model_count is None else f' for {self.model_count} models'} of this solver's vec3"
                )
            trajectory = driven.reshape((1, *driven.shape))
            record = self._batch_view(state_out.d)
            record = record.reshape((1, *record.shape))
            binding = self._binding(state_in, state_out, trajectory, self._step_ring, record, key, force)
            binding.arrays += (control, force)
            self._bindings[key] = binding
        return binding

    def _launch(self, binding) -> None:
        if not self._use_graph:
            self._launch_sequence(binding)
            return
        graph = self._graphs.get(binding.key)
        if graph is None:
            with wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
                self._launch_sequence(binding)
            graph = self._graphs[binding.key] = capture.graph
        wp.capture_launch(graph)

    # ------------------------------------------------------------------ stepping
    def step(
        self, state_in: TissueState, state_out: TissueState, control: TissueControl, dt=None, *, force=None
    ) -> None:
        """Queue one time step from ``state_in`` to ``state_out`` (may be the same object); never waits.

        Args:
            state_in, state_out: States of this solver's size, precision and device.
            control: Driven displacements at the end of the step.
            dt: The time step [s]; None or the solver's own (checked).
            force: External nodal force [N] at the end of the step, added to the step's right-hand side on the
                free nodes (fixed and driven rows are not read): a Warp array of this solver's vec3 (N,) — (B, N)
                for a batch — or of its scalar (N, 3), on its device; read by the step's kernels where it lies
                (write it in place between steps). None: no force.

        The first step with a new combination of state and control arrays binds them (and on CUDA captures
        a graph); later steps with the same arrays reuse it. A convergence failure is booked on the device
        and raised by :meth:`synchronize`.

        Raises:
            TypeError: the states are not TissueStates, the control not a TissueControl, or ``force`` not a Warp
                array.
            ValueError: a state, the control or the force does not match the solver (size, precision, device), or
                another dt.
        """
        check_step_dt(dt, self.coefficients)
        self._launch(self._binding_for_step(state_in, state_out, control, force))

    def run_chunks(self, state: TissueState, driven: np.ndarray):
        """Advance ``state`` in place through driven displacements (T, [B,] D, 3) [m], ``chunk`` steps at a time;
        yields each chunk's displacements (k, [B,] N, 3) float32, a view of a host buffer valid until the next.

        A chunk is one host-to-device copy of its driven inputs, ``k`` launches and one copy back, queued before
        the previous chunk is waited for (:class:`~warpface.fem.chunks.ChunkedRun`): on CUDA the device steps on
        while the host copies a chunk out.

        Raises:
            ConvergenceError: a step of the yielded chunk (or an earlier one) did not converge.
        """
        self.synchronize()
        if not isinstance(state, TissueState):
            raise TypeError(f"state must be a TissueState, got {type(state).__name__}")
        key = ("chunk", state.d.ptr)
        binding = self._bindings.get(key)
        if binding is None:
            self._check_state("state", state)
            binding = self._binding(state, state, self._trajectory, self._ring, self._record, key)
            self._bindings[key] = binding
        if self._chunked is None:
            self._chunked = ChunkedRun(
                self._trajectory, self._record, self._ring, self._barrier, self._status, self._failure
            )
        single = self.model_count is None
        chunks = self._chunked.run(
            driven[:, None] if single else driven, lambda: self._launch(binding), self._raise_on_failure
        )
        return (block[:, 0] for block in chunks) if single else chunks

    # ------------------------------------------------------------------ status and reset
    def synchronize(self) -> None:
        """Wait for queued steps; raise :class:`~warpface.errors.ConvergenceError` if any failed (naming the
        first model that did, in a batch)."""
        wp.synchronize_device(self.device)
        self._raise_on_failure(self._barrier.numpy(), self._status.numpy(), self._failure.numpy())

    def _raise_on_failure(self, barrier: np.ndarray, status: np.ndarray, failure: np.ndarray) -> None:
        """Raise if the device booked a failure: ``barrier`` (B, 3), ``status`` (B, 5), ``failure`` (B, 2)."""
        if np.any(barrier[:, 1]):
            raise RuntimeError(
                f"the persistent CG loop waited too long at a grid barrier on {self.device} (its blocks were not "
                "all resident); use CGOptions(loop='launched')"
            )
        failed = np.flatnonzero(status[:, 0])
        if failed.size:
            b = int(failed[0])
            residual, tolerance = failure[b]
            model = "" if self.model_count is None else f"model {b}: "
            raise ConvergenceError(
                f"{model}CG did not converge at step {int(status[b, 1])} ({int(status[b, 0])} failed steps): "
                f"residual {residual:.3e} > tolerance {tolerance:.3e} after {self.options.maxiter} iterations; "
                "raise CGOptions.maxiter, loosen CGOptions.tolerance or use another preconditioner"
            )

    def reset(self, state: TissueState) -> None:
        """Start a new trajectory from ``state``: clear counters and failure status, and seed the extrapolation
        with the increments of a motion of constant acceleration that ends in ``state`` (so the first
        extrapolated start equals the Newmark predictor). Synchronises."""
        self._check_state("state", state)
        wp.synchronize_device(self.device)
        c = self.coefficients
        _, v, a = state.numpy()
        v = v.reshape(-1, self.node_count, 3)[:, self.free_nodes]
        a = a.reshape(-1, self.node_count, 3)[:, self.free_nodes]
        increments = np.stack([c.dt * v - c.half_dt_squared * a, c.dt * v - 3.0 * c.half_dt_squared * a])
        self._history.assign(increments.astype(np.float64 if self._vec == wp.vec3d else np.float32))
        for array in (
            self._guess,
            self._ring,
            self._step_ring,
            self._step_count,
            self._status,
            self._failure,
            self._barrier,
            self._cg_iter,
        ):
            array.zero_()
