"""``warpface track``: landmark source -> dense face motion -> USD time samples.

Track SOURCE (.npz recording, RGB-D folder, 'synthetic', 'realsense' or 'orbbec') and write landmarks and the
dense motion of the built-in face or of --rig (or, with --solve, solved muscle controls) as time samples.

The work is done by :func:`warpface.pipelines.track.run_track`.
"""

from __future__ import annotations

from .common import add_command, non_negative_float, positive_float, positive_int

__all__ = ["add_parser", "run"]


def add_parser(subparsers, common) -> None:
    track = add_command(subparsers, common, "track", run, __doc__)
    track.add_argument("source", help=".npz, RGB-D folder, synthetic, realsense or orbbec")
    track.add_argument(
        "--stage",
        required=True,
        help="output stage (.usda, folder created if missing); landmarks and dense points go to value clips "
        "in <stage>_track/, flushed every 30 frames or 1 s (a hard kill loses at most that; Ctrl-C nothing)",
    )
    track.add_argument(
        "--rig",
        default=None,
        help="rig stage to drive, e.g. made by `warpface rig` (default: the built-in face); the synthetic camera "
        "films it",
    )
    track.add_argument("--frames", type=positive_int, default=None, help="stop after this many frames")
    track.add_argument("--expression", default="smile", help="synthetic source: expression to perform (default smile)")
    track.add_argument(
        "--fem",
        action="store_true",
        help="let the tissue FEM move the skin the landmarks do not reach (SPEC §3 step 4)",
    )
    track.add_argument("--fem-dt", type=positive_float, default=1e-3, help="FEM time step [s] (default 1e-3)")
    track.add_argument(
        "--fem-nodes", type=positive_int, default=3000, help="approximate tissue node count (default 3000)"
    )
    track.add_argument(
        "--layout", default=None, help="live cameras: JSON with the painted dots' names and initial pixels"
    )
    track.add_argument(
        "--solve",
        action="store_true",
        help="solve the rig's muscle controls from the landmarks (with head pose) and write them as time samples "
        "on /Capture/Rig's muscles, the skin with wrinkles as the baked cache and the per-frame residual",
    )
    track.add_argument(
        "--residual-transfer",
        action="store_true",
        help="with --solve: add the landmark motion the solve cannot explain through the geometric transfer",
    )
    track.add_argument(
        "--smoothness",
        type=non_negative_float,
        default=1e-3,
        help="with --solve: pull of each frame's controls toward the previous frame's (default 1e-3)",
    )


def run(args) -> int:
    from ..pipelines.track import run_track

    return run_track(args)
