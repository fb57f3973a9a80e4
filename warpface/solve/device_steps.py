"""The solver's Levenberg–Marquardt iteration with every frame's state on the Warp device (:mod:`.step_kernels`).

A chunk of F frames goes up once and comes back once; in between, the host only reads one counter per
launch round (frames still iterating, trials outstanding) to know when to stop. Same iteration and
tests as the NumPy loop of :mod:`.host_steps`, so results agree to rounding.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from . import step_kernels
from .host_steps import Iteration

__all__ = ["DeviceSteps"]


class _State:
    """Per-frame iteration state and scratch of one chunk size, on the device (a :class:`.step_kernels.Iterate`)."""

    def __init__(self, frames: int, controls: int, size: int, device):
        def f64(n):
            return wp.zeros(max(n, 1), dtype=wp.float64, device=device)

        def i32(n):
            return wp.zeros(max(n, 1), dtype=wp.int32, device=device)

        s = self.arrays = step_kernels.Iterate()
        s.u, s.previous, s.trial_u = f64(frames * controls), f64(frames * controls), f64(frames * controls)
        s.lower, s.upper = f64(frames * controls), f64(frames * controls)
        """The bounds of the current iteration (the box narrowed to each control's L1 orthant)."""
        s.rotation, s.trial_rotation = (wp.zeros(frames, dtype=wp.mat33d, device=device) for _ in range(2))
        s.translation, s.trial_translation = (wp.zeros(frames, dtype=wp.vec3d, device=device) for _ in range(2))
        s.damping, s.current, s.misfit = f64(frames), f64(frames), f64(frames)
        s.active, s.converged, s.iterations = i32(frames), i32(frames), i32(frames)
        s.tries, s.pending, s.counter = i32(frames), i32(frames), i32(1)
        s.held, s.step, s.system = i32(frames * size), f64(frames * size), f64(frames * size * size)
        self.commands: dict | None = None
        self.cpu = device.is_cpu
        self.counter_view = s.counter.numpy() if self.cpu else None
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
        return int(self.arrays.counter.numpy()[0])


class DeviceSteps(Iteration):
    """Runs the projected Levenberg–Marquardt loop of a :class:`DeviceObjective` on its device
    (arguments: :class:`.host_steps.Iteration`)."""

    def __init__(self, objective, **constants):
        super().__init__(objective, **constants)
        d = self.device = objective.device
        self.control_count = objective.control_count
        self.muscle_count = objective.model.muscle_count
        self.basis_count = objective.model.basis_count
        """Columns of the model's input per frame: muscles, then with a jaw ``sin θ, 1 − cos θ``, protrusion, slide."""
        self.size = objective.variable_count

        def f64(a):
            return wp.array(np.ascontiguousarray(a, dtype=np.float64), dtype=wp.float64, device=d)

        scaling = self._scaling = step_kernels.Scaling()
        # Infinite bounds stay infinite in float64: min/max with ±inf is exact.
        scaling.column, scaling.scale, scaling.low, scaling.high = (
            f64(a) for a in (self.column, self.scale, self.low, self.high)
        )
        self._layout = objective.layout
        pairs = self.pairs.astype(np.int32)
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
        s = state.arrays
        for array, value in (
            (s.u, u),
            (s.previous, previous),
            (s.rotation, rotation),
            (s.translation, translation),
            (s.damping, damping),
            (s.active, active),
        ):
            state.upload(array, value)
        for array in (s.converged, s.iterations, s.misfit):
            array.zero_()
        load, begin, judge = self._commands(state, frames, options, smooth)
        for _ in range(options.max_iterations):
            s.counter.zero_()
            load.launch()
            if state.count() == 0:
                break
            self.objective.launch(jacobian=True)
            s.counter.zero_()
            begin.launch()
            while state.count() > 0:
                self.objective.launch(jacobian=False)
                s.counter.zero_()
                judge.launch()
        m = self.control_count
        host = state.host
        return self.result(
            host(s.u)[: frames * m].reshape(frames, m).copy(),
            host(s.rotation).copy(),
            host(s.translation).copy(),
            host(s.misfit)[:frames].copy(),
            host(s.converged)[:frames],
            host(s.active)[:frames],
            host(s.iterations)[:frames].astype(np.int64),
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
        controls, rotation, translation, frame_on, hessian, gradient, misfit = self.objective.inputs()
        model = step_kernels.ModelInput()
        model.controls, model.rotation, model.translation, model.frame_on = controls, rotation, translation, frame_on
        data = step_kernels.DataTerm()
        data.hessian, data.gradient, data.misfit = hessian, gradient, misfit
        terms = step_kernels.Terms()
        terms.pairs, terms.pair_count = self._pairs, len(self.pairs)
        f = wp.float64
        terms.l2, terms.l1, terms.smooth = f(options.l2), f(options.l1), f(smooth)
        terms.symmetry = f(options.symmetry if len(self.pairs) else 0.0)
        terms.tolerance, terms.step_tolerance = f(options.tolerance), f(options.step_tolerance)
        terms.energy_tolerance = f(options.energy_tolerance)
        iterate, layout, scaling = state.arrays, self._layout, self._scaling

        def record(kernel, *inputs):
            return wp.launch(kernel, dim=frames, device=self.device, record_cmd=True, inputs=list(inputs))

        commands = (
            record(step_kernels.load_current, layout, scaling, iterate, model),
            record(step_kernels.begin_iteration, data, layout, scaling, terms, iterate, model),
            record(step_kernels.judge_trial, data, layout, scaling, terms, iterate, model),
        )
        state.commands = (key, commands)
        return commands
