"""The kinds of take (``animate``, ``track``, ``fit``): their options checked by the commands' own parsers, and one
take run through the command's own handler in a given folder.

A take's options are the options of ``warpface KIND`` itself: the kind's sub-parser is built from the command
module (:func:`warpface.commands.animate.add_parser`, …) with errors raised as ValueError instead of exiting, so
a manifest accepts exactly what the command line accepts, with the same defaults. The batch sets the input, the
output, ``--rig`` and ``--map`` (and ``--device``, ``--quiet``); a manifest that gives them is refused.
"""

from __future__ import annotations

import argparse
import functools
import os
from pathlib import Path

__all__ = ["KINDS", "parse_options", "run_kind", "render_still", "RigCheck"]

KINDS = ("animate", "track", "fit")
"""The kinds of take, each the ``warpface`` command of that name."""

_SET_BY_BATCH = {
    "animate": {"driver", "out", "rig", "map"},
    "track": {"source", "stage", "rig"},
    "fit": {"targets", "rig", "out", "name"},
}
"""Per kind, the destinations the batch fills in itself (input, output, rig, mapping)."""


class _StrictParser(argparse.ArgumentParser):
    """argparse raising ValueError (no printing, no exit) and matching option names exactly."""

    def __init__(self, *args, **kwargs):
        kwargs["allow_abbrev"] = False
        super().__init__(*args, **kwargs)

    def error(self, message):
        raise ValueError(message)


@functools.lru_cache(maxsize=None)
def _parser(kind: str) -> argparse.ArgumentParser:
    """The sub-parser of ``warpface KIND``, built by the command's own module."""
    import importlib

    root = _StrictParser(prog="warpface", add_help=False)
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--device", default=None)
    common.add_argument("--quiet", action="store_true")
    commands = root.add_subparsers(dest="command", parser_class=_StrictParser)
    importlib.import_module(f"warpface.commands.{kind}").add_parser(commands, common)
    return commands.choices[kind]


def _option_flags(kind: str) -> dict[str, argparse.Action]:
    """The options a manifest may give for ``kind``: flag → action (the batch's own ones left out)."""
    taken = _SET_BY_BATCH[kind] | {"device", "quiet", "help"}
    return {
        flag: action
        for action in _parser(kind)._actions  # argparse keeps its actions only here
        for flag in action.option_strings
        if action.dest not in taken
    }


def parse_options(kind: str, words: list[str], off: list[str], where: str) -> tuple[tuple[str, ...], dict]:
    """Check a take's options against ``warpface KIND``'s parser: (the words, every option's parsed value).

    ``off``: flags the manifest set to false (each must be an on/off flag of the command).

    Raises:
        ValueError: an unknown option, one the batch sets itself, or a bad value; the message starts with ``where``.
    """
    known = _option_flags(kind)
    for word in [w.partition("=")[0] for w in words if w.startswith("-")] + list(off):
        if word in known:
            continue
        if word in _parser(kind)._option_string_actions:
            raise ValueError(f"{where}: option {word} is set by the batch (input, output, rig, mapping, device)")
        if _looks_like_option(word):
            raise ValueError(f"{where}: unknown option {word} for kind {kind} (see warpface {kind} --help)")
    for flag in off:
        if known[flag].nargs != 0:
            raise ValueError(f"{where}: option {flag} takes a value, not true/false")
    try:
        parsed = _parser(kind).parse_args(_placeholders(kind) + list(words))
    except ValueError as error:
        raise ValueError(f"{where}: options: {error}") from None
    settings = {
        name: value
        for name, value in sorted(vars(parsed).items())
        if name not in _SET_BY_BATCH[kind] | {"device", "quiet", "handler", "command"}
    }
    return tuple(words), settings


def _looks_like_option(word: str) -> bool:
    """True for ``-x``/``--xyz``; False for a negative number given as a value."""
    try:
        float(word)
    except ValueError:
        return True
    return False


def _placeholders(kind: str) -> list[str]:
    """The arguments the batch fills in, with stand-in values (only the options are being checked)."""
    return {
        "animate": ["driver.csv", "--out", "take.usda"],
        "track": ["synthetic", "--stage", "take.usda"],
        "fit": ["target.obj", "--rig", "rig.usda"],
    }[kind]


class RigCheck:
    """Loads each rig stage of a manifest once, so a rig that does not load is refused before any work."""

    def __init__(self):
        self._checked: dict[Path, int | str] = {}

    def check(self, path: Path, where: str) -> int:
        """The skin vertex count of the rig stage at ``path``; ValueError starting with ``where`` when it does not
        load."""
        if path not in self._checked:
            self._checked[path] = _rig_size(path)
        if isinstance(self._checked[path], str):
            raise ValueError(f"{where}: {self._checked[path]}")
        return self._checked[path]


def _rig_size(path: Path) -> int | str:
    """The skin vertex count of the rig stage at ``path``, or why it does not load."""
    from ..commands.common import one_line

    if not path.is_file():
        return "file not found"
    if path.suffix.lower() not in (".usda", ".usdc", ".usd"):
        return "expected a USD rig stage (.usda, .usdc, .usd)"
    try:
        from ..usd import open_stage, read_rig, stage_meters_per_unit

        stage = open_stage(path)
        return read_rig(stage, meters_per_unit=stage_meters_per_unit(stage)).mesh.vertex_count
    except Exception as error:  # noqa: BLE001 — any failure to load is the row's one-line problem
        return f"does not load ({one_line(error)})"


def run_kind(take, folder: Path, *, device: str | None, rigs=None) -> Path:
    """Run ``take`` (a :class:`~warpface.batch.manifest.Take`) through its command's handler, writing into
    ``folder`` (which exists); returns the take's stage, ``folder/<id>.usda``.

    ``rigs``: the worker's :class:`~warpface.commands.rig_models.RigModels`, which an ``animate`` take takes its
    rig and expression model from (built once per worker, not once per take); None: built for this take.

    The command prints its usual summary (the caller decides where stdout goes); any error propagates.
    """
    stage = folder / f"{take.id}.usda"
    rig = [] if take.rig is None else ["--rig", str(take.rig)]
    if take.kind == "animate":
        mapping = [] if take.mapping is None else ["--map", take.mapping]
        words = [str(take.input), "--out", str(stage), *rig, *mapping]
    elif take.kind == "track":
        words = [str(take.input), "--stage", str(stage), *rig]
    else:
        _overlay_rig(take.rig, stage)
        words = [str(take.input), "--rig", str(stage), "--out", str(folder / "fit")]
    args = _parser(take.kind).parse_args(words + list(take.options))
    args.device, args.quiet = device, True
    if take.kind == "animate":
        from ..commands.animate import run_animate

        code = run_animate(args, rigs=rigs)
    else:
        code = args.handler(args)
    if code:
        raise RuntimeError(f"warpface {take.kind} ended with exit code {code}")
    return stage


def render_still(stage: Path, time: float | None, path: Path, size: tuple[int, int]) -> None:
    """A PNG of ``stage``'s face at ``time`` (default: its first frame), by ``warpface preview``'s own handler."""
    words = [str(stage), "--out", str(path), "--width", str(size[0]), "--height", str(size[1])]
    args = _parser("preview").parse_args(words + ([] if time is None else ["--time", repr(float(time))]))
    args.device, args.quiet = None, True
    args.handler(args)


def _overlay_rig(rig: Path, stage: Path) -> None:
    """A layer at ``stage`` over the rig stage (a relative sublayer): ``fit`` adds its presets there and leaves
    the manifest's rig untouched."""
    from pxr import Sdf

    from ..usd import export_layer_atomically, open_stage

    source = open_stage(rig)
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.subLayerPaths.append(os.path.relpath(rig, stage.parent))
    root = source.GetRootLayer()
    for key in ("defaultPrim", "metersPerUnit", "upAxis", "timeCodesPerSecond", "framesPerSecond"):
        if root.pseudoRoot.HasInfo(key):
            layer.pseudoRoot.SetInfo(key, root.pseudoRoot.GetInfo(key))
    export_layer_atomically(layer, stage)
