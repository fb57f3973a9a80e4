"""Argument types and checks shared by the sub-commands; the one-line form of any error."""

from __future__ import annotations

import argparse
import math
import re

__all__ = [
    "add_command",
    "positive_float",
    "non_negative_float",
    "finite_float",
    "pixel_count",
    "positive_int",
    "check_device",
    "one_line",
]

MAX_PIXELS = 8192
"""Largest --width / --height accepted."""


def add_command(subparsers, common, name: str, handler, doc: str | None):
    """Register the sub-command ``name`` with the shared options ``common``, ``handler(args)`` running it;
    returns its parser, for the command's own arguments.

    ``doc`` is the command module's docstring: its first paragraph after the ``warpface NAME …:`` title (less
    the final period) is the command's one-line help, its second paragraph the description of its ``--help``.
    """
    help_text = description = None
    if doc:  # None under python -OO
        summary, description = (" ".join(part.split()) for part in doc.split("\n\n")[:2])
        help_text = summary.split(": ", 1)[1].removesuffix(".")
    parser = subparsers.add_parser(name, parents=[common], help=help_text, description=description)
    parser.set_defaults(handler=handler)
    return parser


def finite_float(text: str) -> float:
    """An argparse type: a finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text}")
    return value


def positive_float(text: str) -> float:
    """An argparse type: a finite number > 0."""
    value = finite_float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def non_negative_float(text: str) -> float:
    """An argparse type: a finite number ≥ 0."""
    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be ≥ 0, got {text}")
    return value


def _whole_number(text: str, what: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number{what}: {text!r}") from None


def pixel_count(text: str) -> int:
    """An argparse type: an image side in pixels, 16 … 8192."""
    value = _whole_number(text, " of pixels")
    if not 16 <= value <= MAX_PIXELS:
        raise argparse.ArgumentTypeError(f"must be between 16 and {MAX_PIXELS} pixels, got {value}")
    return value


def positive_int(text: str) -> int:
    """An argparse type: a whole number ≥ 1."""
    value = _whole_number(text, "")
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be ≥ 1, got {value}")
    return value


_DEVICE = re.compile(r"^(cpu|cuda)(?::(\d+))?$")


def check_device(name: str | None) -> str | None:
    """``name`` if it names a Warp device this machine has (``cpu``, ``cuda``, ``cuda:N``), else ValueError
    saying which devices there are. ``None`` (Warp's preferred device) passes unchecked."""
    if name is None:
        return None
    match = _DEVICE.match(name.strip())
    if match is None or (match.group(1) == "cpu" and match.group(2) is not None):
        raise ValueError(f"--device {name}: unknown device (use cpu, cuda or cuda:N)")
    if match.group(1) == "cpu":
        return "cpu"
    import warp as wp

    count = wp.get_cuda_device_count()
    if count == 0:
        raise ValueError(f"--device {name}: no CUDA device is available on this machine (use --device cpu)")
    ordinal = int(match.group(2) or 0)
    if ordinal >= count:
        raise ValueError(
            f"--device {name}: this machine has {count} CUDA device{'s' if count > 1 else ''} "
            f"(cuda:0{f' … cuda:{count - 1}' if count > 1 else ''})"
        )
    return f"cuda:{ordinal}"


def one_line(error: BaseException) -> str:
    """The error as one line: pxr diagnostics reduced to their messages, whitespace collapsed, and the
    exception type named when it is not one of warpface's expected kinds."""
    from ..errors import RigError

    if type(error).__name__ == "ErrorException":  # pxr.Tf.ErrorException, without importing pxr here
        from ..usd import usd_error_message

        text = usd_error_message(error)
    else:
        text = str(error)
    text = " ".join(text.split()) or type(error).__name__
    if isinstance(error, MemoryError):
        return f"out of memory ({text})"
    if not isinstance(error, (ValueError, TypeError, OSError, RigError)) and type(error).__name__ != "ErrorException":
        text = f"{type(error).__name__}: {text}"
    return text
