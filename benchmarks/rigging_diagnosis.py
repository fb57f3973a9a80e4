"""Where the automatic landmarks miss on the warped training heads, and how much of it geometry can see at all.

For each warped ICT head of ``benchmarks/rigging.py``'s training set (smooth warps 1–2, 8 % wider, 10 % flatter,
bumpy warps 101–104) the non-rigid landmarks are found as ``warpface rig`` finds them, and their error against the
carried ground truth [mm] is split:

- per iBUG group, and for the jaw line (iBUG 0–16) into its RMS components *along* the contour (the direction
  between the neighbouring ground-truth jaw points, in the tangent plane), *across* it (in the tangent plane) and
  along the skin's *normal*;
- against the **floor**: the warp's own displacement at the landmarks minus the least-squares affine map of the
  warp fitted on the feature landmarks (iBUG 27–67) or on the whole face region, in the tangent plane. A
  registration sees the surface's shape, not where its material came from: tangential motion of a smooth region
  beyond what the features' affine map explains is invisible to it;
- against the mesh: the mean edge length at the ground-truth jaw vertices (a landmark snaps to a vertex, so a
  point one vertex off costs one edge).

With ``--sample FIRST:LAST`` it runs instead on many posed, warped whole heads (``rigging_orientation``'s: odd seeds
smooth, even bumpy; any yaw, tilt ±30°, roll ±15°, Y- or Z-up), each twice: as warped, and with only the part of the
warp geometry can see — the features' affine map of the warp plus the normal component of what it leaves
(:func:`visible_part`). The pass count (mean ≤ 3 and max ≤ 10 mm, issue 24's goal) of the second set is the
method's own share of the misses; the difference to the first is the warps' invisible motion. Each head's floor
(features' affine map, mean and max over the 68 landmarks) is recorded too, and the warped heads are counted apart
by whether their floor is within the goal: where it is not, the landmarks would miss it even at the features'
exact proportions with every point on the skin. Seeds 600–659 are
development heads (looked at while the method was tuned); fits run in two worker processes. ``--broad`` warps
the sampled heads by ``benchmarks.rigging.broad_warp`` instead (faces farther from the template; to find
failures, results in ``rigging_sample_broad.json``).

    python -m benchmarks.rigging_diagnosis [--sample 600:660 [--broad]]
"""

from __future__ import annotations

import argparse
import functools
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from warpface.data import ict_landmark_indices, shared_data_path
from warpface.mesh import load_obj
from warpface.rigging import find_landmarks
from warpface.rigging.surface import vertex_normals

from ._timing import machine_info, print_table, write_results
from .rigging import GROUPS, broad_warp, bumpy_warp, smooth_warp
from .rigging_orientation import head_pose, warped_head

FACE = 9409
"""Vertices of the ICT face region (the first ones of the whole head)."""
JAW = np.arange(17)


def warped_heads(points: np.ndarray):
    """(name, warped points) of the training set."""
    for seed in (1, 2):
        yield f"smooth warp {seed}", smooth_warp(points, seed)
    yield "8 % wider", points * (1.08, 1.0, 1.0)
    yield "10 % flatter", points * (1.0, 1.0, 0.9)
    for seed in (101, 102, 103, 104):
        yield f"bumpy warp {seed}", bumpy_warp(points, seed)


def non_affine_tangential(rest: np.ndarray, warped: np.ndarray, normals: np.ndarray, fit_on: np.ndarray, at):
    """|tangential part| of ``warped − A(rest)`` at the vertices ``at``, A the affine map fitted on ``fit_on``."""
    rows = np.concatenate([rest[fit_on], np.ones((len(fit_on), 1))], axis=1)
    solution = np.linalg.lstsq(rows, warped[fit_on], rcond=None)[0]
    residual = warped[at] - np.concatenate([rest[at], np.ones((len(at), 1))], axis=1) @ solution
    normal = normals[at]
    return np.linalg.norm(residual - np.sum(residual * normal, axis=1)[:, None] * normal, axis=1)


def visible_part(rest: np.ndarray, warped: np.ndarray, triangles: np.ndarray, fit_on: np.ndarray) -> np.ndarray:
    """``A(rest) + ((warped − A(rest))·n) n``: the warp's least-squares affine map ``A`` fitted on the vertices
    ``fit_on`` plus only the normal part of what it leaves (``n`` the normals of ``A(rest)``), (V, 3). Its
    material moves along the surface only as an affine map of the features does."""
    rows = np.concatenate([rest[fit_on], np.ones((len(fit_on), 1))], axis=1)
    solution = np.linalg.lstsq(rows, warped[fit_on], rcond=None)[0]
    mapped = np.concatenate([rest, np.ones((len(rest), 1))], axis=1) @ solution
    normals = vertex_normals(mapped, triangles)
    return mapped + np.sum((warped - mapped) * normals, axis=1)[:, None] * normals


def jaw_components(found: np.ndarray, truth: np.ndarray, normals: np.ndarray) -> dict[str, float]:
    """RMS of the jaw points' error along the contour, across it (both in the tangent plane) and along the normal."""
    error = found[JAW] - truth[JAW]
    normal = normals[JAW]
    ahead, behind = truth[np.minimum(JAW + 1, 16)], truth[np.maximum(JAW - 1, 0)]
    along = ahead - behind
    along -= np.sum(along * normal, axis=1)[:, None] * normal
    along /= np.linalg.norm(along, axis=1)[:, None]
    across = np.cross(normal, along)
    return {
        name: float(np.sqrt(np.mean(np.sum(error * axis, axis=1) ** 2)))
        for name, axis in (("along", along), ("across", across), ("normal", normal))
    }


def jaw_edge_length(points: np.ndarray, triangles: np.ndarray, vertices: np.ndarray) -> float:
    """Mean length of the mesh edges at ``vertices``."""
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    edges = np.unique(np.sort(edges, axis=1), axis=0)
    touching = np.isin(edges, vertices).any(axis=1)
    return float(np.linalg.norm(points[edges[touching, 0]] - points[edges[touching, 1]], axis=1).mean())


@functools.lru_cache(maxsize=1)
def _whole_head() -> tuple[np.ndarray, np.ndarray]:
    """The whole ICT head (points in cm, triangles), read once per worker process."""
    return load_obj(shared_data_path("ict_facekit", "original", "generic_neutral_mesh.obj"))


def sample_errors(seed: int, broad: bool = False) -> dict:
    """Landmark errors [mm] on the posed head ``seed``, as warped and with its visible part only."""
    rest, triangles = _whole_head()
    truth = ict_landmark_indices()
    warped = broad_warp(rest, seed) if broad else warped_head(rest, seed)
    floor = non_affine_tangential(rest, warped, vertex_normals(warped, triangles), truth[27:], truth) * 10.0
    row = {"seed": seed, "floor": {"mean_mm": float(floor.mean()), "max_mm": float(floor.max())}}
    for label, shape in (("warped", warped), ("visible", visible_part(rest, warped, triangles, truth[27:]))):
        posed = head_pose(seed).apply(shape)
        try:
            found = find_landmarks(posed, triangles, label=f"seed {seed}")
        except ValueError as refusal:  # counted as a miss: no face found
            row[label] = {"mean_mm": float("inf"), "max_mm": float("inf"), "worst": -1, "refused": str(refusal)}
            continue
        error = np.linalg.norm(posed[found.indices] - posed[truth], axis=1) * 10.0  # cm → mm
        row[label] = {"mean_mm": float(error.mean()), "max_mm": float(error.max()), "worst": int(error.argmax())}
    return row


def within_goal(errors: list[dict]) -> np.ndarray:
    """Per entry of ``errors`` (dicts with ``mean_mm`` and ``max_mm``), whether it meets issue 24's goal: mean ≤ 3 and
    max ≤ 10 mm, (N,) bool."""
    return np.array([error["mean_mm"] <= 3.0 and error["max_mm"] <= 10.0 for error in errors], dtype=bool)


def sample(first: int, last: int, broad: bool = False) -> None:
    """Pass counts over the posed heads ``first … last − 1``, as warped and visible only (module docstring)."""
    with ProcessPoolExecutor(max_workers=2) as pool:
        heads = []
        for row in pool.map(functools.partial(sample_errors, broad=broad), range(first, last)):
            heads.append(row)
            print(
                f"seed {row['seed']}: "
                + ", ".join(f"{k} {row[k]['mean_mm']:.2f} / {row[k]['max_mm']:.1f} mm" for k in ("warped", "visible")),
                flush=True,
            )
    rows = []
    for label in ("warped", "visible"):
        means = np.array([head[label]["mean_mm"] for head in heads])
        maxima = np.array([head[label]["max_mm"] for head in heads])
        rigged = np.isfinite(means)
        jaw_worst = sum(0 <= head[label]["worst"] < 17 for head in heads if head[label]["max_mm"] > 10.0)
        rows.append(
            {
                "heads": f"{label} ({len(heads)})",
                "refused": int(np.sum(~rigged)),
                "mean_of_means_mm": float(means[rigged].mean()),
                "median_max_mm": float(np.median(maxima)),
                "pass": int(within_goal([head[label] for head in heads]).sum()),
                "mean_within": int(np.sum(means <= 3.0)),
                "max_over_10_at_jaw": int(jaw_worst),
                "max_over_10": int(np.sum(maxima > 10.0)),
            }
        )
    # the floor: the truth's own slide along the skin beyond the features' affine map (module docstring); a head whose
    # floor misses the goal would miss it with the features' proportions known exactly and every point on the skin
    floor_within = within_goal([head["floor"] for head in heads])
    passed = within_goal([head["warped"] for head in heads])
    rows[0]["floor_within"] = int(floor_within.sum())
    rows[0]["pass_where_floor_within"] = int(np.sum(passed & floor_within))
    rows[0]["pass_where_floor_misses"] = int(np.sum(passed & ~floor_within))
    print(f"posed whole ICT heads, {'broad' if broad else 'smooth and bumpy'} warps, seeds {first}–{last - 1}")
    print_table(
        rows,
        [
            ("heads", "heads", "s"),
            ("refused", "no face found", "d"),
            ("mean_of_means_mm", "mean of means mm (found)", ".2f"),
            ("median_max_mm", "median max mm", ".1f"),
            ("pass", "mean ≤ 3 and max ≤ 10", "d"),
            ("mean_within", "mean ≤ 3", "d"),
            ("max_over_10", "max > 10", "d"),
            ("max_over_10_at_jaw", "of which at the jaw", "d"),
        ],
    )
    print(
        f"as warped: {rows[0]['floor_within']} heads whose floor is within the goal, of which "
        f"{rows[0]['pass_where_floor_within']} pass; {rows[0]['pass_where_floor_misses']} of the other "
        f"{len(heads) - rows[0]['floor_within']} pass too"
    )
    path = write_results(
        "rigging_sample_broad" if broad else "rigging_sample",
        {"machine": machine_info("cpu"), "seeds": [first, last], "rows": rows, "heads": heads},
    )
    print(f"results: {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sample", help="FIRST:LAST seeds of posed, warped whole heads instead of the training set")
    parser.add_argument("--broad", action="store_true", help="with --sample: benchmarks.rigging.broad_warp heads")
    args = parser.parse_args()
    ict = shared_data_path("ict_facekit", "original", "generic_neutral_mesh.obj")
    if ict is None:
        raise SystemExit("ICT-FaceKit not found in ../shared/data (set WARPFACE_SHARED_DATA)")
    if args.sample:
        first, last = (int(part) for part in args.sample.split(":"))
        sample(first, last, broad=args.broad)
        return
    truth = ict_landmark_indices()
    rest, triangles = load_obj(ict)
    mm = 10.0  # the ICT head is in cm
    rows = []
    for name, warped in warped_heads(rest):
        found = find_landmarks(warped, triangles, label=name)
        normals = vertex_normals(warped, triangles)
        error = np.linalg.norm(warped[found.indices] - warped[truth], axis=1) * mm
        row = {"head": name, "mean_mm": float(error.mean()), "max_mm": float(error.max())}
        row.update({f"{group}_mm": float(error[where].mean()) for group, where in GROUPS.items()})
        parts = jaw_components(warped[found.indices], warped[truth], normals[truth])
        row.update({f"jaw_{key}_mm": value * mm for key, value in parts.items()})
        for label, fit_on in (("features", truth[27:]), ("face", np.arange(FACE))):
            floor = non_affine_tangential(rest, warped, normals, fit_on, truth) * mm
            row.update({f"floor_{label}_{group}_mm": float(floor[where].mean()) for group, where in GROUPS.items()})
        row["jaw_edge_mm"] = jaw_edge_length(warped, triangles, truth[JAW]) * mm
        rows.append(row)
        print(f"{name}: done", flush=True)
    print_table(
        rows,
        [
            ("head", "head", "s"),
            ("mean_mm", "mean mm", ".2f"),
            ("max_mm", "max mm", ".1f"),
            *((f"{group}_mm", group, ".1f") for group in GROUPS),
            ("jaw_along_mm", "jaw along", ".1f"),
            ("jaw_across_mm", "jaw across", ".1f"),
            ("jaw_normal_mm", "jaw normal", ".2f"),
            ("floor_features_jaw_mm", "floor jaw (feat.)", ".1f"),
            ("floor_face_jaw_mm", "floor jaw (face)", ".1f"),
            ("floor_features_mouth_mm", "floor mouth (feat.)", ".1f"),
            ("jaw_edge_mm", "jaw edge", ".1f"),
        ],
    )
    path = write_results("rigging_diagnosis", {"machine": machine_info("cpu"), "rows": rows})
    print(f"results: {path}")


if __name__ == "__main__":
    main()
