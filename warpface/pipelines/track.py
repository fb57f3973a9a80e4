"""``warpface track SOURCE --stage out.usda``: a landmark stream → a face (the built-in one, or the rig stage of
``--rig``: a head of one's own rigged by ``warpface rig``) → USD time samples.

The synthetic source films the rig's own face (:func:`warpface.pipelines.capture.synthetic_capture`); a
recording, an RGB-D folder or a live camera's layout names its landmarks after the vertices of the face it
was made for (``v01234``), so it drives a rig with that topology.

Output: ``out.usda`` (a small root layer) and ``out_track/`` beside it (``static.usdc`` with the
topology and rest points, ``chunk_NNNN.usdc`` value clips with the landmarks and the dense points
of each frame); see :mod:`warpface.usd.tracking_io`. The stage's folder is created when needed.

With ``--solve`` the landmarks drive the muscles instead (:mod:`warpface.pipelines.track_solve`):
the stage gains the rig under ``/Capture/Rig`` with the solved contractions, the skin (with wrinkles)
and the residual per frame in the same chunks; ``--residual-transfer`` adds the motion the solve
cannot explain through the geometric transfer.

Nothing is written until the first frame has been tracked: every set-up step (the source, the
adapter, the tissue mesh of ``--fem``) runs first, so a run that fails before its first frame
leaves no files (and removes the folder it created). Once frames flow they are flushed every 30
frames or 1 s; Ctrl-C stops between two frames and keeps every frame received.
"""

from __future__ import annotations

import sys
import threading
from contextlib import contextmanager
from pathlib import Path

import numpy as np

__all__ = ["run_track", "TRACK_FLUSH_SECONDS", "TRACK_CHUNK_FRAMES"]

TRACK_CHUNK_FRAMES = 30
"""Frames per flushed chunk."""
TRACK_FLUSH_SECONDS = 1.0
"""Longest a received frame waits in memory [s]: what a hard kill can lose at most."""
_MARKERLESS_PREFETCH = 4
"""Frames a markerless source detects ahead in a background thread while the solve runs."""


def run_track(args) -> int:
    """Handler of the ``track`` sub-command (arguments from :func:`warpface.cli.build_parser`).

    Returns 0, or 130 when Ctrl-C ended the capture (every frame received is on the stage).
    """
    from .._files import create_missing_folders, remove_created_folders
    from ..usd.tracking_io import TrackingStageWriter
    from .track_mono import is_video

    _check_options(args)
    solve = getattr(args, "solve", False) or is_video(args.source)  # a video drives the rig through the solve
    stage = Path(args.stage).absolute()
    created = create_missing_folders(stage.parent)
    writer = None
    try:
        rig = _load_rig(getattr(args, "rig", None), args.quiet)
        source, camera_to_model, closers = _open_source(rig, args)
        try:
            fps = getattr(source, "fps", None) or 30.0
            if solve:
                stats, writer, tracker = _solved_capture(rig, source, camera_to_model, stage, fps, args)
                drive = None
            else:
                writer = TrackingStageWriter(
                    stage,
                    source.landmark_names,
                    fps,
                    dense_rest=rig.mesh.points,
                    triangles=rig.mesh.triangles,
                    chunk_frames=TRACK_CHUNK_FRAMES,
                    flush_seconds=TRACK_FLUSH_SECONDS,
                )
                stats, drive = _capture(rig, source, camera_to_model, writer, fps, args)
        finally:
            for close in closers:
                close()
    finally:
        if writer is None or writer.frames_written == 0:
            remove_created_folders(created)
    if stats.interrupted:
        print(f"interrupted: kept all {stats.frames} frames received in {stage}")
    else:
        print(
            f"tracked {stats.frames} frames at {stats.frames_per_second:.0f} frames/s, "
            f"{100 * stats.landmarks_found:.0f}% of {len(source.landmark_names)} landmarks found per frame"
        )
    if drive is not None:
        print(
            f"  tissue FEM: {drive.simulation.tetmesh.node_count} nodes, "
            f"{len(drive.driven_nodes)} driven, {len(drive.fixed_nodes)} fixed, {drive.substeps} steps per frame"
        )
    if solve:
        solved = tracker.summary
        print(
            f"  solved {solved['frames']} frames: mean landmark residual {1e3 * solved['mean_residual']:.2f} mm, "
            f"{solved['skipped']} skipped (too few landmarks), {solved['not_converged']} not converged"
        )
        print(
            f"  stage {stage}  ({fps:g} time codes per second; rig at /Capture/Rig: contractions, skin and "
            f"residual per frame in {writer.folder.name}/)"
        )
    else:
        print(f"  stage {stage}  ({fps:g} time codes per second; landmarks and dense points in {writer.folder.name}/)")
    return 130 if stats.interrupted else 0


def _check_options(args) -> None:
    """Refuse bad numeric options before anything is loaded or written."""
    import math

    from .track_mono import is_video

    if args.frames is not None and args.frames < 1:
        raise ValueError(f"--frames must be ≥ 1, got {args.frames}")
    if Path(args.stage).suffix not in (".usda", ".usdc"):
        raise ValueError(f"--stage {args.stage}: output must end in one of .usda, .usdc")
    rig = getattr(args, "rig", None)
    if rig is not None and Path(rig).suffix.lower() not in (".usda", ".usdc", ".usd"):
        raise ValueError(f"--rig {rig}: expected a rig stage (.usda, .usdc, .usd), e.g. one made by `warpface rig`")
    if rig is not None and not Path(rig).is_file():
        raise ValueError(f"--rig {rig}: file not found")
    markerless = getattr(args, "markerless", False)
    if is_video(args.source):
        if not Path(args.source).is_file():
            raise ValueError(f"video {args.source}: file not found")
        if args.fem:
            raise ValueError("--fem and a video do not combine (the video's skin comes from the solved muscles)")
    elif args.source in ("realsense", "orbbec"):
        if getattr(args, "layout", None) is None and not markerless:
            raise ValueError(
                f"a live {args.source} capture needs --layout (a JSON file with the dots' 'names' and "
                "'initial_pixels') or --markerless"
            )
    elif (
        args.source != "synthetic"
        and not (Path(args.source).suffix == ".npz" and Path(args.source).is_file())
        and not Path(args.source).is_dir()
    ):
        raise ValueError(
            f"unknown source {args.source!r}: expected an existing .npz recording or RGB-D folder, a video file, "
            "synthetic, realsense or orbbec"
        )
    if markerless and (args.source == "synthetic" or Path(args.source).suffix == ".npz"):
        raise ValueError(f"--markerless needs images: an RGB-D folder, realsense, orbbec or a video, not {args.source}")
    if getattr(args, "dense", False) and not (markerless or is_video(args.source)):
        raise ValueError("--dense needs --markerless or a video")
    if getattr(args, "face", 0) < 0:
        raise ValueError(f"--face must be ≥ 0, got {args.face}")
    if getattr(args, "intrinsics", None) is not None and not is_video(args.source):
        raise ValueError("--intrinsics is for a video (an RGB-D source brings its own)")
    if getattr(args, "solve", False):
        if args.fem:
            raise ValueError("--fem and --solve do not combine (the solved skin comes from the muscles)")
        if not (math.isfinite(args.smoothness) and args.smoothness >= 0.0):
            raise ValueError(f"--smoothness must be a finite number ≥ 0, got {args.smoothness}")
    elif getattr(args, "residual_transfer", False):
        raise ValueError("--residual-transfer needs --solve")
    if args.fem:
        if not (math.isfinite(args.fem_dt) and 1e-8 <= args.fem_dt <= 0.1):
            raise ValueError(f"--fem-dt must be in [1e-8, 0.1] s, got {args.fem_dt}")
        if not 100 <= args.fem_nodes <= 200_000:
            raise ValueError(f"--fem-nodes must be in [100, 200000], got {args.fem_nodes}")


def _load_rig(path, quiet: bool):
    """The rig to drive, in metres: a rig stage (``--rig``, e.g. made by ``warpface rig``) or the built-in face."""
    if path is None:
        with _setup_step("loading the built-in face", quiet):
            from ..assets import default_rig

            return default_rig()
    from ..usd import read_rig

    with _setup_step(f"reading the rig {Path(path).name}", quiet):
        return read_rig(path, meters_per_unit=1.0)


def _open_source(rig, args):
    """The landmark source, its camera → model transform (or None) and what closes it."""
    from .capture import open_source, synthetic_capture
    from .track_mono import is_video

    if args.source == "synthetic":
        with _setup_step("preparing the synthetic camera", args.quiet):
            capture = synthetic_capture(rig, expression=args.expression, device=args.device)
        return capture.source, capture.camera_to_rig, [capture.camera.close]
    if getattr(args, "markerless", False) or is_video(args.source):
        from .track_mono import markerless_source, parse_intrinsics

        source = markerless_source(
            args.source,
            rig,
            intrinsics=parse_intrinsics(getattr(args, "intrinsics", None)),
            face=getattr(args, "face", 0),
            landmark_model=getattr(args, "landmark_model", None),
            dense=getattr(args, "dense", False),
            device=args.device,
        )
    else:
        source = open_source(args.source, layout=getattr(args, "layout", None), device=args.device)
    return source, None, [getattr(source, "close", lambda: None)]


def _capture(rig, source, camera_to_model, writer, fps: float, args):
    from ..tracking import adapter_for_face
    from .capture import TurnedAdapter, record, upright_turn

    turn = upright_turn(rig)
    if np.array_equal(turn, np.eye(3)):
        adapter = adapter_for_face(
            rig.mesh.points, source.landmark_names, camera_to_model=camera_to_model, device=args.device
        )
    else:  # a Z-up or sideways rig: the adapter triangulates its landmarks in the front view
        adapter = TurnedAdapter(
            rig.mesh.points, source.landmark_names, turn, camera_to_rig=camera_to_model, device=args.device
        )
    drive = _tissue_drive(rig, adapter, fps, args) if args.fem else None
    stats = record(source, adapter, writer, max_frames=args.frames, progress=not args.quiet, on_frame=drive)
    return stats, drive


def _solved_capture(rig, source, camera_to_model, stage: Path, fps: float, args):
    """Landmarks → solved controls → skin, into a solved capture stage (nothing lost on Ctrl-C)."""
    from .capture import record
    from .track_solve import SolvingTracker, solved_stage_writer

    with _setup_step("preparing the solver", args.quiet):
        markerless = getattr(args, "markerless", False) or hasattr(source, "video")
        neutral = markerless and not getattr(args, "no_neutral", False)  # docs/CAPTURE.md §1
        options = dict(smoothness=args.smoothness, neutral_offsets=neutral, device=args.device)
        if hasattr(source, "intrinsics") and hasattr(source, "video"):  # rays: the monocular solve
            from .track_mono import MonocularTracker

            tracker = MonocularTracker(rig, source.landmark_names, rounds=getattr(args, "ray_rounds", 1), **options)
        else:
            tracker = SolvingTracker(
                rig,
                source.landmark_names,
                camera_to_model=camera_to_model,
                residual_transfer=args.residual_transfer,
                **options,
            )
        writer, layout = solved_stage_writer(
            stage, tracker, fps, chunk_frames=TRACK_CHUNK_FRAMES, flush_seconds=TRACK_FLUSH_SECONDS
        )
    stats = record(
        source,
        tracker,
        writer,
        max_frames=args.frames,
        progress=not args.quiet,
        samples=lambda frame, skin: layout.samples(tracker.last, skin),
        prefetch=_MARKERLESS_PREFETCH if markerless else 0,  # the face mesh runs on the second core
    )
    return stats, writer, tracker


def _tissue_drive(rig, adapter, fps: float, args):
    """Tissue under the built-in face (Kato's uniform material) driven by the tracked skin."""
    from ..fem import kato_uniform_material
    from ..fem.volume import tissue_from_surface
    from .tissue_drive import TissueDrive

    thickness = max(float(np.median(rig.thickness)), 0.004)
    with _setup_step(f"meshing the tissue (fTetWild, ~{args.fem_nodes} nodes; tens of seconds)", args.quiet):
        tetmesh = tissue_from_surface(rig.mesh, thickness, target_nodes=args.fem_nodes, device=args.device)
    material = kato_uniform_material()
    with _setup_step("setting up the tissue FEM", args.quiet):
        return TissueDrive(adapter, tetmesh, material, fps=fps, dt=args.fem_dt, thickness=thickness, device=args.device)


@contextmanager
def _setup_step(label: str, quiet: bool):
    """A one-line progress display with the elapsed time, ticking while a long set-up step runs."""
    if quiet or not getattr(sys.stderr, "isatty", lambda: False)():  # a log file gets no ticking lines
        yield
        return
    from tqdm import tqdm

    bar = tqdm(desc=label, total=None, bar_format="{desc}: {elapsed}", leave=True)
    done = threading.Event()

    def tick():
        while not done.wait(0.5):
            bar.refresh()

    ticker = threading.Thread(target=tick, daemon=True)
    ticker.start()
    try:
        yield
    finally:
        done.set()
        ticker.join()
        bar.close()
