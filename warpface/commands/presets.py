"""``warpface presets [--rig RIG]``: list the presets (ARKit shapes, expressions) and their controls.

List the named presets and the controls each sets: relative values, or with --rig the values on that rig (lengths
in mm) and the presets stored on its stage by `warpface fit`.

Without ``--rig`` the values are the relative ones of :data:`warpface.assets.PRESETS` (the ARKit shapes and the
paper's expressions: a linear muscle's contraction and the jaw's lengths in inter-ocular units, a sphincter's
``K``, ``jaw_open`` in radians). With ``--rig`` they are the values on that rig (lengths in mm, through
:func:`warpface.assets.preset_controls`), a preset the rig lacks a control for is listed with what it
misses, and the presets stored on the stage (``warpface fit``) follow.
"""

from __future__ import annotations

from .common import add_command

__all__ = ["add_parser", "run"]

_LENGTH_CONTROLS = ("jaw_forward", "jaw_left")


def add_parser(subparsers, common) -> None:
    presets = add_command(subparsers, common, "presets", run, __doc__)
    presets.add_argument("names", nargs="*", metavar="PRESET", help="only these presets (default: all)")
    presets.add_argument("--rig", default=None, help="rig stage (.usda/.usdc/.usd): values on this rig")


def _format(controls: dict[str, float], lengths: set[str], unit: str) -> str:
    return ", ".join(
        f"{name} {value:.4g}{unit if name in lengths else ''}" for name, value in controls.items() if value != 0.0
    )


def run(args) -> int:
    from pathlib import Path

    from ..assets import PRESETS, preset_controls
    from ..errors import RigError
    from ..expression.muscles import LinearMuscle

    unknown = [name for name in args.names if name not in PRESETS]
    if args.rig is None:
        if unknown:
            raise ValueError(f"unknown preset {unknown[0]!r} (run `warpface presets` for the list)")
        print(
            "relative values: linear muscles and jaw_forward/jaw_left in inter-ocular units, sphincters K, jaw_open rad"
        )
        for name in args.names or PRESETS:
            print(f"{name}: {_format(dict(PRESETS[name]), set(), '')}")
        return 0
    from ..usd import open_stage, read_rig
    from ..usd.presets_io import read_presets

    rig_path = Path(args.rig)
    if rig_path.suffix.lower() not in (".usda", ".usdc", ".usd", ".usdz"):
        raise ValueError(f"--rig {rig_path}: expected a USD rig stage (.usda, .usdc, .usd)")
    if not rig_path.is_file():
        raise ValueError(f"--rig {rig_path}: file not found")
    stage = open_stage(rig_path)
    rig = read_rig(stage, meters_per_unit=0.001)
    stored = read_presets(stage, meters_per_unit=0.001)
    unknown = [name for name in unknown if name not in stored]
    if unknown:
        raise ValueError(f"unknown preset {unknown[0]!r}: neither built in nor stored on {rig_path}")
    lengths = {m.name for m in rig.muscles if isinstance(m, LinearMuscle)} | set(_LENGTH_CONTROLS)
    print(f"on rig {rig.name!r} ({rig_path}): linear muscles and jaw lengths in mm, sphincters K, jaw_open rad")
    for name in [n for n in args.names or PRESETS if n in PRESETS]:
        try:
            controls = preset_controls(name, rig)
        except RigError as error:
            missing = str(error).rpartition("needs control(s) ")[2]
            print(f"{name}: (not on this rig: needs {missing})")
            continue
        print(f"{name}: {_format(controls, lengths, ' mm')}")
    for name in [n for n in args.names or stored if n in stored]:
        print(f"{name} (stored): {_format(stored[name], lengths, ' mm')}")
    return 0
