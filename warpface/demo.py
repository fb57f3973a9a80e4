"""The demo: the built-in face makes the paper's four expressions, as a USD stage, a bake and pictures.

Writes, under ``out_dir``:

- ``face.usda`` — the rig (skin mesh, muscles, wrinkles, thickness) with the contractions as time samples;
- ``face_anim.usdc`` — the baked skin points (sublayered under ``face.usda``);
- ``<expression>.png`` — neutral | without wrinkles | with wrinkles, for each expression;
- ``expressions.png`` — all four, without (top) and with (bottom) wrinkles;
- ``heatmap_<expression>.png`` — displacement magnitude [mm] at the expression's peak;
- ``face_anim.mp4`` — the baked animation, read back from the stage.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["DemoResult", "run_demo", "expression_sequence"]

BACKGROUND = (0.12, 0.12, 0.14)
"""Dark, so the eye and mouth openings of the open face surface read as eyes and mouth."""


@dataclass
class DemoResult:
    """Where the demo wrote everything, and how long the steps took."""

    stage: Path
    cache: Path
    images: list[Path] = field(default_factory=list)
    video: Path | None = None
    timings: dict[str, float] = field(default_factory=dict)


def expression_sequence(rig, names, seconds: float, fps: float) -> tuple[np.ndarray, dict[str, int]]:
    """Neutral → expression → neutral for each name in turn: contractions (F, M) and each peak's frame index."""
    from .assets import expression_timeline

    blocks, peaks, start = [], {}, 0
    for index, name in enumerate(names):
        block = expression_timeline(name, rig, seconds=seconds, fps=fps)
        if index:
            block = block[1:]  # the previous block already ends on the shared neutral frame
        peaks[name] = start + int(np.argmax(np.abs(block).sum(axis=1)))
        blocks.append(block)
        start += len(block)
    return np.concatenate(blocks), peaks


def run_demo(out_dir: str | Path = "demo", *, device=None, fps: float = 30.0, seconds: float = 2.0, video: bool = True,
             size: tuple[int, int] = (480, 560), progress: bool = True) -> DemoResult:
    """Build the built-in face, animate the four expressions, bake to USD, and render previews.

    Args:
        out_dir: output folder (created).
        device: Warp device for the expression model.
        fps: frames per second (``timeCodesPerSecond`` of the stage).
        seconds: length of each neutral → expression → neutral segment.
        video: also write ``face_anim.mp4``.
        size: (width, height) of each preview panel in pixels.
        progress: show progress bars.
    """
    from . import preview, usd
    from .assets import EXPRESSIONS, default_rig
    from .expression import ExpressionModel

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    timings: dict[str, float] = {}
    clock = time.perf_counter()

    rig = default_rig()
    names = list(EXPRESSIONS)
    contractions, peaks = expression_sequence(rig, names, seconds, fps)
    timings["rig"] = time.perf_counter() - clock

    clock = time.perf_counter()
    stage_path = out / "face.usda"
    stage = usd.write_rig(stage_path, rig, fps=fps)
    usd.write_animation(stage, np.arange(len(contractions), dtype=np.float64), contractions=contractions, fps=fps)
    usd.export_layer_atomically(stage.GetRootLayer(), stage_path)
    model = ExpressionModel.from_rig(rig, device=device)
    cache = usd.bake(stage, model=model, progress=progress)
    timings["usd"] = time.perf_counter() - clock

    clock = time.perf_counter()
    smooth = ExpressionModel(rig.mesh, rig.muscles, [], rig.thickness, device=device)
    rest = rig.mesh.points
    camera = preview.Camera.for_face(rest[rig.landmarks], yaw_deg=30.0, pitch_deg=5.0)
    style = {"camera": camera, "size": size, "background": BACKGROUND}
    triangles = rig.mesh.triangles
    images, without_row, with_row = [], [], []
    for name in names:
        peak = contractions[peaks[name]]
        plain, wrinkled = smooth.evaluate(peak), model.evaluate(peak)
        views = [("neutral", rest), (f"{name}: no wrinkles", plain), (f"{name}: with wrinkles", wrinkled)]
        images.append(out / f"{name}.png")
        preview.render_comparison(views, triangles, images[-1], **style)
        without_row.append((f"{name}: no wrinkles", plain))
        with_row.append((f"{name}: with wrinkles", wrinkled))
        displacement_mm = np.linalg.norm(wrinkled - rest, axis=1) * 1e3
        images.append(out / f"heatmap_{name}.png")
        preview.render_heat_map(wrinkled, triangles, displacement_mm, images[-1], title=f"{name}: |displacement|",
                                units="mm", **style)
    top = preview.render_comparison(without_row, triangles, **style)
    bottom = preview.render_comparison(with_row, triangles, **style)
    images.append(preview.save_image(out / "expressions.png", np.concatenate([top, bottom], axis=0)))
    timings["previews"] = time.perf_counter() - clock

    result = DemoResult(stage=stage_path, cache=cache, images=images, timings=timings)
    if video:
        clock = time.perf_counter()
        result.video = preview.write_video(_baked_frames(stage_path), triangles, out / "face_anim.mp4", fps=fps,
                                           label="warpface", progress=progress, **style)
        timings["video"] = time.perf_counter() - clock
    return result


def _baked_frames(stage_path: Path):
    """The skin's baked points at every time code, read back from the stage (proves the cache plays)."""
    from pxr import Usd, UsdGeom

    from .usd import frame_times, rig_prims

    stage = Usd.Stage.Open(str(stage_path))
    points = rig_prims(stage).skin.GetAttribute(UsdGeom.Tokens.points)
    for time_code in frame_times(stage):
        yield np.asarray(points.Get(Usd.TimeCode(float(time_code))), dtype=np.float64)
