"""Rig-time cost, this tree against another checkout in the same run: what a user waits for before the first frame.

Rows (seconds, wall, on the CPU):

- ``warpface rig`` of the whole ICT head (26.7k vertices, quads, 56 shells) as a user types it: the command in a
  fresh process, interpreter start and imports included;
- inside one process: :func:`~warpface.rigging.find_landmarks` on that head (the registration template built
  beforehand), :func:`~warpface.assets.default_rig` on the built-in face, the ICT face region, the whole ICT head
  (the skin and its 55 other shells in one mesh, as ``warpface animate --rig`` builds it for that head) and the Lee
  Perry-Smith scan (its landmarks found), ``rig.model(device="cpu")`` on each (the rig-time fields: tissue
  response, fold and lift guards, the lips' seal), and then the solver's operators of the same rig, which ``fit`` and
  ``track --solve`` build beside the model (they read the same rig-time fields); on a tree with the fields' cache, the
  whole head's model once more in a fresh process's place, its fields read from a cache folder (the peer has no such
  row).

The peer is the same measurement of ``--before TREE`` (a checkout of an earlier commit, e.g. ``git worktree add
/tmp/before <commit>``), run in alternation with this tree, ``--rounds`` times each, medians reported with the
ratio before / after: the machines here are shared and noisy, so only a ratio from one run means anything.

    python -m benchmarks.rig_build --before /tmp/before [--rounds 3]
    python -m benchmarks.rig_build --measure [--tree TREE]   # one round of the in-process rows as JSON
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ._timing import machine_info, print_table, write_results

ROOT = Path(__file__).resolve().parent.parent
HEAD = ("ict_facekit", "original", "generic_neutral_mesh.obj")
PEERS = {"model build, whole ICT head, fields from the cache": "model build, whole ICT head"}
"""Rows the tree before has no form of, each measured against another row of this tree in the same run."""


def measure(tree: Path) -> dict[str, float]:
    """One round of the in-process rows, with warpface imported from ``tree`` [s]."""
    sys.path.insert(0, str(tree))
    import warp as wp

    wp.config.quiet = True
    from warpface.assets import default_face, default_landmarks, default_rig
    from warpface.data import ict_landmark_indices, shared_data_path
    from warpface.mesh import FaceMesh, load_obj
    from warpface.rigging import find_landmarks
    from warpface.rigging.template import template
    from warpface.solve.local_model import RigOperators

    try:
        from warpface.expression.rig_fields import forget_rig_fields

        has_cache = True
    except ImportError:  # a tree from before the fields were shared: nothing kept, no cache
        has_cache = False

        def forget_rig_fields():
            return None

    template()
    rows: dict[str, float] = {}
    points, triangles = load_obj(shared_data_path(*HEAD))
    started = time.perf_counter()
    find_landmarks(points, triangles)
    rows["find_landmarks, whole ICT head"] = time.perf_counter() - started
    faces = [("built-in face", default_face(), default_landmarks())]
    points, triangles = load_obj(shared_data_path("ict_facekit", "face_region_tri", "neutral.obj"))
    faces.append(("ICT face", FaceMesh(points, triangles, degenerate="ignore"), ict_landmark_indices()))
    points, triangles = load_obj(shared_data_path(*HEAD))
    faces.append(("whole ICT head", FaceMesh(points, triangles, degenerate="ignore"), ict_landmark_indices()))
    points, triangles = load_obj(shared_data_path("lee_perry_smith", "LeePerrySmith.obj"))
    found = find_landmarks(points, triangles).indices
    faces.append(("Lee Perry-Smith", FaceMesh(points, triangles, degenerate="ignore"), found))
    default_rig(*faces[0][1:], device="cpu").model(device="cpu")  # kernels loaded before the clock runs
    for name, mesh, landmarks in faces:
        started = time.perf_counter()
        rig = default_rig(mesh, landmarks, device="cpu")
        rows[f"default_rig, {name}"] = time.perf_counter() - started
        forget_rig_fields()  # the warm-up's built-in rig computed afresh too
        started = time.perf_counter()
        rig.model(device="cpu")
        rows[f"model build, {name}"] = time.perf_counter() - started
        started = time.perf_counter()
        RigOperators.from_rig(rig, device="cpu")  # what `fit` and `track --solve` build beside the model
        rows[f"solver operators after the model, {name}"] = time.perf_counter() - started
    if has_cache:  # a later command on the whole head: its fields read from the cache folder
        with tempfile.TemporaryDirectory() as folder:
            os.environ["WARPFACE_CACHE"] = folder
            rig = default_rig(faces[2][1], faces[2][2], device="cpu")
            forget_rig_fields()
            rig.model(device="cpu")  # computed and written
            forget_rig_fields()
            started = time.perf_counter()
            rig.model(device="cpu")
            rows["model build, whole ICT head, fields from the cache"] = time.perf_counter() - started
            os.environ["WARPFACE_CACHE"] = "off"
    return rows


def _environment(tree: Path) -> dict[str, str]:
    from warpface.data import shared_data_path

    environment = {**os.environ, "PYTHONPATH": str(tree), "WARPFACE_SHARED_DATA": str(shared_data_path())}
    environment["WARPFACE_CACHE"] = "off"  # the rig-time fields computed each round, not read from the last one's
    return environment


def _round(tree: Path, scratch: Path) -> dict[str, float]:
    """One round of every row of ``tree``: the command line in a fresh process, then the in-process rows."""
    from warpface.data import shared_data_path

    environment = _environment(tree)
    out = scratch / tree.name / "rig.usda"
    started = time.perf_counter()
    command = [sys.executable, "-m", "warpface.cli", "rig", str(shared_data_path(*HEAD)), "--out", str(out), "--quiet"]
    subprocess.run(command, env=environment, cwd=tree, check=True, capture_output=True)
    rows = {"warpface rig, whole ICT head (command)": time.perf_counter() - started}
    measured = subprocess.run(
        [sys.executable, "-m", "benchmarks.rig_build", "--measure", "--tree", str(tree)],
        env=environment,
        cwd=ROOT,
        check=True,
        capture_output=True,
        text=True,
    )
    rows.update(json.loads(measured.stdout.strip().splitlines()[-1]))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", type=Path, help="a checkout of the tree to compare with (the peer)")
    parser.add_argument("--rounds", type=int, default=3, help="alternating rounds per tree (default 3)")
    parser.add_argument("--measure", action="store_true", help="print one round of the in-process rows as JSON")
    parser.add_argument("--tree", type=Path, default=ROOT, help="with --measure: the warpface checkout to measure")
    args = parser.parse_args()
    if args.measure:
        print(json.dumps(measure(args.tree.resolve())))
        return
    from warpface.data import shared_data_path

    if shared_data_path(*HEAD) is None:
        sys.exit("rig_build: needs ../shared/data (the ICT-FaceKit and Lee Perry-Smith heads)")
    if args.before is None or not (args.before / "warpface").is_dir():
        sys.exit("rig_build: --before TREE must be a warpface checkout (git worktree add /tmp/before <commit>)")
    trees = {"before": args.before.resolve(), "after": ROOT}
    samples: dict[str, dict[str, list[float]]] = {side: {} for side in trees}
    with tempfile.TemporaryDirectory() as scratch:
        for index in range(args.rounds):
            for side, tree in trees.items():
                print(f"round {index + 1}/{args.rounds}: {side} ({tree})", flush=True)
                for row, seconds in _round(tree, Path(scratch)).items():
                    samples[side].setdefault(row, []).append(seconds)
    rows = [
        {
            "row": row if row in samples["before"] else f"{row} (peer: {PEERS[row]}, this tree)",
            "before": statistics.median(samples["before"].get(row) or samples["after"][PEERS[row]]),
            "after": statistics.median(samples["after"][row]),
        }
        for row in samples["after"]
    ]
    for row in rows:
        row["ratio"] = row["before"] / row["after"]
    print_table(
        rows,
        [
            ("row", "row", "s"),
            ("before", "before s", ".2f"),
            ("after", "after s", ".2f"),
            ("ratio", "before / after", ".2f"),
        ],
    )
    payload = {"machine": machine_info(), "before": str(trees["before"]), "rounds": args.rounds, "rows": rows}
    print(f"wrote {write_results('rig_build', payload)}")


if __name__ == "__main__":
    main()
