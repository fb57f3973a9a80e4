"""``warpface animate DRIVER``: driver curves (ARKit, MediaPipe, Audio2Face, OpenFace AUs) -> rig time samples, bake,
video.

The driver file's format comes from its extension and content (:func:`warpface.usd.read_driver`).
Its channels are cleaned (neutral, gains, clamping, optional 1€ filter), resampled to the stage's
rate, mapped onto the rig's controls (SPEC §6.4: the mapping stored on the rig stage, or the default
table), written as time samples on a new rig stage, baked into a points cache beside it, and
previewed as a video labelled with the active channels.

Every input problem is found before anything is written; files are written through temporary
files and renames, so an error or Ctrl-C leaves no half-written output.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._validate import as_count, expect_instance
from .common import add_command

__all__ = ["add_parser", "run_animate", "animate", "AnimateResult", "prepare_controls", "PREVIEW_MAX_FRAMES"]

PREVIEW_MAX_FRAMES = 120
"""Default length of the preview video in frames. Offscreen rendering without a GPU costs about 0.1 s of
CPU a frame, so a longer take is previewed at every k-th frame: any take's preview then costs about ten
seconds of CPU, not the better part of an hour for ten minutes (``--video-max-frames`` asks for more)."""


@dataclass
class AnimateResult:
    """What :func:`animate` wrote and found."""

    stage: Path
    cache: Path | None
    video: Path | None
    fps: float
    frame_count: int
    mapping: str
    """``"default table"`` or the stored mapping's name."""
    unmapped_channels: list[str]
    notes: list[str] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    """Wall time of each step: ``read driver and rig``, ``clean and map``, ``write controls``, ``model``, ``bake``,
    ``save stage``, ``video``."""


def _mapping(rig, rig_stage, map_spec):
    """(mapping in the rig's units, label, channels it cannot drive on this rig).

    ``map_spec``: None (the rig stage's ``default`` mapping, else the default table), ``NAME`` (stored on
    the rig stage), or ``FILE.usda[:NAME]`` (stored on another rig stage; NAME defaults to ``default``).
    """
    from ..drivers import mapping_for_rig
    from ..drivers.default_tables import rig_control_names
    from ..usd import open_stage
    from ..usd.mapping_io import mapping_names, read_mapping
    from .rig_models import RIG_SUFFIXES

    if map_spec is None and (rig_stage is None or "default" not in mapping_names(rig_stage)):
        mapping, _, orphaned = mapping_for_rig(rig)
        return mapping, "default table", orphaned
    name, source = map_spec or "default", rig_stage
    file, colon, stored_name = (map_spec or "").rpartition(":")
    if colon and Path(file).suffix.lower() in RIG_SUFFIXES:
        source, name = open_stage(file), stored_name or "default"
    elif map_spec and Path(map_spec).suffix.lower() in RIG_SUFFIXES:
        source, name = open_stage(map_spec), "default"
    if source is None:
        raise ValueError(f"--map {map_spec}: the built-in rig has no stored mappings; pass --rig or FILE.usda[:NAME]")
    mapping = read_mapping(source, name)
    missing = [c for c in mapping.controls if c not in set(rig_control_names(rig))]
    if missing:
        raise ValueError(f"mapping {name!r} drives control {missing[0]!r}, which rig {rig.name!r} does not have")
    return mapping, f"stored mapping {name!r}", []


def prepare_controls(curves, mapping, *, fps: float, neutral=None, gain=None, one_euro=None):
    """Clean ``curves``, resample them to ``fps`` and map them: (cleaned curves, MappedControls)."""
    from ..drivers.cleanup import clean

    cleaned = clean(curves, neutral=neutral, gain=gain, clamp=True, filter=one_euro, fps=fps)
    return cleaned, mapping.apply(cleaned)


def animate(
    driver,
    out,
    *,
    rig=None,
    map_spec=None,
    fps=None,
    neutral=None,
    gain=None,
    one_euro=None,
    video: bool = True,
    video_size=(360, 420),
    video_max_frames: int = PREVIEW_MAX_FRAMES,
    device=None,
    progress: bool = True,
    rigs=None,
) -> AnimateResult:
    """Drive a rig with a driver file and write ``out`` (the rig + control time samples), its baked cache
    ``<out stem>_anim.usdc`` and, with ``video``, ``<out stem>.mp4``.

    Args:
        driver: driver file (any format of :data:`warpface.drivers.DRIVER_FORMATS`).
        out: output stage (``.usda``/``.usdc``).
        rig: rig stage; default: the built-in face's rig.
        map_spec: stored mapping name on the rig stage, or ``FILE.usda[:NAME]``; default: the rig stage's
            ``default`` mapping when it has one, else the default table (which is then stored on ``out``).
        fps: output rate; default: the rig stage's ``timeCodesPerSecond``, else the driver's rate
            (rounded), else 30.
        neutral, gain, one_euro: clean-up (see :func:`warpface.drivers.clean`).
        video: render a preview video labelled with the active channels (at most ``video_max_frames``
            frames: a longer take is shown at every k-th frame).
        rigs: a :class:`~warpface.commands.rig_models.RigModels` to take the rig and its expression model from
            (and keep them in) across calls; default: read and built for this call only. The output is the same
            bits either way.

    Raises:
        ValueError: bad driver, rig, mapping or output path (nothing is written then).
    """
    from pxr import Sdf, Usd

    from .. import usd
    from .._files import create_missing_folders, remove_created_folders
    from ..drivers.mouth_close import close_mouth
    from ..usd.animation import CACHE_SUFFIX
    from ..usd.asset_io import asset_link, attach_asset
    from ..usd.jaw_io import JAW_CONTROL_ATTRIBUTES
    from ..usd.mapping_io import write_mapping
    from .rig_models import RigModels

    out = _output_path(out)
    if video:
        as_count(video_max_frames, "--video-max-frames", minimum=1)
    rigs = RigModels() if rigs is None else expect_instance(rigs, RigModels, "rigs")
    clock = _StepClock()
    curves = usd.read_driver(driver)
    rig_model, rig_stage, units, stage_rate = rigs.load(rig)
    mapping, label, orphaned = _mapping(rig_model, rig_stage, map_spec)
    clock.step("read driver and rig")
    rate = float(fps or stage_rate or (round(curves.fps) if curves.fps else 30.0))
    if not math.isfinite(rate) or rate <= 0:
        raise ValueError(f"--fps must be a positive number, got {rate}")
    cleaned, mapped = prepare_controls(curves, mapping, fps=rate, neutral=neutral, gain=gain, one_euro=one_euro)
    mapped = close_mouth(rig_model, cleaned, mapped)  # mouthClose over jawOpen: docs/RIG.md §12
    unmapped = list(dict.fromkeys(mapped.unmapped_channels + [c for c in orphaned if c in curves.names]))
    if all(name in unmapped for name in curves.names):
        raise ValueError(
            f"{curves.source}: none of its channels ({', '.join(curves.names[:5])}"
            f"{', …' if len(curves.names) > 5 else ''}) drives a control of rig {rig_model.name!r}"
        )
    notes = list(cleaned.notes)
    clock.step("clean and map")

    stage = Usd.Stage.CreateInMemory("animate" + out.suffix)
    usd.write_rig(stage, rig_model, meters_per_unit=units, fps=rate)
    link = None if rig_stage is None else asset_link(rig_stage, usd.rig_prims(rig_stage).skin)
    if link is not None:  # keep referencing the user's asset (absolute while in memory)
        attach_asset(stage.GetRootLayer(), usd.rig_prims(stage).skin.GetPath(), link)
    write_mapping(stage, mapping, name=mapping.name if label != "default table" else "default")
    time_codes = np.round((mapped.times - mapped.times[0]) * rate, 6)
    muscles = set(rig_model.muscle_names)
    contractions = {name: mapped.values[:, k] for k, name in enumerate(mapped.names) if name in muscles}
    jaw = {name: mapped.values[:, k] for k, name in enumerate(mapped.names) if name in JAW_CONTROL_ATTRIBUTES}
    usd.write_animation(
        stage,
        time_codes,
        contractions=contractions,
        jaw=jaw if rig_model.jaw is not None and jaw else None,
        fps=rate,
        meters_per_unit=units,
    )
    clock.step("write controls")
    root = stage.GetRootLayer()
    cache_path = out.with_name(out.stem + CACHE_SUFFIX)
    model = rigs.model(rig_model, device=device)
    clock.step("model")
    created = create_missing_folders(out.parent)  # as `track` does; removed again if the bake writes nothing
    try:
        cache = usd.bake(stage, time_codes, cache_path=cache_path, model=model, device=device, progress=progress)
    except BaseException:
        remove_created_folders(created)
        raise
    clock.step("bake")
    saved = Sdf.Layer.CreateAnonymous(out.suffix)  # a copy: re-pathing the stage's own layer would recompose it
    saved.TransferContent(root)
    saved.subLayerPaths[0] = "./" + cache.name  # bake gave the in-memory stage an absolute path
    if link is not None:
        attach_asset(saved, usd.rig_prims(stage).skin.GetPath(), link, anchor=out.parent)
    usd.export_layer_atomically(saved, out)
    clock.step("save stage")
    video_path = None
    if video:
        video_path = _preview(
            out.with_suffix(".mp4"), model, rig_model, mapped, rate, video_size, progress, video_max_frames
        )
        clock.step("video")
    return AnimateResult(
        stage=out,
        cache=cache,
        video=video_path,
        fps=rate,
        frame_count=len(time_codes),
        mapping=label,
        unmapped_channels=unmapped,
        notes=notes,
        seconds=clock.seconds,
    )


class _StepClock:
    """Wall seconds between successive :meth:`step` calls, by step name."""

    def __init__(self):
        self.seconds: dict[str, float] = {}
        self._last = time.perf_counter()

    def step(self, name: str) -> None:
        now = time.perf_counter()
        self.seconds[name] = now - self._last
        self._last = now


def _output_path(path) -> Path:
    """The output stage path, checked before any work: a USD layer extension in a writable folder (or one that
    can be made)."""
    from .._files import check_output_folder

    out = Path(path).absolute()
    if out.suffix not in (".usda", ".usdc", ".usd"):
        raise ValueError(f"--out {path}: must end in .usda, .usdc or .usd")
    check_output_folder(out.parent, "--out", path)  # a missing folder is created once the inputs are good
    if out.is_dir():
        raise ValueError(f"--out {path}: cannot write there")
    return out


def _preview(path: Path, model, rig, mapped, rate: float, size, progress: bool, max_frames: int) -> Path:
    """An MP4 of the animation, each frame labelled with its time and strongest active channels.

    A take longer than ``max_frames`` is shown whole at every k-th frame (played at ``rate / k``; see
    :data:`PREVIEW_MAX_FRAMES`).
    """
    import cv2

    from .. import preview
    from .._files import atomic_path

    muscles = list(rig.control_names)  # the muscles, then a jaw's controls
    index = {name: k for k, name in enumerate(mapped.names)}
    step = max(1, math.ceil(len(mapped.times) / max(1, int(max_frames))))
    shown = np.arange(0, len(mapped.times), step)
    contractions = np.zeros((len(shown), len(muscles)))
    for column, name in enumerate(muscles):
        if name in index:
            contractions[:, column] = mapped.values[shown, index[name]]
    from .face_view import face_view_of

    view = face_view_of(rig)  # upright and frontal whatever the rig's axes (None without 68 landmarks)
    landmarks = rig.landmarks if rig.landmarks is not None else np.arange(rig.mesh.vertex_count)
    marks = rig.mesh.points[landmarks]
    camera = preview.Camera.for_face(marks if view is None else view(marks), yaw_deg=20.0, pitch_deg=5.0)
    from tqdm import tqdm

    with atomic_path(path, path.suffix) as temporary:
        writer = cv2.VideoWriter(str(temporary), cv2.VideoWriter_fourcc(*"mp4v"), float(rate) / step, tuple(size))
        if not writer.isOpened():
            raise ValueError(f"cannot open a video writer for {path}")
        try:
            with preview.PreviewRenderer(
                rig.mesh.triangles, size=size, camera=camera, background=(0.12, 0.12, 0.14)
            ) as renderer:
                with tqdm(
                    total=len(contractions), desc=f"video {path.name}", unit="frame", disable=not progress, leave=False
                ) as bar:
                    for start in range(0, len(contractions), 64):
                        frames = model.evaluate(contractions[start : start + 64])
                        for offset, points in enumerate(frames):
                            frame = int(shown[start + offset])
                            image = np.ascontiguousarray(renderer.render(points if view is None else view(points)))
                            text = f"{mapped.times[frame] - mapped.times[0]:6.2f} s  " + " ".join(
                                mapped.active_channels[frame][:3]
                            )
                            cv2.putText(
                                image, text, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (235, 235, 235), 1, cv2.LINE_AA
                            )
                            writer.write(cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
                        bar.update(len(frames))
        finally:
            writer.release()
    return path


def _neutral(text: str | None):
    if text is None:
        return None
    if ":" in text:
        start, _, end = text.partition(":")
        try:
            return (float(start), float(end))
        except ValueError:
            raise ValueError(f"--neutral {text!r}: expected FRAME or START:END seconds") from None
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"--neutral {text!r}: expected FRAME or START:END seconds") from None


def _gains(items) -> dict[str, float] | None:
    if not items:
        return None
    from ..drivers.channels import canonical_channel

    gains = {}
    for item in items:
        name, _, value = item.partition("=")
        try:
            gains[canonical_channel(name)] = float(value)
        except ValueError:
            raise ValueError(f"--gain {item!r}: expected CHANNEL=NUMBER") from None
    return gains


def run_animate(args, *, rigs=None) -> int:
    """The ``animate`` command's handler: one summary line per output; notes and unmapped channels once.

    ``rigs``: see :func:`animate` (the batch's workers keep one between takes)."""
    from ..drivers.cleanup import OneEuroFilter

    one_euro = OneEuroFilter(min_cutoff=args.filter_min_cutoff, beta=args.filter_beta) if args.filter else None
    try:
        result = animate(
            args.driver,
            args.out,
            rig=args.rig,
            map_spec=args.map,
            fps=args.fps,
            neutral=_neutral(args.neutral),
            gain=_gains(args.gain),
            one_euro=one_euro,
            video=not args.no_video,
            device=args.device,
            video_max_frames=args.video_max_frames,
            progress=not args.quiet,
            rigs=rigs,
        )
    except ValueError as error:  # messages relayed from pxr can span lines: the CLI prints one
        raise ValueError(" ".join(str(error).split())) from None
    for note in result.notes:
        print(f"note: {note}")
    if result.unmapped_channels:
        print(
            f"note: ignored {len(result.unmapped_channels)} channels the rig cannot drive: "
            f"{', '.join(result.unmapped_channels)}"
        )
    print(f"animated {result.frame_count} frames at {result.fps:g} frames/s with the {result.mapping}")
    print(f"  stage {result.stage}")
    print(f"  cache {result.cache}")
    if result.video:
        print(f"  video {result.video}")
    return 0


def add_parser(subparsers, common):
    """Register ``animate`` on the CLI's sub-parsers (``common``: the shared options); returns the parser."""
    parser = add_command(subparsers, common, "animate", run_animate, __doc__)
    parser.add_argument("driver", help="OpenFace/Live Link Face CSV, MediaPipe .pbtxt/.jsonl, or USD SkelAnimation")
    parser.add_argument("--rig", default=None, help="rig stage (default: the built-in face's rig)")
    parser.add_argument(
        "--out", required=True, help="output stage (.usda/.usdc); cache <out>_anim.usdc, video <out>.mp4"
    )
    parser.add_argument(
        "--map",
        default=None,
        help="mapping stored on the rig stage (NAME) or FILE.usda[:NAME] "
        "(default: the rig's 'default' mapping, else the default table)",
    )
    parser.add_argument(
        "--fps", type=float, default=None, help="output frame rate (default: the rig stage's, else the driver's)"
    )
    parser.add_argument("--neutral", default=None, help="neutral FRAME index or START:END segment in seconds")
    parser.add_argument(
        "--gain", action="append", default=None, metavar="CHANNEL=GAIN", help="per-channel gain (repeatable)"
    )
    parser.add_argument("--filter", action="store_true", help="smooth the channels with a 1€ filter")
    parser.add_argument(
        "--filter-min-cutoff", type=float, default=1.5, help="1€ filter cut-off at rest [Hz] (default 1.5)"
    )
    parser.add_argument("--filter-beta", type=float, default=0.5, help="1€ filter speed coefficient (default 0.5)")
    parser.add_argument("--no-video", action="store_true", help="skip the preview video")
    parser.add_argument(
        "--video-max-frames",
        type=int,
        default=PREVIEW_MAX_FRAMES,
        help=f"longest preview in frames; longer takes show every k-th frame (default {PREVIEW_MAX_FRAMES})",
    )
    return parser
