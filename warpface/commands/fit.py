"""``warpface fit TARGET... --rig face.usda``: solve muscle contractions for shapes, store them as presets on the
rig stage.

Fit the rig of --rig to each TARGET (OBJ, or a USD stage with a mesh of the rig's topology), write the controls
as named presets on the rig stage, print per-region error before/after in mm and the controls used, and render a
heat map of the remaining error.

Each target (an OBJ, or a USD stage whose mesh has the rig's vertex count) is fitted densely (or from
the rig's landmarks only with ``--landmarks``); the controls are written as a named preset on the rig
stage (:mod:`warpface.usd.presets_io`), the error before/after is printed per face region in mm,
with the controls used, and a heat map of the remaining error is rendered per target.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .common import add_command

__all__ = ["add_parser", "run_fit", "REGIONS", "region_labels"]

REGIONS = {
    "jaw line": range(0, 17),
    "brows": range(17, 27),
    "nose": range(27, 36),
    "eyes": range(36, 48),
    "mouth": range(48, 68),
}
"""Face regions by the iBUG-68 landmarks nearest to a vertex."""


def add_parser(subparsers, common) -> None:
    """Register ``fit`` on the CLI's sub-parsers (``common``: the shared options)."""
    fit = add_command(subparsers, common, "fit", run_fit, __doc__)
    fit.add_argument(
        "targets", nargs="+", metavar="TARGET", help="shape(s) with the rig's topology (.obj, .usda/.usdc/.usd)"
    )
    fit.add_argument(
        "--rig", required=True, help="rig stage (.usda/.usdc) written by warpface; presets are added to it"
    )
    fit.add_argument(
        "--name",
        action="append",
        default=None,
        help="preset name per target, in order (default: the target's file name without extension)",
    )
    fit.add_argument(
        "--target-scale",
        type=float,
        default=1.0,
        help="multiply OBJ coordinates by this to get the rig stage's units (e.g. 0.01 for cm -> m)",
    )
    fit.add_argument("--landmarks", action="store_true", help="fit from the rig's landmark vertices only")
    fit.add_argument("--symmetry", type=float, default=0.0, help="left/right symmetry weight (default 0)")
    fit.add_argument("--out", default=None, help="folder for heat maps (default: <rig>_fit next to the rig)")
    fit.add_argument("--no-images", action="store_true", help="skip the heat-map pictures")


def region_labels(points: np.ndarray, landmarks) -> tuple[list[str], np.ndarray]:
    """Region names and each vertex's region index (nearest landmark's group); one region without landmarks."""
    if landmarks is None or len(landmarks) != 68:
        return ["face"], np.zeros(len(points), dtype=np.int64)
    from scipy.spatial import cKDTree

    group = np.empty(68, dtype=np.int64)
    for index, indices in enumerate(REGIONS.values()):
        group[list(indices)] = index
    _, nearest = cKDTree(points[landmarks]).query(points)
    return list(REGIONS), group[nearest]


def _load_target(path: Path, rig, scale: float, stage_units: float) -> np.ndarray:
    """Points (V, 3) of a target in the rig stage's units; ValueError naming the file on any mismatch."""
    if not path.is_file():
        raise ValueError(f"{path}: file not found")
    if path.suffix.lower() == ".obj":
        from ..mesh import load_obj

        points, triangles = load_obj(path)
        points = points * scale
        if len(points) == rig.mesh.vertex_count and (
            triangles.shape != rig.mesh.triangles.shape or not np.array_equal(triangles, rig.mesh.triangles)
        ):
            raise ValueError(f"{path}: same vertex count as the rig but different triangles (topology differs)")
    else:
        from pxr import Usd, UsdGeom

        from ..usd import open_stage, stage_meters_per_unit

        stage = open_stage(path)
        meshes = [UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
        sized = [m for m in meshes if len(m.GetPointsAttr().Get(Usd.TimeCode.Default()) or []) == rig.mesh.vertex_count]
        if not sized:
            counts = ", ".join(str(len(m.GetPointsAttr().Get() or [])) for m in meshes) or "no meshes"
            raise ValueError(f"{path}: no mesh with the rig's {rig.mesh.vertex_count} vertices ({counts})")
        points = np.asarray(sized[0].GetPointsAttr().Get(Usd.TimeCode.Default()), dtype=np.float64)
        points = points * (stage_meters_per_unit(stage) / stage_units)
    if points.shape != rig.mesh.points.shape:
        raise ValueError(f"{path}: {len(points)} vertices, the rig has {rig.mesh.vertex_count} (topology mismatch)")
    if not np.all(np.isfinite(points)):
        raise ValueError(f"{path}: non-finite coordinates")
    return points


def run_fit(args) -> int:
    """Handler of ``warpface fit`` (returns the exit code; errors raise ValueError for the CLI to report)."""
    from ..solve import Solver
    from ..usd import export_layer_atomically, open_stage, read_rig, stage_meters_per_unit
    from ..usd.presets_io import write_presets

    rig_path = Path(args.rig)
    stage = open_stage(rig_path)
    units = stage_meters_per_unit(stage)
    rig = read_rig(stage, meters_per_unit=units)
    mm = units * 1000.0
    names = args.name or [Path(t).stem for t in args.targets]
    if len(names) != len(args.targets):
        raise ValueError(f"--name: {len(names)} names for {len(args.targets)} targets")
    if args.landmarks and rig.landmarks is None:
        raise ValueError(f"{rig_path}: --landmarks needs a rig with landmark indices")
    targets = [_load_target(Path(t), rig, args.target_scale, units) for t in args.targets]
    vertices = rig.landmarks if args.landmarks else None
    solver = Solver(rig, vertices, device=args.device, symmetry=args.symmetry, lip_rolls=True)  # as fit()
    region_names, region = region_labels(rig.mesh.points, rig.landmarks)
    out = Path(args.out) if args.out else rig_path.with_name(f"{rig_path.stem}_fit")
    presets, residuals = {}, {}
    for name, target_path, target in zip(names, args.targets, targets):
        solver.reset()
        fit = solver.solve(target if vertices is None else target[vertices])
        before = np.linalg.norm(target - rig.mesh.points, axis=1) * mm
        after = np.linalg.norm(fit.points - target, axis=1) * mm
        presets[name] = {k: v for k, v in fit.controls.items() if v != 0.0}
        residuals[name] = fit.residual
        status = "converged" if fit.converged else "NOT converged (best iterate kept)"
        print(
            f"{target_path} -> preset {name!r}: {status} in {fit.iterations} iterations, RMS {fit.residual * mm:.3f} mm"
        )
        print(f"  {'region':<10} {'vertices':>8} {'before mean':>11} {'max':>7} {'after mean':>10} {'max':>7}   [mm]")
        for index, region_name in enumerate(region_names):
            rows = region == index
            if rows.any():
                print(
                    f"  {region_name:<10} {int(rows.sum()):>8} {before[rows].mean():>11.3f} {before[rows].max():>7.3f} "
                    f"{after[rows].mean():>10.3f} {after[rows].max():>7.3f}"
                )
        print(
            f"  {'all':<10} {len(before):>8} {before.mean():>11.3f} {before.max():>7.3f} {after.mean():>10.3f} "
            f"{after.max():>7.3f}"
        )
        used = sorted(presets[name].items(), key=lambda item: -abs(item[1]))
        print("  controls: " + (", ".join(f"{k} {v:.4g}" for k, v in used) if used else "none (neutral)"))
        if not args.no_images:
            from .. import preview

            out.mkdir(parents=True, exist_ok=True)
            image = out / f"{name}_error.png"
            from .face_view import face_view_of

            view = face_view_of(rig) or (lambda points: points)  # a rig of any axes drawn upright
            camera = preview.Camera.framing(view(rig.mesh.points), yaw_deg=15.0, pitch_deg=5.0)
            preview.render_heat_map(
                view(fit.points),
                rig.mesh.triangles,
                after,
                image,
                camera=camera,
                title=f"{name}: |fit - target|",
                units="mm",
            )
            print(f"  heat map {image}")
    write_presets(stage, presets, residuals=residuals, meters_per_unit=units)
    export_layer_atomically(stage.GetRootLayer(), rig_path)
    print(f"wrote {len(presets)} preset(s) to {rig_path}: {', '.join(presets)}")
    return 0
