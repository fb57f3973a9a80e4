"""``warpface preview``: render a stage frame (or all of them) or an OBJ to PNG/MP4.

Render SOURCE — a warpface rig stage, a capture written by `warpface track`, or an OBJ — at --time to a PNG,
or every frame to an MP4 (--video), with pyrender (offscreen). A rig with 68 landmarks is framed on its face,
upright in the face's own frame, with optional --landmarks and --muscles overlays; --bust frames the whole mesh
in its own axes, as an OBJ always is.
"""

from __future__ import annotations

from pathlib import Path

from .common import add_command, finite_float, pixel_count

__all__ = ["add_parser", "run"]


def add_parser(subparsers, common) -> None:
    show = add_command(subparsers, common, "preview", run, __doc__)
    show.add_argument("source", help="stage (.usda/.usdc/.usd) or mesh (.obj)")
    show.add_argument(
        "--time",
        type=finite_float,
        default=None,
        help="time code, within the stage's time range (default: its first frame)",
    )
    show.add_argument("--out", default=None, help="PNG path (default: <source>_preview.png)")
    show.add_argument("--video", default=None, metavar="MP4", help="also render every frame of the stage into this MP4")
    show.add_argument("--heat", action="store_true", help="colour by displacement magnitude from rest [mm]")
    show.add_argument("--landmarks", action="store_true", help="draw the rig's 68 landmarks, numbered")
    show.add_argument("--muscles", action="store_true", help="draw the rig's muscles (lines, sphincter ellipses)")
    show.add_argument(
        "--bust", action="store_true", help="frame the whole mesh in its own axes (default for a rig: the face)"
    )
    show.add_argument("--yaw", type=finite_float, default=15.0, help="camera yaw [degrees] (default 15)")
    show.add_argument("--pitch", type=finite_float, default=5.0, help="camera pitch [degrees] (default 5)")
    show.add_argument("--width", type=pixel_count, default=640, help="image width [pixels] (default 640)")
    show.add_argument("--height", type=pixel_count, default=720, help="image height [pixels] (default 720)")


def run(args) -> int:
    import numpy as np

    from .. import preview
    from .face_view import FaceView, draw_landmarks, draw_muscles, rig_of_stage

    source = Path(args.source)
    out = Path(args.out) if args.out else source.with_name(f"{source.stem}_preview.png")
    _check_output(out, (".png",), "--out")
    video = None if args.video is None else _check_output(Path(args.video), (".mp4",), "--video")
    if not source.is_file():
        raise ValueError(f"{source}: file not found")
    preview.check_offscreen_rendering()
    if source.suffix.lower() == ".obj":
        from ..mesh import FaceMesh

        if args.heat or args.video or args.time is not None:
            raise ValueError(f"{source}: an OBJ has no animation; --time, --heat and --video need a stage")
        mesh = FaceMesh.from_obj(source)
        frames, points, unit_mm, rig = None, mesh.points, 1.0, None
        triangles, rest = mesh.triangles, mesh.points
    else:
        from pxr import UsdGeom

        from ..usd.frames import open_frames

        frames = open_frames(source)
        time = None if args.time is None else frames.check_time(args.time)
        points, triangles, rest = frames.points_at(time), frames.triangles, frames.rest
        unit_mm = UsdGeom.GetStageMetersPerUnit(frames.stage) * 1e3
        rig = None if args.bust else rig_of_stage(frames.stage, UsdGeom.GetStageMetersPerUnit(frames.stage))
    if (args.landmarks or args.muscles) and rig is None:
        raise ValueError(f"{source}: --landmarks and --muscles need a rig stage with 68 landmarks (and no --bust)")
    size = (args.width, args.height)
    view = None
    if rig is not None and len(rest) == rig.mesh.vertex_count:  # the face's frame and a portrait camera
        view = FaceView.of(rig)
        camera = view.camera(rest[rig.landmarks], yaw_deg=args.yaw, pitch_deg=args.pitch)
        points, rest = view(points), view(rest)
    else:
        camera = preview.Camera.framing(rest, yaw_deg=args.yaw, pitch_deg=args.pitch, aspect=args.width / args.height)
    if args.heat:
        magnitude = np.linalg.norm(points - rest, axis=1) * unit_mm
        preview.render_heat_map(
            points, triangles, magnitude, out, camera=camera, size=size, title="|displacement| from rest", units="mm"
        )
    elif view is None:
        preview.render(points, triangles, out, camera=camera, size=size)
    else:
        image = preview.render(points, triangles, camera=camera, size=size)
        if args.muscles:
            image = draw_muscles(image, camera, rig.muscles, view)
        if args.landmarks:
            image = draw_landmarks(image, camera, points[rig.landmarks])
        preview.save_image(out, image)
    print(f"wrote {out}")
    if video is not None:
        if not len(frames.times):
            raise ValueError(f"{source}: the stage is not animated; nothing to put in --video")
        fps = frames.stage.GetTimeCodesPerSecond()
        preview.write_video(
            frames if view is None else (view(p) for p in frames),
            triangles,
            video,
            fps=fps,
            size=size,
            camera=camera,
            progress=not args.quiet,
            total=len(frames.times),
            label=lambda index: f"time {frames.times[index]:g}",
        )
        print(f"wrote {video}")
    return 0


def _check_output(path: Path, suffixes: tuple[str, ...], option: str) -> Path:
    if path.suffix.lower() not in suffixes:
        raise ValueError(f"{option} {path}: must end in {' or '.join(suffixes)}")
    if not path.parent.is_dir():
        raise ValueError(f"{option} {path}: folder {path.parent} does not exist")
    if path.is_dir():
        raise ValueError(f"{option} {path}: is a folder")
    return path
