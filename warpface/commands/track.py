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
    track.add_argument(
        "source",
        help=".npz, RGB-D folder, a video file (.mp4 …: monocular, always solved), synthetic, realsense or orbbec",
    )
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

    track.add_argument(
        "--markerless",
        action="store_true",
        help="RGB-D folder or live camera: find the face's own landmarks (MediaPipe face mesh → the rig's 68 iBUG "
        "points) instead of painted dots; needs the markerless extra (see README)",
    )
    track.add_argument(
        "--intrinsics",
        default=None,
        help="video: the camera, a .json with fx, fy, cx, cy, width, height or those six numbers comma-separated "
        "(default: f = the frame's longer side, centred)",
    )
    track.add_argument(
        "--face", type=int, default=0, help="markerless: which face when there are several (0 = the largest)"
    )
    track.add_argument(
        "--no-neutral",
        action="store_true",
        help="markerless: do not take the first frame with a face as neutral (by default each landmark's offset "
        "from the rig's own there is subtracted from later frames)",
    )
    track.add_argument(
        "--dense",
        action="store_true",
        help="markerless (video, RGB-D folder): also the face mesh's points the rig's skin has (~260 on the built-in "
        "face), matched on the first frame with a face",
    )
    track.add_argument("--landmark-model", default=None, help="markerless: a face-mesh .tflite file of one's own")
    track.add_argument(
        "--ray-rounds", type=positive_int, default=1, help="video: closest-ray / solve rounds per frame (default 1)"
    )


def run(args) -> int:
    from ..pipelines.track import run_track

    return run_track(args)
