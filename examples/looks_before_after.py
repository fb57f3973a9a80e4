"""Before/after pictures of issue 25 (faces that look right): the default rig of an older checkout against this one.

Each face gets one image of two rows, the older tree's default rig on top and this tree's below, at neutral, the
paper's four expressions (thinking, puzzled, disgust, smile), a blink (``eyeBlinkLeft`` + ``eyeBlinkRight``), an
ARKit smile (``mouthSmileLeft`` + ``mouthSmileRight``) and ``mouthStretchLeft``, every preset at weight 1: the
built-in face to ``docs/images/looks_builtin.png``, the ICT-FaceKit face from ``../shared/data`` (rigged from its
68 landmarks) to ``docs/images/looks_ict.png``, the Lee Perry-Smith scan (rigged from found landmarks) to
``docs/images/looks_lps.png``; and per face ``docs/images/wrinkles_<face>.png``, close-ups of the forehead and the
left eye's outer corner (:data:`CLOSEUPS`). The older tree's points are computed by running this file with
that tree first on ``PYTHONPATH`` (``--points-only``), using only API both trees have.

    git worktree add /tmp/before d73361f          # the tree before issues 23-25
    python examples/looks_before_after.py --before-tree /tmp/before [--out docs/images] [--device cpu]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

CENTIMETRE = 0.01
VIEWS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("neutral", ()),
    ("thinking", ("thinking",)),
    ("puzzled", ("puzzled",)),
    ("disgust", ("disgust",)),
    ("smile", ("smile",)),
    ("eyeBlink", ("eyeBlinkLeft", "eyeBlinkRight")),
    ("mouthSmile", ("mouthSmileLeft", "mouthSmileRight")),
    ("mouthStretchLeft", ("mouthStretchLeft",)),
)
"""(title, presets summed at weight 1) of each tile."""
FACES = ("builtin", "ict", "lps")
CLOSEUPS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("forehead", ("thinking",)),
    ("eye", ("thinking", "disgust", "smile", "mouthSmile")),
)
"""(camera, titles of :data:`VIEWS`) of the wrinkle close-ups: the forehead from the front, the subject's left eye
corner from its side (crow's feet)."""


def _face(face: str, device):
    """The default rig of ``face`` in whichever warpface is imported, or None when its data is absent."""
    import warpface as wf
    from warpface.assets import default_rig
    from warpface.data import ict_face_region, ict_landmark_indices

    if face == "builtin":
        return default_rig(device=device)
    if face == "lps":  # rigged from found landmarks, as benchmarks/face_quality.py does (its tree's copy)
        sys.path.append(str(Path(__file__).resolve().parents[1]))  # after PYTHONPATH: the older tree's comes first
        from benchmarks.face_quality import face_rig

        built = face_rig("lps")
        return None if built is None else built[0]
    path, landmarks = ict_face_region(), ict_landmark_indices()
    if path is None or landmarks is None:
        return None
    source = wf.FaceMesh.from_obj(path)
    mesh = wf.FaceMesh(source.points * CENTIMETRE, source.triangles, name="ict_face")
    return default_rig(mesh, landmarks, name="ICTFace", device=device)


def face_points(device=None) -> dict[str, np.ndarray]:
    """``{face: (views, vertices, 3) points [m]}``, ``{face_triangles: (T, 3)}`` and ``{face_landmarks: (68,)}``."""
    from warpface.assets import preset_controls

    result = {}
    for face in FACES:
        rig = _face(face, device)
        if rig is None:
            continue
        model = rig.model(device=device)
        frames = []
        for _, presets in VIEWS:
            summed: dict[str, float] = {}
            for name in presets:
                for control, value in preset_controls(name, rig).items():
                    summed[control] = summed.get(control, 0.0) + value
            frames.append(np.asarray(model.evaluate(summed), dtype=np.float64))
        result[face] = np.stack(frames)
        result[f"{face}_triangles"] = np.asarray(rig.mesh.triangles)
        result[f"{face}_landmarks"] = np.asarray(rig.landmarks)
    return result


def _before_points(tree: Path, device) -> dict[str, np.ndarray]:
    """:func:`face_points` computed by the warpface of ``tree`` (a child process with it first on the path)."""
    from warpface.data import shared_data_path

    if not (tree / "warpface" / "__init__.py").is_file():
        raise SystemExit(f"looks_before_after: {tree} is not a warpface checkout (no warpface/__init__.py)")
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "points.npz"
        command = [sys.executable, str(Path(__file__).resolve()), "--points-only", str(out)]
        command += ["--device", device] if device else []
        environment = dict(
            os.environ, PYTHONPATH=os.pathsep.join([str(tree.resolve()), os.environ.get("PYTHONPATH", "")])
        )
        data = shared_data_path()  # this tree's data, wherever the older checkout lies
        if data is not None:
            environment["WARPFACE_SHARED_DATA"] = str(data)
        subprocess.run(command, check=True, env=environment, cwd=tree)
        with np.load(out) as data:
            return dict(data)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--before-tree", type=Path, help="an older warpface checkout (the top row)")
    parser.add_argument("--out", type=Path, default=Path("docs/images"), help="output folder")
    parser.add_argument("--device", default=None, help="Warp device")
    parser.add_argument("--points-only", type=Path, metavar="NPZ", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.points_only is not None:
        np.savez(args.points_only, **face_points(args.device))
        return 0
    if args.before_tree is None:
        parser.error("--before-tree is required (an older checkout, e.g. `git worktree add /tmp/before d73361f`)")

    from warpface import preview

    before, after = _before_points(args.before_tree, args.device), face_points(args.device)
    args.out.mkdir(parents=True, exist_ok=True)
    for face in FACES:
        if face not in after or face not in before:
            print(f"{face}: no data (the ICT face needs ../shared/data); skipped")
            continue
        if not np.array_equal(before[f"{face}_triangles"], after[f"{face}_triangles"]):
            raise SystemExit(f"looks_before_after: the {face} face's triangles differ between the two trees")
        rest = after[face][0]
        camera = preview.Camera.for_face(rest[after[f"{face}_landmarks"]], yaw_deg=25.0, pitch_deg=5.0)
        style = dict(camera=camera, size=(360, 420), background=(0.12, 0.12, 0.14))
        rows = []
        for label, points in (("before", before[face]), ("after", after[face])):
            views = [(f"{label}: {title}", frame) for (title, _), frame in zip(VIEWS, points)]
            rows.append(preview.render_comparison(views, after[f"{face}_triangles"], **style))
        path = preview.save_image(args.out / f"looks_{face}.png", np.concatenate(rows, axis=0))
        print(f"wrote {path}")
        path = preview.save_image(args.out / f"wrinkles_{face}.png", _closeups(face, before, after))
        print(f"wrote {path}")
    return 0


def _closeups(face: str, before: dict, after: dict) -> np.ndarray:
    """Two rows (before, after) of :data:`CLOSEUPS`: the forehead and the left eye's outer corner up close."""
    from warpface import preview
    from warpface.assets.frame import FaceFrame

    rest = after[face][0]
    marks = rest[after[f"{face}_landmarks"]]
    frame = FaceFrame.from_landmarks(marks)
    right, up, front = frame.axes
    size = frame.scale  # the inter-ocular distance
    brow = marks[17:27].mean(axis=0) + 0.55 * size * up
    corner = marks[45] + 0.35 * size * right - 0.10 * size * up
    cameras = {
        "forehead": preview.Camera(brow + 3.2 * size * front, brow, yfov_deg=30.0),
        "eye": preview.Camera(corner + 1.8 * size * (0.75 * front + 0.66 * right), corner, yfov_deg=30.0),
    }
    titles = [title for title, _ in VIEWS]
    rows = []
    for label, points in (("before", before[face]), ("after", after[face])):
        tiles = []
        for camera, names in CLOSEUPS:
            views = [(f"{label}: {name}", points[titles.index(name)]) for name in names]
            style = dict(camera=cameras[camera], size=(300, 300), background=(0.12, 0.12, 0.14))
            tiles.append(preview.render_comparison(views, after[f"{face}_triangles"], **style))
        rows.append(np.concatenate(tiles, axis=1))
    return np.concatenate(rows, axis=0)


if __name__ == "__main__":
    sys.exit(main())
