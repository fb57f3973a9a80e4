"""The paper's flat demonstration (Bando et al., SPEC §1.3–1.4): muscle → bulge → wrinkle on a sheet.

A 450 × 450 square mesh, one linear muscle, subcutaneous thickness 60, and one wrinkle with
k_d = 70, k_w = 50, k_r = 0 across the compressed skin in front of the muscle's attachment.
Writes one image per stage, a side-by-side of the three, and a stretch-ratio heat map.

    python examples/flat_sheet.py [--out out/flat_sheet] [--device cpu]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import warpface as wf
from warpface import preview

SIDE = 450.0
PANEL = (480, 320)
"""Pixels of each panel: landscape, like the tilted sheet."""
ASPECT = PANEL[0] / PANEL[1]
THICKNESS = 60.0


def flat_sheet(resolution: int = 91) -> wf.FaceMesh:
    """A SIDE × SIDE square lying in the x–z plane (a floor), normal +y, split into right triangles."""
    xs = np.linspace(0.0, SIDE, resolution)
    x, z = np.meshgrid(xs, xs)
    index = np.arange(resolution * resolution).reshape(resolution, resolution)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel()
    triangles = np.r_[np.c_[a, d, b], np.c_[a, c, d]]  # wound so that the normal is +y
    return wf.FaceMesh(np.c_[x.ravel(), np.zeros(x.size), z.ravel()], triangles, name="sheet")


def flat_sheet_rig():
    """The muscle pulls skin toward its attachment at (225, 0, 330); the furrow crosses the compressed
    band just behind it, in the sheet's (x, z) plane."""
    muscle = wf.LinearMuscle(
        "muscle",
        attachment=[225.0, 0.0, 330.0],
        insertion=[225.0, 0.0, 80.0],
        zone_angle_deg=40.0,
        falloff_start=160.0,
        falloff_finish=320.0,
    )
    furrow = wf.Wrinkle(
        "furrow",
        control_points=[[110.0, 250.0], [170.0, 235.0], [280.0, 235.0], [340.0, 250.0]],
        projection=wf.PlanarProjection([0, 0, 0], [1, 0, 0], [0, 0, 1]),
        depth=70.0,
        width=50.0,
        kr=0.0,
    )
    return muscle, furrow


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("out/flat_sheet"), help="output folder")
    parser.add_argument("--contraction", type=float, default=35.0, help="muscle contraction K [mesh units]")
    parser.add_argument("--device", default=None, help="Warp device")
    args = parser.parse_args(argv)

    mesh = flat_sheet()
    muscle, furrow = flat_sheet_rig()
    model = wf.ExpressionModel(mesh, [muscle], [furrow], THICKNESS, device=args.device)
    stages = model.stages({"muscle": args.contraction})
    print(f"stretch ratio r: min {stages.stretch.min():.3f}, max {stages.stretch.max():.3f}")
    print(
        f"bulge height: {np.ptp(stages.bulge[:, 1]):.1f}; furrow depth below the bulge: "
        f"{(stages.bulge[:, 1] - stages.final[:, 1]).max():.1f}"
    )

    # margin > 1: the tilted sheet projects taller than its bounding box; every panel shows it whole
    camera = preview.Camera.framing(mesh.points, pitch_deg=35.0, margin=1.05, aspect=ASPECT)
    moved = np.linalg.norm(stages.muscle - mesh.points, axis=1)  # in-plane: shown as colour, not relief
    views = [
        ("1 muscle (colour: |displacement|)", stages.muscle),
        ("2 + bulge (h = 60)", stages.bulge),
        ("3 + wrinkle (kd 70, kw 50)", stages.final),
    ]
    args.out.mkdir(parents=True, exist_ok=True)
    colors = [preview.heat_colors(moved, cmap="viridis"), None, None]
    for index, (title, points) in enumerate(views, start=1):
        preview.render(
            points,
            mesh.triangles,
            args.out / f"stage{index}.png",
            camera=camera,
            size=PANEL,
            label=title,
            colors=colors[index - 1],
        )
    preview.render_comparison(views, mesh.triangles, args.out / "stages.png", camera=camera, colors=colors, size=PANEL)
    preview.render_heat_map(
        stages.bulge,
        mesh.triangles,
        stages.stretch,
        args.out / "stretch.png",
        camera=camera,
        title="stretch ratio r",
        size=PANEL,
        cmap="coolwarm",
    )
    print(f"wrote {args.out}/stage1.png stage2.png stage3.png stages.png stretch.png")


if __name__ == "__main__":
    main()
