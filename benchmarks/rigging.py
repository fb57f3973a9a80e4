"""Automatic landmarks on real heads: error against ground truth [mm] and time to find them, rigid vs non-rigid.

Heads (from ``../shared/data``): the ICT-FaceKit face region (cm, triangles), the whole ICT head
(cm, quads, 56 shells: eyes, teeth, gums, sockets) and the menpo ``james`` scan (mm, its landmarks
reordered from menpo's grouping to iBUG). Without ``--quick``, the whole ICT head also runs turned
(35° yaw, 15° tilt), Z-up, in metres and with shuffled vertex order, and Lee Perry-Smith (no ground
truth: its unit, confidence and time only), two smooth random warps of the ICT head (stand-ins for
other identities, with the ICT ground truth carried along) and the ICT head 8 % wider and 10 % flatter
(other proportions: what the affine stages of the registration are for) and four rougher "bumpy" warps
(:func:`bumpy_warp`). These are the heads the method is chosen on. ``--held-out`` runs five other warped
heads instead (three bumpy, two smooth, each turned, tilted, in another unit and shuffled): report them
once per method change, never tune on them. The Spearman rank correlation of landmark error and confidence
over all landmarks is printed per method.

Two methods in the same run: **rigid** — the similarity and affine fits of the template alone (symmetry
plane, orientation search, scale, proportions) with its landmarks carried over unchanged — and **non-rigid** — the same
followed by non-rigid ICP (the default, docs/RIG.md). The template's landmark points are calibrated on
the ICT neutral (``--calibrate`` recomputes them), so the ICT rows measure the registration's
consistency on that face; ``james`` is held out and follows menpo's annotation of the jaw and brows.

    python -m benchmarks.rigging [--quick] [--held-out] [--calibrate]
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from scipy.stats import spearmanr

from warpface.data import ict_landmark_indices, shared_data_path
from warpface.landmarks import IBUG_MIRROR
from warpface.mesh import load_obj
from warpface.rigging import find_landmarks
from warpface.rigging.detect import register
from warpface.rigging.template import template

from ._timing import machine_info, print_table, write_results

GROUPS = {
    "jaw": slice(0, 17),
    "brows": slice(17, 27),
    "nose": slice(27, 36),
    "eyes": slice(36, 48),
    "mouth": slice(48, 68),
}
"""iBUG landmark groups whose mean error is reported separately [mm]."""

MENPO_TO_IBUG = np.r_[0:17, 29:34, 43:48, 34:43, 17:23, 23:29, 48:68]
"""james.ljson: chin, eyes (subject's right first), brows, nose, mouth → iBUG order."""


def smooth_warp(points: np.ndarray, seed: int) -> np.ndarray:
    """A stand-in for another identity: the width scaled by ±6 % and 12 Gaussian bumps (σ 3 cm, ~5 mm each)."""
    rng = np.random.default_rng(seed)
    face = points[:9409]  # the ICT face region's vertices
    centres = rng.uniform(face.min(axis=0), face.max(axis=0), (12, 3))
    amplitudes = rng.normal(0.0, 0.5, (12, 3))
    weights = np.exp(-np.sum((points[:, None, :] - centres[None]) ** 2, axis=2) / (2.0 * 3.0**2))
    return points * [1.0 + (0.06 if seed % 2 else -0.06), 1.0, 1.0] + weights @ amplitudes


def bumpy_warp(points: np.ndarray, seed: int) -> np.ndarray:
    """A rougher stand-in: per-axis scale ±8 % about the face and 20 Gaussian bumps (σ 2.5 cm, ~5 mm each)."""
    rng = np.random.default_rng(seed)
    face = points[:9409]
    centres = rng.uniform(face.min(axis=0), face.max(axis=0), (20, 3))
    amplitudes = rng.normal(0.0, 0.5, (20, 3))
    weights = np.exp(-np.sum((points[:, None, :] - centres[None]) ** 2, axis=2) / (2.0 * 2.5**2))
    centre = face.mean(axis=0)
    return (points - centre) * (1.0 + rng.uniform(-0.08, 0.08, 3)) + centre + weights @ amplitudes


def broad_warp(points: np.ndarray, seed: int, symmetric: bool = True) -> np.ndarray:
    """A head farther from the template: per-axis scale ±10 %, six broad Gaussian bumps (σ 4 cm, ~1.4 cm each)
    and the nose tip and the chin (iBUG 30, 8) pushed ~9 mm each way; ``symmetric`` mirrors every bump and push
    through the ICT head's mid-plane (x = 0; faces are near mirror-symmetric, so the proportions vary but the
    features stay level). Only to look for failures, not to tune on: bumps this broad bend the neck and, unmirrored,
    tilt the features ~10° against the skull and shift the jaw line by up to a centimetre along the face."""
    rng = np.random.default_rng(seed)
    face = points[:9409]
    landmarks = points[ict_landmark_indices()]
    centre = face.mean(axis=0)
    scale = 1.0 + rng.uniform(-0.10, 0.10, 3)
    warped = (points - centre) * scale + centre
    centres = rng.uniform(face.min(axis=0), face.max(axis=0), (6, 3))
    amplitudes = rng.normal(0.0, 0.8, (6, 3))
    pushes = [(landmarks[landmark], sigma, rng.normal(0.0, 0.5, 3)) for landmark, sigma in ((30, 1.5), (8, 2.0))]
    mirror = np.array([-1.0, 1.0, 1.0])
    if symmetric:
        centres = np.vstack([centres, centres * mirror])
        amplitudes = np.vstack([amplitudes, amplitudes * mirror]) / np.sqrt(2.0)
        pushes = [
            (where, sigma, push / np.sqrt(2.0))
            for original, sigma, once in pushes
            for where, push in ((original * mirror, once * mirror), (original, once))
        ]
    weights = np.exp(-np.sum((points[:, None, :] - centres[None]) ** 2, axis=2) / (2.0 * 4.0**2))
    warped += weights @ amplitudes
    for where, sigma, push in pushes:
        warped += np.exp(-np.sum((points - where) ** 2, axis=1) / (2.0 * sigma**2))[:, None] * push
    return warped


def posed(points: np.ndarray, triangles: np.ndarray, truth: np.ndarray, seed: int, per_cm: float):
    """The head turned (any yaw, tilt ±30°, roll ±15°), Z-up for odd draws, in another unit, moved and with its
    vertices shuffled: (points, triangles, ground-truth points)."""
    rng = np.random.default_rng(seed)
    yaw, tilt, roll = rng.uniform(-180.0, 180.0), rng.uniform(-30.0, 30.0), rng.uniform(-15.0, 15.0)
    up = Rotation.from_euler("x", -90.0 if rng.integers(2) else 0.0, degrees=True)
    moved = (up * Rotation.from_euler("yxz", [yaw, tilt, roll], degrees=True)).apply(points) * per_cm
    moved += rng.normal(0.0, 50.0 * per_cm, 3)
    order = rng.permutation(len(points))
    return moved[order], np.argsort(order)[triangles], moved[truth]


def held_out_heads():
    """Warped ICT heads never used to choose or tune the method (docs/RIG.md §9): three bumpy warps posed in
    cm, m and mm and two smooth warps posed in cm."""
    truth = ict_landmark_indices()
    points, triangles = load_obj(shared_data_path("ict_facekit", "original", "generic_neutral_mesh.obj"))
    for seed, (unit, per_cm) in zip((201, 202, 203), (("cm", 1.0), ("m", 0.01), ("mm", 10.0))):
        moved, shuffled, marks = posed(bumpy_warp(points, seed), triangles, truth, seed, per_cm)
        yield f"held out: bumpy warp {seed}, posed ({unit})", moved, shuffled, marks, 10.0 / per_cm
    for seed in (3, 4):
        moved, shuffled, marks = posed(smooth_warp(points, seed), triangles, truth, seed, 1.0)
        yield f"held out: smooth warp {seed}, posed (cm)", moved, shuffled, marks, 10.0


def heads(quick: bool):
    """(name, points, triangles, ground-truth points or None, mm per unit)."""
    ict = shared_data_path("ict_facekit")
    if ict is not None:
        truth = ict_landmark_indices()
        points, triangles = load_obj(ict / "face_region_tri" / "neutral.obj")
        yield "ICT face region (cm)", points, triangles, points[truth], 10.0
        points, triangles = load_obj(ict / "original" / "generic_neutral_mesh.obj")
        yield "ICT whole head (cm, quads, shells)", points, triangles, points[truth], 10.0
        if not quick:
            turn = Rotation.from_euler("xyz", [-90.0 + 15.0, 0.0, 35.0], degrees=True)
            moved = turn.apply(points) * 0.01
            order = np.random.default_rng(0).permutation(len(points))
            yield (
                "ICT head turned, Z-up, m, shuffled",
                moved[order],
                np.argsort(order)[triangles],
                moved[truth],
                1000.0,
            )
            for seed in (1, 2):
                warped = smooth_warp(points, seed)
                yield f"ICT head, smooth warp {seed} (cm)", warped, triangles, warped[truth], 10.0
            for label, factor in (("8 % wider", (1.08, 1.0, 1.0)), ("10 % flatter", (1.0, 1.0, 0.9))):
                scaled = points * factor
                yield f"ICT head, {label} (cm)", scaled, triangles, scaled[truth], 10.0
            for seed in (101, 102, 103, 104):
                warped = bumpy_warp(points, seed)
                yield f"ICT head, bumpy warp {seed} (cm)", warped, triangles, warped[truth], 10.0
    james = shared_data_path("menpo3d_james")
    if james is not None:
        points, triangles = load_obj(james / "james.obj")
        data = json.loads((james / "james.ljson").read_text())
        truth = np.asarray(data["groups"]["LJSON"]["landmarks"]["points"])[MENPO_TO_IBUG]
        yield "james scan (mm)", points, triangles, truth, 1.0
    lee = shared_data_path("lee_perry_smith", "LeePerrySmith.obj")
    if lee is not None and not quick:
        points, triangles = load_obj(lee)
        yield "Lee Perry-Smith (no truth)", points, triangles, None, None


def calibrate(rounds: int = 3) -> np.ndarray:
    """The template's landmark points in the ICT annotation's convention: the ICT neutral's ground-truth
    landmarks mapped back through the registration onto the undeformed template, made mirror-symmetric.
    The registration's second pass depends on the points themselves (its affine map is read off the
    feature landmarks), so the mapping is repeated ``rounds`` times from the points it gave."""
    model = template()
    points, triangles = load_obj(shared_data_path("ict_facekit", "face_region_tri", "neutral.obj"))
    for _ in range(rounds):
        fitted = register(points, triangles, model=model)
        truth = fitted.to_local(points[ict_landmark_indices()])
        nearest = cKDTree(fitted.deformed.points).query(truth)[1]
        maps = fitted.deformed.maps[model.cell[nearest]]
        back = np.stack([np.linalg.solve(m[:3].T, t - m[3]) for m, t in zip(maps, truth)])
        # the fit started from the template moved to the head's profile (docs/RIG.md §9, step 5a): undo that move
        nearest_shaped = cKDTree(fitted.shaped.points).query(back)[1]
        back -= fitted.shaped.points[nearest_shaped] - model.points[nearest_shaped]
        back = 0.5 * (back + back[np.asarray(IBUG_MIRROR)] * [-1.0, 1.0, 1.0])
        print(f"calibration round: points moved {np.abs(back - model.landmark_points).max():.4f} d at most")
        vertices = np.argmin(np.linalg.norm(model.points[None] - back[:, None], axis=2), axis=1)
        model = replace(model, landmark_points=back, landmark_vertices=vertices, landmark_nodes=model.cell[vertices])
    return model.landmark_points


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the three heads with ground truth only")
    parser.add_argument("--calibrate", action="store_true", help="print the calibrated LANDMARK_POINTS table")
    parser.add_argument("--held-out", action="store_true", help="the held-out warped heads only (report them once)")
    args = parser.parse_args()
    if args.calibrate:
        table = calibrate()
        print("LANDMARK_POINTS = np.array(\n    (")
        for row in range(0, 68, 3):
            print("        " + " ".join("(%.4f, %.4f, %.4f)," % tuple(p) for p in table[row : row + 3]))
        print("    )\n)")
        return
    started = time.perf_counter()
    template()  # built once per process (~1.5 s): not charged to the first head
    print(f"template built in {time.perf_counter() - started:.1f} s")
    rows, pooled = [], {"rigid": ([], []), "non-rigid": ([], [])}
    for name, points, triangles, truth, mm in held_out_heads() if args.held_out else heads(args.quick):
        for method, nonrigid in (("rigid", False), ("non-rigid", True)):
            found = find_landmarks(points, triangles, nonrigid=nonrigid, label=name)
            row = {
                "head": name,
                "vertices": len(points),
                "method": method,
                "units": found.units,
                "seconds": found.seconds,
                "confidence": float(found.confidence.mean()),
            }
            if truth is not None:
                error = np.linalg.norm(points[found.indices] - truth, axis=1) * mm
                row.update(mean_mm=float(error.mean()), max_mm=float(error.max()), worst=int(np.argmax(error)))
                row.update(features_mm=float(error[27:].mean()))
                row.update({f"{group}_mm": float(error[where].mean()) for group, where in GROUPS.items()})
                pooled[method][0].append(error)
                pooled[method][1].append(found.confidence)
            rows.append(row)
    print_table(
        rows,
        [
            ("head", "head", "s"),
            ("vertices", "V", "d"),
            ("method", "method", "s"),
            ("units", "unit", "s"),
            ("mean_mm", "mean mm", ".2f"),
            ("max_mm", "max mm", ".1f"),
            ("worst", "worst iBUG", "d"),
            ("features_mm", "27-67 mm", ".2f"),
            *((f"{group}_mm", group, ".1f") for group in GROUPS),
            ("confidence", "conf", ".2f"),
            ("seconds", "time s", ".2f"),
        ],
    )
    ranks = {}
    for method, (errors, confidences) in pooled.items():
        if errors:
            ranks[method] = float(spearmanr(np.concatenate(errors), np.concatenate(confidences))[0])
            print(f"{method}: Spearman rank correlation of landmark error and confidence {ranks[method]:+.2f}")
    name = "rigging_held_out" if args.held_out else "rigging"
    path = write_results(name, {"machine": machine_info("cpu"), "rows": rows, "error_confidence_spearman": ranks})
    print(f"results: {path}")


if __name__ == "__main__":
    main()
