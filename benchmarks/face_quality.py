"""Does the default rig look right: lid gaps in a blink, lip order, folded triangles (issue 25's checks).

Per face (the built-in face; the ICT-FaceKit face rigged from its 68 landmarks; a smooth warp of it
standing in for another identity; the Lee Perry-Smith scan rigged from landmarks found by
:func:`warpface.rigging.find_landmarks`; the whole ICT-FaceKit head — skin, eyes, teeth, gums and mouth socket in
one mesh — rigged from its 68 landmarks), measured with :mod:`warpface.assets.quality`:

- **blink**: ARKit ``eyeBlinkLeft/Right`` = 1 through the default Live Link/ARKit mapping (what
  ``warpface animate`` does), and the ``eyeBlink`` presets: the largest lid-midpoint distance [mm] (rest
  gap in brackets) and the lowest signed height of an upper midpoint above its lower one [mm];
- **lips**: the lowest signed height of an upper inner-lip midpoint above its lower one [mm] over every
  ARKit preset at weight 1 and over random ARKit weight combinations through the mapping; and a take's
  ``jawOpen`` = 1 alone, with ``mouthClose`` = 1 (lowest … highest midpoint height) and with ``mouthClose`` = ½
  (highest), through the mapping and :func:`~warpface.drivers.close_mouth` as ``warpface animate`` maps them;
- **flips**: triangles whose normal turned over (rest · deformed < 0), summed over every ARKit and FACS
  channel at weight 1 through the default mapping (a FACS intensity of 1), without
  ``mouthRollUpper/Lower`` (those lips turn inward), with the worst channels; on the landmarks' shell only (a whole
  head's eyes and teeth are moved rigidly by the bake, docs/RIG.md §10).

    python -m benchmarks.face_quality [--faces builtin ict warp lps head] [--combinations 200] [--before-tree DIR]

``--before-tree`` first runs an older checkout's own copy of this benchmark (its warpface, its measures) on the
same faces and stores its rows as ``before`` next to this tree's in the results.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

import warpface as wf
from warpface.assets import ARKIT_PRESET_NAMES, default_rig, preset_controls
from warpface.assets.lips import LIP_SEAL_NAME, mouth_close_shares
from warpface.assets.quality import LID_PAIRS, LIP_PAIRS, face_up, flipped_triangles, pair_distances, pair_heights
from warpface.data import ict_face_region, ict_landmark_indices, shared_data_path
from warpface.drivers.default_tables import mapping_for_rig

from ._timing import machine_info, print_table, write_results

FACES = ("builtin", "ict", "warp", "lps", "head")
ROLLS = ("mouthRollUpper", "mouthRollLower", "AU28")
CENTIMETRE = 0.01


def smooth_warp(points: np.ndarray, seed: int = 1) -> np.ndarray:
    """Another identity: width scaled by ±6 % and 12 Gaussian bumps (σ 3 cm, ~5 mm each), ICT units (cm)."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(points.min(axis=0), points.max(axis=0), (12, 3))
    amplitudes = rng.normal(0.0, 0.5, (12, 3))
    weights = np.exp(-np.sum((points[:, None, :] - centres[None]) ** 2, axis=2) / (2.0 * 3.0**2))
    return points * [1.0 + (0.06 if seed % 2 else -0.06), 1.0, 1.0] + weights @ amplitudes


def face_rig(face: str):
    """(rig, mm per mesh unit) of a named face, or None when its data is absent."""
    if face == "builtin":
        return default_rig(), 1000.0
    if face in ("ict", "warp"):
        path, landmarks = ict_face_region(), ict_landmark_indices()
        if path is None or landmarks is None:
            return None
        source = wf.FaceMesh.from_obj(path)
        points = source.points if face == "ict" else smooth_warp(source.points)
        mesh = wf.FaceMesh(points * CENTIMETRE, source.triangles, name=f"{face}_face")
        return default_rig(mesh, landmarks), 1000.0
    if face == "lps":
        path = shared_data_path("lee_perry_smith", "LeePerrySmith.obj")
        if path is None:
            return None
        from warpface.rigging import find_landmarks

        mesh = wf.FaceMesh.from_obj(path)
        found = find_landmarks(mesh.points, mesh.triangles, label="Lee Perry-Smith")
        return default_rig(mesh, found.indices), 1000.0 * found.meters_per_unit
    if face == "head":
        path = shared_data_path("ict_facekit", "original", "generic_neutral_mesh.obj")
        landmarks = ict_landmark_indices()
        if path is None or landmarks is None:
            return None
        source = wf.FaceMesh.from_obj(path, degenerate="ignore")
        mesh = wf.FaceMesh(source.points * CENTIMETRE, source.triangles, name="ict_head", degenerate="ignore")
        return default_rig(mesh, landmarks), 1000.0
    raise ValueError(f"face: expected one of {', '.join(FACES)}, got {face!r}")


def channel_frames(rig, kind: str, channels=None, weight: float | None = None) -> tuple[list[str], np.ndarray]:
    """Each channel of the default ``kind`` table alone at full weight, as the rig's control vectors (F, C)."""
    mapping, _, _ = mapping_for_rig(rig, kind)
    names = [c for c in mapping.channels if channels is None or c in channels]
    full = 1.0 if weight is None else weight
    index = {c: i for i, c in enumerate(rig.control_names)}
    frames = np.zeros((len(names), len(rig.control_names)))
    for f, channel in enumerate(names):
        column = mapping.channels.index(channel)
        for row, control in enumerate(mapping.controls):
            frames[f, index[control]] += full * mapping.matrix[row, column]
    return names, frames


def arkit_controls(rig, names: list[str], weights: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """ARKit weights (F, channels ``names``) as the rig's controls the way ``warpface animate`` makes them: the
    linear mapping (``frames``, one control vector per channel at weight 1, from :func:`channel_frames`) and the lip
    seal's share for ``mouthClose`` over ``jawOpen`` (:func:`~warpface.drivers.close_mouth`)."""
    controls = weights @ frames
    if "mouthClose" in names and LIP_SEAL_NAME in rig.control_names and rig.jaw is not None:
        jaw = controls[:, [rig.control_names.index(c) for c in ("jaw_open", "jaw_forward", "jaw_left")]]
        opened = weights[:, names.index("jawOpen")] if "jawOpen" in names else np.zeros(len(weights))
        shares = mouth_close_shares(rig, jaw, weights[:, names.index("mouthClose")], opened)
        controls[:, rig.control_names.index(LIP_SEAL_NAME)] += shares
    return controls


def random_combinations(rig, count: int, seed: int = 0) -> np.ndarray:
    """``count`` random ARKit weight sets (each channel on with probability 0.3, weight U(0, 1)) as controls."""
    names, frames = channel_frames(rig, "arkit", weight=1.0)
    rng = np.random.default_rng(seed)
    weights = rng.uniform(0.0, 1.0, (count, len(names))) * (rng.uniform(size=(count, len(names))) < 0.3)
    return arkit_controls(rig, names, weights, frames)


def preset_frames(rig, names) -> np.ndarray:
    index = {c: i for i, c in enumerate(rig.control_names)}
    frames = np.zeros((len(names), len(rig.control_names)))
    for f, name in enumerate(names):
        for control, value in preset_controls(name, rig).items():
            frames[f, index[control]] = value
    return frames


def measure(rig, mm: float, combinations: int = 200) -> dict:
    """The checks of the module docstring on one rig."""
    model = rig.model(device="cpu")
    up = face_up(rig.mesh, rig.landmarks)
    rest = rig.mesh.points
    row: dict = {}
    rest_gap = pair_distances(rest, rig.landmarks, LID_PAIRS, mm)
    blink_channels, blink = channel_frames(rig, "arkit", ("eyeBlinkLeft", "eyeBlinkRight"))
    blink = blink.sum(axis=0, keepdims=True)
    presets = preset_frames(rig, ["eyeBlinkLeft", "eyeBlinkRight"]).sum(axis=0, keepdims=True)
    for label, frames in (("blink_arkit", blink), ("blink_preset", presets)):
        points = model.evaluate(frames)
        row[f"{label}_gap_mm"] = float(pair_distances(points, rig.landmarks, LID_PAIRS, mm).max())
        row[f"{label}_order_mm"] = float(pair_heights(points, rig.landmarks, LID_PAIRS, up, mm).min())
    row["rest_lid_gap_mm"] = float(rest_gap.min())
    # a pair whose two landmarks are one vertex (a closed mouth's found 62/66) reads 0 at every frame: left out
    lips = tuple(p for p in LIP_PAIRS if rig.landmarks[p[0]] != rig.landmarks[p[1]]) or LIP_PAIRS
    lips_at = model.evaluate(preset_frames(rig, ARKIT_PRESET_NAMES))
    heights = pair_heights(lips_at, rig.landmarks, lips, up, mm).min(axis=1)
    row["lips_preset_mm"] = float(heights.min())
    row["lips_preset_worst"] = ARKIT_PRESET_NAMES[int(np.argmin(heights))]
    if combinations:
        mixed = model.evaluate(random_combinations(rig, combinations))
        row["lips_random_mm"] = float(pair_heights(mixed, rig.landmarks, lips, up, mm).min())
    row["rest_lip_mm"] = float(pair_heights(rest, rig.landmarks, lips, up, mm).min())
    names, frames = channel_frames(rig, "arkit")
    if "mouthClose" in names and "jawOpen" in names:  # a Live Link take's jawOpen + mouthClose, as animate maps it
        weights = np.zeros((3, len(names)))
        weights[:, names.index("jawOpen")] = 1.0
        weights[1:, names.index("mouthClose")] = (1.0, 0.5)
        held = pair_heights(model.evaluate(arkit_controls(rig, names, weights, frames)), rig.landmarks, lips, up, mm)
        row["jaw_open_lips_mm"] = float(held[0].max())
        row["mouth_close_lips_mm"] = f"{held[1].min():.2f} … {held[1].max():.2f}"
        row["half_close_lips_mm"] = float(held[2].max())
    counts = {}
    shells = rig.mesh.shells
    on_skin = shells[rig.mesh.triangles[:, 0]] == shells[rig.landmarks[30]]
    skin = wf.FaceMesh(rest, rig.mesh.triangles[on_skin], degenerate="ignore")
    for kind in ("arkit", "facs"):
        names, frames = channel_frames(rig, kind)
        keep = [i for i, n in enumerate(names) if n not in ROLLS]
        flips = flipped_triangles(skin, model.evaluate(frames[keep]))
        counts.update({names[i]: int(n) for i, n in zip(keep, flips)})
    row["flips"] = int(sum(counts.values()))
    worst = sorted(counts.items(), key=lambda item: -item[1])[:5]
    row["flips_worst"] = ", ".join(f"{n} {c}" for n, c in worst if c)
    return row


COLUMNS = [
    ("face", "face", "s"),
    ("rest_lid_gap_mm", "rest lid gap", ".2f"),
    ("blink_arkit_gap_mm", "blink gap (ARKit)", ".2f"),
    ("blink_arkit_order_mm", "lid order", ".2f"),
    ("blink_preset_gap_mm", "blink gap (preset)", ".2f"),
    ("blink_preset_order_mm", "lid order", ".2f"),
    ("rest_lip_mm", "rest lips", ".2f"),
    ("lips_preset_mm", "lips (presets)", ".2f"),
    ("lips_preset_worst", "worst preset", "s"),
    ("lips_random_mm", "lips (random)", ".2f"),
    ("jaw_open_lips_mm", "jawOpen lips", ".2f"),
    ("mouth_close_lips_mm", "+ mouthClose", "s"),
    ("half_close_lips_mm", "+ ½ mouthClose", ".2f"),
    ("flips", "flips", "d"),
    ("flips_worst", "worst channels", "s"),
]


def _before(tree: Path, faces, combinations: int) -> list[dict]:
    """The rows of ``tree``'s own face_quality benchmark (run in a child process with that tree first on the path;
    its results file is restored afterwards)."""
    results = tree / "benchmarks" / "results" / "face_quality.json"
    kept = results.read_bytes() if results.is_file() else None
    environment = dict(os.environ, PYTHONPATH=str(tree.resolve()))
    data = shared_data_path()
    if data is not None:
        environment["WARPFACE_SHARED_DATA"] = str(data)
    command = [sys.executable, "-m", "benchmarks.face_quality", "--faces", *faces]
    try:
        subprocess.run([*command, "--combinations", str(combinations)], check=True, env=environment, cwd=tree)
        return json.loads(results.read_text())["rows"]
    finally:
        if kept is not None:
            results.write_bytes(kept)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--faces", nargs="+", choices=FACES, default=list(FACES))
    parser.add_argument("--combinations", type=int, default=200, help="random ARKit combinations per face")
    parser.add_argument("--before-tree", type=Path, help="an older checkout measured first, in the same run")
    args = parser.parse_args()
    before = _before(args.before_tree, args.faces, args.combinations) if args.before_tree else None
    rows = []
    for face in args.faces:
        built = face_rig(face)
        if built is None:
            print(f"skipped {face}: its data is not in ../shared/data")
            continue
        row = {"face": face, **measure(*built, combinations=args.combinations)}
        rows.append(row)
        print(row, flush=True)
    if before is not None:
        print("before:")
        print_table(before, COLUMNS)
        print("after:")
    print_table(rows, COLUMNS)
    payload = {"machine": machine_info(), "rows": rows}
    if before is not None:
        payload.update(before=before, before_tree=str(args.before_tree))
    write_results("face_quality", payload)


if __name__ == "__main__":
    main()
