"""Automatic landmarks on low-poly heads: the skin's edge midpoints in the similarity fit (docs/RIG.md §9, step 2)
against its own vertices only, in the same run.

Heads: MediaPipe's canonical face (468 vertices, face only, cm; no iBUG annotation: error at the 11 points
MediaPipe names as iBUG does, :data:`NAMED_ALIKE`), and the whole ICT head and its smooth warp 1
(:func:`benchmarks.rigging.smooth_warp`) decimated by vertex clustering (:func:`clustered`) to 1.5k–7k vertices, their
error against the original ground-truth points. A landmark is a vertex, so a coarse head cannot come nearer than its
nearest vertex to each truth point: the *floor* column.

    python -m benchmarks.rigging_lowpoly
"""

from __future__ import annotations

import numpy as np

from warpface.data import ict_landmark_indices, shared_data_path
from warpface.geometry.triangles import vertex_shells
from warpface.mesh import load_obj
from warpface.rigging import find_landmarks, surface
from warpface.rigging.template import template

from ._timing import machine_info, print_table, write_results
from .rigging import smooth_warp

NAMED_ALIKE = {27: 168, 33: 2, 36: 33, 39: 133, 42: 362, 45: 263, 48: 61, 51: 0, 54: 291, 57: 17, 62: 13}
"""iBUG point → the canonical face's vertex MediaPipe names the same place (eye and mouth corners, nose bridge and
base, lip centres). Left out where the two conventions differ: MediaPipe's nose tip (vertex 1) lies 6.7 mm below the
face's most forward point, where iBUG 30 is; its chin (152) is the menton, iBUG 8 in front of it; and the closed
mouth's inner lip centres 13 and 14 are one place to the surface, but two vertices 5.8 mm apart."""
CELLS_CM = (0.6, 1.0, 1.5)
"""Clustering cell sizes [cm] of the decimated ICT heads."""


def clustered(points: np.ndarray, triangles: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """The mesh decimated by vertex clustering: the vertices of one shell in one grid cell of side ``cell`` become
    their mean (shells apart, so an eyelid never joins its eyeball), triangles that collapse are dropped:
    (points, triangles)."""
    shells = vertex_shells(triangles, len(points))
    keys = np.column_stack([np.floor(points / cell).astype(np.int64), shells])
    cluster = np.unique(keys, axis=0, return_inverse=True)[1].ravel()
    count = int(cluster.max()) + 1
    means = np.zeros((count, 3))
    np.add.at(means, cluster, points)
    means /= np.bincount(cluster, minlength=count)[:, None]
    merged = cluster[triangles]
    kept = (merged[:, 0] != merged[:, 1]) & (merged[:, 1] != merged[:, 2]) & (merged[:, 0] != merged[:, 2])
    merged = np.unique(merged[kept], axis=0)
    used = np.unique(merged)
    renumber = np.full(count, -1, dtype=np.int64)
    renumber[used] = np.arange(len(used))
    return means[used], renumber[merged]


def heads():
    """(name, points, triangles, landmarks measured (iBUG numbers), their truth points, mm per unit)."""
    mediapipe = shared_data_path("mediapipe", "canonical_face_model.obj")
    if mediapipe is not None:
        points, triangles = load_obj(mediapipe)
        named = np.array(list(NAMED_ALIKE))
        yield "MediaPipe canonical face", points, triangles, named, points[list(NAMED_ALIKE.values())], 10.0
    if shared_data_path("ict_facekit") is None:
        return
    truth = ict_landmark_indices()
    points, triangles = load_obj(shared_data_path("ict_facekit", "original", "generic_neutral_mesh.obj"))
    for label, shape in (("ICT head", points), ("ICT head, smooth warp 1", smooth_warp(points, 1))):
        for cell in CELLS_CM:
            coarse, faces = clustered(shape, triangles, cell)
            yield f"{label}, {cell:g} cm cells", coarse, faces, np.arange(68), shape[truth], 10.0


def main() -> None:
    template()  # built once per process: not charged to the first head
    default, rows = surface.MIN_FIT_POINTS, []
    for name, points, triangles, measured, truth, mm in heads():
        floor = np.min(np.linalg.norm(points[None] - truth[:, None], axis=2), axis=1) * mm
        skin = len(surface.HeadSurface(points, triangles).skin_vertices)
        row = {"head": name, "vertices": len(points), "skin": skin, "floor_mean_mm": float(floor.mean())}
        for label, minimum in (("midpoints", default), ("own", 0)):
            surface.MIN_FIT_POINTS = minimum
            try:
                found = find_landmarks(points, triangles, label=name)
            except ValueError as refusal:
                row[f"{label}_refused"] = str(refusal)
                continue
            finally:
                surface.MIN_FIT_POINTS = default
            error = np.linalg.norm(points[found.indices[measured]] - truth, axis=1) * mm
            row.update({f"{label}_mean_mm": float(error.mean()), f"{label}_max_mm": float(error.max())})
            row[f"{label}_seconds"] = found.seconds
        if "midpoints_seconds" in row and "own_seconds" in row:
            row["time_ratio"] = row["midpoints_seconds"] / row["own_seconds"]
        rows.append(row)
    print_table(
        rows,
        [
            ("head", "head", "s"),
            ("vertices", "V", "d"),
            ("skin", "skin V", "d"),
            ("floor_mean_mm", "floor mm", ".2f"),
            ("midpoints_mean_mm", "midpoints mean", ".2f"),
            ("midpoints_max_mm", "max", ".1f"),
            ("own_mean_mm", "own vertices mean", ".2f"),
            ("own_max_mm", "max", ".1f"),
            ("midpoints_seconds", "time s", ".2f"),
            ("own_seconds", "own vertices s", ".2f"),
            ("time_ratio", "time ratio", ".2f"),
        ],
    )
    for row in rows:
        for label in ("midpoints", "own"):
            if f"{label}_refused" in row:
                print(f"{row['head']}, {label}: refused: {row[f'{label}_refused']}")
    path = write_results("rigging_lowpoly", {"machine": machine_info("cpu"), "rows": rows})
    print(f"results: {path}")


if __name__ == "__main__":
    main()
