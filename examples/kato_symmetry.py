"""Kato's heterogeneous-material experiment (SPEC §2.1, §4): does a scar change the face's symmetry?

The tissue under a face is tetrahedralised (thickness from the default thickness map), the upper
face (brows and forehead) is fixed, and the mouth is opened by driving four lip points and three
chin points along a jaw rotation (1.3 s at dt = 1 ms). The same motion is simulated with Kato's
three material models — healthy (1), a stiffer right crista philtri superior (2, a scar) and a
softer one (3) — with the locking-free average-nodal-pressure tets, and the left/right symmetry
cost ξ_cost(t) = log|ξ_L − ξ_R| of the landmark distances from each mouth corner is plotted for
the three models, with ξ_L − ξ_R and its change from model 1 (the tet mesh is not mirror-symmetric,
so the healthy face is a little asymmetric too; the change isolates the material's effect). A
heat map shows where model 2's surface moves differently from model 1's.

    python examples/kato_symmetry.py [--face builtin|ict|all] [--quick] [--out out/kato_symmetry]

By default the built-in face runs, and the ICT-FaceKit face as well when ../shared/data has it
(its narrow face region, converted from centimetres to metres). ICT's render surface cannot be
thickened as it is — nostril cavities, lid and lip margins curling into the head, lips crossing
at the mouth corners — so its tissue is built from a cleaned proxy of the surface
(:func:`warpface.fem.proxy.tissue_proxy`: hidden and inward-facing parts removed, nostrils and
eyes capped, the mouth kept open) and the original surface is embedded in that tissue, its
removed parts bound to their nearest tets. ``--quick`` uses coarser tissue meshes.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")

import warpface as wf  # noqa: E402
from warpface.assets import default_face, default_landmarks, default_thickness  # noqa: E402
from warpface.data import ict_face_region, ict_landmark_indices  # noqa: E402
from warpface.fem import KATO_MODELS, TissueBatch  # noqa: E402
from warpface.fem.embedding import embed_points  # noqa: E402
from warpface.fem.proxy import tissue_proxy  # noqa: E402
from warpface.fem.regions import kato_material_model, kato_regions  # noqa: E402
from warpface.fem.volume import mesh_tissue  # noqa: E402
from warpface.metrics import kato_landmarks, symmetry  # noqa: E402

DT = 1.0e-3
"""Time step [s] (thesis, heterogeneous experiment)."""
DURATION = 1.3
"""Simulated time [s] (thesis)."""
MIN_THICKNESS = 0.002
"""Tissue thinner than this [m] (eyelids in the thickness map) is raised to it: a few tets must fit."""
DRIVEN_LIPS = (51, 62, 57, 66)
"""iBUG points driven on the lips: upper lip top and inner midpoint, lower lip bottom and inner midpoint.
The mouth corners (48, 54), the cupid's-bow peaks (50, 52) and the nose wings stay free: they are
what ξ measures."""
DRIVEN_JAW = (7, 8, 9)
"""iBUG points driven on the jaw line: the chin and its neighbours."""
OPEN_DEG = 10.0
"""Peak jaw rotation [deg]: about 2 cm of chin travel."""
ICT_NARROW_FACE_VERTICES = 6706
"""ICT-FaceKit's narrow face region is vertices 0..6705 (all 68 landmarks lie in it)."""
UPPER_LIP_SHARE = -0.12
"""The upper lip rotates by this fraction of the jaw angle (it lifts slightly as the mouth opens)."""


FAIR_FOLDS = 10
"""Rounds of local fairing the mesher may apply to a proxy's coarsened surface (ICT needs 1-4)."""


@dataclass
class Face:
    name: str
    mesh: wf.FaceMesh
    landmarks: np.ndarray
    """The 68 iBUG vertex indices."""
    proxy: bool = False
    """Build the tissue from a cleaned proxy of the surface (render surfaces with cavities and curls)."""


def load_faces(which: str) -> list[Face]:
    faces = []
    if which in ("builtin", "all", "auto"):
        faces.append(Face("builtin", default_face(), default_landmarks()))
    if which in ("ict", "all", "auto"):
        path, indices = ict_face_region("neutral"), ict_landmark_indices()
        if path is None or indices is None:
            if which != "auto":
                raise SystemExit("the ICT face is not in ../shared/data (set WARPFACE_SHARED_DATA)")
        else:
            raw = wf.FaceMesh.from_obj(path)
            # the "narrow face" (vertices 0-6705, README of the data): no ears or neck; cm -> m
            narrow = raw.triangles[(raw.triangles < ICT_NARROW_FACE_VERTICES).all(axis=1)]
            mesh = wf.FaceMesh(raw.points[:ICT_NARROW_FACE_VERTICES] * 0.01, narrow, name="ict")
            faces.append(Face("ict", mesh, indices, proxy=True))
    return faces


def opening_angle(t: np.ndarray) -> np.ndarray:
    """Jaw rotation [rad] over time: opens over 0.05–0.35 s, holds, closes over 0.75–1.05 s."""

    def smoothstep(a, b):
        s = np.clip((t - a) / (b - a), 0.0, 1.0)
        return s * s * (3.0 - 2.0 * s)

    return np.radians(OPEN_DEG) * (smoothstep(0.05, 0.35) - smoothstep(0.75, 1.05))


def rotate_about_x(points: np.ndarray, hinge: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Displacements (T, P, 3) of points rotated by ``angles`` (T,) about the x axis through ``hinge``;
    a positive angle swings the chin down and back (mouth opening)."""
    rel = points - hinge
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    y = c * rel[None, :, 1] + s * rel[None, :, 2]
    z = -s * rel[None, :, 1] + c * rel[None, :, 2]
    moved = np.stack([np.broadcast_to(rel[:, 0], y.shape), y, z], axis=2) + hinge
    return moved - points


def run_face(face: Face, args) -> dict:
    out = args.out
    ibug = face.mesh.points[face.landmarks]
    print(f"\n=== {face.name} face: {face.mesh.vertex_count} vertices ===")
    thickness = np.maximum(default_thickness(face.mesh, face.landmarks, device="cpu"), MIN_THICKNESS)
    if face.proxy:
        # the eyes are capped too: lids resting on a closed opening (as on the eyeball) instead of
        # holes whose pointed corners an inward offset cannot follow; the mouth stays open
        eyes = np.stack([ibug[36:42].mean(axis=0), ibug[42:48].mean(axis=0)])
        start = time.perf_counter()
        proxy = tissue_proxy(face.mesh, thickness, close_near=eyes, device="cpu")
        print(f"proxy: {proxy} ({time.perf_counter() - start:.2f} s)")
        meshing = mesh_tissue(
            (proxy.points, proxy.triangles),
            proxy.thickness,
            target_nodes=args.nodes,
            fair_folds=FAIR_FOLDS,
            device="cpu",
        )
        # removed parts (nostril interiors, inner lips, lid margins) lie off the tissue: bind them to
        # their nearest tet
        reach = proxy.max_deviation + meshing.report.edge_length
    else:
        meshing = mesh_tissue(face.mesh, thickness, target_nodes=args.nodes, device="cpu")
        reach = None
    tetmesh = meshing.tetmesh
    print(f"tissue: {meshing.report}")
    embedding = embed_points(tetmesh, face.mesh, max_distance=reach, device="cpu")
    print(
        f"embedding: {embedding.outside_count} of {embedding.point_count} vertices outside the tets "
        f"(at most {1e3 * embedding.distances.max():.2f} mm), bound to the nearest tet"
    )

    # boundary conditions: fixed brows and forehead; lips and chin driven by a jaw rotation
    brow_y = ibug[17:27, 1].mean()
    fixed = np.flatnonzero(tetmesh.points[:, 1] > brow_y)
    lip_nodes = embedding.nodes_for(face.landmarks[list(DRIVEN_LIPS)])
    jaw_nodes = embedding.nodes_for(face.landmarks[list(DRIVEN_JAW)])
    driven = np.unique(np.r_[lip_nodes, jaw_nodes])
    upper = np.isin(driven, lip_nodes[:2])
    eye_y = ibug[36:48, 1].mean()
    height = eye_y - ibug[8, 1]
    hinge = np.array([0.0, eye_y - 0.3 * height, ibug[30, 2] - height])  # near the jaw joints
    steps = int(round(DURATION / DT))
    times = DT * np.arange(1, steps + 1)
    angle = opening_angle(times)
    trajectory = np.where(
        upper[None, :, None],
        rotate_about_x(tetmesh.points[driven], hinge, UPPER_LIP_SHARE * angle),
        rotate_about_x(tetmesh.points[driven], hinge, angle),
    )
    chin_travel = np.linalg.norm(trajectory[:, ~upper], axis=2).max()
    print(
        f"{len(fixed)} fixed nodes (above y = {brow_y * 1e3:.1f} mm), {len(driven)} driven nodes "
        f"(chin travel up to {chin_travel * 1e3:.1f} mm), {steps} steps of {DT * 1e3:g} ms"
    )

    # landmark tracks need only the nodes of the landmark vertices' tets
    landmark_embedding = embedding.subset(face.landmarks)
    record = np.unique(landmark_embedding.nodes)
    local = landmark_embedding.on_nodes(record)
    landmarks_at_rest = kato_landmarks(ibug)
    regions = kato_regions(tetmesh, landmarks_at_rest)
    print("regions (tets): " + ", ".join(f"{k} {int(v.sum())}" for k, v in regions.items()))

    results = {}
    materials = [kato_material_model(tetmesh, landmarks_at_rest, model) for model in KATO_MODELS]
    for model in KATO_MODELS:  # the thesis's tables 6.4-6.5 (warpface.fem.presets)
        print(
            f"model {model}: right cphs E = {KATO_MODELS[model]['E']['cphs_R'] / 1e3:.1f} kPa, "
            f"eta = {KATO_MODELS[model]['eta']['cphs_R']:.1f} Pa s"
        )
    # the three models as one batch: one graph per step for all of them on CUDA, one direct solver each on the CPU
    start = time.perf_counter()
    batch = TissueBatch(tetmesh, materials, DT, fixed=fixed, driven=driven, formulation="anp", device=args.device)
    setup = time.perf_counter() - start
    snapshot_every = 10
    tracks = np.empty((steps, batch.model_count, len(record), 3))
    snapshots = []
    start = time.perf_counter()
    for begin in range(0, steps, snapshot_every):  # displacements of every node, kept every 10th step
        block = batch.run(trajectory[begin : begin + snapshot_every])  # (k, models, N, 3)
        tracks[begin : begin + len(block)] = block[:, :, record]
        snapshots.append(block[-1])
    elapsed = time.perf_counter() - start
    snapshots = np.stack(snapshots, axis=1)  # (models, S, N, 3)
    print(
        f"{batch}: set-up {setup:.2f} s, {elapsed / steps * 1e3:.2f} ms/step for {batch.model_count} models "
        f"({elapsed / steps / batch.model_count * 1e3:.2f} ms/step/model)"
    )
    window = (times >= 0.2) & (times <= 0.6)
    for index, model in enumerate(KATO_MODELS):
        # iBUG landmark positions over time: rest + displacement interpolated in their tets
        moved = ibug[None] + local.apply(tracks[:, index], device="cpu")
        result = symmetry(kato_landmarks(np.concatenate([ibug[None], moved])))  # frame 0: rest (t0)
        results[model] = {
            "cost": result.cost[1:],
            "xi_left": result.xi_left[1:],
            "xi_right": result.xi_right[1:],
            "snapshots": snapshots[index],
        }
        print(f"model {model}: mean ξ_cost over 0.2–0.6 s = {results[model]['cost'][window].mean():.3f}")

    _plot(face.name, times, angle, results, out / f"{face.name}_xi_cost.png")
    difference = np.linalg.norm(results[2]["snapshots"] - results[1]["snapshots"], axis=2)  # (S, N)
    worst_frame = int(np.argmax(difference.max(axis=1)))
    node_difference = results[2]["snapshots"][worst_frame] - results[1]["snapshots"][worst_frame]
    surface_difference = np.linalg.norm(embedding.apply(node_difference.astype(np.float64), device="cpu"), axis=1)
    shown = face.mesh.points + embedding.apply(results[1]["snapshots"][worst_frame].astype(np.float64), device="cpu")
    from warpface import preview

    t_worst = (worst_frame + 1) * snapshot_every * DT
    path = out / f"{face.name}_model2_vs_model1.png"
    preview.render_heat_map(
        shown,
        face.mesh.triangles,
        surface_difference,
        path,
        title=f"|u2 - u1| at t = {t_worst:.2f} s (model 1 shape)",
        units="mm",
        scale=1e3,
    )
    print(
        f"model 2 vs 1: largest surface difference {surface_difference.max() * 1e3:.3f} mm at t = {t_worst:.2f} s "
        f"-> {path}"
    )
    np.savez(
        out / f"{face.name}_xi.npz",
        time=times,
        angle=angle,
        **{f"cost_{m}": r["cost"] for m, r in results.items()},
        **{f"xi_left_{m}": r["xi_left"] for m, r in results.items()},
        **{f"xi_right_{m}": r["xi_right"] for m, r in results.items()},
    )
    return results


def _plot(name: str, times, angle, results, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = {1: "model 1 (healthy)", 2: "model 2 (stiff right cphs: scar)", 3: "model 3 (soft right cphs)"}
    styles = {1: "-", 2: "--", 3: "-."}
    colors = {1: "C0", 2: "C1", 3: "C2"}
    fig, (top, middle, change, bottom) = plt.subplots(
        4, 1, figsize=(8, 10), sharex=True, gridspec_kw={"height_ratios": [3, 2, 2, 1]}
    )
    # the tet mesh is not mirror-symmetric, so even the healthy face moves a little asymmetrically;
    # on ICT that baseline dwarfs the material's effect, so the jaw's hold is also shown enlarged
    # (inset) and the effect itself as the change from model 1
    held = (times >= 0.35) & (times <= 0.75)
    inset = top.inset_axes([0.38, 0.07, 0.33, 0.40])
    baseline = results[1]["xi_left"] - results[1]["xi_right"]
    for model in (1, 2, 3):
        r = results[model]
        asymmetry = r["xi_left"] - r["xi_right"]
        # before the jaw moves both ξ are exactly 0 and ξ_cost is undefined (SPEC §4: t != t0): leave a gap
        cost = np.where(np.abs(asymmetry) > 1e-12, r["cost"], np.nan)
        style = dict(ls=styles[model], color=colors[model], lw=1.4)
        top.plot(times, cost, label=labels[model], **style)
        inset.plot(times[held], cost[held], **style)
        middle.plot(times, 1e3 * asymmetry, label=labels[model], **style)
        change.plot(times, 1e3 * (asymmetry - baseline), label=labels[model], **style)
    for axis in (top, middle, change):
        axis.axvspan(0.2, 0.6, color="0.92", zorder=0)
        axis.grid(alpha=0.3)
    inset.set_title("jaw held open, 0.35–0.75 s", fontsize=8)
    inset.tick_params(labelsize=7)
    inset.grid(alpha=0.3)
    top.set_ylabel(r"$\xi_{cost} = \log|\xi_L - \xi_R|$")
    top.set_title(f"Left/right symmetry of the mouth-opening motion ({name} face)")
    top.legend(loc="lower left", fontsize=8)
    for axis in (middle, change):
        axis.axhline(0.0, color="k", lw=0.6)
    middle.set_ylabel(r"$(\xi_L - \xi_R) \times 10^3$")
    change.set_ylabel("change from\nmodel 1 $\\times 10^3$")
    bottom.plot(times, np.degrees(angle), color="k", lw=1.2)
    bottom.set_ylabel("jaw [deg]")
    bottom.set_xlabel("time [s]")
    bottom.grid(alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.stem}.partial.png")
    fig.savefig(temporary, dpi=120)
    os.replace(temporary, path)
    plt.close(fig)
    print(f"ξ_cost plot -> {path}")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--face",
        choices=("auto", "builtin", "ict", "all"),
        default="auto",
        help="which face (auto: built-in, plus ICT when its data is present)",
    )
    parser.add_argument("--out", type=Path, default=Path("out/kato_symmetry"), help="output folder")
    parser.add_argument("--nodes", type=int, default=None, help="target tet nodes (default 6400, --quick 2500)")
    parser.add_argument("--quick", action="store_true", help="coarser tissue mesh for a fast run")
    parser.add_argument(
        "--device",
        default=None,
        help="Warp device of the simulation (default: Warp's preferred; "
        "CUDA steps the three models as one batched graph)",
    )
    args = parser.parse_args(argv)
    if args.nodes is None:
        args.nodes = 2500 if args.quick else 6400
    args.out.mkdir(parents=True, exist_ok=True)
    import warp as wp

    wp.config.quiet = True
    start = time.perf_counter()
    for face in load_faces(args.face):
        run_face(face, args)
    print(f"\ndone in {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()
