"""Newmark-β simulation of viscoelastic tissue driven by prescribed displacements (SPEC §2).

:class:`TissueSimulation` assembles K, M, C once, splits the nodes into free (``o``), fixed
and driven (together ``c``), and advances ``M ä + C ḋ + K d = f`` on the free nodes with
``A_oo d_o = q_o − A_oc d_c + f_o`` (``f``: an external nodal force given to :meth:`TissueSimulation.step`, else
zero). Fixed nodes stay at zero displacement; driven nodes follow the displacement given for each step.

Solvers (``solver=``):

* ``"direct"`` (default on CPU): ``A_oo`` factorised once as a block LDLᵀ with a float32 factor,
  each step refined to float64 accuracy from an extrapolated start (SuperLU in float64 when the
  matrix is too ill-conditioned for that; see :mod:`warpface.fem.solver_direct`), float64 NumPy state.
* ``"cg"`` (default on CUDA): preconditioned CG in fused Warp kernels (FSAI preconditioner from
  ``warp.optim.linear``), started from an extrapolation of past displacements, with the whole
  step captured in one graph (see :mod:`warpface.fem.solver_cg`). It also runs on the CPU
  device, which is how its code path is tested.

Changing ``dt``, the material or the constrained sets means building a new simulation; that
is when the factorisation / preconditioner is rebuilt, and only then.
"""

from __future__ import annotations

import time

import numpy as np
import warp as wp

from .._validate import as_device, as_finite_array, expect_instance
from ..errors import ConvergenceError
from .assembly import FORMULATIONS, SystemMatrices, assemble
from .material import TissueMaterial
from .newmark import newmark_coefficients, validate_newmark
from .options import CGOptions, as_cg_options
from .solver_cg import CGSolver
from .solver_direct import DirectSolver, factorize_spd, node_dofs
from .state import ControlFeed, TissueControl, TissueState
from .tetmesh import TetMesh

__all__ = ["SOLVERS", "TissueSimulation", "check_model_options", "displacement_limit", "split_nodes"]

SOLVERS = ("auto", "direct", "cg")
"""Solver families: ``"direct"`` (CPU factorisation), ``"cg"`` (device CG), ``"auto"`` (direct on the CPU)."""

DISPLACEMENT_LIMIT = 10.0
"""Largest accepted driven (or reset) displacement, in multiples of the mesh's bounding-box diagonal.

Linear elasticity means nothing far beyond the mesh's own size, and the bound keeps every quantity
of a step (accelerations ``~ Δd / dt²``, energies) finite in float64."""

# run() shows a progress bar (tqdm, when installed) from this many steps on.
_PROGRESS_MIN_STEPS = 500


def _node_set(name: str, nodes, node_count: int) -> np.ndarray:
    try:
        arr = np.asarray(nodes if nodes is not None else [])
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be node indices or a boolean mask, got {type(nodes).__name__}") from None
    if arr.size == 0:
        return np.zeros(0, dtype=np.int64)
    if arr.dtype == bool:
        if arr.shape != (node_count,):
            raise ValueError(f"{name} mask has shape {arr.shape}, expected ({node_count},)")
        return np.flatnonzero(arr).astype(np.int64)
    if not np.issubdtype(arr.dtype, np.integer):
        if not (np.issubdtype(arr.dtype, np.floating) and np.all(np.isfinite(arr)) and np.all(arr == np.round(arr))):
            raise ValueError(f"{name} must hold integer node indices, got dtype {arr.dtype}")
    flat = arr.ravel()
    bad = np.flatnonzero((flat < 0) | (flat >= node_count))
    if bad.size:
        raise ValueError(f"{name} node index {flat[bad[0]]} (entry {bad[0]}) is out of range [0, {node_count})")
    return flat.astype(np.int64)


def displacement_limit(tetmesh: TetMesh) -> float:
    """Largest accepted driven or reset displacement [m] on ``tetmesh``: :data:`DISPLACEMENT_LIMIT` diagonals of
    its bounding box."""
    return DISPLACEMENT_LIMIT * float(np.linalg.norm(np.ptp(tetmesh.points, axis=0)))


def check_model_options(tetmesh, materials: list, dt, beta, gamma, formulation, solver, *, device) -> tuple:
    """Check what a simulation or a batch of them is built from; returns ``(dt, beta, gamma, formulation, solver,
    device)`` with the numbers as floats, ``solver`` resolved (``"auto"``: direct on the CPU, CG elsewhere) and
    ``device`` a Warp device.

    Raises:
        TypeError: ``tetmesh`` is not a TetMesh, a material not a TissueMaterial, a number not a number, or
            ``formulation`` / ``solver`` not a string.
        ValueError: a value out of range (naming it), per-tet material values of the wrong size, an unknown
            device, or ``solver="direct"`` on a non-CPU device.
    """
    expect_instance(tetmesh, TetMesh, "tetmesh")
    for index, material in enumerate(materials):
        expect_instance(
            material, TissueMaterial, "material" if len(materials) == 1 else f"materials[{index}] (model {index})"
        )
        material.per_tet(tetmesh.tet_count)  # size check with a clear message
    dt, beta, gamma = validate_newmark(dt, beta, gamma)
    for option, value, allowed in (("formulation", formulation, FORMULATIONS), ("solver", solver, SOLVERS)):
        expect_instance(value, str, option)
        if value not in allowed:
            raise ValueError(f"{option} must be one of {allowed}, got {value!r}")
    try:
        device = as_device(device)
    except Exception:  # Warp raises RuntimeError/ValueError/TypeError for unknown devices
        raise ValueError(
            f"device {device!r} is not a Warp device here ({[str(d) for d in wp.get_devices()]})"
        ) from None
    if solver == "auto":
        solver = "direct" if device.is_cpu else "cg"
    if solver == "direct" and not device.is_cpu:
        raise ValueError(f"solver='direct' runs on the CPU; got device {device}. Use solver='cg' or device='cpu'")
    return dt, beta, gamma, formulation, solver, device


class TissueSimulation:
    """Viscoelastic tet FEM advanced by Newmark-β with fixed and driven nodes: the convenience wrapper around
    a model (mesh, material, matrices), its :attr:`state`, :attr:`control` and :attr:`solver`.

    Args:
        tetmesh: The tissue mesh.
        material: Uniform or per-tet :class:`TissueMaterial`.
        dt: Time step [s], in [1e-8, 10] (:data:`~warpface.fem.newmark.DT_RANGE`).
        fixed: Nodes held at zero displacement: indices or a boolean mask of shape (N,).
        driven: Nodes whose displacement is given every step, in the column order of the
            trajectories passed to :meth:`step` / :meth:`run` (indices; no duplicates).
        beta, gamma: Newmark parameters (default 1/4, 1/2: average acceleration,
            unconditionally stable, energy conserving without damping); β in [0.01, 1], γ in
            [0.5, 1] (:data:`~warpface.fem.newmark.BETA_RANGE`, :data:`~warpface.fem.newmark.GAMMA_RANGE`).
        formulation: ``"linear"`` or ``"anp"`` (locking-free average nodal pressure), see
            :mod:`warpface.fem.assembly`.
        solver: ``"auto"`` (direct on CPU, CG elsewhere), ``"direct"`` or ``"cg"`` (:data:`SOLVERS`).
        device: Warp device; ``None`` uses Warp's preferred device.
        cg: :class:`~warpface.fem.options.CGOptions` of the CG solver (tolerance, iteration limit,
            preconditioner, ring size, loop, precision, graphs); default ``CGOptions()``. CG starts from the
            better of the Newmark predictor and a cubic extrapolation of the last four displacements, which
            during smooth motion is much closer and saves iterations.

    Raises:
        TypeError: ``tetmesh``, ``material`` or ``cg`` of the wrong type; ``dt``, ``beta`` or ``gamma`` not a number.
        ValueError: ``dt``, ``beta`` or ``gamma`` out of range, node indices out of range, duplicated driven
            nodes, a node both fixed and driven, no constrained node (or a connected part of the mesh without
            one: its rigid motion would be singular), no free node, unknown solver/formulation, options the CG
            solver does not implement, or ``solver="direct"`` on a non-CPU device.
    """

    def __init__(
        self,
        tetmesh: TetMesh,
        material: TissueMaterial,
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
        self.dt, self.beta, self.gamma, formulation, solver, device = check_model_options(
            tetmesh, [material], dt, beta, gamma, formulation, solver, device=device
        )
        cg = as_cg_options(cg)
        n = tetmesh.node_count
        fixed_nodes, driven_nodes, free_nodes = split_nodes(tetmesh, fixed, driven)

        self.tetmesh = tetmesh
        """The mesh."""
        self.material = material
        """The material."""
        self.formulation = formulation
        """Stiffness formulation, "linear" or "anp"."""
        self.device = device
        """Warp device of the CG solver (the direct solver always runs on the CPU)."""
        self.fixed_nodes = fixed_nodes
        """Fixed nodes, shape (Fx,), int64, sorted."""
        self.driven_nodes = driven_nodes
        """Driven nodes in trajectory column order, shape (D,), int64."""
        self.free_nodes = free_nodes
        """Free (solved) nodes, shape (F,), int64, sorted."""
        self.coefficients = newmark_coefficients(self.dt, self.beta, self.gamma)
        """Newmark constants (:class:`~warpface.fem.newmark.NewmarkCoefficients`)."""
        self.timings: dict[str, float] = {}
        """Set-up wall times [s]: "assembly", "factorization" (direct) or "solver_setup" (CG)."""
        self.steps_taken = 0
        """Steps since construction or the last :meth:`reset`."""
        self.max_displacement = displacement_limit(tetmesh)
        """Largest accepted driven or reset displacement [m] (:data:`DISPLACEMENT_LIMIT` mesh diagonals)."""

        t0 = time.perf_counter()
        self.matrices: SystemMatrices = assemble(tetmesh, material, formulation=formulation, device=device)
        """K, M, C (Warp BSR) on ``device``."""
        self.timings["assembly"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        if solver == "direct":
            K, M, C = self.matrices.to_scipy()
            self.solver = DirectSolver(K, M, C, self.coefficients, free_nodes, driven_nodes)
            """The solver: a :class:`~warpface.fem.solver_direct.DirectSolver` or
            :class:`~warpface.fem.solver_cg.CGSolver` (``solver.step(state_in, state_out, control, dt)``)."""
            self.timings["factorization"] = self.solver.factor_seconds
            state_dtype = wp.float64
        else:
            self.solver = CGSolver(self.matrices, self.coefficients, free_nodes, driven_nodes, cg)
            state_dtype = cg.dtype
        self.timings["solver_setup"] = time.perf_counter() - t0
        state_device = self.solver.device
        self.state = TissueState(n, dtype=state_dtype, device=state_device)
        """The current :class:`~warpface.fem.state.TissueState` (stepped in place by :meth:`step` and :meth:`run`)."""
        self.control = TissueControl(driven_nodes.size, dtype=state_dtype, device=state_device)
        """The :class:`~warpface.fem.state.TissueControl` that :meth:`step` fills from its argument."""
        self._feed = ControlFeed(self.control, 1 if solver == "direct" else cg.chunk)
        self._failed = False

    @property
    def solver_kind(self) -> str:
        """The solver family in use, ``"direct"`` or ``"cg"``."""
        return self.solver.kind

    # ------------------------------------------------------------------ state
    @property
    def node_count(self) -> int:
        """Number of nodes N."""
        return self.tetmesh.node_count

    @property
    def time(self) -> float:
        """Simulated time since the last reset [s]."""
        return self.steps_taken * self.dt

    def _state(self):
        self.synchronize()
        return self.state.numpy()

    @property
    def d(self) -> np.ndarray:
        """Displacement [m], shape (N, 3), float64 (a copy on non-CPU devices)."""
        return self._state()[0]

    @property
    def v(self) -> np.ndarray:
        """Velocity [m/s], shape (N, 3), float64."""
        return self._state()[1]

    @property
    def a(self) -> np.ndarray:
        """Acceleration [m/s^2], shape (N, 3), float64."""
        return self._state()[2]

    @property
    def cg_iterations(self) -> tuple[int, int] | None:
        """``(most, last)`` CG iterations per step since the last reset; None for the direct solver."""
        return None if self.solver.kind == "direct" else self.solver.iterations

    @property
    def cg_mean_iterations(self) -> float | None:
        """Mean CG iterations per step since the last reset (NaN before the first); None for the direct solver."""
        if self.solver.kind == "direct":
            return None
        total = self.solver.total_iterations
        return total / self.steps_taken if self.steps_taken else float("nan")

    def energy(self) -> tuple[float, float]:
        """``(kinetic, strain)`` energy [J]: ``½ vᵀMv`` and ``½ dᵀKd`` (float64, on the host)."""
        if not hasattr(self, "_host_matrices"):
            self._host_matrices = self.matrices.to_scipy()
        K, M, _ = self._host_matrices
        d, v, _ = self._state()
        d, v = d.ravel(), v.ravel()
        return 0.5 * float(v @ (M @ v)), 0.5 * float(d @ (K @ d))

    def reset(self, displacement=None, velocity=None) -> None:
        """Restart from a given state (default: rest) with a consistent acceleration.

        The acceleration of free nodes solves ``M_oo a_o = −(K d + C v)_o`` (constrained nodes get
        zero), so the first step starts in equilibrium, as Newmark's energy balance assumes.

        Args:
            displacement: [m], shape (N, 3); zero at fixed nodes. Default zero.
            velocity: [m/s], shape (N, 3); zero at fixed nodes. Default zero.

        Raises:
            ValueError: wrong shape, non-finite values, or non-zero values at fixed nodes.
        """
        n = self.node_count
        state = []
        for name, value in (("displacement", displacement), ("velocity", velocity)):
            arr = np.zeros((n, 3)) if value is None else as_finite_array(value, f"reset {name}")
            if arr.shape != (n, 3):
                raise ValueError(f"reset {name} must have shape ({n}, 3), got {arr.shape}")
            bad = np.flatnonzero(~np.isfinite(arr).all(axis=1))
            if bad.size:
                raise ValueError(f"reset {name} of node {bad[0]} is not finite")
            moving = self.fixed_nodes[np.any(arr[self.fixed_nodes] != 0.0, axis=1)]
            if moving.size:
                raise ValueError(f"reset {name} of fixed node {moving[0]} must be zero")
            limit = self.max_displacement / (1.0 if name == "displacement" else self.dt)
            big = np.flatnonzero(np.abs(arr).max(axis=1) > limit)
            if big.size:
                raise ValueError(
                    f"reset {name} of node {big[0]} exceeds {limit:.3g} (|value| {np.abs(arr[big[0]]).max():.3g}; "
                    f"at most {DISPLACEMENT_LIMIT:g} mesh diagonals{'' if name == 'displacement' else ' per dt'})"
                )
            state.append(arr)
        d, v = state
        a = np.zeros((n, 3))
        if np.any(d) or np.any(v):
            if not hasattr(self, "_host_matrices"):
                self._host_matrices = self.matrices.to_scipy()
            K, M, C = self._host_matrices
            o = node_dofs(self.free_nodes)
            force = -(K @ d.ravel() + C @ v.ravel())[o]
            a[self.free_nodes] = factorize_spd(M.tocsr()[o][:, o]).solve(force).reshape(-1, 3)
        wp.synchronize_device(self.solver.device)
        self.state.assign(d, v, a)
        self.solver.reset(self.state)
        self._feed.rewind()
        self.steps_taken = 0
        self._failed = False

    # ------------------------------------------------------------------ stepping
    def _check_driven(self, driven, steps: int | None) -> np.ndarray:
        k = self.driven_nodes.size
        shape = (k, 3) if steps is None else (steps, k, 3)
        if driven is None:
            if k:
                raise ValueError(f"{k} driven nodes need displacements of shape {shape}")
            return np.zeros(shape)
        try:
            arr = np.asarray(driven, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"driven displacements must be numbers of shape {shape}") from None
        if steps is None and arr.shape != shape:
            raise ValueError(f"driven displacements must have shape {shape}, got {arr.shape}")
        if steps is not None and (arr.ndim != 3 or arr.shape[1:] != (k, 3)):
            raise ValueError(f"trajectory must have shape (steps, {k}, 3), got {arr.shape}")
        finite = np.isfinite(arr).all(axis=-1)
        if not finite.all():
            where = np.argwhere(~finite)[0]
            if steps is None:
                raise ValueError(f"driven displacement of node {self.driven_nodes[where[0]]} is not finite")
            raise ValueError(
                f"trajectory has a non-finite value at step {where[0]}, driven node {self.driven_nodes[where[1]]}"
            )
        big = np.abs(arr).max(axis=-1) > self.max_displacement
        if big.any():
            where = np.argwhere(big)[0]
            at = (
                f"driven node {self.driven_nodes[where[0]]}"
                if steps is None
                else f"step {where[0]}, driven node {self.driven_nodes[where[1]]}"
            )
            raise ValueError(
                f"driven displacement at {at} is {np.abs(arr[tuple(where)]).max():.3g} m, beyond the "
                f"{self.max_displacement:.3g} m limit ({DISPLACEMENT_LIMIT:g} mesh diagonals)"
            )
        return arr

    def _check_usable(self) -> None:
        if self._failed:
            raise RuntimeError("the simulation failed to converge earlier; call reset() before stepping again")

    def step(self, driven=None, *, force=None) -> None:
        """Advance one time step.

        Args:
            driven: Displacement of every driven node at the *end* of the step [m]: host values of shape
                (D, 3) in the order of ``driven`` (may be omitted when there are none), checked; or a
                :class:`~warpface.fem.state.TissueControl` of this simulation's driven nodes, dtype and device
                already on the device (e.g. filled by a kernel), used as it is: no host transfer, no check.
            force: External nodal force [N] at the end of the step, ``M ä + C ḋ + K d = f`` on the free nodes
                (the rows of fixed and driven nodes are not read; SPEC-style statement: docs/NEWTON.md §2): a Warp
                array on the solver's device (:attr:`state`'s), (N,) of the state's vec3 (``vec3d`` for float64)
                or (N, 3) of its scalar. Its values are read by the step where they lie (a kernel may fill it;
                no host transfer, no finiteness check: a non-finite force fails the step as a non-finite solve
                does). None (default): no external force.

        On CUDA this only queues work; a convergence failure is raised by the next call that
        reads results (``d``, ``v``, ``a``, :meth:`run`, :meth:`synchronize`) or at the latest
        ``CGOptions.chunk`` steps later.

        Raises:
            TypeError: ``force`` is not a Warp array.
            ValueError: wrong shape, a non-finite value, or a displacement beyond :attr:`max_displacement`; a force
                of another shape, precision or device.
            ConvergenceError: CG did not converge (CG solver).
            FloatingPointError: the direct solve gave non-finite displacements (state left as it was).
        """
        self._check_usable()
        if isinstance(driven, TissueControl):
            control = driven
        else:
            self._feed.put(self._check_driven(driven, None))
            control = self.control
        try:
            self.solver.step(self.state, self.state, control, force=force)
        except FloatingPointError:
            self._failed = True
            raise
        self.steps_taken += 1
        if self._feed.wrapped and self.solver.kind == "cg":
            self.synchronize()

    def run(self, trajectory, *, nodes=None, progress: bool | None = None) -> np.ndarray:
        """Advance ``len(trajectory)`` steps and return the displacement after each.

        Args:
            trajectory: Driven-node displacements [m], shape (T, D, 3); row ``t`` is imposed at
                the end of step ``t``.
            nodes: Nodes to record (indices), default all.
            progress: Show a tqdm progress bar; default when T >= 500 and tqdm is installed.

        Returns:
            Displacements [m], shape (T, len(nodes), 3), float32.

        Raises:
            ValueError: bad trajectory (shape, NaN/inf, beyond :attr:`max_displacement`; naming step
                and node) or node indices.
            ConvergenceError: CG did not converge at some step (the residual is in the message).
        """
        self._check_usable()
        try:
            arr = np.asarray(trajectory, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"trajectory must be numbers of shape (steps, {self.driven_nodes.size}, 3)") from None
        if arr.ndim != 3:
            raise ValueError(f"trajectory must have shape (steps, {self.driven_nodes.size}, 3), got {arr.shape}")
        steps = arr.shape[0]
        traj = self._check_driven(arr, steps)
        record = np.arange(self.node_count) if nodes is None else _node_set("nodes", nodes, self.node_count)
        out = np.empty((steps, record.size, 3), dtype=np.float32)
        bar = _progress_bar(steps, progress)
        try:
            if self.solver.kind == "direct":
                driven_view = self.control.driven.numpy()[: self.driven_nodes.size]  # zero-copy (CPU)
                d_view = self.state.d.numpy()
                for t in range(steps):
                    driven_view[:] = traj[t]
                    self.solver.step(self.state, self.state, self.control)
                    out[t] = d_view if nodes is None else d_view[record]
                    self.steps_taken += 1
                    if bar is not None:
                        bar.update(1)
            else:
                start = 0
                for block in self.solver.run_chunks(self.state, traj):
                    out[start : start + block.shape[0]] = block if nodes is None else block[:, record]
                    start += block.shape[0]
                    self.steps_taken += block.shape[0]
                    if bar is not None:
                        bar.update(block.shape[0])
        except (ConvergenceError, FloatingPointError):
            self._failed = True
            raise
        finally:
            if bar is not None:
                bar.close()
        return out

    def synchronize(self) -> None:
        """Wait for queued device steps; raise :class:`ConvergenceError` if one failed."""
        if self.solver.kind == "cg":
            try:
                self.solver.synchronize()
            except ConvergenceError:
                self._failed = True
                raise

    def __repr__(self) -> str:
        return (
            f"TissueSimulation({self.tetmesh!r}, dt={self.dt:g} s, {self.formulation}, solver={self.solver.kind}, "
            f"free={self.free_nodes.size}, fixed={self.fixed_nodes.size}, driven={self.driven_nodes.size})"
        )


def split_nodes(tetmesh: TetMesh, fixed, driven) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Check the constrained node sets of a simulation and return ``(fixed, driven, free)`` node indices.

    Args:
        tetmesh: The mesh.
        fixed: Nodes held at zero displacement: indices or a boolean mask of shape (N,).
        driven: Driven nodes in trajectory column order (indices; no duplicates).

    Returns:
        Fixed nodes (sorted, unique), driven nodes (as given), free nodes (sorted); int64 arrays.

    Raises:
        ValueError: see :class:`TissueSimulation` (indices out of range, duplicates, a node both fixed
            and driven, no constrained node or an unconstrained connected part, no free node).
    """
    n = tetmesh.node_count
    fixed_nodes = np.unique(_node_set("fixed", fixed, n))
    driven_nodes = _node_set("driven", driven, n)
    uniq, counts = np.unique(driven_nodes, return_counts=True)
    if np.any(counts > 1):
        raise ValueError(f"driven node {uniq[counts > 1][0]} is listed more than once")
    both = np.intersect1d(fixed_nodes, driven_nodes)
    if both.size:
        raise ValueError(f"node {both[0]} is both fixed and driven ({both.size} such nodes)")
    constrained = np.union1d(fixed_nodes, driven_nodes)
    if constrained.size == 0:
        raise ValueError(
            "no fixed or driven node: the stiffness matrix is singular (6 rigid-body modes) and the "
            "tissue would drift freely; fix or drive at least three non-collinear nodes"
        )
    _check_every_part_constrained(tetmesh, constrained)
    free_mask = np.ones(n, dtype=bool)
    free_mask[constrained] = False
    free_nodes = np.flatnonzero(free_mask)
    if free_nodes.size == 0:
        raise ValueError("every node is fixed or driven: there is nothing to simulate")
    return fixed_nodes, driven_nodes, free_nodes


def _check_every_part_constrained(tetmesh: TetMesh, constrained: np.ndarray) -> None:
    """Raise if a connected part of the mesh has no constrained node (its K block is singular)."""
    import scipy.sparse as sps
    from scipy.sparse.csgraph import connected_components

    edges = tetmesh.edges
    n = tetmesh.node_count
    graph = sps.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    parts, labels = connected_components(graph, directed=False)
    if parts == 1:
        return
    held = np.zeros(parts, dtype=bool)
    held[labels[constrained]] = True
    if not held.all():
        part = int(np.flatnonzero(~held)[0])
        node = int(np.flatnonzero(labels == part)[0])
        raise ValueError(
            f"the mesh has {parts} disconnected parts and the part containing node {node} has no fixed or "
            "driven node: its stiffness is singular (rigid-body modes)"
        )


def _progress_bar(steps: int, progress: bool | None):
    if progress is False or (progress is None and steps < _PROGRESS_MIN_STEPS):
        return None
    try:
        from tqdm.auto import tqdm
    except ImportError:
        return None
    return tqdm(total=steps, unit="step", desc="tissue")
