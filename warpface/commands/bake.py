"""``warpface bake``: evaluate a rig stage at its time codes into a .usdc points cache and a shot stage.

Evaluate the expression model at every time code of STAGE (or --start..--end) and write the skin's points (extent,
and normals when the skin's asset has them) as time samples in a .usdc cache layer of their own, and a small shot
stage (default STAGE_shot.usda) that layers the cache over STAGE. STAGE, the rig and the skin's asset are not edited.
"""

from __future__ import annotations

from .common import add_command, finite_float, positive_float, positive_int

__all__ = ["add_parser", "run"]


def add_parser(subparsers, common) -> None:
    from ..usd.animation import MAX_FRAMES

    bake = add_command(subparsers, common, "bake", run, __doc__)
    bake.add_argument("stage", help="rig stage (.usda/.usdc) with contraction time samples")
    bake.add_argument(
        "--cache", default=None, help="cache file (default: <stage>_anim.usdc); not the stage or one of its layers"
    )
    bake.add_argument(
        "--shot",
        default=None,
        help="shot stage to write, the cache layered over STAGE (default: <stage>_shot.usda); open this one to play",
    )
    bake.add_argument("--start", type=finite_float, default=None, help="first time code (default: the stage's start)")
    bake.add_argument("--end", type=finite_float, default=None, help="last time code (default: the stage's end)")
    bake.add_argument("--step", type=positive_float, default=1.0, help="time code step, > 0 (default 1)")
    bake.add_argument(
        "--max-frames",
        type=positive_int,
        default=MAX_FRAMES,
        help=f"refuse to bake more frames than this (default {MAX_FRAMES}); raise it for longer bakes",
    )


def run(args) -> int:
    from .. import usd
    from ..usd.animation import frame_range
    from ..usd.baking import default_shot_path

    shot = args.shot if args.shot is not None else default_shot_path(args.stage)
    frames = None
    if args.start is not None or args.end is not None or args.step != 1.0:
        stage = usd.open_stage(args.stage)
        start = stage.GetStartTimeCode() if args.start is None else args.start
        end = stage.GetEndTimeCode() if args.end is None else args.end
        frames = frame_range(start, end, args.step, max_frames=args.max_frames, label="--start/--end/--step")
    cache = usd.bake(
        args.stage,
        frames,
        cache_path=args.cache,
        device=args.device,
        progress=not args.quiet,
        max_frames=args.max_frames,
        shot=shot,
    )
    print(f"baked {args.stage} -> {cache}; play {shot}")
    return 0
