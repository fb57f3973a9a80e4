"""Automatic landmarks on cropped faces: template points past the mesh's open boundary charged at most ``BEYOND``
in the similarity score (docs/RIG.md §9, step 3, "Cropped faces") against the full ``MISS`` (the tree before), in
the same run.

Heads: the ICT-FaceKit face region (cm) with its triangles above, beside or behind a cut removed (the vertices stay,
so the ground truth keeps its indices; a landmark cut off the mesh cannot be found, and its error counts).

    python -m benchmarks.rigging_crops
"""

from __future__ import annotations

import numpy as np

from warpface.data import ict_landmark_indices, shared_data_path
from warpface.mesh import load_obj
from warpface.rigging import align, find_landmarks
from warpface.rigging.template import template

from ._timing import machine_info, print_table, write_results


def crops():
    """(name, points, triangles kept, ground-truth points) of the ICT face region cut at its features."""
    points, triangles = load_obj(shared_data_path("ict_facekit", "face_region_tri", "neutral.obj"))
    truth = points[ict_landmark_indices()]
    brows, nose, jaw = truth[17:27, 1].mean(), truth[30, 1], np.abs(truth[[0, 16], 0]).mean()
    front = points[:, 2].max()
    cuts = {
        "whole face region": np.ones(len(points), bool),
        "forehead cut 1 cm above the brows": points[:, 1] < brows + 1.0,
        "forehead cut at the brows": points[:, 1] < brows,
        "forehead cut 1 cm below the brows": points[:, 1] < brows - 1.0,
        "sides cut at the jaw's ends": np.abs(points[:, 0]) < jaw,
        "only 8 cm behind the nose tip": points[:, 2] > front - 8.0,
        "only below the nose": points[:, 1] < nose + 0.5,
    }
    for name, kept in cuts.items():
        yield name, points, triangles[kept[triangles].all(axis=1)], truth


def main() -> None:
    template()  # built once per process: not charged to the first head
    default, rows = align.BEYOND, []
    for name, points, triangles, truth in crops():
        row = {"head": name, "triangles": len(triangles)}
        for label, charge in (("beyond", default), ("miss", align.MISS)):
            align.BEYOND = charge
            try:
                found = find_landmarks(points, triangles, label=name)
            except ValueError:
                row[f"{label}_mean_mm"] = row[f"{label}_max_mm"] = float("nan")
                row[f"{label}_note"] = "refused"
                continue
            finally:
                align.BEYOND = default
            error = np.linalg.norm(points[found.indices] - truth, axis=1) * 10.0
            row.update({f"{label}_mean_mm": float(error.mean()), f"{label}_max_mm": float(error.max())})
            row[f"{label}_seconds"] = found.seconds
        rows.append(row)
    print_table(
        rows,
        [
            ("head", "ICT face region", "s"),
            ("triangles", "T", "d"),
            ("beyond_mean_mm", f"BEYOND {default:g} mean", ".2f"),
            ("beyond_max_mm", "max", ".1f"),
            ("miss_mean_mm", f"MISS {align.MISS:g} (before) mean", ".2f"),
            ("miss_max_mm", "max", ".1f"),
            ("beyond_seconds", "time s", ".2f"),
            ("miss_seconds", "before s", ".2f"),
        ],
    )
    path = write_results("rigging_crops", {"machine": machine_info("cpu"), "rows": rows})
    print(f"results: {path}")


if __name__ == "__main__":
    main()
