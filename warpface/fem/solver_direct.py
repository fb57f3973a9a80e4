"""CPU Newmark solver: one sparse factorisation of ``A_oo``, reused every time step.

``A_oo`` (free-free block of ``K + c0 M + c3 C``) is symmetric positive definite. It is factorised
once as a block LDLᵀ of 3x3 node blocks with a float32 factor (:class:`~warpface.fem.ldlt.BlockLDLT`):
each step starts from a cubic extrapolation of the last four displacements (the Newmark predictor
until there are four) and refines it with the float64 residual, one round in smooth motion, until
the estimated error is below ``1e-10`` of the displacement's scale. The triangular sweeps stream
``L`` once, in float32, instead of SuperLU's ``L`` and ``U`` in float64. When the float32 factor would
not refine reliably (an ill-conditioned matrix), SuperLU's float64 factor is used instead
(symmetric mode, minimum degree on ``A + Aᵀ``, no pivoting: :func:`factorize_spd`). Measurements:
``benchmarks/README.md``.

State and arithmetic are float64 (CPU Warp arrays read through zero-copy NumPy views); each
time step is two sparse products with the mass and damping rows of the free nodes, one with
``A_od``, the solve and the shared Newmark update kernel.
"""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spla
import warp as wp

from .kernels_integrator import newmark_constants, newmark_update
from .ldlt import BlockLDLT, UnsuitableFactor
from .newmark import NewmarkCoefficients, check_step_dt, step_key
from .state import TissueControl, TissueState, force_vectors

__all__ = ["BatchedDirectSolver", "DirectSolver", "SuperLUFactor", "factorize_spd", "node_dofs"]


def factorize_spd(matrix):
    """SuperLU factorisation of a sparse SPD matrix without pivoting (symmetric mode, MMD on ``A + Aᵀ``):
    an LDLᵀ in LU clothing, with less fill and faster solves than SciPy's default (COLAMD + partial
    pivoting) on face shells."""
    return spla.splu(
        sps.csc_matrix(matrix),
        permc_spec="MMD_AT_PLUS_A",
        diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )


class SuperLUFactor:
    """The float64 fallback of :class:`DirectSolver`: :func:`factorize_spd` with the solve signature of
    :class:`~warpface.fem.ldlt.BlockLDLT` (the guess and reference are not needed)."""

    def __init__(self, matrix):
        self._lu = factorize_spd(matrix)
        self.factor_nnz = int(self._lu.L.nnz + self._lu.U.nnz)
        """Non-zeros of the L and U factors."""

    def solve(self, rhs: np.ndarray, guess: np.ndarray | None = None, *, reference: float = 0.0) -> np.ndarray:
        """``A⁻¹ rhs``, shape (3n,)."""
        return self._lu.solve(rhs)


def node_dofs(nodes: np.ndarray) -> np.ndarray:
    """Dof indices ``3 * node + axis`` of ``nodes``, shape (3 len(nodes),), int64."""
    nodes = np.asarray(nodes, dtype=np.int64)
    return (3 * nodes[:, None] + np.arange(3)).ravel()


class DirectSolver:
    """Newmark steps on the CPU with a prefactored ``A_oo``; the state lives in CPU Warp arrays.

    Args:
        K, M, C: SciPy sparse (3N x 3N) stiffness, mass and damping.
        coefficients: :class:`~warpface.fem.newmark.NewmarkCoefficients`.
        free_nodes: Nodes solved for, shape (F,), int.
        driven_nodes: Nodes with prescribed displacement, shape (D,), int (fixed nodes are the rest).

    :meth:`step` reads ``state_in`` and the control through zero-copy NumPy views, solves, and
    writes ``state_out`` with the shared Newmark update kernel
    (:data:`~warpface.fem.kernels_integrator.newmark_update`).
    """

    device = wp.get_device("cpu")
    kind = "direct"
    """Solver family, as ``TissueSimulation(solver=...)`` names it."""

    def __init__(self, K, M, C, coefficients: NewmarkCoefficients, free_nodes: np.ndarray, driven_nodes: np.ndarray):
        self.coefficients = coefficients
        c = coefficients
        n = K.shape[0] // 3
        self.node_count = n
        self.free_nodes = np.asarray(free_nodes, dtype=np.int64)
        self.driven_nodes = np.asarray(driven_nodes, dtype=np.int64)
        o = node_dofs(self.free_nodes)
        dd = node_dofs(self.driven_nodes)
        A = (K + c.mass_displacement * M + c.damping_displacement * C).tocsr()
        rows = A[o]
        t0 = time.perf_counter()
        try:
            self.factor = BlockLDLT(rows[:, o])
            """The factorisation: :class:`~warpface.fem.ldlt.BlockLDLT`, or :class:`SuperLUFactor` when the
            float32 factor would not refine reliably."""
        except UnsuitableFactor:
            self.factor = SuperLUFactor(rows[:, o])
        self.factor_seconds = time.perf_counter() - t0
        """Wall time of the factorisation [s]."""
        self.factor_nnz = self.factor.factor_nnz
        """Stored non-zeros of the factor."""
        self._A_od = rows[:, dd].tocsr()
        # M is (scalar node mass) ⊗ I3, so its product acts on (N, 3) arrays with a third of the work.
        self._M_node = sps.csr_matrix(M.tocsr()[0::3][:, 0::3])[self.free_nodes]
        self._C_o = C.tocsr()[o]
        free_index = np.full(n, -1, dtype=np.int32)
        free_index[self.free_nodes] = np.arange(self.free_nodes.size, dtype=np.int32)
        driven_slot = np.full(n, -1, dtype=np.int32)
        driven_slot[self.driven_nodes] = np.arange(self.driven_nodes.size, dtype=np.int32)
        cpu = self.device
        self._free_index = wp.array(free_index, dtype=wp.int32, device=cpu)
        self._driven_slot = wp.array(driven_slot, dtype=wp.int32, device=cpu)
        self._solution = wp.zeros(self.free_nodes.size, dtype=wp.vec3d, device=cpu)
        self._solution_view = self._solution.numpy().reshape(-1)
        self._update_constants = newmark_constants(c, wp.float64)
        self._bindings: dict = {}
        self._forces: dict = {}
        # the last four solutions, newest last, for the extrapolated start of the next step
        self._history = np.zeros((4, 3 * self.free_nodes.size))
        self._history_count = 0

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``A_oo^{-1} rhs`` for a free-dof vector, shape (3F,) (a new array)."""
        return np.array(self.factor.solve(rhs))

    def _start(self, d: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """The step's starting guess for the free dofs: the cubic extrapolation of the last four solutions when
        ``d`` continues them, else the Newmark predictor ``d + dt v + dt²/2 a``."""
        free = self.free_nodes
        d_free = d[free].ravel()
        if self._history_count and not np.array_equal(d_free, self._history[-1]):
            self._history_count = 0  # a new trajectory (reset, or another state)
        if self._history_count == 4:
            h = self._history
            return 4.0 * h[3] - 6.0 * h[2] + 4.0 * h[1] - h[0]
        c = self.coefficients
        return d_free + c.dt * v[free].ravel() + c.half_dt_squared * a[free].ravel()

    def _remember(self, x: np.ndarray) -> None:
        self._history[:-1] = self._history[1:]
        self._history[-1] = x
        self._history_count = min(self._history_count + 1, 4)

    def reset(self, state: TissueState) -> None:
        """Start a new trajectory from ``state``: the next step starts from the Newmark predictor (the
        extrapolation needs four solutions of the new trajectory first)."""
        self._history_count = 0

    def step(
        self, state_in: TissueState, state_out: TissueState, control: TissueControl, dt=None, *, force=None
    ) -> None:
        """Advance one time step from ``state_in`` to ``state_out`` (may be the same object).

        Args:
            state_in, state_out: float64 states on the CPU.
            control: Driven displacements at the end of the step (float64, CPU).
            dt: The time step [s]; None or the solver's own (checked).
            force: External nodal force [N] at the end of the step on the free nodes: a float64 CPU Warp array
                (N,) vec3d or (N, 3) (read through a zero-copy view; fixed and driven rows are not read), or None.

        The first step with a new combination of state and control arrays records the update
        launch and the input views; later steps reuse them.

        Raises:
            TypeError: the states are not TissueStates, the control not a TissueControl, or ``force`` not a Warp
                array.
            ValueError: a state, the control or the force does not match the solver (size, type, device), or
                another dt.
            FloatingPointError: the solve produced non-finite displacements (``state_out`` untouched).
        """
        check_step_dt(dt, self.coefficients)
        binding = self._binding(state_in, state_out, control)
        rhs = self._rhs(binding, force)
        d, v, a = binding.d, binding.v, binding.a
        reference = float(np.abs(binding.driven).max()) if self.driven_nodes.size else 0.0
        x = self.factor.solve(rhs, self._start(d, v, a), reference=reference)
        if not np.all(np.isfinite(x)):
            self._history_count = 0
            raise FloatingPointError("direct solve produced non-finite displacements")
        self._solution_view[:] = x
        binding.update.launch()
        self._remember(x)

    def _rhs(self, binding: SimpleNamespace, force) -> np.ndarray:
        """The step's right-hand side ``q_o − A_od d_driven (+ f_o)`` of the free dofs, shape (3F,)."""
        c = self.coefficients
        d, v, a = binding.d, binding.v, binding.a
        u = c.mass_displacement * d + c.mass_velocity * v + c.mass_acceleration * a
        w = c.damping_displacement * d + c.damping_velocity * v + c.damping_acceleration * a
        rhs = (self._M_node @ u).ravel() + self._C_o @ w.ravel()
        if self.driven_nodes.size:
            rhs -= self._A_od @ binding.driven.ravel()
        if force is not None:
            key = (force.ptr, force.shape) if isinstance(force, wp.array) else None
            view = self._forces.get(key)
            if view is None:  # checked once per array; a zero-copy (N, 3) view that keeps the array
                checked = force_vectors(force, self.node_count, wp.vec3d, device=self.device)
                view = self._forces[key] = checked.numpy()
            rhs += view[self.free_nodes].ravel()
        return rhs

    def _binding(self, state_in: TissueState, state_out: TissueState, control: TissueControl) -> SimpleNamespace:
        """Zero-copy NumPy views of the inputs and the recorded update launch, cached per combination of arrays."""
        key = step_key(state_in, state_out, control)
        binding = self._bindings.get(key)
        if binding is None:
            for name, value, kind in (
                ("state_in", state_in, TissueState),
                ("state_out", state_out, TissueState),
                ("control", control, TissueControl),
            ):
                if not isinstance(value, kind):
                    raise TypeError(f"{name} must be a {kind.__name__}, got {type(value).__name__}")
            for name, state in (("state_in", state_in), ("state_out", state_out)):
                if (
                    state.d.shape != (self.node_count,)
                    or not wp.types.types_equal(state.d.dtype, wp.vec3d)
                    or not state.device.is_cpu
                ):
                    raise ValueError(f"{name} must hold {self.node_count} nodes of float64 vec3 on the CPU")
            if control.driven.shape != (max(self.driven_nodes.size, 1),) or not control.driven.device.is_cpu:
                raise ValueError(f"control must hold {self.driven_nodes.size} driven displacements on the CPU")
            update = wp.launch(
                newmark_update,
                dim=self.node_count,
                inputs=[
                    self._solution,
                    self._free_index,
                    self._driven_slot,
                    control.driven,
                    state_in.d,
                    state_in.v,
                    state_in.a,
                    self._update_constants,
                ],
                outputs=[state_out.d, state_out.v, state_out.a],
                device=self.device,
                record_cmd=True,
            )
            binding = SimpleNamespace(
                d=state_in.d.numpy(),
                v=state_in.v.numpy(),
                a=state_in.a.numpy(),
                driven=control.driven.numpy()[: self.driven_nodes.size],
                update=update,
                arrays=(state_in, state_out, control),
            )  # keeps the pointers valid
            self._bindings[key] = binding
        return binding


class BatchedDirectSolver:
    """Newmark steps of B models on the CPU, one :class:`DirectSolver` (one factorisation) per model, with the
    step contract of the batched CG solver: batched states (B, N) and controls (B, D).

    Args:
        solvers: One :class:`DirectSolver` per model (same nodes and time step).
    """

    device = DirectSolver.device
    kind = "direct"

    def __init__(self, solvers: list[DirectSolver]):
        self.solvers = list(solvers)
        self.model_count = len(self.solvers)
        self.coefficients = self.solvers[0].coefficients
        self._views: dict = {}

    def step(
        self, state_in: TissueState, state_out: TissueState, control: TissueControl, dt=None, *, force=None
    ) -> None:
        """Advance every model one step: :meth:`DirectSolver.step` on each model's rows (views made once per
        combination of arrays); ``force`` [N]: None or a float64 CPU Warp array (B, N) vec3d, row ``b`` model b's.

        Raises:
            ValueError: the states or the control are not batched for these models, or another dt.
            FloatingPointError: a model's solve produced non-finite displacements.
        """
        key = step_key(state_in, state_out, control)
        views = self._views.get(key)
        if views is None:
            for name, shape in (("state_in", state_in.d.shape), ("state_out", state_out.d.shape)):
                if len(shape) != 2 or shape[0] != self.model_count:
                    raise ValueError(f"{name} must be a TissueState of {self.model_count} models, got shape {shape}")
            if control.driven.ndim != 2 or control.driven.shape[0] != self.model_count:
                raise ValueError(f"control must be a TissueControl of {self.model_count} models")
            views = self._views[key] = [
                (state_in.model(b), state_out.model(b), control.model(b)) for b in range(self.model_count)
            ]
        if force is not None:
            force = force_vectors(
                force, self.solvers[0].node_count, wp.vec3d, device=self.device, models=self.model_count
            )
        for b, (solver, (model_in, model_out, model_control)) in enumerate(zip(self.solvers, views)):
            solver.step(model_in, model_out, model_control, dt, force=None if force is None else force[b])

    def reset(self, state: TissueState) -> None:
        """Start new trajectories (:meth:`DirectSolver.reset` of every model)."""
        for solver in self.solvers:
            solver.reset(state)
