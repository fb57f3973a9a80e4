"""Exceptions raised by warpface."""

__all__ = ["ConvergenceError", "RigError"]


class RigError(ValueError):
    """A rig (mesh, muscles, wrinkles, thickness) or a stage describing one is invalid.

    Subclass of ``ValueError``; the message names the offending item (prim path, index, name).
    """


class ConvergenceError(RuntimeError):
    """An iterative solver did not reach its tolerance within its iteration limit.

    Subclass of ``RuntimeError``: the input was valid, the solve failed; the message names the step (and the
    model of a batch), the residual and the tolerance.
    """
