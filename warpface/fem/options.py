"""Options of the tissue's CG solvers, one dataclass shared by the single-model and the batched solver.

:class:`CGOptions` is checked when it is made (TypeError for a wrong type, ValueError for a value out of
range, each naming the field); the solver that receives it checks what only it knows (the preconditioners
and loops it implements, the precision it supports).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import warp as wp

__all__ = ["BATCH_PRECONDITIONERS", "CG_LOOPS", "CGOptions", "PRECONDITIONERS", "as_cg_options"]

PRECONDITIONERS = ("fsai", "block_jacobi", "diag")
"""Preconditioners of the single-model solver: FSAI (factorised sparse approximate inverse), the inverse
Cholesky factors of the 3x3 diagonal blocks, or of the diagonal (Jacobi)."""

BATCH_PRECONDITIONERS = ("fsai", "fsai_each", "block_jacobi")
"""Preconditioners of the batched solver: one FSAI factor shared by the models, its support refitted to every
model, or block Jacobi per model."""

CG_LOOPS = ("auto", "persistent", "launched")
"""How the CG iterations run: ``"persistent"`` (one kernel for all iterations, grid-wide barriers between
phases, :mod:`warpface.fem.kernels_persistent`), ``"launched"`` (three kernels per iteration in a
``wp.capture_while`` loop) or ``"auto"`` (persistent on CUDA when the occupancy query says its blocks can all
be resident, else launched; launched on the CPU)."""


@dataclasses.dataclass(frozen=True)
class CGOptions:
    """Settings of the preconditioned CG of a tissue solver (:class:`~warpface.fem.solver_cg.CGSolver`,
    :class:`~warpface.fem.solver_batch.BatchedCGSolver`, and through them ``TissueSimulation(cg=...)`` and
    ``TissueBatch(cg=...)``).

    Args:
        tolerance: Stop when the residual is at most ``tolerance`` times the residual of the Newmark predictor
            ``d + dt v + dt²/2 a``. That residual is small, so the error left in the displacement is
            ``tolerance`` times the (tiny) correction to the predictor. In (0, 1].
        maxiter: Iteration limit per step; a step that reaches it raises
            :class:`~warpface.errors.ConvergenceError`. The default 200 is several times what any tissue step of
            the benchmarks needs, and stays small because every step clears ``4 (maxiter + 1)`` dot-product slots
            per model.
        preconditioner: One of :data:`PRECONDITIONERS` (single model) or :data:`BATCH_PRECONDITIONERS` (batch).
        chunk: Time steps per ring buffer of ``run`` and of ``step``'s host input; the host checks convergence
            once per ring.
        loop: One of :data:`CG_LOOPS` (the batch always uses the persistent kernel).
        dtype: ``wp.float64`` or ``wp.float32`` state and solver precision (the batch: float64 only). float32
            gains little: its state is too coarse for the extrapolated start, which then needs more iterations.
        use_graph: Capture each step as a CUDA graph; ``None``: on CUDA devices only.
    """

    tolerance: float = 1.0e-5
    maxiter: int = 200
    preconditioner: str = "fsai"
    chunk: int = 64
    loop: str = "auto"
    dtype: type = wp.float64
    use_graph: bool | None = None

    def __post_init__(self):
        set_field = object.__setattr__  # frozen: normalise the numbers once here
        set_field(self, "tolerance", _number("tolerance", self.tolerance, 1e-16, 1.0))
        set_field(self, "maxiter", int(_number("maxiter", self.maxiter, 1, 100_000, integer=True)))
        set_field(self, "chunk", int(_number("chunk", self.chunk, 1, 100_000, integer=True)))
        for name, allowed in (("preconditioner", PRECONDITIONERS + BATCH_PRECONDITIONERS), ("loop", CG_LOOPS)):
            value = getattr(self, name)
            if not isinstance(value, str):
                raise TypeError(f"CGOptions.{name} must be a string, got {type(value).__name__}")
            if value not in allowed:
                raise ValueError(f"CGOptions.{name} must be one of {tuple(dict.fromkeys(allowed))}, got {value!r}")
        if self.dtype not in (wp.float32, wp.float64):
            raise ValueError(f"CGOptions.dtype must be wp.float32 or wp.float64, got {self.dtype!r}")
        if self.use_graph is not None and not isinstance(self.use_graph, (bool, np.bool_)):
            raise TypeError(f"CGOptions.use_graph must be a bool or None, got {type(self.use_graph).__name__}")

    def graph_on(self, *, device) -> bool:
        """Whether steps on ``device`` are captured as graphs (:attr:`use_graph`, or CUDA when it is None)."""
        return device.is_cuda if self.use_graph is None else bool(self.use_graph)

    def require(self, solver: str, preconditioners: tuple, loops: tuple = CG_LOOPS, dtypes: tuple = ()) -> None:
        """Raise ValueError if ``solver`` (its name, for the message) does not implement these options."""
        if self.preconditioner not in preconditioners:
            raise ValueError(
                f"CGOptions.preconditioner of {solver} must be one of {preconditioners}, got {self.preconditioner!r}"
            )
        if self.loop not in loops:
            raise ValueError(f"CGOptions.loop of {solver} must be one of {loops}, got {self.loop!r}")
        if dtypes and self.dtype not in dtypes:
            raise ValueError(f"CGOptions.dtype of {solver} must be {' or '.join(map(str, dtypes))}, got {self.dtype}")


def as_cg_options(cg) -> CGOptions:
    """``cg`` itself, the defaults for ``None``; TypeError for anything but a CGOptions."""
    if cg is None:
        return CGOptions()
    if not isinstance(cg, CGOptions):
        raise TypeError(f"cg must be a CGOptions, got {type(cg).__name__}")
    return cg


def _number(name: str, value, low: float, high: float, *, integer: bool = False) -> float:
    """``value`` as a float in ``[low, high]`` (whole when ``integer``); TypeError / ValueError naming the field."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"CGOptions.{name} must be a number, got {type(value).__name__}")
    number = float(value)
    if not (np.isfinite(number) and low <= number <= high) or (integer and number != round(number)):
        kind = "a whole number" if integer else "a number"
        raise ValueError(f"CGOptions.{name} must be {kind} in [{low:g}, {high:g}], got {value!r}")
    return number
