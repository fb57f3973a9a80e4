"""A shoot of many takes: ``warpface batch`` (local engine) against a serial loop of ``warpface animate``.

Twenty one-minute Live Link Face takes (30 frames/s, a few channels moving differently in each, written here) are
animated and baked twice in the same run (with ``--video`` also previewed as MP4s):

* ``serial animate``: one ``warpface animate TAKE --out …`` process after another, as a shell loop over the
  takes does (each pays Python's start-up, warpface's imports, Warp's initialisation and kernel loads);
* ``warpface batch``: one ``warpface batch MANIFEST --out …`` process, the local engine's worker processes
  (one per core, or per CUDA device) paying those once each; it also renders each take's contact-sheet picture
  and writes the report and the shoot stage.

The ratio is serial / batch wall time; beside it, serial / batch CPU seconds (user + system of the processes and
of the batch's workers: the work each side does, which other jobs on a loaded machine inflate far less than they
inflate wall time). The start-up a pool amortises is measured on its own (``python -c`` of
warpface's imports and Warp's initialisation, best of two), with the in-process split of one take's ``animate``
(read, model, bake, video) as a serial process runs it (its rig's model built for it) and as a batch worker runs
it (the model kept from the worker's earlier take), so the table says where the serial loop's time goes. The
last frame of the first take is checked to be identical between the two. Outputs (about 250 MB of cache per
take) are deleted as soon as they are measured. ``--jobs 1 2 4`` adds a batch row per worker count.

On a GPU (``--device cuda:0``; ``--device cuda`` gives the batch every device, one worker each, while the serial
loop runs on ``cuda:0``) the run prints takes per minute for each row. ``--json PATH`` also writes the results
there (e.g. into ``$OUT`` on the device machine). The run first checks that the packages the batch imports can
be imported (Warp, usd-core, SciPy, tqdm, OpenCV) and stops with one line naming the missing ones; without
offscreen OpenGL (pyrender) the takes have no contact-sheet picture, which the output says.

Without a GPU the preview video is drawn by Mesa's llvmpipe, a software rasteriser that already spreads each
frame over every core, so running takes side by side cannot make the videos faster; the default leaves them out
(``--no-video`` on both sides) to measure what the pool changes, ``--video`` puts them in.

    python -m benchmarks.batch [--quick] [--takes 20] [--seconds 60] [--device cpu|cuda:0|cuda] [--jobs N ...]
                               [--video] [--json PATH]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
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
NEEDED = {"warp": "warp-lang", "pxr": "usd-core", "scipy": "scipy", "tqdm": "tqdm", "cv2": "opencv-python-headless"}
"""The modules a batch of ``animate`` takes imports (module: the package that provides it)."""


def check_packages() -> None:
    """Stop with one line naming the packages to install when a module the batch imports is missing."""
    missing = [package for module, package in NEEDED.items() if importlib.util.find_spec(module) is None]
    if missing:
        raise SystemExit(f"benchmarks.batch: install {' '.join(missing)} first (the batch imports them)")


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


def animate_split(driver: Path, folder: Path, device: str, video: bool) -> dict[str, dict[str, float]]:
    """Seconds of each step of one take's ``animate`` in this process (kernels already loaded): ``fresh``, its
    rig read and model built for it (a serial ``animate`` process), and ``kept``, both kept from an earlier take
    (a batch worker's :class:`~warpface.commands.rig_models.RigModels`)."""
    from warpface.commands.animate import animate
    from warpface.commands.rig_models import RigModels

    rigs = RigModels()
    animate(driver, folder / "warm.usda", device=device, progress=False, video=False, rigs=rigs)  # loads kernels
    fresh = animate(driver, folder / "fresh.usda", device=device, progress=False, video=video)
    kept = animate(driver, folder / "kept.usda", device=device, progress=False, video=video, rigs=rigs)
    return {"fresh": dict(fresh.seconds), "kept": dict(kept.seconds)}


def last_frame(stage_path: Path) -> np.ndarray:
    from pxr import Usd

    from warpface import usd

    stage = Usd.Stage.Open(str(stage_path))
    points = usd.rig_prims(stage).skin.GetAttribute("points")
    return np.asarray(points.Get(points.GetTimeSamples()[-1]))


def _children_cpu() -> float:
    """CPU seconds (user + system) of this process's finished child processes and theirs (a batch's workers)."""
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def serial_loop(scratch: Path, takes: int, device: str, options: list[str]) -> tuple[float, float, np.ndarray]:
    """(wall seconds of one ``warpface animate`` process per take, one after another; their CPU seconds; take00's
    last frame)."""
    seconds, reference, cpu = 0.0, None, _children_cpu()
    for take in range(takes):
        name = f"take{take:02d}"
        out = scratch / "serial" / name / f"{name}.usda"
        seconds += _warpface("--device", device, "animate", str(scratch / f"{name}.csv"), "--out", str(out), *options)
        if reference is None:
            reference = last_frame(out)
        shutil.rmtree(out.parent)
    return seconds, _children_cpu() - cpu, reference


def batch_run(scratch: Path, manifest: Path, device: str, jobs: int | None) -> tuple[float, float, np.ndarray, int]:
    """(wall seconds of one ``warpface batch`` process, its CPU seconds with its workers', take00's last frame,
    takes with a contact-sheet picture)."""
    out = scratch / "batch"
    jobs_option = ["--jobs", str(jobs)] if jobs else []
    cpu = _children_cpu()
    seconds = _warpface("--device", device, "batch", str(manifest), "--out", str(out), *jobs_option)
    cpu = _children_cpu() - cpu
    takes = json.loads((out / "report.json").read_text())["takes"]
    if any(entry["status"] != "done" for entry in takes):
        raise RuntimeError(f"the batch did not finish every take: {[e['error'] for e in takes if e['error']]}")
    pictures = sum(bool(entry.get("thumbnail")) for entry in takes)
    reference = last_frame(out / "take00" / "take00.usda")
    shutil.rmtree(out)
    return seconds, cpu, reference, pictures


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--takes", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=60.0, help="length of each take [s] (default 60)")
    parser.add_argument("--device", default="cpu", help="cpu, cuda:N, or cuda (the batch on every CUDA device)")
    parser.add_argument(
        "--jobs", type=int, nargs="+", default=[0], help="batch workers, one batch row each (default: cores or GPUs)"
    )
    parser.add_argument("--rounds", type=int, default=1, help="serial loop and batch rows, alternated, this often")
    parser.add_argument("--quick", action="store_true", help="4 takes of 10 s (a smoke run)")
    parser.add_argument("--video", action="store_true", help="render each take's preview video on both sides")
    parser.add_argument("--json", type=Path, default=None, help="also write the results to this file")
    args = parser.parse_args(argv)
    if args.quick:
        args.takes, args.seconds = 4, 10.0
    check_packages()
    import warp as wp

    import warpface

    warpface.init_runtime(quiet=True)
    load_before = os.getloadavg()[0]
    runs = ["serial animate"] + [f"warpface batch{f' --jobs {j}' if j else ''}" for j in args.jobs]
    seconds: dict[str, list[float]] = {run: [] for run in runs}
    cpu: dict[str, list[float]] = {run: [] for run in runs}
    pictures = {}
    with tempfile.TemporaryDirectory(prefix="warpface_batch_bench_") as scratch:
        scratch = Path(scratch)
        options = [] if args.video else ["--no-video"]
        manifest = write_takes(scratch, args.takes, args.seconds, options=" ".join(options))
        split = animate_split(
            scratch / "take00.csv", scratch, "cuda:0" if args.device == "cuda" else args.device, args.video
        )
        startup = startup_seconds()
        for _ in range(args.rounds):
            serial, serial_cpu, reference = serial_loop(scratch, args.takes, args.device, options)
            seconds["serial animate"].append(serial)
            cpu["serial animate"].append(serial_cpu)
            for run, jobs in zip(runs[1:], args.jobs):
                batch, batch_cpu, frame, pictures[run] = batch_run(scratch, manifest, args.device, jobs)
                seconds[run].append(batch)
                cpu[run].append(batch_cpu)
                if not np.array_equal(reference, frame):
                    raise RuntimeError(f"{run}: take00 differs from animate's")
    load = (load_before, os.getloadavg()[0])
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    serial, serial_cpu = sum(seconds["serial animate"]), sum(cpu["serial animate"])
    rows = [
        {
            "run": run,
            "seconds": sum(values) / args.rounds,
            "per_take": sum(values) / args.rounds / args.takes,
            "ratio": serial / sum(values),
            "takes_per_minute": 60 * args.takes * args.rounds / sum(values),
            "cpu_seconds": sum(cpu[run]) / args.rounds,
            "cpu_ratio": serial_cpu / sum(cpu[run]),
            "rounds": values,
            "cpu_rounds": cpu[run],
        }
        for run, values in seconds.items()
    ]
    gpus = wp.get_cuda_device_count() if args.device.startswith("cuda") else 0
    print(
        f"{args.takes} takes of {args.seconds:g} s at 30 frames/s ({int(args.seconds * 30)} frames each), "
        f"device {args.device}{f' ({gpus} GPUs)' if gpus else ''}, {cores} cores, "
        f"{'with' if args.video else 'no'} preview videos, {args.rounds} round(s), "
        f"load average {load[0]:.2f} -> {load[1]:.2f}"
    )
    print_table(
        rows,
        [
            ("run", "run", ""),
            ("seconds", "wall s", ".1f"),
            ("per_take", "s per take", ".2f"),
            ("ratio", "× serial", ".2f"),
            ("takes_per_minute", "takes/min", ".1f"),
            ("cpu_seconds", "CPU s", ".1f"),
            ("cpu_ratio", "CPU × serial", ".2f"),
        ],
    )
    if args.rounds > 1:
        for run, values in seconds.items():
            print(f"{run}: " + ", ".join(f"{v:.1f}" for v in values) + " s by round")
    print(
        f"start-up per animate process (python, imports, Warp init): {startup:.2f} s = "
        f"{100 * startup * args.takes / (serial / args.rounds):.0f}% of the serial loop"
    )
    for kind, label in (("fresh", "as animate runs it"), ("kept", "in a batch worker (rig and model kept)")):
        print(f"one take {label}: " + ", ".join(f"{step} {value:.2f} s" for step, value in split[kind].items()))
    print("contact-sheet pictures: " + ", ".join(f"{run} {count} of {args.takes}" for run, count in pictures.items()))
    name = "batch" if args.device == "cpu" else f"batch_{args.device.replace(':', '')}"
    results = {
        "machine": machine_info("cuda:0" if args.device == "cuda" else args.device),
        "cores": cores,
        "cuda_devices": gpus,
        "load_average": load,
        "takes": args.takes,
        "seconds_per_take": args.seconds,
        "video": args.video,
        "rounds": args.rounds,
        "rows": rows,
        "startup_seconds": startup,
        "animate_split_seconds": split,
        "pictures": pictures,
        "identical_points": True,
    }
    if (args.takes, args.seconds) != (20, 60.0):  # the goal's shoot keeps the plain name
        name += "_quick" if args.quick else f"_{args.takes}x{args.seconds:g}s"
    path = write_results(name + ("_video" if args.video else ""), results)
    print(f"wrote {path}")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2, default=float))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
