"""A shoot of many takes: ``warpface batch`` (local engine) against a serial loop of ``warpface animate``.

Twenty one-minute Live Link Face takes (30 frames/s, a few channels moving differently in each, written here) are
animated and baked twice in the same run (with ``--video`` also previewed as MP4s):

* ``serial animate``: one ``warpface animate TAKE --out …`` process after another, as a shell loop over the
  takes does (each pays Python's start-up, warpface's imports, Warp's initialisation and kernel loads);
* ``warpface batch``: one ``warpface batch MANIFEST --out …`` process, the local engine's worker processes
  (one per core, or per CUDA device) paying those once each; it also renders each take's contact-sheet picture
  and writes the report and the shoot stage.

The ratio is serial / batch wall time. The start-up a pool amortises is measured on its own (``python -c`` of
warpface's imports and Warp's initialisation, best of two), with the in-process split of one take's ``animate``
(read, model, bake, video), so the table says where the serial loop's time goes. The last frame of the first
take is checked to be identical between the two. Outputs (about 250 MB of cache per take) are deleted as soon
as they are measured. ``--device cuda:0`` also prints takes per minute on that device.

Without a GPU the preview video is drawn by Mesa's llvmpipe, a software rasteriser that already spreads each
frame over every core, so running takes side by side cannot make the videos faster; the default leaves them out
(``--no-video`` on both sides) to measure what the pool changes, ``--video`` puts them in.

    python -m benchmarks.batch [--quick] [--takes 20] [--seconds 60] [--device cpu|cuda:0] [--jobs N] [--video]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ._timing import machine_info, print_table, write_results

ROOT = Path(__file__).resolve().parents[1]
CHANNELS = ("browInnerUp", "mouthSmileLeft", "mouthSmileRight", "jawOpen", "eyeBlinkLeft", "mouthPucker")


def write_takes(folder: Path, takes: int, seconds: float, fps: int = 30, options: str = "") -> Path:
    """``takes`` Live Link Face CSVs of ``seconds`` each and their manifest (each take with the ``animate``
    ``options``); returns the manifest."""
    from warpface.drivers import ARKIT_CHANNELS

    columns = [name[0].upper() + name[1:] for name in ARKIT_CHANNELS]
    frames = int(round(seconds * fps))
    t = np.arange(frames) / fps
    rows = ["id,input,kind,options"]
    for take in range(takes):
        rng = np.random.default_rng(take)
        curves = {
            name: np.clip(0.5 + 0.5 * np.sin(2 * np.pi * rng.uniform(0.1, 0.8) * t + rng.uniform(0, 6)), 0, 1)
            for name in CHANNELS
        }
        lines = ["Timecode,BlendshapeCount," + ",".join(columns)]
        for frame in range(frames):
            whole, sub = divmod(frame, fps)
            minutes, secs = divmod(whole, 60)
            weights = ",".join(f"{curves[n][frame]:.4f}" if n in curves else "0" for n in ARKIT_CHANNELS)
            lines.append(f"10:{minutes:02d}:{secs:02d}:{sub:02d}.000,52,{weights}")
        (folder / f"take{take:02d}.csv").write_text("\n".join(lines) + "\n")
        rows.append(f"take{take:02d},take{take:02d}.csv,animate,{options}")
    manifest = folder / "takes.csv"
    manifest.write_text("\n".join(rows) + "\n")
    return manifest


def _warpface(*arguments: str) -> float:
    """Wall seconds of one ``python -m warpface.cli …`` process (it must succeed)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "warpface.cli", "--quiet", *arguments], env=env, capture_output=True)
    seconds = time.perf_counter() - started
    if done.returncode != 0:
        raise RuntimeError(f"warpface {' '.join(arguments)} failed: {done.stderr.decode()[-2000:]}")
    return seconds


def startup_seconds() -> float:
    """Best of two: a fresh Python importing warpface's CLI and animate, and initialising Warp."""
    code = "import warpface.cli, warpface.commands.animate as a, warpface; warpface.init_runtime(quiet=True)"
    best = float("inf")
    for _ in range(2):
        started = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT, capture_output=True)
        best = min(best, time.perf_counter() - started)
    return best


def animate_split(driver: Path, folder: Path, device: str, video: bool) -> dict[str, float]:
    """Seconds of each step of one take's ``animate``, in this process (kernels already loaded)."""
    from warpface.commands.animate import animate

    animate(driver, folder / "warm.usda", device=device, progress=False, video=False)  # loads the kernels
    result = animate(driver, folder / "split.usda", device=device, progress=False, video=video)
    return dict(result.seconds)


def last_frame(stage_path: Path) -> np.ndarray:
    from pxr import Usd

    from warpface import usd

    stage = Usd.Stage.Open(str(stage_path))
    points = usd.rig_prims(stage).skin.GetAttribute("points")
    return np.asarray(points.Get(points.GetTimeSamples()[-1]))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--takes", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=60.0, help="length of each take [s] (default 60)")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--jobs", type=int, default=None, help="batch workers (default: cores, or CUDA devices)")
    parser.add_argument("--quick", action="store_true", help="4 takes of 10 s (a smoke run)")
    parser.add_argument("--video", action="store_true", help="render each take's preview video on both sides")
    args = parser.parse_args(argv)
    if args.quick:
        args.takes, args.seconds = 4, 10.0
    import warpface

    warpface.init_runtime(quiet=True)
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="warpface_batch_bench_") as scratch:
        scratch = Path(scratch)
        options = [] if args.video else ["--no-video"]
        manifest = write_takes(scratch, args.takes, args.seconds, options=" ".join(options))
        split = animate_split(scratch / "take00.csv", scratch, args.device, args.video)
        startup = startup_seconds()
        serial, reference = 0.0, None
        for take in range(args.takes):
            name = f"take{take:02d}"
            out = scratch / "serial" / name / f"{name}.usda"
            driver = str(scratch / f"{name}.csv")
            serial += _warpface("--device", args.device, "animate", driver, "--out", str(out), *options)
            if reference is None:
                reference = last_frame(out)
            shutil.rmtree(out.parent)
        jobs = ["--jobs", str(args.jobs)] if args.jobs else []
        batch = _warpface("--device", args.device, "batch", str(manifest), "--out", str(scratch / "batch"), *jobs)
        same = bool(np.array_equal(reference, last_frame(scratch / "batch" / "take00" / "take00.usda")))
    if not same:
        raise RuntimeError("the batch's take00 differs from animate's")
    load = (load_before, os.getloadavg()[0])
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    rows = [
        {"run": "serial animate", "seconds": serial, "per_take": serial / args.takes, "ratio": 1.0},
        {"run": "warpface batch", "seconds": batch, "per_take": batch / args.takes, "ratio": serial / batch},
    ]
    print(
        f"{args.takes} takes of {args.seconds:g} s at 30 frames/s ({int(args.seconds * 30)} frames each), "
        f"device {args.device}, {cores} cores, {'with' if args.video else 'no'} preview videos, "
        f"load average {load[0]:.2f} -> {load[1]:.2f}"
    )
    print_table(
        rows,
        [
            ("run", "run", ""),
            ("seconds", "wall s", ".1f"),
            ("per_take", "s per take", ".2f"),
            ("ratio", "× serial", ".2f"),
        ],
    )
    print(
        f"start-up per animate process (python, imports, Warp init): {startup:.2f} s = "
        f"{100 * startup * args.takes / serial:.0f}% of the serial loop"
    )
    print("one take in process: " + ", ".join(f"{name} {value:.2f} s" for name, value in split.items()))
    print(f"takes per minute: serial {60 * args.takes / serial:.1f}, batch {60 * args.takes / batch:.1f}")
    name = "batch" if args.device == "cpu" else f"batch_{args.device.replace(':', '')}"
    path = write_results(
        name + ("_video" if args.video else "") + ("_quick" if args.quick else ""),
        {
            "machine": machine_info(args.device),
            "cores": cores,
            "load_average": load,
            "takes": args.takes,
            "seconds_per_take": args.seconds,
            "video": args.video,
            "rows": rows,
            "startup_seconds": startup,
            "animate_split_seconds": split,
            "takes_per_minute": {"serial": 60 * args.takes / serial, "batch": 60 * args.takes / batch},
            "identical_points": same,
        },
    )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
