"""Which way the face looks, on many uneven heads: the symmetry plane and the upright fit, with and without the net
of plane starts (docs/RIG.md §9, step 2).

Heads: the whole ICT head (26.7k vertices, 56 shells) warped — odd seeds by ``smooth_warp`` (width ±6 %, twelve
~5 mm bumps), even seeds by ``bumpy_warp`` (per-axis ±8 %, twenty ~5 mm bumps) — and posed (any yaw, tilt ±30°,
roll ±15°, Y-up or Z-up). The peer is the same fit with the plane started from the skin's principal axes alone
(``PLANE_NET = 0``), run on the same heads in the same process. Reported per variant: the plane's angle to the
truth's left-right axis (the eye corners 36 → 45), how many heads were fitted upside down or turned (up or front
more than ~25° off), and the time of the similarity stage (``fit_similarity``).

    python -m benchmarks.rigging_orientation [--seeds 500:540]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.spatial.transform import Rotation

from warpface.data import ict_landmark_indices, shared_data_path
from warpface.mesh import read_obj_polygons
from warpface.rigging import align, polygons_to_triangles
from warpface.rigging.surface import HeadSurface
from warpface.rigging.template import template

from ._timing import machine_info, print_table, write_results
from .rigging import bumpy_warp, smooth_warp


def head_pose(seed: int) -> Rotation:
    """The turn of the posed head ``seed``: any yaw, tilt ±30°, roll ±15°, then Y-up or (odd draws) Z-up."""
    rng = np.random.default_rng(seed + 9000)
    up = Rotation.from_euler("x", -90.0 if rng.integers(2) else 0.0, degrees=True)
    turn = Rotation.from_euler(
        "yxz", [rng.uniform(-180, 180), rng.uniform(-30, 30), rng.uniform(-15, 15)], degrees=True
    )
    return up * turn


def warped_head(points: np.ndarray, seed: int) -> np.ndarray:
    """The head warped by ``seed`` (odd: smooth, even: bumpy), unturned: (V, 3)."""
    return (smooth_warp if seed % 2 else bumpy_warp)(points, seed)


def posed_head(points: np.ndarray, seed: int) -> np.ndarray:
    """The head warped by ``seed`` (odd: smooth, even: bumpy) and turned by :func:`head_pose`: (V, 3)."""
    return head_pose(seed).apply(warped_head(points, seed))


def measure(seeds: range, net: int) -> dict:
    """Plane angles [°], wrong orientations and similarity time [s] over the heads, with ``net`` plane starts."""
    polygons = read_obj_polygons(shared_data_path("ict_facekit", "original", "generic_neutral_mesh.obj"))
    triangles = polygons_to_triangles(polygons.counts, polygons.indices)
    truth_indices = ict_landmark_indices()
    model = template()
    saved, align.PLANE_NET = align.PLANE_NET, net
    angles, wrong, seconds = [], [], 0.0
    try:
        for seed in seeds:
            points = posed_head(polygons.points, seed)
            truth = points[truth_indices]
            across = (truth[45] - truth[36]) / np.linalg.norm(truth[45] - truth[36])
            up = (truth[27] - truth[8]) / np.linalg.norm(truth[27] - truth[8])
            front = np.cross(across, up)
            surface = HeadSurface(points, triangles, f"seed {seed}")
            skin = surface.points[surface.skin_vertices]
            started = time.perf_counter()
            plane_fit = align.fit_similarity(model, skin, surface.skin_normals)[0]
            seconds += time.perf_counter() - started
            normal = align.skin_symmetry_plane(skin, np.random.default_rng(0))[0]  # the plane fit_similarity used
            angles.append(float(np.degrees(np.arccos(min(1.0, abs(normal @ across))))))
            found_up, found_front = plane_fit.rotation @ model.vertical, plane_fit.rotation @ model.forward
            if found_up @ up < 0.9 or found_front @ front < 0.9:
                wrong.append(seed)
    finally:
        align.PLANE_NET = saved
    return {
        "plane_angle_median_deg": float(np.median(angles)),
        "plane_angle_worst_deg": float(np.max(angles)),
        "plane_off_over_10deg": int(np.sum(np.asarray(angles) > 10.0)),
        "wrong_orientation": len(wrong),
        "wrong_seeds": wrong,
        "similarity_seconds_per_head": seconds / len(seeds),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="500:540", help="FIRST:LAST warp seeds (odd smooth, even bumpy)")
    args = parser.parse_args()
    first, last = (int(part) for part in args.seeds.split(":"))
    seeds = range(first, last)
    rows = [
        {"variant": "principal axes only (peer)", **measure(seeds, 0)},
        {"variant": f"with the net ({align.PLANE_NET} starts)", **measure(seeds, align.PLANE_NET)},
    ]
    rows[1]["time_ratio"] = rows[1]["similarity_seconds_per_head"] / rows[0]["similarity_seconds_per_head"]
    print(f"{len(seeds)} warped, posed whole ICT heads (seeds {first}–{last - 1})")
    print_table(
        rows,
        [
            ("variant", "variant", "s"),
            ("plane_angle_median_deg", "plane ° median", ".1f"),
            ("plane_angle_worst_deg", "worst", ".1f"),
            ("plane_off_over_10deg", "> 10°", "d"),
            ("wrong_orientation", "upside down / turned", "d"),
            ("similarity_seconds_per_head", "similarity s / head", ".2f"),
            ("time_ratio", "× peer", ".2f"),
        ],
    )
    write_results("rigging_orientation", {"machine": machine_info(), "seeds": [first, last], "rows": rows})


if __name__ == "__main__":
    main()
