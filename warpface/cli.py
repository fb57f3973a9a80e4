"""The ``warpface`` command line: one sub-command per module of :mod:`warpface.commands` (``demo``, ``rig``,
``bake``, ``preview``, ``validate``, ``track``, ``animate``, ``fit``, ``presets``, ``calibrate``), and ``batch``
(:mod:`warpface.batch.command`: it runs the others, so it lives with :mod:`warpface.batch`).

Warp is initialised quietly (:func:`warpface.init_runtime`) before a command runs. Every sub-command has
``--help``; ``--device`` and ``--quiet`` work before or after the command. Any
error — bad arguments, a bad or unreadable stage, a full disk, pxr's own exceptions — is one line on
stderr and exit code 2, never a traceback (``WARPFACE_DEBUG=1`` shows the traceback instead); problems
found by ``validate`` give exit code 1; Ctrl-C gives 130. Arguments are checked before any file or
folder is created.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from . import __version__, init_runtime
from .batch import command as batch_command
from .commands import COMMANDS
from .commands.common import check_device, one_line
from .errors import CameraError

__all__ = ["main", "build_parser"]


class _Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors (``warpface demo: error: …``), exit code 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _common_options(top_level: bool) -> argparse.ArgumentParser:
    """--device and --quiet; on the sub-parsers without defaults, so a value given before the command
    is not overwritten when it is not repeated after it."""
    common = argparse.ArgumentParser(add_help=False)
    default = {} if top_level else {"default": argparse.SUPPRESS}
    common.add_argument(
        "--device",
        help="Warp device: cpu, cuda or cuda:N (default: Warp's preferred device)",
        **({"default": None} if top_level else default),
    )
    common.add_argument("--quiet", action="store_true", help="no progress bars (results are still printed)", **default)
    return common


def build_parser() -> argparse.ArgumentParser:
    """The full parser; each command module in :data:`warpface.commands.COMMANDS` adds its sub-parser."""
    parser = _Parser(
        prog="warpface",
        parents=[_common_options(True)],
        description="Muscle-driven facial expressions with wrinkles, on Warp and USD.",
    )
    parser.add_argument("--version", action="version", version=f"warpface {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_Parser)
    common = _common_options(False)
    for name in COMMANDS:
        importlib.import_module(f"{__package__}.commands.{name}").add_parser(commands, common)
    batch_command.add_parser(commands, common)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``warpface`` console script; returns the exit code."""
    args = build_parser().parse_args(argv)
    try:
        init_runtime(quiet=True)
        args.device = check_device(args.device)
        return int(args.handler(args) or 0)
    except KeyboardInterrupt:
        print(f"warpface {args.command}: interrupted; files written so far are intact", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 2
    except Exception as error:  # noqa: BLE001 — the one place every error becomes one line
        if os.environ.get("WARPFACE_DEBUG"):
            raise
        kind = "camera error" if isinstance(error, CameraError) else "error"
        print(f"warpface {args.command}: {kind}: {one_line(error)}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
