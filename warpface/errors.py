"""Exceptions raised by warpface."""

__all__ = ["RigError"]


class RigError(ValueError):
    """A rig (mesh, muscles, wrinkles, thickness) or a stage describing one is invalid.

    Subclass of ``ValueError``; the message names the offending item (prim path, index, name).
    """
