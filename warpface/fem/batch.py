"""Many tissue simulations at once: B material models on one mesh, each with its own trajectory and state.

:class:`TissueBatch` is the batched sibling of :class:`~warpface.fem.integrator.TissueSimulation`
for parameter sweeps and model comparisons (Kato's three models, a sweep of E and η). On CUDA all
models advance together, one kernel for every model's CG and one update per step, captured as a graph
(:class:`~warpface.fem.solver_batch.BatchedCGSolver`);
on the CPU each model gets its own prefactored direct solver (the ``"cg"`` solver also runs there,
which is how its code path is tested).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import warp as wp

from .._validate import as_device
from .assembly import FORMULATIONS, assemble
from .integrator import DISPLACEMENT_LIMIT, TissueSimulation, split_nodes
from .material import TissueMaterial
from .newmark import newmark_coefficients, validate_newmark
from .solver_batch import BATCH_PRECONDITIONERS, BatchedCGSolver
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
        cg_tol: CG tolerance relative to each model's predictor residual (see :class:`TissueSimulation`).
        cg_maxiter: CG iteration limit per step.
        cg_preconditioner: ``"fsai"`` (one FSAI factor shared by the models), ``"fsai_each"`` (its support
            refitted to each model: fewer iterations where the models differ) or ``"block_jacobi"`` (per model).
        chunk: Steps per ring buffer of :meth:`run` and of :meth:`step`'s host input.
        use_graph: Capture the batched step as a graph (default: on CUDA).

    Raises:
        ValueError, TypeError: as :class:`TissueSimulation`, or an empty / non-material ``materials``.
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
        cg_tol: float = 1.0e-5,
        cg_maxiter: int = 500,
        cg_preconditioner: str = "fsai",
        chunk: int = 64,
        use_graph: bool | None = None,
    ):
        if not isinstance(tetmesh, TetMesh):
            raise ValueError(f"TissueBatch needs a TetMesh, got {type(tetmesh).__name__}")
        materials = list(materials) if isinstance(materials, Sequence) else None
        if not materials:
            raise ValueError("TissueBatch needs a non-empty sequence of TissueMaterial (one per model)")
        for b, material in enumerate(materials):
            if not isinstance(material, TissueMaterial):
                raise ValueError(f"model {b}: expected a TissueMaterial, got {type(material).__name__}")
            material.per_tet(tetmesh.tet_count)
        if formulation not in FORMULATIONS:
            raise ValueError(f"formulation must be one of {FORMULATIONS}, got {formulation!r}")
        if cg_preconditioner not in BATCH_PRECONDITIONERS:
            raise ValueError(f"cg_preconditioner must be one of {BATCH_PRECONDITIONERS}, got {cg_preconditioner!r}")
        if solver not in ("auto", "direct", "cg"):
            raise ValueError(f"solver must be one of ('auto', 'direct', 'cg'), got {solver!r}")
        for name, value, low in (("cg_tol", cg_tol, 1e-16), ("cg_maxiter", cg_maxiter, 1), ("chunk", chunk, 1)):
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise TypeError(f"{name} must be a number, got {type(value).__name__}")
            if not (np.isfinite(value) and value >= low):
                raise ValueError(f"{name} must be >= {low:g}, got {value!r}")
        dt, beta, gamma = validate_newmark(dt, beta, gamma)
        try:
            device = as_device(device)
        except Exception:  # Warp raises RuntimeError/ValueError/TypeError for unknown devices
            raise ValueError(f"device {device!r} is not a Warp device here") from None
        if solver == "auto":
            solver = "direct" if device.is_cpu else "cg"
        if solver == "direct" and not device.is_cpu:
            raise ValueError(f"solver='direct' runs on the CPU; got device {device}")
        self.fixed_nodes, self.driven_nodes, self.free_nodes = split_nodes(tetmesh, fixed, driven)
        self.tetmesh, self.materials, self.dt, self.formulation, self.solver = (
            tetmesh,
            materials,
            dt,
            formulation,
            solver,
        )
        self.device = device
        self.steps_taken = 0
        """Steps since construction or the last :meth:`reset`."""
        self.max_displacement = DISPLACEMENT_LIMIT * float(np.linalg.norm(np.ptp(tetmesh.points, axis=0)))
        """Largest accepted driven displacement [m]."""
        self.chunk = int(chunk)
        if solver == "direct":
            self._simulations = [
                TissueSimulation(
                    tetmesh,
                    m,
                    dt,
                    fixed=self.fixed_nodes,
                    driven=self.driven_nodes,
                    beta=beta,
                    gamma=gamma,
                    formulation=formulation,
                    solver="direct",
                    device="cpu",
                )
                for m in materials
            ]
            self.stepper = None
            return
        matrices = [assemble(tetmesh, m, formulation=formulation, device=device) for m in materials]
        self.stepper = BatchedCGSolver(
            matrices,
            newmark_coefficients(dt, beta, gamma),
            self.free_nodes,
            self.driven_nodes,
            tol=float(cg_tol),
            maxiter=int(cg_maxiter),
            chunk=self.chunk,
            preconditioner=cg_preconditioner,
            use_graph=device.is_cuda if use_graph is None else bool(use_graph),
        )
        """:class:`~warpface.fem.solver_batch.BatchedCGSolver` (``None`` for the direct solver)."""
        pinned = device.is_cuda
        width = max(self.driven_nodes.size, 1)
        self._staging_in = wp.zeros((self.chunk, len(materials), width), dtype=wp.vec3d, device="cpu", pinned=pinned)
        self._slot = 0

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
        if self.stepper is None:
            return np.stack([sim.d for sim in self._simulations])
        self.stepper.synchronize()
        return self.stepper.d.numpy().astype(np.float64)

    @property
    def cg_iterations(self) -> np.ndarray | None:
        """Per model ``[most, last, total]`` CG iterations since the last reset, shape (B, 3); None for direct."""
        return None if self.stepper is None else self.stepper.iterations

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

    def step(self, driven_displacements=None) -> None:
        """Advance every model one step; driven displacements [m] (D, 3) for all models or (B, D, 3) per model.

        Raises:
            ValueError: wrong shape, non-finite or too large values.
            ConvergenceError: CG did not converge for a model (raised at the next synchronisation).
        """
        driven = self._driven(driven_displacements, None)[0]
        if self.stepper is None:
            for sim, row in zip(self._simulations, driven):
                sim.step(row)
        else:
            if driven.shape[1]:
                self._staging_in.numpy()[self._slot, :, : driven.shape[1]] = driven
                width = self._staging_in.shape[1] * self._staging_in.shape[2]
                wp.copy(
                    self.stepper.trajectory,
                    self._staging_in,
                    dest_offset=self._slot * width,
                    src_offset=self._slot * width,
                    count=width,
                )
            self.stepper.step()
            self._slot = (self._slot + 1) % self.chunk
            if self._slot == 0:
                self.stepper.synchronize()
        self.steps_taken += 1

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
        if self.stepper is None:
            for t in range(steps):
                self.step(traj[t])
                out[t] = self.d[:, record]
            return out
        start = 0
        for block in self.stepper.run_chunks(traj):
            out[start : start + block.shape[0]] = block if nodes is None else block[:, :, record]
            start += block.shape[0]
            self.steps_taken += block.shape[0]
            self._slot = block.shape[0] % self.chunk
        return out

    def reset(self) -> None:
        """Every model back to rest (zero displacement, velocity and acceleration)."""
        self.steps_taken = 0
        if self.stepper is None:
            for sim in self._simulations:
                sim.reset()
            return
        wp.synchronize_device(self.device)
        for array in (self.stepper.d, self.stepper.v, self.stepper.a):
            array.zero_()
        self.stepper.restart()
        self._slot = 0

    def synchronize(self) -> None:
        """Wait for queued steps; raise ConvergenceError if a model failed."""
        if self.stepper is not None:
            self.stepper.synchronize()

    def __repr__(self) -> str:
        return (
            f"TissueBatch({self.model_count} models, {self.tetmesh!r}, dt={self.dt:g} s, {self.formulation}, "
            f"solver={self.solver})"
        )
