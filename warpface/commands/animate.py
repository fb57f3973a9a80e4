"""``warpface animate``: driver curves → rig time samples, bake, video (see :mod:`warpface.cli_animate`)."""

from __future__ import annotations

__all__ = ["add_parser"]


def add_parser(subparsers, common) -> None:
    from ..cli_animate import add_parser as add_animate_parser

    parser = add_animate_parser(subparsers)
    for action in common._actions:  # --device/--quiet after the command too, as parents=[common] would give
        parser._add_action(action)
