"""The ``warpface`` command line: ``demo``, ``bake``, ``preview``, ``validate``, ``track``.

Every sub-command has ``--help``. Errors in the input (a bad stage, a missing file) are reported in
one line on stderr with exit code 2, not as a traceback; problems found by ``validate`` give exit code 1.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

__all__ = ["main", "build_parser"]


def _demo(args) -> int:
    from .demo import run_demo

    result = run_demo(args.out, device=args.device, fps=args.fps, seconds=args.seconds, video=not args.no_video,
                      progress=not args.quiet)
    print(f"warpface demo — built-in face, expressions: thinking, puzzled, disgust, smile")
    print(f"  stage   {result.stage}   (rig + contraction time samples; open with any USD tool)")
    print(f"  cache   {result.cache}   (baked skin points, sublayered under the stage)")
    for image in result.images:
        print(f"  image   {image}")
    if result.video:
        print(f"  video   {result.video}")
    print("  timings " + ", ".join(f"{step} {seconds:.1f} s" for step, seconds in result.timings.items()))
    return 0


def _bake(args) -> int:
    import numpy as np

    from . import usd

    frames = None
    if args.start is not None or args.end is not None:
        stage = usd.open_stage(args.stage)
        start = stage.GetStartTimeCode() if args.start is None else args.start
        end = stage.GetEndTimeCode() if args.end is None else args.end
        if end < start:
            raise ValueError(f"--end ({end}) is before --start ({start})")
        frames = np.arange(start, end + 0.5 * args.step, args.step)
    cache = usd.bake(args.stage, frames, cache_path=args.cache, device=args.device, progress=not args.quiet)
    print(f"baked {args.stage} -> {cache}")
    return 0


def _preview(args) -> int:
    import numpy as np

    from . import preview

    source = Path(args.source)
    if source.suffix.lower() == ".obj":
        from .mesh import FaceMesh

        mesh = FaceMesh.from_obj(source)
        points, triangles, rest = mesh.points, mesh.triangles, mesh.points
    else:
        points, triangles, rest = _stage_points(source, args.time)
    out = Path(args.out) if args.out else source.with_name(f"{source.stem}_preview.png")
    camera = preview.Camera.framing(rest, yaw_deg=args.yaw, pitch_deg=args.pitch, aspect=args.width / args.height)
    if args.heat:
        magnitude = np.linalg.norm(points - rest, axis=1)
        preview.render_heat_map(points, triangles, magnitude, out, camera=camera, size=(args.width, args.height),
                                title="|displacement| from rest", units="stage units")
    else:
        preview.render(points, triangles, out, camera=camera, size=(args.width, args.height))
    print(f"wrote {out}")
    return 0


def _stage_points(path: Path, time_code):
    """The skin's points at ``time_code`` (default: the stage's start), its triangles and its rest points."""
    import numpy as np
    from pxr import Usd, UsdGeom

    from .usd import open_stage, read_rig, rig_prims, stage_meters_per_unit

    stage = open_stage(path)
    rig = read_rig(stage, meters_per_unit=stage_meters_per_unit(stage))
    attribute = rig_prims(stage).skin.GetAttribute(UsdGeom.Tokens.points)
    when = Usd.TimeCode(stage.GetStartTimeCode() if time_code is None else time_code)
    points = np.asarray(attribute.Get(when), dtype=np.float64)
    if points.shape != rig.mesh.points.shape:
        points = rig.mesh.points
    return points, rig.mesh.triangles, rig.mesh.points


def _validate(args) -> int:
    from .usd import validate_stage

    problems = validate_stage(args.stage)
    errors = [p for p in problems if getattr(p, "severity", "error") == "error"]
    for problem in problems:
        print(problem)
    if not problems:
        print(f"{args.stage}: no problems found")
    return 1 if errors or (args.strict and problems) else 0


def _track(args) -> int:
    from .pipelines.track import run_track

    return run_track(args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="warpface", description="Muscle-driven facial expressions with wrinkles, on Warp and USD.")
    parser.add_argument("--device", default=None, help="Warp device, e.g. cpu or cuda:0 (default: Warp's preferred device)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    demo = commands.add_parser("demo", help="built-in face -> four expressions -> USD stage, bake, images, video",
                               description="Build the built-in face, animate thinking/puzzled/disgust/smile, write "
                                           "DIR/face.usda + DIR/face_anim.usdc, PNG previews with and without wrinkles, "
                                           "heat maps and an MP4.")
    demo.add_argument("--out", default="demo", help="output folder (default: demo)")
    demo.add_argument("--fps", type=float, default=30.0, help="frames per second (default 30)")
    demo.add_argument("--seconds", type=float, default=2.0, help="seconds per expression, neutral -> peak -> neutral (default 2)")
    demo.add_argument("--no-video", action="store_true", help="skip the MP4")
    demo.set_defaults(handler=_demo)

    bake = commands.add_parser("bake", help="evaluate a rig stage at its time codes into a .usdc points cache",
                               description="Evaluate the expression model at every time code of STAGE (or --start..--end) "
                                           "and write the skin's points as time samples in a .usdc cache sublayered under STAGE.")
    bake.add_argument("stage", help="rig stage (.usda/.usdc) with contraction time samples")
    bake.add_argument("--cache", default=None, help="cache file (default: <stage>_anim.usdc)")
    bake.add_argument("--start", type=float, default=None, help="first time code (default: the stage's start)")
    bake.add_argument("--end", type=float, default=None, help="last time code (default: the stage's end)")
    bake.add_argument("--step", type=float, default=1.0, help="time code step (default 1)")
    bake.set_defaults(handler=_bake)

    show = commands.add_parser("preview", help="render a stage frame or an OBJ to PNG",
                               description="Render SOURCE (a warpface stage at --time, or an OBJ) to a PNG with pyrender (offscreen).")
    show.add_argument("source", help="stage (.usda/.usdc) or mesh (.obj)")
    show.add_argument("--time", type=float, default=None, help="time code (default: the stage's start)")
    show.add_argument("--out", default=None, help="PNG path (default: <source>_preview.png)")
    show.add_argument("--heat", action="store_true", help="colour by displacement magnitude from rest")
    show.add_argument("--yaw", type=float, default=15.0, help="camera yaw [degrees]")
    show.add_argument("--pitch", type=float, default=5.0, help="camera pitch [degrees]")
    show.add_argument("--width", type=int, default=640)
    show.add_argument("--height", type=int, default=720)
    show.set_defaults(handler=_preview)

    check = commands.add_parser("validate", help="check a stage with UsdValidation and warpface's rig checks",
                                description="Run pxr.UsdValidation and warpface's rig checks on STAGE; exit 1 on errors.")
    check.add_argument("stage", help="stage to check")
    check.add_argument("--strict", action="store_true", help="exit 1 on warnings too")
    check.set_defaults(handler=_validate)

    track = commands.add_parser("track", help="landmark source -> dense face motion -> USD time samples",
                                description="Track SOURCE (.npz recording, RGB-D folder, 'synthetic', 'realsense' or 'orbbec') "
                                            "and write landmarks and the dense face as time samples.")
    track.add_argument("source", help=".npz, RGB-D folder, synthetic, realsense or orbbec")
    track.add_argument("--stage", required=True, help="output stage (.usda, folder created if missing); landmarks and dense points go to value clips "
                       "in <stage>_track/, flushed every 30 frames or 1 s (a hard kill loses at most that; Ctrl-C nothing)")
    track.add_argument("--frames", type=int, default=None, help="stop after this many frames")
    track.add_argument("--expression", default="smile", help="synthetic source: expression to perform (default smile)")
    track.add_argument("--fem", action="store_true",
                       help="let the tissue FEM move the skin the landmarks do not reach (SPEC §3 step 4)")
    track.add_argument("--fem-dt", type=float, default=1e-3, help="FEM time step [s] (default 1e-3)")
    track.add_argument("--fem-nodes", type=int, default=3000, help="approximate tissue node count (default 3000)")
    track.add_argument("--layout", default=None, help="live cameras: JSON with the painted dots' names and initial pixels")
    track.set_defaults(handler=_track)

    from .cli_animate import add_parser as add_animate_parser

    add_animate_parser(commands)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``warpface`` console script."""
    os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    args = build_parser().parse_args(argv)
    import warp as wp

    wp.config.quiet = True
    wp.config.log_level = wp.LOG_WARNING  # no per-module load timings on the console
    try:
        return int(args.handler(args) or 0)
    except KeyboardInterrupt:
        print("interrupted; files written so far are intact", file=sys.stderr)
        return 130
    except (ValueError, OSError) as error:
        print(f"warpface {args.command}: error: {error}", file=sys.stderr)
        return 2
    except RuntimeError as error:
        from .tracking.cameras import CameraError

        if not isinstance(error, CameraError):
            raise
        print(f"warpface {args.command}: camera error: {error} (frames received so far are kept)", file=sys.stderr)
        return 3


if __name__ == "__main__":
    sys.exit(main())
