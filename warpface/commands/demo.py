"""``warpface demo``: built-in face -> four expressions -> USD stage, bake, images, video.

Build the built-in face, animate thinking/puzzled/disgust/smile, write DIR/face.usda + DIR/face_anim.usdc, PNG
previews with and without wrinkles, heat maps and an MP4.
"""

from __future__ import annotations

from .common import add_command, positive_float

__all__ = ["add_parser", "run"]


def add_parser(subparsers, common) -> None:
    demo = add_command(subparsers, common, "demo", run, __doc__)
    demo.add_argument("--out", default="demo", help="output folder (default: demo)")
    demo.add_argument("--fps", type=positive_float, default=30.0, help="frames per second (default 30)")
    demo.add_argument(
        "--seconds",
        type=positive_float,
        default=2.0,
        help="seconds per expression, neutral -> peak -> neutral (default 2)",
    )
    demo.add_argument("--no-video", action="store_true", help="skip the MP4")


def run(args) -> int:
    from ..demo import run_demo

    result = run_demo(
        args.out,
        device=args.device,
        fps=args.fps,
        seconds=args.seconds,
        video=not args.no_video,
        progress=not args.quiet,
    )
    print("warpface demo — built-in face, expressions: thinking, puzzled, disgust, smile")
    print(f"  stage   {result.stage}   (rig + contraction time samples; open with any USD tool)")
    print(f"  cache   {result.cache}   (baked skin points, sublayered under the stage)")
    for image in result.images:
        print(f"  image   {image}")
    if result.video:
        print(f"  video   {result.video}")
    print("  timings " + ", ".join(f"{step} {seconds:.1f} s" for step, seconds in result.timings.items()))
    return 0
