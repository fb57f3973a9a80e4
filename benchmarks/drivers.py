"""Animation drivers end to end: minutes of 60 fps ARKit curves animate the built-in face and bake.

A Live Link Face CSV with all 52 ARKit channels (smooth random curves, 60 fps) drives the built-in
face's rig through :func:`warpface.commands.animate.animate`: read the CSV, clamp, resample, map with
the default table, write the controls as time samples, bake the skin with wrinkles into a ``.usdc``.

Rows (same run):

* ``animate total``: the whole command, as ``warpface animate take.csv --out face.usda --no-video``,
  then its steps (:attr:`AnimateResult.seconds`) — the bake evaluates frames in one worker thread per
  core while the main thread reads controls and writes the cache.
* ``preview video``: the default preview of the same take (``PREVIEW_MAX_FRAMES`` frames) on its own.
* Peers for the bake, on the first minute of the take and scaled to the whole take: ``bake, 1 worker``
  (the same bake with one evaluation thread: the serial pipeline) and ``naive per-frame bake`` — per
  frame the single-frame ``evaluate``, then ``UsdAttribute.Set`` of points and extent on a stage, saved
  as ``.usdc``. ``× peer`` is the naive bake's time over each row's.
* ``naive controls Attribute.Set``: per frame and muscle ``UsdAttribute.Set``: the peer of ``write controls``.

The run checks that the cache is what the single-frame model gives, bit for bit, at sampled frames.
The JSON names the machine (CPU model, cores) and the load averages before and after.

    python -m benchmarks.drivers [--minutes 10] [--fps 60] [--peer-minutes 1] [--device cpu]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
import warp as wp

from ._timing import machine_info, print_table, write_results


def smooth_curves(frames: int, channels: int, fps: float, seed: int = 0) -> np.ndarray:
    """(frames, channels) weights in [0, 1]: sums of slow sinusoids (0.05–1 Hz), as a face performs."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames)[:, None] / fps
    out = np.zeros((frames, channels))
    for _ in range(3):
        frequency = rng.uniform(0.05, 1.0, channels)
        phase = rng.uniform(0, 2 * np.pi, channels)
        out += np.sin(2 * np.pi * frequency * t + phase)
    return np.clip(0.5 + out / 6.0 - 0.25, 0.0, 1.0)


def _timed(function):
    """(wall seconds, CPU seconds of this process, value): on a shared machine the wall time includes
    waiting for a core, the CPU time does not (and counts every thread)."""
    started, cpu = time.perf_counter(), time.process_time()
    value = function()
    return time.perf_counter() - started, time.process_time() - cpu, value


def _naive_controls(path: Path, rig, names, values, time_codes) -> None:
    """Per-frame, per-muscle ``Attribute.Set`` on a stage, then ``Save``."""
    from warpface import usd

    stage = usd.write_rig(path, rig)
    prims = usd.rig_prims(stage)
    attributes = {name: prim.GetAttribute("contraction") for name, prim in zip(prims.muscle_names, prims.muscles)}
    columns = [(attributes[name], k) for k, name in enumerate(names) if name in attributes]
    for frame, time_code in enumerate(time_codes.tolist()):
        for attribute, column in columns:
            attribute.Set(float(values[frame, column]), time_code)
    stage.GetRootLayer().Save()


def _naive_bake(path: Path, model, animation) -> None:
    """Per frame: the single-frame ``evaluate``, then ``Attribute.Set`` of points and extent; saved as ``.usdc``."""
    from pxr import Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    mesh = UsdGeom.Mesh.Define(stage, "/Face/Skin")
    points, extent = mesh.CreatePointsAttr(), mesh.CreateExtentAttr()
    for time_code, controls, depths in zip(animation.times.tolist(), animation.controls, animation.wrinkle_depths):
        frame = model.evaluate(controls, wrinkle_depths=depths)
        points.Set(Vt.Vec3fArray.FromNumpy(frame), time_code)
        extent.Set(Vt.Vec3fArray.FromNumpy(np.stack([frame.min(axis=0), frame.max(axis=0)])), time_code)
    stage.GetRootLayer().Save()


def _controls_stage(path: Path, rig, mapped, frames: int, fps: float):
    """A rig stage with the first ``frames`` frames of the mapped controls (what animate writes)."""
    from warpface import usd

    stage = usd.write_rig(path, rig, fps=fps)
    from warpface.usd.jaw_io import JAW_CONTROL_ATTRIBUTES

    muscles = set(rig.muscle_names)
    contractions = {n: mapped.values[:frames, k] for k, n in enumerate(mapped.names) if n in muscles}
    jaw = {n: mapped.values[:frames, k] for k, n in enumerate(mapped.names) if n in JAW_CONTROL_ATTRIBUTES}
    usd.write_animation(
        stage,
        np.arange(frames, dtype=np.float64),
        contractions=contractions,
        jaw=jaw if rig.jaw is not None and jaw else None,
        fps=fps,
    )
    stage.GetRootLayer().Save()
    return stage


def _check_cache(stage_path: Path, model, frames: int) -> None:
    """The baked points equal the single-frame model's at sampled frames, bit for bit."""
    from pxr import Usd, UsdGeom

    from warpface import usd

    stage = Usd.Stage.Open(str(stage_path))
    points = UsdGeom.Mesh(stage.GetPrimAtPath(usd.rig_prims(stage).skin.GetPath())).GetPointsAttr()
    sampled = np.unique(np.linspace(0, frames - 1, 7).round()).astype(np.float64)
    animation = usd.read_animation(stage, sampled, meters_per_unit=usd.stage_meters_per_unit(stage))
    for time_code, controls, depths in zip(sampled.tolist(), animation.controls, animation.wrinkle_depths):
        expected = model.evaluate(controls, wrinkle_depths=depths)  # muscles, then the jaw's controls
        assert np.array_equal(np.asarray(points.Get(time_code), dtype=np.float32), expected), (
            f"cache differs at frame {time_code:g}"
        )


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=10.0, help="length of the performance (default 10)")
    parser.add_argument("--fps", type=float, default=60.0)
    parser.add_argument("--peer-minutes", type=float, default=1.0, help="slice timed for the bake peers (default 1)")
    parser.add_argument("--device", default=None, help="Warp device (default: Warp's preferred device)")
    args = parser.parse_args(argv)
    wp.config.quiet = True
    wp.init()
    device = wp.get_device(args.device)
    load_before = os.getloadavg()

    from warpface import usd
    from warpface.assets import default_rig
    from warpface.commands.animate import PREVIEW_MAX_FRAMES, animate, prepare_controls
    from warpface.drivers import ARKIT_CHANNELS, Curves, mapping_for_rig, write_live_link
    from warpface.usd import read_driver

    frames = int(round(args.minutes * 60 * args.fps))
    peer_frames = min(frames, int(round(args.peer_minutes * 60 * args.fps)))
    scale = frames / peer_frames
    rig = default_rig(device=device)
    mapping, _, _ = mapping_for_rig(rig)
    model = rig.model(device=device)
    model.evaluate(np.zeros((2, len(model.control_names))))  # load kernels outside the timings
    rows = []

    def row(name, wall, cpu, timed_frames=frames, scaled=1.0):
        rows.append(
            {
                "row": name,
                "seconds": wall * scaled,
                "cpu_seconds": None if cpu is None else cpu * scaled,
                "frames_timed": timed_frames,
                "frames_per_s": frames / (wall * scaled),
            }
        )

    with tempfile.TemporaryDirectory(prefix="warpface-drivers-") as folder:
        folder = Path(folder)
        curves = Curves(
            times=np.arange(frames) / args.fps,
            names=list(ARKIT_CHANNELS),
            values=smooth_curves(frames, len(ARKIT_CHANNELS), args.fps),
            fps=args.fps,
        )
        csv_path = write_live_link(folder / "take.csv", curves)
        csv_mb = csv_path.stat().st_size / 1e6
        _, mapped = prepare_controls(read_driver(csv_path), mapping, fps=args.fps)

        wall, cpu, result = _timed(
            lambda: animate(csv_path, folder / "face.usda", video=False, fps=args.fps, device=device, progress=False)
        )
        row("animate total (read→bake, no video)", wall, cpu)
        for step, seconds in result.seconds.items():
            row(f"  {step}", seconds, None)
        cache_mb = result.cache.stat().st_size / 1e6
        _check_cache(folder / "face.usda", model, frames)
        result.cache.unlink()

        total_s = wall
        # The preview renders PREVIEW_MAX_FRAMES frames whatever the take's length: time it on the peer slice.
        short = Curves(
            times=curves.times[:peer_frames], names=curves.names, values=curves.values[:peer_frames], fps=args.fps
        )
        short_csv = write_live_link(folder / "short.csv", short)
        with_video = animate(short_csv, folder / "video.usda", video=True, fps=args.fps, device=device, progress=False)
        video_s = with_video.seconds["video"]
        row(f"  preview video ({min(frames, PREVIEW_MAX_FRAMES)} frames, default)", video_s, None)
        row("animate total with the default video", total_s + video_s, None)

        stage = _controls_stage(folder / "slice.usda", rig, mapped, peer_frames, args.fps)
        times = np.arange(peer_frames, dtype=np.float64)
        wall, cpu, _ = _timed(
            lambda: usd.bake(stage, times, cache_path=folder / "slice_anim.usdc", model=model, progress=False)
        )
        row("bake (threads), peer slice", wall, cpu, peer_frames, scale)
        wall, cpu, _ = _timed(
            lambda: usd.bake(
                stage, times, cache_path=folder / "slice1_anim.usdc", model=model, progress=False, workers=1
            )
        )
        row("bake, 1 worker (serial)", wall, cpu, peer_frames, scale)
        animation = usd.read_animation(stage, times)
        wall, cpu, _ = _timed(lambda: _naive_bake(folder / "naive.usdc", model, animation))
        row("naive per-frame bake (evaluate + Attribute.Set)", wall, cpu, peer_frames, scale)

        time_codes = np.arange(len(mapped.times), dtype=np.float64)
        wall, cpu, _ = _timed(
            lambda: _naive_controls(folder / "naive.usda", rig, mapped.names, mapped.values, time_codes)
        )
        row("naive controls Attribute.Set", wall, cpu)

    naive_bake = next(r["seconds"] for r in rows if r["row"].startswith("naive per-frame bake"))
    for entry in rows:  # steps and the video are parts of a total, not alternatives to the peer
        entry["x_naive_bake"] = None if entry["row"].startswith(" ") else naive_bake / entry["seconds"]
    load_after = os.getloadavg()
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(
        f"\nDrivers: {args.minutes:g} min of {args.fps:g} fps ARKit curves ({frames:,} frames × 52 channels, CSV "
        f"{csv_mb:.0f} MB) → built-in face ({rig.mesh.vertex_count:,} points, {len(rig.muscles)} muscles, "
        f"{len(rig.wrinkles)} wrinkles), cache {cache_mb:,.0f} MB, device {device} ({device.name})"
    )
    print(f"machine: {_cpu_name()}, {cores} cores; load average before {load_before[0]:.2f}, after {load_after[0]:.2f}")
    print(
        f"peers: the first {peer_frames:,} frames, times ×{scale:g}; target: total < 60 s; cache checked bit for bit\n"
    )
    print_table(
        rows,
        [
            ("row", "row", "s"),
            ("seconds", "seconds", ".2f"),
            ("cpu_seconds", "CPU s", ".2f"),
            ("frames_timed", "frames timed", ",d"),
            ("frames_per_s", "frames/s", ",.0f"),
            ("x_naive_bake", "× naive bake", ".2f"),
        ],
    )
    machine = machine_info(device) | {
        "cpu": _cpu_name(),
        "cores": cores,
        "host": platform.node(),
        "load_average_before": load_before,
        "load_average_after": load_after,
    }
    write_results(
        "drivers" + ("" if device.is_cpu else f"_{device.alias.replace(':', '')}"),
        {
            "benchmark": "drivers",
            "machine": machine,
            "minutes": args.minutes,
            "fps": args.fps,
            "frames": frames,
            "peer_frames": peer_frames,
            "vertices": rig.mesh.vertex_count,
            "muscles": len(rig.muscles),
            "wrinkles": len(rig.wrinkles),
            "cache_mb": cache_mb,
            "target_seconds": 60.0,
            "rows": rows,
        },
    )


if __name__ == "__main__":
    main()
