"""Animation drivers end to end: minutes of 60 fps ARKit curves animate the built-in face and bake.

A Live Link Face CSV with all 52 ARKit channels (smooth random curves, 60 fps) drives the built-in
face's rig through :func:`warpface.commands.animate.animate` (no video): read the CSV, clamp, resample,
map with the default table, write the controls as time samples, bake the skin into a ``.usdc``.

Rows (same run):

* ``animate total``: the whole command, as ``warpface animate take.csv --out face.usda --no-video``.
* ``read CSV``, ``clean + map``, ``write controls``: its first steps on their own.
* ``naive controls Attribute.Set``: the peer for ``write controls`` — per frame and muscle,
  ``UsdAttribute.Set(value, time)`` on a stage, then ``Save``. Ratios are against this row.

The bake's own peer (per-frame ``Attribute.Set`` of the points) is ``benchmarks/usd_bake.py``.

    python -m benchmarks.drivers [--minutes 10] [--fps 60] [--device cpu]
"""

from __future__ import annotations

import argparse
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


_CPU: dict[str, float] = {}


def _timed(function, row: str | None = None):
    """(wall seconds, value); the process's CPU seconds go to ``_CPU[row]`` (on a shared machine the wall
    time includes waiting for a core, the CPU time does not)."""
    started, cpu = time.perf_counter(), time.process_time()
    value = function()
    if row:
        _CPU[row] = time.process_time() - cpu
    return time.perf_counter() - started, value


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


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=10.0, help="length of the performance (default 10)")
    parser.add_argument("--fps", type=float, default=60.0)
    parser.add_argument("--device", default=None, help="Warp device (default: Warp's preferred device)")
    args = parser.parse_args(argv)
    wp.config.quiet = True
    wp.init()
    device = wp.get_device(args.device)

    from warpface import usd
    from warpface.assets import default_rig
    from warpface.commands.animate import animate, prepare_controls
    from warpface.drivers import ARKIT_CHANNELS, Curves, mapping_for_rig, read_driver, write_live_link

    frames = int(round(args.minutes * 60 * args.fps))
    rig = default_rig(device=device)
    mapping, _, _ = mapping_for_rig(rig)
    rig.model(device=device).evaluate_batch(np.zeros((2, len(rig.muscles))))  # load kernels outside the timings
    with tempfile.TemporaryDirectory(prefix="warpface-drivers-") as folder:
        folder = Path(folder)
        curves = Curves(times=np.arange(frames) / args.fps, names=list(ARKIT_CHANNELS),
                        values=smooth_curves(frames, len(ARKIT_CHANNELS), args.fps), fps=args.fps)
        csv_path = write_live_link(folder / "take.csv", curves)
        csv_mb = csv_path.stat().st_size / 1e6

        read_s, read_back = _timed(lambda: read_driver(csv_path), "read Live Link CSV")
        map_s, (_, mapped) = _timed(lambda: prepare_controls(read_back, mapping, fps=args.fps), "clean + map")
        time_codes = np.arange(len(mapped.times), dtype=np.float64)
        stage = usd.write_rig(folder / "controls.usda", rig, fps=args.fps)
        muscles = set(rig.muscle_names)
        contractions = {n: mapped.values[:, k] for k, n in enumerate(mapped.names) if n in muscles}
        write_s, _ = _timed(lambda: (usd.write_animation(stage, time_codes, contractions=contractions, fps=args.fps),
                                     stage.GetRootLayer().Save()), "write controls (write_animation)")
        naive_s, _ = _timed(lambda: _naive_controls(folder / "naive.usda", rig, mapped.names, mapped.values, time_codes),
                            "naive controls Attribute.Set")

        total_s, result = _timed(lambda: animate(csv_path, folder / "face.usda", video=False, fps=args.fps, device=device,
                                                 progress=False), "animate total (read→bake)")
        cache_mb = result.cache.stat().st_size / 1e6
        check = usd.read_animation(folder / "face.usda", time_codes[[frames // 2]])
        column = check.muscle_names.index("zygomaticus_major_L")
        expected = mapped.values[frames // 2, mapped.names.index("zygomaticus_major_L")]
        assert abs(check.contractions[0, column] - expected) <= 1e-9 * max(1.0, abs(expected)), "controls differ"

    rows = [
        {"row": "animate total (read→bake)", "seconds": total_s},
        {"row": "read Live Link CSV", "seconds": read_s},
        {"row": "clean + map", "seconds": map_s},
        {"row": "write controls (write_animation)", "seconds": write_s},
        {"row": "naive controls Attribute.Set", "seconds": naive_s},
    ]
    for row in rows:
        row["cpu_seconds"] = _CPU[row["row"]]
        row["frames_per_s"] = frames / row["seconds"]
        row["x_naive"] = naive_s / row["seconds"]
    print(f"\nDrivers: {args.minutes:g} min of {args.fps:g} fps ARKit curves ({frames:,} frames × 52 channels, CSV "
          f"{csv_mb:.0f} MB) → built-in face ({rig.mesh.vertex_count:,} points, {len(rig.muscles)} muscles), "
          f"cache {cache_mb:,.0f} MB, device {device} ({device.name})")
    print("peer: naive per-frame, per-muscle Attribute.Set of the same controls, same run; target: total < 60 s\n")
    print_table(rows, [("row", "row", "s"), ("seconds", "seconds", ".2f"), ("cpu_seconds", "CPU s", ".2f"),
                       ("frames_per_s", "frames/s", ",.0f"),
                       ("x_naive", "× naive", ".2f")])
    write_results("drivers" + ("" if device.is_cpu else f"_{device.alias.replace(':', '')}"), {
        "benchmark": "drivers", "machine": machine_info(device), "minutes": args.minutes, "fps": args.fps,
        "frames": frames, "vertices": rig.mesh.vertex_count, "muscles": len(rig.muscles), "cache_mb": cache_mb,
        "target_seconds": 60.0, "rows": rows})


if __name__ == "__main__":
    main()
