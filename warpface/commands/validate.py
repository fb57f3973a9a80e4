"""``warpface validate``: check a stage with UsdValidation and warpface's rig checks.

Run pxr.UsdValidation and warpface's checks on STAGE (a rig stage, or a capture written by `warpface track`):
everything bake or preview would refuse. Exit 1 on errors; exit 2 when the stage, a sublayer or the
asset its skin references cannot be read.
"""

from __future__ import annotations

from .common import add_command

__all__ = ["add_parser", "run"]


def add_parser(subparsers, common) -> None:
    check = add_command(subparsers, common, "validate", run, __doc__)
    check.add_argument("stage", help="stage to check")
    check.add_argument("--strict", action="store_true", help="exit 1 on warnings too")


def run(args) -> int:
    from pathlib import Path

    from ..usd import open_stage, validate_stage
    from ..usd.asset_io import check_asset
    from ..usd.rig_io import SKIN_API

    if not Path(args.stage).is_file():
        raise ValueError(f"{args.stage}: file not found")
    stage = open_stage(args.stage)  # an unreadable stage or sublayer is an error (exit 2), not a finding
    for skin in (prim for prim in stage.Traverse() if prim.HasAPI(SKIN_API)):
        check_asset(skin)  # so is a referenced asset that is missing: nothing can be checked without it
    problems = validate_stage(stage, device=args.device, progress=not args.quiet)
    errors = [p for p in problems if p.severity == "error"]
    for problem in problems:
        print(problem)
    if not problems:
        print(f"{args.stage}: no problems found")
    return 1 if errors or (args.strict and problems) else 0
