"""The solver's Levenberg–Marquardt iteration with every frame's state on the Warp device (:mod:`.step_kernels`).

A chunk of F frames goes up once and comes back once; in between, the host only reads one counter per
launch round (frames still iterating, trials outstanding) to know when to stop. Same iteration and
tests as the host loop in :meth:`.solver.Solver._solve_frames`, so results agree to rounding.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from . import step_kernels
from .objective import DeviceObjective

__all__ = ["DeviceSteps"]


class _State:
    """Per-frame iteration state and scratch of one chunk size, on the device."""

    def __init__(self, frames: int, controls: int, size: int, device):
        def f64(n):
            return wp.zeros(max(n, 1), dtype=wp.float64, device=device)

        def i32(n):
            return wp.zeros(max(n, 1), dtype=wp.int32, device=device)

        self.u, self.previous, self.trial_u = f64(frames * controls), f64(frames * controls), f64(frames * controls)
        self.lower, self.upper = f64(frames * controls), f64(frames * controls)
        """The bounds of the current iteration (the box narrowed to each control's L1 orthant)."""
        self.rotation, self.trial_rotation = (wp.zeros(frames, dtype=wp.mat33d, device=device) for _ in range(2))
        self.translation, self.trial_translation = (wp.zeros(frames, dtype=wp.vec3d, device=device) for _ in range(2))
        self.damping, self.current, self.misfit = f64(frames), f64(frames), f64(frames)
        self.active, self.converged, self.iterations = i32(frames), i32(frames), i32(frames)
        self.tries, self.pending, self.counter = i32(frames), i32(frames), i32(1)
        self.held, self.step, self.system = i32(frames * size), f64(frames * size), f64(frames * size * size)
        self.commands: dict | None = None
        self.cpu = device.is_cpu
        self.counter_view = self.counter.numpy() if self.cpu else None
        self._views: dict[int, np.ndarray] = {}
        """CPU: NumPy views sharing the arrays' memory (read and written in place, no copies)."""

    def host(self, array: wp.array) -> np.ndarray:
        """The array's values on the host (CPU: a cached view; CUDA: a copy)."""
        if not self.cpu:
            return array.numpy()
        view = self._views.get(id(array))
        if view is None:
            view = self._views[id(array)] = array.numpy()
        return view

    def upload(self, array: wp.array, value: np.ndarray) -> None:
        """Write host values into a state array of the same size (CPU: in place)."""
        if self.cpu:
            self.host(array).reshape(-1)[: np.size(value)] = np.reshape(value, -1)
            return
        dtype = array.dtype
        flat = np.ascontiguousarray(value, dtype=np.int32 if dtype is wp.int32 else np.float64)
        array.assign(wp.array(flat.reshape(-1) if dtype in (wp.float64, wp.int32) else flat, dtype=dtype, device="cpu"))

    def count(self) -> int:
        """The counter's value (a host read: on CUDA, a synchronisation)."""
        if self.counter_view is not None:
            return int(self.counter_view[0])
        return int(self.counter.numpy()[0])


class DeviceSteps:
    """Runs the projected Levenberg–Marquardt loop of a :class:`DeviceObjective` on its device.

    Args:
        objective: the data term (targets bound per chunk by the caller).
        scale: (C,) control scale (``u = c·scale``); low, high: (C,) scaled bounds.
        pairs: (P, 2) mirrored control pairs; unit: the face unit ℓ [mesh units].
    """

    def __init__(
        self,
        objective: DeviceObjective,
        *,
        scale: np.ndarray,
        low: np.ndarray,
        high: np.ndarray,
        pairs: np.ndarray,
        unit: float,
    ):
        self.objective = objective
        d = self.device = objective.device
        self.control_count = objective.control_count
        self.muscle_count = objective.model.muscle_count
        self.basis_count = objective.model.basis_count
        """Columns of the model's input per frame: muscles, then with a jaw ``sin θ, 1 − cos θ``, protrusion, slide."""
        self.size = objective.variable_count
        column = np.full(self.size, 1.0 / unit)
        column[: self.control_count] = 1.0 / (scale * unit)
        f64 = lambda a: wp.array(np.ascontiguousarray(a, dtype=np.float64), dtype=wp.float64, device=d)  # noqa: E731
        self._column, self._scale = f64(column), f64(scale)
        # Infinite bounds stay infinite in float64: min/max with ±inf is exact.
        self._low, self._high = f64(low), f64(high)
        pairs = np.asarray(pairs, dtype=np.int32).reshape(-1, 2)
        self._pair_count = len(pairs)
        self._pairs = wp.array(pairs.reshape(-1) if len(pairs) else np.zeros(2, np.int32), dtype=wp.int32, device=d)
        self._states: dict[int, _State] = {}

    def run(self, u, rotation, translation, previous, active, damping, *, options, smooth: float) -> dict:
        """Iterate the bound chunk from ``u`` (F, M) scaled controls, ``rotation`` (F, 3, 3), ``translation``
        (F, 3) [face units], ``previous`` (F, M) temporal anchor, ``active`` (F,) bool, ``damping`` (F,).

        Returns host arrays: ``u``, ``rotation``, ``translation``, ``misfit``, ``converged``, ``active``,
        ``iterations``.
        """
        frames = len(u)
        state = self._states.get(frames)
        if state is None:
            state = self._states[frames] = _State(frames, self.control_count, self.size, self.device)
        for array, value in (
            (state.u, u),
            (state.previous, previous),
            (state.rotation, rotation),
            (state.translation, translation),
            (state.damping, damping),
            (state.active, active),
        ):
            state.upload(array, value)
        for array in (state.converged, state.iterations, state.misfit):
            array.zero_()
        load, begin, judge = self._commands(state, frames, options, smooth)
        for _ in range(options.max_iterations):
            state.counter.zero_()
            load.launch()
            if state.count() == 0:
                break
            self.objective.launch(jacobian=True)
            state.counter.zero_()
            begin.launch()
            while state.count() > 0:
                self.objective.launch(jacobian=False)
                state.counter.zero_()
                judge.launch()
        m = self.control_count
        host = state.host
        return dict(
            u=host(state.u)[: frames * m].reshape(frames, m).copy(),
            rotation=host(state.rotation).copy(),
            translation=host(state.translation).copy(),
            misfit=host(state.misfit)[:frames].copy(),
            converged=host(state.converged)[:frames].astype(bool),
            active=host(state.active)[:frames].astype(bool),
            iterations=host(state.iterations)[:frames].astype(np.int64),
        )

    def _commands(self, state: _State, frames: int, options, smooth: float):
        """The three launches of a chunk, recorded once per (options, smoothness) and replayed."""
        key = (
            options.l2,
            options.l1,
            smooth,
            options.symmetry,
            options.tolerance,
            options.step_tolerance,
            options.energy_tolerance,
        )
        if state.commands is not None and state.commands[0] == key:
            return state.commands[1]
        controls, rotation_out, translation_out, frame_on, hessian, gradient, data_misfit = self.objective.inputs()
        s, d, m, k = state, self.device, self.control_count, self.size
        layout = [m, self.muscle_count, self.basis_count]
        f = wp.float64
        symmetry = options.symmetry if self._pair_count else 0.0
        regular = [self._pairs, self._pair_count, f(options.l2), f(options.l1), f(smooth), f(symmetry)]
        model_io = [controls, rotation_out, translation_out, frame_on]
        load = wp.launch(
            step_kernels.load_current,
            dim=frames,
            device=d,
            record_cmd=True,
            inputs=[s.u, s.rotation, s.translation, s.active, self._scale, *layout],
            outputs=[controls, rotation_out, translation_out, frame_on, s.counter],
        )
        begin = wp.launch(
            step_kernels.begin_iteration,
            dim=frames,
            device=d,
            record_cmd=True,
            inputs=[
                hessian,
                gradient,
                data_misfit,
                self._column,
                self._low,
                self._high,
                self._scale,
                s.previous,
                *regular,
                f(options.tolerance),
                f(options.energy_tolerance),
                *layout,
                k,
            ],
            outputs=[
                s.u,
                s.rotation,
                s.translation,
                s.damping,
                s.current,
                s.misfit,
                s.active,
                s.converged,
                s.iterations,
                s.held,
                s.lower,
                s.upper,
                s.tries,
                s.system,
                s.step,
                s.trial_u,
                s.trial_rotation,
                s.trial_translation,
                *model_io,
                s.pending,
                s.counter,
            ],
        )
        judge = wp.launch(
            step_kernels.judge_trial,
            dim=frames,
            device=d,
            record_cmd=True,
            inputs=[
                hessian,
                gradient,
                data_misfit,
                s.lower,
                s.upper,
                self._scale,
                s.previous,
                *regular,
                f(options.tolerance),
                f(options.step_tolerance),
                f(options.energy_tolerance),
                *layout,
                k,
            ],
            outputs=[
                s.u,
                s.rotation,
                s.translation,
                s.damping,
                s.current,
                s.misfit,
                s.active,
                s.converged,
                s.held,
                s.tries,
                s.system,
                s.step,
                s.trial_u,
                s.trial_rotation,
                s.trial_translation,
                *model_io,
                s.pending,
                s.counter,
            ],
        )
        state.commands = (key, (load, begin, judge))
        return load, begin, judge
