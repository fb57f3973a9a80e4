"""Every exception class warpface defines, in one place.

Bad arguments follow one rule: a wrong type raises :class:`TypeError`, a wrong value :class:`ValueError`
(:class:`RigError` is a ValueError), and the one-line message names the argument. The classes below
are for what is not a bad argument: a machine without a camera or an OpenGL back end, a USD install
that did not take the schema plugin.
"""

__all__ = [
    "RigError",
    "ConvergenceError",
    "UnsuitableFactor",
    "SchemaRegistrationError",
    "CameraError",
    "CameraUnavailable",
    "CameraDisconnected",
    "OffscreenUnavailable",
]


class RigError(ValueError):
    """A rig (mesh, muscles, wrinkles, thickness) or a stage describing one is invalid.

    Subclass of ``ValueError``; the message names the offending item (prim path, index, name).
    """


class ConvergenceError(RuntimeError):
    """An iterative solver did not reach its tolerance within its iteration limit.

    Subclass of ``RuntimeError``: the input was valid, the solve failed; the message names the step (and the
    model of a batch), the residual and the tolerance.
    """


class UnsuitableFactor(ValueError):
    """The float32 block factor would not refine reliably (an ill-conditioned matrix): use a float64 factor."""


class SchemaRegistrationError(RuntimeError):
    """warpface's USD schema plugin is not (or not fully) known to OpenUSD in this process."""


class CameraError(RuntimeError):
    """A live camera could not deliver frames."""


class CameraUnavailable(CameraError):
    """The camera's SDK is not installed, or no device is attached."""


class CameraDisconnected(CameraError):
    """The camera stopped delivering frames during a capture."""


class OffscreenUnavailable(OSError):
    """No offscreen OpenGL back end can start on this machine; the message says what to install."""
