"""Many tissue simulations at once: B material models on one mesh, each with its own trajectory and state.

:class:`TissueBatch` is the batched sibling of :class:`~warpface.fem.integrator.TissueSimulation`
for parameter sweeps and model comparisons (Kato's three models, a sweep of E and η). On CUDA all
models advance together, one kernel for every model's CG and one update per step, captured as a graph
(:class:`~warpface.fem.solver_batch.BatchedCGSolver`);
on the CPU each model gets its own prefactored direct solver
(:class:`~warpface.fem.solver_direct.BatchedDirectSolver`; the ``"cg"`` solver also runs there, which is how its
code path is tested). Either way the batch is a batched :class:`~warpface.fem.state.TissueState` and
:class:`~warpface.fem.state.TissueControl` stepped by ``solver.step(state_in, state_out, control, dt)``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import warp as wp

from .assembly import assemble
from .integrator import DISPLACEMENT_LIMIT, check_model_options, displacement_limit, split_nodes
from .material import TissueMaterial
from .newmark import newmark_coefficients
from .options import CGOptions, as_cg_options
from .solver_batch import BatchedCGSolver
from .solver_direct import BatchedDirectSolver, DirectSolver
from .state import ControlFeed, TissueControl, TissueState
from .tetmesh import TetMesh

__all__ = ["TissueBatch"]


class TissueBatch:
    """B viscoelastic tissue models on one mesh, advanced together by Newmark-β.

    Args:
        tetmesh: The shared mesh.
        materials: One :class:`TissueMaterial` per model (uniform or per tet).
        dt, fixed, driven, beta, gamma, formulation: as for :class:`TissueSimulation` (shared by all models).
        solver: ``"auto"`` (direct on CPU, CG elsewhere), ``"direct"`` (CPU, one factorisation per
            model) or ``"cg"`` (preconditioned CG of every model in one persistent kernel on ``device``).
        device: Warp device; ``None`` uses Warp's preferred device.
        cg: :class:`~warpface.fem.options.CGOptions` of the batched CG (tolerance relative to each model's
            predictor residual; preconditioner ``"fsai"``, ``"fsai_each"`` or ``"block_jacobi"``, see
            :class:`~warpface.fem.solver_batch.BatchedCGSolver`); default ``CGOptions()``.

    Raises:
        TypeError: as :class:`TissueSimulation`, or ``materials`` not a sequence of TissueMaterial.
        ValueError: as :class:`TissueSimulation`, or an empty ``materials``.
    """

    def __init__(
        self,
        tetmesh: TetMesh,
        materials: Sequence[TissueMaterial],
        dt: float,
        *,
        fixed=None,
        driven=None,
        beta: float = 0.25,
        gamma: float = 0.5,
        formulation: str = "linear",
        solver: str = "auto",
        device=None,
        cg: CGOptions | None = None,
    ):
        if not isinstance(materials, Sequence) or isinstance(materials, str):
            raise TypeError(f"materials must be a sequence of TissueMaterial, got {type(materials).__name__}")
        materials = list(materials)
        if not materials:
            raise ValueError("materials: TissueBatch needs a non-empty sequence of TissueMaterial (one per model)")
        dt, beta, gamma, formulation, solver, device = check_model_options(
            tetmesh, materials, dt, beta, gamma, formulation, solver, device=device
        )
        cg = as_cg_options(cg)
        self.fixed_nodes, self.driven_nodes, self.free_nodes = split_nodes(tetmesh, fixed, driven)
        self.tetmesh, self.materials, self.dt, self.formulation = tetmesh, materials, dt, formulation
        self.device = device
        self.steps_taken = 0
        """Steps since construction or the last :meth:`reset`."""
        self.max_displacement = displacement_limit(tetmesh)
        """Largest accepted driven displacement [m]."""
        coefficients = newmark_coefficients(dt, beta, gamma)
        if solver == "direct":
            direct = []
            for material in materials:
                K, M, C = assemble(tetmesh, material, formulation=formulation, device="cpu").to_scipy()
                direct.append(DirectSolver(K, M, C, coefficients, self.free_nodes, self.driven_nodes))
            self.solver = BatchedDirectSolver(direct)
        else:
            matrices = [assemble(tetmesh, m, formulation=formulation, device=device) for m in materials]
            self.solver = BatchedCGSolver(matrices, coefficients, self.free_nodes, self.driven_nodes, cg)
        """:class:`~warpface.fem.solver_direct.BatchedDirectSolver` or
        :class:`~warpface.fem.solver_batch.BatchedCGSolver` (``solver.step(state_in, state_out, control, dt)``)."""
        models, device = len(materials), self.solver.device
        self.state = TissueState(tetmesh.node_count, models=models, device=device)
        """The batched :class:`~warpface.fem.state.TissueState` (B, N), stepped in place."""
        self.control = TissueControl(self.driven_nodes.size, models=models, device=device)
        """The batched :class:`~warpface.fem.state.TissueControl` (B, D) that :meth:`step` fills."""
        self._feed = ControlFeed(self.control, cg.chunk if solver == "cg" else 1)

    @property
    def solver_kind(self) -> str:
        """The solver family in use, ``"direct"`` or ``"cg"``."""
        return self.solver.kind

    @property
    def model_count(self) -> int:
        """B."""
        return len(self.materials)

    @property
    def node_count(self) -> int:
        """N."""
        return self.tetmesh.node_count

    @property
    def d(self) -> np.ndarray:
        """Displacements [m] of every model, shape (B, N, 3), float64 (a copy)."""
        self.synchronize()
        return self.state.numpy()[0]

    @property
    def cg_iterations(self) -> np.ndarray | None:
        """Per model ``[most, last, total]`` CG iterations since the last reset, shape (B, 3); None for direct."""
        return None if self.solver.kind == "direct" else self.solver.iterations

    def _driven(self, driven, steps: int | None) -> np.ndarray:
        """Driven displacements as (steps or 1, B, D, 3) float64, checked (shape, finite, size)."""
        k, b = self.driven_nodes.size, self.model_count
        shared, own = ((k, 3), (b, k, 3)) if steps is None else ((steps, k, 3), (steps, b, k, 3))
        if driven is None and k == 0:
            driven = np.zeros(shared)
        try:
            arr = np.asarray(driven, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"driven displacements must be numbers of shape {shared} or {own}") from None
        if arr.shape == shared:
            arr = np.broadcast_to(arr[..., None, :, :], own)
        if arr.shape != own:
            raise ValueError(f"driven displacements must have shape {shared} or {own}, got {arr.shape}")
        if not np.isfinite(arr).all():
            raise ValueError("driven displacements must be finite (found NaN or inf)")
        if arr.size and np.abs(arr).max() > self.max_displacement:
            raise ValueError(
                f"a driven displacement exceeds the {self.max_displacement:.3g} m limit "
                f"({DISPLACEMENT_LIMIT:g} mesh diagonals)"
            )
        return arr.reshape((-1, b, k, 3))

    def step(self, driven=None) -> None:
        """Advance every model one step.

        Args:
            driven: Driven displacements [m], (D, 3) for all models or (B, D, 3) per model (checked); or a
                batched :class:`~warpface.fem.state.TissueControl` already on the device, used as it is.

        Raises:
            ValueError: wrong shape, non-finite or too large values.
            ConvergenceError: CG did not converge for a model (raised at the next synchronisation).
        """
        if isinstance(driven, TissueControl):
            control = driven
        else:
            self._feed.put(self._driven(driven, None)[0])
            control = self.control
        self.solver.step(self.state, self.state, control)
        self.steps_taken += 1
        if self._feed.wrapped and self.solver.kind == "cg":
            self.solver.synchronize()

    def run(self, trajectory, *, nodes=None) -> np.ndarray:
        """Advance ``T`` steps; trajectory [m] (T, D, 3) shared or (T, B, D, 3) per model.

        Returns:
            Displacements [m] after each step, shape (T, B, len(nodes), 3), float32 (``nodes`` default: all).
        """
        try:
            steps = int(np.shape(trajectory)[0])
        except (TypeError, IndexError):
            raise ValueError("trajectory must have shape (T, D, 3) or (T, B, D, 3)") from None
        traj = self._driven(trajectory, steps)
        record = np.arange(self.node_count) if nodes is None else np.asarray(nodes, dtype=np.int64).ravel()
        if record.size and (record.min() < 0 or record.max() >= self.node_count):
            raise ValueError(f"recorded node indices must be in [0, {self.node_count})")
        out = np.empty((steps, self.model_count, record.size, 3), dtype=np.float32)
        if self.solver.kind == "direct":
            d_view = self.state.d.numpy()  # zero-copy (CPU)
            for t in range(steps):
                self.step(traj[t])
                out[t] = d_view[:, record]
            return out
        start = 0
        for block in self.solver.run_chunks(self.state, traj):
            out[start : start + block.shape[0]] = block if nodes is None else block[:, :, record]
            start += block.shape[0]
            self.steps_taken += block.shape[0]
        self._feed.rewind()  # run_chunks waited for the device
        return out

    def reset(self) -> None:
        """Every model back to rest (zero displacement, velocity and acceleration)."""
        self.steps_taken = 0
        wp.synchronize_device(self.solver.device)
        for array in (self.state.d, self.state.v, self.state.a):
            array.zero_()
        self.solver.reset(self.state)
        self._feed.rewind()

    def synchronize(self) -> None:
        """Wait for queued steps; raise :class:`~warpface.errors.ConvergenceError` if a model failed."""
        if self.solver.kind == "cg":
            self.solver.synchronize()

    def __repr__(self) -> str:
        return (
            f"TissueBatch({self.model_count} models, {self.tetmesh!r}, dt={self.dt:g} s, {self.formulation}, "
            f"solver={self.solver.kind})"
        )
