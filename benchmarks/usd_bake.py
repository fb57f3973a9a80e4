"""Baking an expression animation into a USD point cache: warpface's bake vs naive USD authoring.

A 10k-vertex face-sized grid with 16 linear muscles and 21 wrinkles (the rig of
``benchmarks.expression``) is written as a rig layer with 300 frames of contractions, then baked.

Rows (same run, same positions):

* ``bake (usdc)``: :func:`warpface.usd.bake` with a prebuilt model — reading the controls, evaluating
  every frame, writing points + extent into a ``.usdc`` cache (``Vt.Vec3fArray.FromNumpy``, Sdf-level
  writes in ``Sdf.ChangeBlock``, temporary file + rename) and saving the rig layer.
* ``bake incl. model setup``: the same, building the model from the stage (rig read, muscle weights,
  wrinkle distances).
* ``evaluate only``: the expression model's share (``evaluate`` of all frames).
* ``write usda``: the same fast writing path, to a text ``.usda`` layer.
* ``naive Attribute.Set``: the usual first attempt — per frame, a Python list of ``Gf.Vec3f`` through
  ``UsdAttribute.Set`` on a stage, then ``Save`` to ``.usdc``. The ratios are against this row.

    python -m benchmarks.usd_bake [--vertices 10000] [--frames 300] [--device cpu] [--repeats 3]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import warp as wp

from ._timing import machine_info, print_table, write_results
from .expression import benchmark_rig, wavy_grid


def _best(function, repeats: int) -> float:
    """Shortest wall time of ``repeats`` calls [s] (I/O timings are noisy upward on a shared machine)."""
    best = float("inf")
    for _ in range(repeats):
        started = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - started)
    return best


def _write_fast(positions: np.ndarray, times: np.ndarray, path: Path) -> None:
    """The bake's writing path on its own: Sdf-level samples from numpy, exported to ``path``."""
    from pxr import Sdf, Vt

    layer = Sdf.Layer.CreateAnonymous(path.suffix)
    prim = Sdf.CreatePrimInLayer(layer, "/Face/Skin")
    Sdf.AttributeSpec(prim, "points", Sdf.ValueTypeNames.Point3fArray)
    bounds = np.stack([positions.min(axis=1), positions.max(axis=1)], axis=1)
    Sdf.AttributeSpec(prim, "extent", Sdf.ValueTypeNames.Float3Array)
    with Sdf.ChangeBlock():
        for frame, time_code in enumerate(times.tolist()):
            layer.SetTimeSample("/Face/Skin.points", time_code, Vt.Vec3fArray.FromNumpy(positions[frame]))
            layer.SetTimeSample("/Face/Skin.extent", time_code, Vt.Vec3fArray.FromNumpy(bounds[frame]))
    layer.Export(str(path))


def _write_naive(positions: np.ndarray, times: np.ndarray, path: Path) -> None:
    """Per-frame ``Attribute.Set`` with Python lists of Gf.Vec3f on a stage, then ``Save``."""
    from pxr import Gf, Usd, UsdGeom

    if path.exists():
        path.unlink()
    stage = Usd.Stage.CreateNew(str(path))
    mesh = UsdGeom.Mesh.Define(stage, "/Face/Skin")
    points, extent = mesh.CreatePointsAttr(), mesh.CreateExtentAttr()
    for frame, time_code in enumerate(times.tolist()):
        values = positions[frame].tolist()
        points.Set([Gf.Vec3f(*p) for p in values], time_code)
        extent.Set(
            [Gf.Vec3f(*positions[frame].min(axis=0).tolist()), Gf.Vec3f(*positions[frame].max(axis=0).tolist())],
            time_code,
        )
    stage.Save()


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--vertices", type=int, default=10_000)
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--device", default=None, help="Warp device (default: Warp's preferred device)")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    wp.config.quiet = True
    wp.init()
    device = wp.get_device(args.device)

    import warpface as wf
    from warpface.usd import bake, write_animation, write_rig

    grid = wavy_grid(args.vertices)  # points rounded to float32, as the stage stores them
    mesh = wf.FaceMesh(grid.points.astype(np.float32).astype(np.float64), grid.triangles, name=grid.name)
    muscles, wrinkles, thickness, peak = benchmark_rig(mesh)
    rig = wf.FaceRig(mesh, muscles, wrinkles, thickness)
    times = np.arange(float(args.frames))
    envelope = np.sin(np.pi * times / max(args.frames - 1, 1)) ** 2
    contractions = envelope[:, None] * peak[None, :] * (1 + 0.2 * np.sin(times[:, None] / 7 + np.arange(len(muscles))))

    rows = []
    with tempfile.TemporaryDirectory(prefix="warpface-bake-") as folder:
        folder = Path(folder)
        rig_path = folder / "face.usda"
        stage = write_rig(rig_path, rig)
        write_animation(stage, times, contractions=contractions)
        stage.GetRootLayer().Save()
        model = wf.ExpressionModel.from_rig(rig, device=device)
        model.evaluate(contractions[:2])  # compile / load kernels outside the timings

        bake_s = _best(lambda: bake(rig_path, model=model, progress=False), args.repeats)
        cache = folder / "face_anim.usdc"
        setup_s = _best(lambda: bake(rig_path, device=device, progress=False), 1)
        positions = model.evaluate(contractions, wrinkle_depths=np.tile(model.default_depths, (len(times), 1)))
        evaluate_s = _best(lambda: model.evaluate(contractions), args.repeats)
        usda = folder / "fast.usda"
        usda_s = _best(lambda: _write_fast(positions, times, usda), 1)
        naive = folder / "naive.usdc"
        naive_s = _best(lambda: _write_naive(positions, times, naive), 1)

        from pxr import Usd, UsdGeom

        check = Usd.Stage.Open(str(rig_path))
        baked = np.asarray(UsdGeom.Mesh(check.GetPrimAtPath("/Face/Skin")).GetPointsAttr().Get(times[len(times) // 2]))
        assert np.array_equal(baked, positions[len(times) // 2]), "baked cache differs from the model output"
        megabytes = lambda p: p.stat().st_size / 1e6  # noqa: E731
        rows = [
            {"row": "bake (usdc)", "seconds": bake_s, "file_mb": megabytes(cache)},
            {"row": "bake incl. model setup", "seconds": setup_s, "file_mb": megabytes(cache)},
            {"row": "evaluate only", "seconds": evaluate_s, "file_mb": None},
            {"row": "write usda (fast path)", "seconds": usda_s, "file_mb": megabytes(usda)},
            {"row": "naive Attribute.Set → usdc", "seconds": naive_s, "file_mb": megabytes(naive)},
        ]
    for row in rows:
        row["frames_per_s"] = args.frames / row["seconds"]
        row["x_naive"] = naive_s / row["seconds"]

    print(
        f"\nUSD bake: {mesh.vertex_count:,} points × {args.frames} frames, {len(muscles)} muscles + {len(wrinkles)} "
        "wrinkles, "
        f"device {device} ({device.name})"
    )
    print("baseline: naive per-frame Attribute.Set with Python lists, same run, same positions\n")
    print_table(
        rows,
        [
            ("row", "row", "s"),
            ("seconds", "seconds", ".3f"),
            ("frames_per_s", "frames/s", ",.0f"),
            ("x_naive", "× naive", ".1f"),
            ("file_mb", "file MB", ".1f"),
        ],
    )
    path = write_results(
        "usd_bake",
        {
            "benchmark": "usd_bake",
            "machine": machine_info(device),
            "vertices": mesh.vertex_count,
            "frames": args.frames,
            "muscles": len(muscles),
            "wrinkles": len(wrinkles),
            "target_seconds": 2.0,
            "rows": rows,
        },
    )
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
