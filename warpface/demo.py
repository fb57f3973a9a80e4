"""The demo: the built-in face makes the paper's four expressions, as a USD stage, a bake and pictures.

Writes, under ``out_dir``:

- ``face.usda`` — the rig (skin mesh, muscles, wrinkles, thickness) with the contractions as time samples;
- ``face_anim.usdc`` — the baked skin points (sublayered under ``face.usda``);
- ``<expression>.png`` — neutral | without wrinkles | with wrinkles, for each expression;
- ``expressions.png`` — all four, without (top) and with (bottom) wrinkles;
- ``blink_smile.png`` — neutral | a blink | a smile (the ARKit presets on both sides at weight 1);
- ``heatmap_<expression>.png`` — displacement magnitude [mm] at the expression's peak;
- ``face_anim.mp4`` — the baked animation, read back from the stage.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["DemoResult", "run_demo", "expression_sequence", "both_sides", "SIDED_PRESETS"]

BACKGROUND = (0.12, 0.12, 0.14)
"""Dark, so the eye and mouth openings of the open face surface read as eyes and mouth."""
INTERIOR = (0.06, 0.05, 0.05)
"""The back of the face surface, seen through the eye and mouth openings: darker than the background."""


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


def run_demo(
    out_dir: str | Path = "demo",
    *,
    device=None,
    fps: float = 30.0,
    seconds: float = 2.0,
    video: bool = True,
    size: tuple[int, int] = (480, 560),
    progress: bool = True,
) -> DemoResult:
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
    from ._validate import as_positive
    from .assets import EXPRESSIONS, default_rig
    from .expression import ExpressionModel
    from .usd.animation import MAX_FRAMES

    fps, seconds = as_positive(fps, "fps"), as_positive(seconds, "seconds")
    if fps * seconds < 2:
        raise ValueError(f"fps × seconds must give at least 2 frames per expression, got {fps:g} × {seconds:g}")
    if fps * seconds * len(EXPRESSIONS) > MAX_FRAMES:
        raise ValueError(f"fps × seconds gives more than {MAX_FRAMES} frames")
    preview.check_offscreen_rendering()
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"output folder {out}: exists and is not a folder")
    timings: dict[str, float] = {}
    clock = time.perf_counter()

    rig = default_rig()
    names = list(EXPRESSIONS)
    contractions, peaks = expression_sequence(rig, names, seconds, fps)
    model = ExpressionModel.from_rig(rig, device=device)  # a bad device fails here, before anything is written
    timings["rig"] = time.perf_counter() - clock

    clock = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    stage_path = out / "face.usda"
    stage = usd.write_rig(stage_path, rig, fps=fps)
    usd.write_animation(stage, np.arange(len(contractions), dtype=np.float64), contractions=contractions, fps=fps)
    usd.export_layer_atomically(stage.GetRootLayer(), stage_path)
    cache = usd.bake(stage, model=model, progress=progress)
    timings["usd"] = time.perf_counter() - clock

    clock = time.perf_counter()
    smooth = ExpressionModel(rig.mesh, rig.muscles, [], rig.thickness, device=device)
    rest = rig.mesh.points
    camera = preview.Camera.for_face(rest[rig.landmarks], yaw_deg=30.0, pitch_deg=5.0)
    style = {"camera": camera, "size": size, "background": BACKGROUND, "interior": INTERIOR}
    triangles = rig.mesh.triangles
    images, without_row, with_row, peaks_wrinkled = [], [], [], {}
    for name in names:
        peak = contractions[peaks[name]]
        named = dict(zip(rig.muscle_names, peak.tolist()))  # by name: the jaw (``model`` only) stays at rest
        plain, wrinkled = smooth.evaluate(named), model.evaluate(named)
        views = [("neutral", rest), (f"{name}: no wrinkles", plain), (f"{name}: with wrinkles", wrinkled)]
        images.append(out / f"{name}.png")
        preview.render_comparison(views, triangles, images[-1], **style)
        without_row.append((f"{name}: no wrinkles", plain))
        with_row.append((f"{name}: with wrinkles", wrinkled))
        peaks_wrinkled[name] = wrinkled
    # One colour scale for all four heat maps, so they compare: 0 to the largest displacement, rounded up.
    displacement_mm = {name: np.linalg.norm(p - rest, axis=1) * 1e3 for name, p in peaks_wrinkled.items()}
    top_mm = _nice_ceiling(max(float(d.max()) for d in displacement_mm.values()))
    for name in names:
        images.append(out / f"heatmap_{name}.png")
        preview.render_heat_map(
            peaks_wrinkled[name],
            triangles,
            displacement_mm[name],
            images[-1],
            title=f"{name}: |displacement|",
            units="mm",
            vmin=0.0,
            vmax=top_mm,
            **style,
        )
    top = preview.render_comparison(without_row, triangles, **style)
    bottom = preview.render_comparison(with_row, triangles, **style)
    images.append(preview.save_image(out / "expressions.png", np.concatenate([top, bottom], axis=0)))
    views = [("neutral", rest)] + [(title, model.evaluate(both_sides(rig, name))) for title, name in SIDED_PRESETS]
    images.append(out / "blink_smile.png")
    preview.render_comparison(views, triangles, images[-1], **style)
    timings["previews"] = time.perf_counter() - clock

    result = DemoResult(stage=stage_path, cache=cache, images=images, timings=timings)
    if video:
        clock = time.perf_counter()
        labels = _frame_labels(names, peaks, len(contractions), fps)
        result.video = preview.write_video(
            _baked_frames(stage_path),
            triangles,
            out / "face_anim.mp4",
            fps=fps,
            label=labels.__getitem__,
            total=len(contractions),
            progress=progress,
            **style,
        )
        timings["video"] = time.perf_counter() - clock
    return result


SIDED_PRESETS = (("blink (eyeBlink)", "eyeBlink"), ("smile (mouthSmile)", "mouthSmile"))
"""(title, ARKit preset stem) of the demo's extra panel: each preset on both sides at weight 1."""


def both_sides(rig, stem: str) -> dict[str, float]:
    """The controls of an ARKit preset's ``Left`` and ``Right`` halves together at weight 1."""
    from .assets import preset_controls

    return {**preset_controls(f"{stem}Left", rig), **preset_controls(f"{stem}Right", rig)}


def _baked_frames(stage_path: Path):
    """The skin's baked points at every time code, read back from the stage (proves the cache plays)."""
    from .usd.frames import open_frames

    return open_frames(stage_path)


def _frame_labels(names: list[str], peaks: dict[str, int], frame_count: int, fps: float) -> list[str]:
    """Per frame: the expression being performed, and the time — each expression owns the frames from
    the neutral frame before its peak to the neutral frame after."""
    labels, start = [], 0
    bounds = [peaks[n] for n in names]
    for index in range(frame_count):
        while start + 1 < len(names) and index > (bounds[start] + bounds[start + 1]) // 2:
            start += 1
        labels.append(f"{names[start]}   {index / fps:5.2f} s")
    return labels


def _nice_ceiling(value: float) -> float:
    """The smallest of 1, 2, 2.5, 5 × 10^k at or above ``value`` (> 0): a clean top for a colour bar."""
    import math

    if not value > 0:
        return 1.0
    power = 10.0 ** math.floor(math.log10(value))
    return next(step * power for step in (1.0, 2.0, 2.5, 5.0, 10.0) if step * power >= value * (1 - 1e-9))
