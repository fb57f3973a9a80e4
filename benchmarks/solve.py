"""Solving controls (SPEC §6.1): accuracy on real shapes, and speed against SciPy on the same objective.

(a) Real shapes: the ICT-FaceKit face region (``../shared/data``; skipped when absent) rigged from its
    own 68 landmarks with the default rig; each expression shape (browInnerUp_L/R, browOuterUp_L/R,
    eyeSquint_L/R, jawOpen; cm → m) is fitted densely and from the 68 landmarks only. Errors are over
    the vertices the shape moves (> 0.1 mm): "before" is the rest face against the shape, "after" the
    fitted rig.
(b) Speed on the built-in face (default rig: its muscles and the jaw's three controls, all solved;
    the four expression animations with the jaw opening to 0.2 rad and back during each), same
    objective for both solvers (``l2 = 1e-6``, ``l1 = 1e-6``, bounds): warpface's projected
    Levenberg–Marquardt with the exact Jacobian against ``scipy.optimize.least_squares`` (trust-region
    reflective, 2-point differences with a 20 µm step; its residual is evaluated by the same Warp
    kernels). Rows: a warm-started
    landmark solve of the four expression animations (frames/s), a dense fit of one shape (seconds),
    and a batched landmark solve of many frames (frames/s) on ``--device``. The iteration runs on the
    device (``device_steps``, the default); the "NumPy loop" rows run the same solves with the
    iteration on the host (``device_steps=False``) in the same run, for the gain of keeping it there.

Every phase prints a line when it starts (elapsed seconds, flushed at once). ``--quick`` runs the same
small sizes on every device (a quarter of the animation frames, :data:`QUICK_FRAMES` batched frames).

    python -m benchmarks.solve [--device cuda:0] [--frames 4096] [--quick]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
import warp as wp

import warpface as wf
from warpface.assets import EXPRESSIONS, default_rig, expression_timeline, rig_scale
from warpface.data import ict_face_region, ict_landmark_indices
from warpface.solve import Solver

from ._timing import machine_info, print_table, write_results

ICT_SHAPES = (
    "browInnerUp_L",
    "browInnerUp_R",
    "browOuterUp_L",
    "browOuterUp_R",
    "eyeSquint_L",
    "eyeSquint_R",
    "jawOpen",
)
CENTIMETRE = 0.01
MOVED = 1e-4
"""A vertex counts as moved by a shape when it moves more than 0.1 mm."""
OPTIONS = dict(l2=1e-6, l1=1e-6)
FD_STEP = 20e-6
"""SciPy's finite-difference step [m]: well above float32 resolution of face coordinates."""
SIGNED_SMOOTHING = 1e-6
"""δ of SciPy's smoothed ``|u|`` for signed controls [face units] (see :func:`scipy_solve`)."""
QUICK_FRAMES = 512
"""Batched frames of a ``--quick`` run, on any device (the full run: 512 on the CPU, 65536 on CUDA)."""
_STARTED = time.perf_counter()


def progress(message: str) -> None:
    """One line on stdout with the seconds since the start, flushed at once (a long phase shows where it is)."""
    print(f"[{time.perf_counter() - _STARTED:7.1f} s] {message}", flush=True)
    sys.stdout.flush()


def scipy_solve(solver: Solver, target: np.ndarray, start: np.ndarray):
    """``least_squares`` on the same objective as ``solver`` (no pose/symmetry/smoothness terms used here).

    The L1 term enters as residuals ``sqrt(l1·|u|)``; for a signed control (the jaw's) ``|u|`` is
    smoothed to ``sqrt(u² + δ²)`` (δ = :data:`SIGNED_SMOOTHING`, which shifts E by at most ``l1·δ``):
    ``sqrt(|u|)`` has an infinite slope at 0 where trust-region steps stall.
    """
    from scipy.optimize import least_squares

    opts = solver.options
    scale = solver.control_scale
    valid = np.all(np.isfinite(target), axis=1)
    weight = solver.weights * valid
    weight = weight / weight.sum()
    y = np.where(valid[:, None], target, 0.0) / solver.unit
    root_w = np.sqrt(weight)[:, None]
    low, high = solver.low * scale, solver.high * scale
    signed = low < 0.0

    def residual(u):
        x, _ = solver.local.evaluate((u / scale)[None], jacobian=False)
        e = solver.observation.apply_frames(x)[0] / solver.unit - y
        size = np.where(signed, np.sqrt(u * u + SIGNED_SMOOTHING**2), np.maximum(u, 0.0))
        return np.concatenate([(root_w * e).ravel(), np.sqrt(opts.l2) * u, np.sqrt(opts.l1 * size)])

    result = least_squares(
        residual,
        np.clip(start * scale, low, high),
        bounds=(low, high),
        method="trf",
        diff_step=FD_STEP / solver.unit,
        x_scale=1.0,
    )
    return result.x / scale, result.nfev


def real_shapes(device, quick: bool) -> list[dict]:
    path, landmarks = ict_face_region(), ict_landmark_indices()
    if path is None or landmarks is None:
        print("(a) ICT-FaceKit data not found in ../shared/data: real-shape rows skipped")
        return []
    progress("(a) real shapes: rigging the ICT-FaceKit face")
    neutral = wf.FaceMesh.from_obj(path)
    mesh = wf.FaceMesh(neutral.points * CENTIMETRE, neutral.triangles, name="ict_face")
    rig = default_rig(mesh, landmarks, name="ICTFace", device=device)
    dense = Solver(rig, device=device, **OPTIONS)
    sparse = Solver(rig, landmarks, device=device, **OPTIONS)
    rows = []
    for shape in ICT_SHAPES[:2] if quick else ICT_SHAPES:
        shape_path = ict_face_region(shape)
        if shape_path is None:
            continue
        progress(f"(a) fitting {shape} (dense, then 68 landmarks)")
        target = wf.load_obj(shape_path)[0] * CENTIMETRE
        before = np.linalg.norm(target - mesh.points, axis=1)
        moved = before > MOVED
        row = {
            "shape": shape,
            "moved": int(moved.sum()),
            "before_mean_mm": before[moved].mean() * 1e3,
            "before_max_mm": before[moved].max() * 1e3,
        }
        for label, solver, goal in (("dense", dense, target), ("landmarks", sparse, target[landmarks])):
            solver.reset()
            began = time.perf_counter()
            fit = solver.solve(goal)
            seconds = time.perf_counter() - began
            after = np.linalg.norm(fit.points - target, axis=1)
            row[f"{label}_mean_mm"] = after[moved].mean() * 1e3
            row[f"{label}_max_mm"] = after[moved].max() * 1e3
            row[f"{label}_s"] = seconds
            row[f"{label}_controls"] = {k: v for k, v in fit.controls.items() if v > 0.0}
        rows.append(row)
    return rows


JAW_OPENING = 0.2
"""Peak jaw opening [rad] during each expression of the speed rows (the jaw's columns take part)."""


def performance(rig) -> np.ndarray:
    """The four expression animations, each with the jaw opening to :data:`JAW_OPENING` and back: (F, C)."""
    parts = []
    for name in EXPRESSIONS:
        muscles = expression_timeline(name, rig, seconds=1.0, fps=30.0)
        jaw = np.zeros((len(muscles), len(rig.control_names) - len(rig.muscles)))
        if jaw.shape[1]:
            jaw[:, 0] = JAW_OPENING * np.sin(np.linspace(0.0, np.pi, len(muscles))) ** 2
        parts.append(np.concatenate([muscles, jaw], axis=1))
    return np.concatenate(parts)


def speed(device, frames_batched: int, quick: bool) -> list[dict]:
    progress(f"(b) speed: building the default rig and its target frames on {device.alias}")
    rig = default_rig(device=device)
    model = rig.model(device=device)
    timeline = performance(rig)
    if quick:
        timeline = timeline[::4]
    frames = model.evaluate(timeline).astype(np.float64)[:, rig.landmarks]
    rows = []

    # Warm-started landmark solve, frame after frame (the NumPy loop first, the same frames).
    progress("(b) landmarks, warm-started: building the solvers, compiling (first run on a device: slow)")
    host_loop = Solver(rig, rig.landmarks, device=device, device_steps=False, **OPTIONS)
    solver = Solver(rig, rig.landmarks, device=device, **OPTIONS)
    for frame in frames[:5]:
        solver.solve(frame)  # compile and allocate outside the timing
        host_loop.solve(frame)
    host_loop.reset()
    progress(f"(b) landmarks, warm-started: {len(frames)} frames, NumPy loop")
    began = time.perf_counter()
    host_fits = [host_loop.solve(frame) for frame in frames]
    host_seconds = (time.perf_counter() - began) / len(frames)
    solver.reset()
    progress(f"(b) landmarks, warm-started: {len(frames)} frames, device steps")
    began = time.perf_counter()
    fits = [solver.solve(frame) for frame in frames]
    ours = (time.perf_counter() - began) / len(frames)
    ours_error = max(f.residual for f in fits) / rig_scale(rig)
    reference = frames[: max(8, len(frames) // 8)]
    progress(f"(b) landmarks, warm-started: SciPy on {len(reference)} frames")
    start = np.zeros(len(solver.names))
    began = time.perf_counter()
    evaluations = 0
    worst = 0.0
    for frame in reference:
        start, nfev = scipy_solve(solver, frame, start)
        evaluations += nfev
        x, _ = solver.local.evaluate(start[None], jacobian=False)
        observed = solver.observation.apply_frames(x)[0]
        worst = max(worst, float(np.sqrt(np.mean(np.sum((observed - frame) ** 2, axis=1)))) / rig_scale(rig))
    theirs = (time.perf_counter() - began) / len(reference)
    rows.append(
        {
            "case": "landmarks, warm-started",
            "unit": "frames/s",
            "warpface": 1.0 / ours,
            "scipy": 1.0 / theirs,
            "ratio": theirs / ours,
            "warpface_rms_iod": ours_error,
            "scipy_rms_iod": worst,
            "warpface_iterations": float(np.mean([f.iterations for f in fits])),
            "scipy_evaluations": evaluations / len(reference),
            "frames": len(frames),
        }
    )
    rows.append(
        {
            "case": "landmarks, warm-started, NumPy loop",
            "unit": "frames/s",
            "warpface": 1.0 / host_seconds,
            "scipy": 1.0 / theirs,
            "ratio": theirs / host_seconds,
            "warpface_rms_iod": max(f.residual for f in host_fits) / rig_scale(rig),
            "warpface_iterations": float(np.mean([f.iterations for f in host_fits])),
            "frames": len(frames),
        }
    )

    # Dense fit of one shape (the smile at full intensity), from neutral.
    progress("(b) dense fit of one shape: warpface, then SciPy")
    peak = timeline[len(timeline) // 8 * 7]
    target = model.evaluate(peak).astype(np.float64)
    dense = Solver(rig, device=device, **OPTIONS)
    dense.solve(target)
    dense.reset()
    began = time.perf_counter()
    fit = dense.solve(target)
    ours = time.perf_counter() - began
    began = time.perf_counter()
    controls, nfev = scipy_solve(dense, target, np.zeros(len(dense.names)))
    theirs = time.perf_counter() - began
    x, _ = dense.local.evaluate(controls[None], jacobian=False)
    rows.append(
        {
            "case": "dense fit, one shape",
            "unit": "s",
            "warpface": ours,
            "scipy": theirs,
            "ratio": theirs / ours,
            "warpface_rms_iod": fit.residual / rig_scale(rig),
            "scipy_rms_iod": float(np.sqrt(np.mean(np.sum((x[0] - target) ** 2, axis=1)))) / rig_scale(rig),
            "warpface_iterations": fit.iterations,
            "scipy_evaluations": nfev,
        }
    )

    # Batched: many independent landmark frames at once (from neutral), on the device.
    repeats = int(np.ceil(frames_batched / len(frames)))
    batch = np.tile(frames, (repeats, 1, 1))[:frames_batched]
    results = {}
    for label, on_device in (("NumPy loop", False), ("device steps", True)):
        progress(f"(b) landmarks, batched: {len(batch)} frames, {label} (a warm-up pass, then the timed one)")
        batched = Solver(rig, rig.landmarks, device=device, device_steps=on_device, **OPTIONS)
        batched.solve_batch(batch)  # compile, and allocate every pass size, outside the timing
        wp.synchronize_device(device)
        began = time.perf_counter()
        result = results[label] = batched.solve_batch(batch)
        wp.synchronize_device(device)
        seconds = time.perf_counter() - began
        rows.append(
            {
                "case": f"landmarks, batched ({len(batch)} frames), {label}",
                "unit": "frames/s",
                "warpface": len(batch) / seconds,
                "scipy": None,
                "ratio": None,
                "warpface_rms_iod": float(result.residual.max()) / rig_scale(rig),
                "warpface_iterations": float(result.iterations.mean()),
                "frames": len(batch),
            }
        )
    # Each control's difference as the skin displacement it makes (the solver's scaled controls, IOD).
    gap = float(
        (np.abs(results["NumPy loop"].controls - results["device steps"].controls) * batched.control_scale).max()
    )
    print(f"batched: device steps vs NumPy loop, largest control difference {gap:.1e} IOD of skin motion")
    rows[-1]["max_control_difference_iod"] = gap
    rows[-1]["controls"] = len(batched.names)
    return rows


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default=None, help="Warp device (default: Warp's preferred device)")
    parser.add_argument(
        "--frames",
        type=int,
        default=None,
        help=f"frames of the batched solve (default 512 on CPU, 65536 on CUDA, {QUICK_FRAMES} with --quick)",
    )
    parser.add_argument("--quick", action="store_true", help="fewer shapes and frames (smoke run)")
    parser.add_argument("--skip-shapes", action="store_true", help="skip the real-shape rows")
    args = parser.parse_args(argv)
    wp.config.quiet = True
    device = wp.get_device(args.device)
    frames = args.frames or (QUICK_FRAMES if args.quick else 65536 if device.is_cuda else 512)
    progress(f"solve benchmark on {device.alias}{' (quick)' if args.quick else ''}, {frames} batched frames")
    shapes = [] if args.skip_shapes else real_shapes(device, args.quick)
    if shapes:
        print("(a) ICT-FaceKit shapes: error over moved vertices [mm], before → after (dense | 68 landmarks only)")
        print_table(
            shapes,
            [
                ("shape", "shape", "s"),
                ("moved", "moved", "d"),
                ("before_mean_mm", "before mean", ".2f"),
                ("before_max_mm", "before max", ".2f"),
                ("dense_mean_mm", "dense mean", ".2f"),
                ("dense_max_mm", "dense max", ".2f"),
                ("landmarks_mean_mm", "lmk mean", ".2f"),
                ("landmarks_max_mm", "lmk max", ".2f"),
                ("dense_s", "dense s", ".3f"),
            ],
        )
    rows = speed(device, frames, args.quick)
    print(f"\n(b) speed on the built-in face, device {device.alias} (ratio = warpface speed / SciPy speed)")
    print_table(
        rows,
        [
            ("case", "case", "s"),
            ("unit", "unit", "s"),
            ("warpface", "warpface", ".4g"),
            ("scipy", "scipy", ".4g"),
            ("ratio", "ratio", ".1f"),
            ("warpface_rms_iod", "rms/IOD", ".1e"),
            ("scipy_rms_iod", "scipy rms/IOD", ".1e"),
            ("warpface_iterations", "iterations", ".1f"),
            ("scipy_evaluations", "scipy evals", ".0f"),
        ],
    )
    name = "solve" if device.is_cpu else f"solve_{device.alias.replace(':', '')}"
    path = write_results(
        name,
        {
            "benchmark": "solve",
            "machine": machine_info(device),
            "options": OPTIONS,
            "fd_step_m": FD_STEP,
            "shapes": shapes,
            "speed": rows,
        },
    )
    progress(f"wrote {path}")


if __name__ == "__main__":
    main()
