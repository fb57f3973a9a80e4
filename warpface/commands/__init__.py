"""The sub-commands of the ``warpface`` command line, one module each.

A command module provides ``add_parser(subparsers, common)`` — it adds its sub-parser (with
``parents=[common]`` so the shared options work after the command too) and sets ``handler`` to its
``run(args) -> int``; :func:`~warpface.commands.common.add_command` does both, taking the command's
help and description from the first two paragraphs of the module's docstring. Register a new command
by adding its module name to :data:`COMMANDS`.
"""

COMMANDS = ("demo", "rig", "bake", "preview", "validate", "track", "animate", "fit", "presets", "calibrate")
"""Module names under :mod:`warpface.commands`, in the order ``warpface --help`` lists them."""

__all__ = ["COMMANDS"]
