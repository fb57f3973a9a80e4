"""Your own head, end to end from the command line: rig it, animate it with a Live Link take, bake, check, preview.

For two real heads from ``../shared/data`` — the Lee Perry-Smith scan (a bust, one shell) and the whole
ICT-FaceKit head (eyes, teeth, gums, tongue, mouth socket and neck in one OBJ, in centimetres):

1. ``warpface rig HEAD --out rig.usda --preview rig.png``: the 68 landmarks found on the mesh, the default
   rig built on them, a picture of landmarks and muscles;
2. a Live Link Face take written here (a smile, raised brows, a blink and an open jaw: ARKit weights at 30
   fps, the CSV an iPhone records), then ``warpface animate take.csv --rig rig.usda --out anim.usda``:
   the weights mapped to the rig's controls, time samples, the baked points cache and a video;
3. ``warpface validate anim.usda``: everything bake would refuse, the landmarks' layout, the face's size;
4. ``warpface preview anim.usda --time T --landmarks --muscles``: the face at the take's peak.

Writes ``out/own_head/<head>/`` (rig.usda, rig.png, take.csv, anim.usda, anim_anim.usdc, anim.mp4, peak.png).
Renders of third-party data stay out of the repository. Without ``../shared/data`` (or
``WARPFACE_SHARED_DATA``) the example says so and exits 0.

    python examples/own_head.py [--out out/own_head] [--device cpu] [--head lee_perry_smith|ict_whole_head]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from warpface.cli import main as warpface
from warpface.data import shared_data_path
from warpface.drivers import Curves, write_live_link

HEADS = {
    "lee_perry_smith": ("lee_perry_smith", "LeePerrySmith.obj"),
    "ict_whole_head": ("ict_facekit", "original", "generic_neutral_mesh.obj"),
}
"""Head name → its OBJ under ``../shared/data``."""

FPS = 30


def live_link_take(path: Path) -> float:
    """Write a 3 s Live Link Face take (ARKit weights) to ``path``; returns the time of its peak [s]."""
    times = np.arange(3 * FPS) / FPS
    rise = np.clip((times - 0.3) / 0.6, 0.0, 1.0)  # neutral, a 0.6 s rise, held
    rise = rise * np.clip((2.8 - times) / 0.4, 0.0, 1.0)  # back to neutral at the end
    blink = np.exp(-(((times - 1.2) / 0.06) ** 2))
    channels = {
        "mouthSmileLeft": 0.8 * rise,
        "mouthSmileRight": 0.8 * rise,
        "browInnerUp": 0.7 * rise,
        "cheekSquintLeft": 0.3 * rise,
        "cheekSquintRight": 0.3 * rise,
        "jawOpen": 0.35 * rise,
        "eyeBlinkLeft": blink,
        "eyeBlinkRight": blink,
    }
    curves = Curves(times, list(channels), np.stack(list(channels.values()), axis=1), source=path.name, fps=FPS)
    write_live_link(path, curves)
    return 2.0


def run_head(name: str, head: Path, out: Path, device: str | None) -> None:
    """The four steps on one head; raises SystemExit with warpface's exit code when a step fails."""
    out.mkdir(parents=True, exist_ok=True)
    options = ["--quiet"] + (["--device", device] if device else [])
    take = out / "take.csv"
    peak = live_link_take(take)
    steps = [
        ["rig", str(head), "--out", str(out / "rig.usda"), "--preview", str(out / "rig.png")],
        ["animate", str(take), "--rig", str(out / "rig.usda"), "--out", str(out / "anim.usda")],
        ["validate", str(out / "anim.usda")],
        [
            "preview",
            str(out / "anim.usda"),
            "--time",
            f"{peak * FPS:g}",
            "--landmarks",
            "--muscles",
            "--out",
            str(out / "peak.png"),
        ],
    ]
    for step in steps:
        print(f"$ warpface {' '.join(step)}")
        code = warpface(options + step)
        if code != 0:
            raise SystemExit(f"{name}: `warpface {step[0]}` failed (exit {code})")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("out/own_head"), help="output folder")
    parser.add_argument("--device", default=None, help="Warp device (default: Warp's preferred one)")
    parser.add_argument("--head", choices=sorted(HEADS), action="append", help="only this head (repeatable)")
    args = parser.parse_args(argv)
    found = {name: shared_data_path(*HEADS[name]) for name in args.head or HEADS}
    missing = [name for name, path in found.items() if path is None]
    if len(missing) == len(found):
        print(
            f"skipped: the heads ({', '.join('/'.join(HEADS[n]) for n in missing)}) are not in ../shared/data; "
            "set WARPFACE_SHARED_DATA to the folder that holds them"
        )
        return 0
    for name, head in found.items():
        if head is None:
            print(f"skipped {name}: {'/'.join(HEADS[name])} is not in ../shared/data")
            continue
        run_head(name, head, args.out / name, args.device)
    print(f"wrote {args.out}/<head>/: rig.usda, rig.png, take.csv, anim.usda (+ anim_anim.usdc, anim.mp4), peak.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
