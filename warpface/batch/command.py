"""``warpface batch MANIFEST --out DIR``: many takes at once (animate, track, fit), on this machine or a Ray cluster.

Run every take of MANIFEST (TOML, JSON or CSV: id,input,kind[,rig,mapping,options]) into DIR/<id>/, each
complete or absent, with DIR/report.json, the contact sheet DIR/report.png and DIR/shoot.usda (every completed
take as a variant of one character). A re-run skips unchanged complete takes (--force redoes them); exit code 1
when a take failed.
"""

from __future__ import annotations

__all__ = ["add_parser", "run"]


def add_parser(subparsers, common):
    """Register ``batch`` on the CLI's sub-parsers (``common``: the shared options); returns the parser."""
    from ..commands.common import add_command, positive_int
    from .runner import ENGINES

    parser = add_command(subparsers, common, "batch", run, __doc__)
    parser.add_argument("manifest", help="takes: .toml, .json or .csv (header id,input,kind[,rig,mapping,options])")
    parser.add_argument("--out", required=True, help="output folder: one sub-folder per take, report, shoot.usda")
    parser.add_argument(
        "--engine", choices=ENGINES, default="local", help="local worker processes (default) or Ray tasks"
    )
    parser.add_argument(
        "--address", default=None, help="with --engine ray: the cluster's address (default: RAY_ADDRESS, else local)"
    )
    parser.add_argument("--force", action="store_true", help="redo takes that are complete and unchanged")
    parser.add_argument(
        "--jobs", type=positive_int, default=None, help="takes at once (local engine; default: cores, or CUDA devices)"
    )
    return parser


def run(args) -> int:
    """The ``batch`` command's handler: a summary line, one line per failed take; exit code 1 when one failed."""
    from .runner import run as run_batch

    options = {name: getattr(args, name) for name in ("engine", "address", "force", "jobs", "device")}
    result = run_batch(args.manifest, args.out, progress=not args.quiet, **options)
    for entry in result.failed:
        print(f"failed {entry['id']}: {entry['error']}")
    print(
        f"batch: {result.count('done')} done, {result.count('skipped')} skipped, {result.count('failed')} failed "
        f"of {len(result.takes)} takes"
    )
    print(f"  report {result.report}")
    print(f"  sheet  {result.sheet}")
    if result.shoot is not None:
        print(f"  shoot  {result.shoot}")
    return 1 if result.failed else 0
