"""How much of a real expression the default rig can reach: fit its controls to ICT-FaceKit shapes.

For each expression shape of ``../shared/data/ict_facekit/face_region_tri`` (delta = shape − neutral)
the default rig, placed on the ICT face from its 68 landmarks, is fitted with :func:`warpface.solve.fit`
(Levenberg–Marquardt on the exact Jacobian of the full pipeline: jaw → muscles → stretch → bulge →
wrinkles; default options, muscles and the jaw's three controls). Two fits per shape:

- **dense**: every vertex is a target;
- **landmarks**: only the 68 landmark vertices are targets.

Reported per shape, over the *moved* vertices (|delta| > 0.2 mm): mean and max error before (the
neutral face) and after the fit, and the reduction of the mean. A peer column fits the same shapes
with the §1.1 rig of the first issue (``--compare``: Waters falloffs, no sliding, bunching or jaw).

    python -m benchmarks.rig_reach [--shapes jawOpen eyeSquint_L] [--compare]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
import warp as wp

import warpface as wf
from warpface import FaceRig
from warpface.assets import default_rig
from warpface.assets.rig import rig_scale
from warpface.data import ict_face_region, ict_landmark_indices
from warpface.solve import fit

from ._timing import machine_info, print_table, write_results

SHAPES = ("browInnerUp_L", "browInnerUp_R", "browOuterUp_L", "browOuterUp_R", "eyeSquint_L", "eyeSquint_R", "jawOpen")
CENTIMETRE = 0.01
MOVED_MM = 0.2


def load_face():
    neutral_path, landmarks = ict_face_region(), ict_landmark_indices()
    if neutral_path is None or landmarks is None:
        return None, None
    source = wf.FaceMesh.from_obj(neutral_path)
    return wf.FaceMesh(source.points * CENTIMETRE, source.triangles, name="ict_face"), landmarks


def errors(points: np.ndarray, target: np.ndarray, moved: np.ndarray) -> tuple[float, float]:
    distance = np.linalg.norm(points[moved] - target[moved], axis=1) * 1000.0
    return float(distance.mean()), float(distance.max())


def reach(rig, mesh, landmarks, shapes, device, dense_only: bool = False) -> list[dict]:
    model = rig.model(device=device)
    scale = rig_scale(rig)
    results = []
    for shape in shapes:
        target = wf.FaceMesh.from_obj(ict_face_region(shape)).points * CENTIMETRE
        delta = np.linalg.norm(target - mesh.points, axis=1) * 1000.0
        moved = delta > MOVED_MM
        before_mean, before_max = errors(mesh.points, target, moved)
        row = {"shape": shape, "moved": int(moved.sum()), "before_mean_mm": before_mean, "before_max_mm": before_max}
        fits = (("dense", None),) if dense_only else (("dense", None), ("landmarks", np.asarray(landmarks)))
        for label, rows in fits:
            started = time.perf_counter()
            solved = fit(rig, target if rows is None else target[rows], vertices=rows, device=device)
            controls = solved.vector
            after_mean, after_max = errors(solved.points.astype(np.float64), target, moved)
            row[f"{label}_mean_mm"] = after_mean
            row[f"{label}_max_mm"] = after_max
            row[f"{label}_reduction"] = 1.0 - after_mean / before_mean
            row[f"{label}_seconds"] = time.perf_counter() - started
            row[f"{label}_converged"] = bool(solved.converged)
            size = np.abs(controls) / np.where(
                np.array([n.startswith("jaw_") for n in model.control_names]), 1.0, scale
            )
            top = np.argsort(-size)[:4]
            row[f"{label}_top"] = {model.control_names[i]: float(size[i]) for i in top}
        results.append(row)
    return results


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--shapes", nargs="*", default=list(SHAPES))
    parser.add_argument("--device", default="cpu")
    parser.add_argument(
        "--compare", action="store_true", help="also fit the classic rig (§1.1 zones, 23 muscles, no jaw)"
    )
    parser.add_argument(
        "--response",
        nargs="*",
        default=[],
        metavar="S,B",
        help="also fit the full rig with every muscle's sliding S and bunching B replaced",
    )
    parser.add_argument("--dense-only", action="store_true", help="skip the landmark fits")
    args = parser.parse_args(argv)
    wp.config.quiet = True
    mesh, landmarks = load_face()
    if mesh is None:
        print("ICT-FaceKit data not found in ../shared/data (set WARPFACE_SHARED_DATA); nothing to measure")
        return 0
    rigs = {"default": default_rig(mesh, landmarks, name="ICTFace", device=args.device)}
    if args.compare:
        rigs["classic"] = default_rig(mesh, landmarks, name="ICTFace", device=args.device, anatomy="classic")
    for pair in args.response:
        sliding, bunching = (float(v) for v in pair.split(","))
        base = rigs["default"]
        muscles = [replace(m, sliding=sliding, bunching=bunching) for m in base.muscles]
        rigs[f"s={sliding:g},b={bunching:g}"] = FaceRig(
            mesh=mesh,
            muscles=muscles,
            wrinkles=base.wrinkles,
            thickness=base.thickness,
            landmarks=base.landmarks,
            name=base.name,
            jaw=base.jaw,
        )
    payload = {"machine": machine_info(args.device), "moved_mm": MOVED_MM, "rigs": {}}
    for label, rig in rigs.items():
        rows = reach(rig, mesh, landmarks, args.shapes, args.device, dense_only=args.dense_only)
        payload["rigs"][label] = {"controls": len(rig.model(device=args.device).control_names), "rows": rows}
        print(f"\n{label} rig ({payload['rigs'][label]['controls']} controls), error over moved vertices [mm]:")
        print_table(
            rows,
            [
                ("shape", "shape", "s"),
                ("moved", "moved", "d"),
                ("before_mean_mm", "mean before", ".3f"),
                ("before_max_mm", "max before", ".2f"),
                ("dense_mean_mm", "dense mean", ".3f"),
                ("dense_max_mm", "dense max", ".2f"),
                ("dense_reduction", "dense red.", ".1%"),
                ("landmarks_mean_mm", "lmk mean", ".3f"),
                ("landmarks_max_mm", "lmk max", ".2f"),
                ("landmarks_reduction", "lmk red.", ".1%"),
            ],
        )
        for row in rows:
            print(f"  {row['shape']}: dense top {', '.join(f'{k}={v:.3f}' for k, v in row['dense_top'].items())}")
    path = write_results("rig_reach", payload)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
