"""``warpface calibrate RIG --shapes DIR|FILES... --out CALIBRATED``: learn a rig's muscle geometry from example shapes.

Fit the rig's controls to every example shape (OBJ files with the rig's topology, or folders of them), move each
muscle's ends, zone, falloff and skin response (the same for both sides, in the landmark frame) to reduce what
the fits cannot reach, and write the calibrated rig stage, a JSON report (per-shape reach before/after, training
and held-out) and a picture. A calibration that does not improve the fit writes the input rig and says so
(docs/RIG.md §13).
"""

from __future__ import annotations

from pathlib import Path

from .common import add_command

__all__ = ["add_parser", "run_calibrate"]

_RIG_SUFFIXES = (".usda", ".usdc", ".usd")


def add_parser(subparsers, common) -> None:
    """Register ``calibrate`` on the CLI's sub-parsers (``common``: the shared options)."""
    parser = add_command(subparsers, common, "calibrate", run_calibrate, __doc__)
    parser.add_argument("rig", metavar="RIG", help="rig stage (.usda/.usdc) with the 68 iBUG landmarks")
    parser.add_argument("--shapes", nargs="+", required=True, help="example shapes: OBJ files or folders of them")
    parser.add_argument(
        "--names", choices=("file", "arkit"), default="file", help="read shape names as ARKit names (checked)"
    )
    parser.add_argument("--out", required=True, help="calibrated rig stage to write (.usda/.usdc)")
    parser.add_argument("--report", default=None, help="JSON report (default: <out>_calibration.json)")
    parser.add_argument("--picture", default=None, help="PNG of per-shape reach (default: <out>_calibration.png)")
    parser.add_argument("--holdout", nargs="*", default=[], help="shape names measured but not trained on")
    parser.add_argument("--iterations", type=int, default=4, help="Gauss-Newton iterations (default 4)")
    parser.add_argument(
        "--shape-scale", type=float, default=1.0, help="multiply OBJ coordinates by this to get the rig stage's units"
    )
    parser.add_argument("--landmarks", action="store_true", help="also report the reach of landmark-only fits")


def _checked_paths(args) -> tuple[Path, Path, Path, Path]:
    rig_path, out = Path(args.rig), Path(args.out)
    if rig_path.suffix.lower() not in _RIG_SUFFIXES:
        raise ValueError(f"{rig_path}: a rig stage must be .usda, .usdc or .usd")
    if not rig_path.is_file():
        raise ValueError(f"{rig_path}: file not found")
    if out.suffix.lower() not in (".usda", ".usdc"):
        raise ValueError(f"--out {out}: must end in .usda or .usdc")
    report = Path(args.report) if args.report else out.with_name(f"{out.stem}_calibration.json")
    picture = Path(args.picture) if args.picture else out.with_name(f"{out.stem}_calibration.png")
    if report.suffix.lower() != ".json":
        raise ValueError(f"--report {report}: must end in .json")
    if picture.suffix.lower() != ".png":
        raise ValueError(f"--picture {picture}: must end in .png")
    if args.iterations < 0:
        raise ValueError(f"--iterations: expected >= 0, got {args.iterations}")
    for path in (out, report, picture):
        if path.is_dir():
            raise ValueError(f"{path}: is a folder, not a file")
    return rig_path, out, report, picture


def run_calibrate(args) -> int:
    """Handler of ``warpface calibrate`` (errors raise ValueError for the CLI to report in one line)."""
    from ..calibration import calibrate, read_shapes, write_report
    from ..usd import open_stage, read_rig, stage_meters_per_unit, write_rig

    rig_path, out, report, picture = _checked_paths(args)
    stage = open_stage(rig_path)
    units = stage_meters_per_unit(stage)
    rig = read_rig(stage, meters_per_unit=units)
    shapes = read_shapes(args.shapes, rig, names=args.names, scale=args.shape_scale)
    millimetre = 1e-3 / units
    result = calibrate(
        rig,
        shapes,
        holdout=args.holdout,
        millimetre=millimetre,
        iterations=args.iterations,
        landmarks=args.landmarks,
        device=args.device,
        log=None if args.quiet else print,
    )
    write_rig(str(out), result.rig, meters_per_unit=units)
    data = write_report(result, report, picture=picture, millimetre=millimetre)
    for split, pair in data["reach"].items():
        print(
            f"{split}: mean reach {pair['before']['mean_reduction']:.1%} -> {pair['after']['mean_reduction']:.1%} "
            f"({len(pair['before']['shapes'])} shapes)"
        )
    print(result.message)
    print(f"wrote {out}, {report}, {picture}")
    return 0
