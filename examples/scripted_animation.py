"""Scripted, time-sampled animation authored in Python: facial action units drive the built-in rig.

The driver is a real recording when ``../shared/data`` is present — OpenFace 2.x action-unit
intensities (AUplayer, recorded for the AMHUSE dataset, Boccignone et al., ICMI 2017) at the
recording's own frame rate — and otherwise a scripted sequence of AU pulses. The curves go through
:mod:`warpface.drivers`: clamped to the AU range, mapped onto the rig's muscles by the default FACS
table (SPEC §6.4; stored on the stage under ``/Face/Drivers/default`` where any USD tool can edit
it), written as time samples on the rig's muscle prims, baked to a ``.usdc`` point cache, and
rendered to a video and a contact sheet from the baked stage. ``warpface animate`` does the same
from the command line for any driver format.

    python examples/scripted_animation.py [--recording 10_3_au.txt] [--out out/scripted] [--device cpu]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import warp as wp

from warpface import preview, usd
from warpface.assets import default_rig
from warpface.data import shared_data_path
from warpface.drivers import Curves, clean, mapping_for_rig
from warpface.usd.mapping_io import write_mapping


def scripted_aus(fps: float = 30.0, seconds: float = 6.0) -> Curves:
    """A scripted performance: brows up, a frown, a sneer, then a smile, as smooth AU pulses (0–5)."""
    times = np.arange(int(seconds * fps) + 1) / fps
    pulse = lambda centre: 5.0 * np.exp(-0.5 * ((times - centre) / 0.35) ** 2)  # noqa: E731
    aus = {
        "AU01": pulse(1.0),
        "AU02": pulse(1.0),
        "AU04": pulse(2.4),
        "AU09": pulse(3.7),
        "AU10": pulse(3.7),
        "AU06": pulse(5.0),
        "AU12": pulse(5.0),
    }
    return Curves(times=times, names=list(aus), values=np.stack(list(aus.values()), axis=1), source="scripted", fps=fps)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--recording", default="10_3_au.txt", help="AUplayer OpenFace file in ../shared/data")
    parser.add_argument("--out", type=Path, default=Path("out/scripted"), help="output folder")
    parser.add_argument("--device", default=None, help="Warp device")
    args = parser.parse_args(argv)
    wp.config.log_level = wp.LOG_WARNING
    args.out.mkdir(parents=True, exist_ok=True)

    recording = shared_data_path("auplayer_openface_au", args.recording)
    curves = usd.read_driver(recording) if recording is not None else scripted_aus()
    source = (
        f"OpenFace recording {recording.name}"
        if recording is not None
        else "scripted AU pulses (../shared/data not present)"
    )
    fps = float(round(curves.fps or 30.0, 3))
    curves = clean(curves, fps=fps)  # clamp to [0, 5], resample onto whole frames
    rig = default_rig()
    mapping, _, no_control = mapping_for_rig(rig, "facs")
    mapped = mapping.apply(curves)
    contractions = np.zeros((len(mapped.times), len(rig.muscles)))
    for column, name in enumerate(rig.muscle_names):
        if name in mapped.names:
            contractions[:, column] = mapped.values[:, mapped.names.index(name)]

    stage_path = args.out / "face.usda"
    stage = usd.write_rig(stage_path, rig, fps=fps)
    write_mapping(stage, mapping)
    time_codes = np.arange(len(mapped.times), dtype=np.float64)  # the recording's clock, at its native rate
    times = mapped.times
    usd.write_animation(stage, time_codes, contractions=contractions, fps=fps)
    usd.export_layer_atomically(stage.GetRootLayer(), stage_path)
    cache = usd.bake(stage, device=args.device)
    ignored = [c for c in dict.fromkeys(mapped.unmapped_channels + no_control) if c in curves.names]
    print(
        f"driver: {source} ({len(times)} frames at {fps:g} frames/s); no control on this rig for: "
        f"{', '.join(ignored) or 'none'}"
    )
    print(f"wrote {stage_path} (contractions as time samples, mapping under /Face/Drivers) and {cache} (baked points)")

    from pxr import Usd

    baked = Usd.Stage.Open(str(stage_path))
    points = usd.rig_prims(baked).skin.GetAttribute("points")
    frames = [np.asarray(points.Get(Usd.TimeCode(t))) for t in time_codes]
    camera = preview.Camera.for_face(rig.mesh.points[rig.landmarks], yaw_deg=25.0, pitch_deg=5.0)
    style = dict(camera=camera, size=(360, 420), background=(0.12, 0.12, 0.14))
    busiest = np.argsort(-np.abs(contractions).sum(axis=1))
    picks = np.sort(np.r_[0, busiest[np.linspace(0, len(busiest) // 4, 5).astype(int)]])
    views = [(f"t = {times[i] - times[0]:.2f} s", frames[i]) for i in picks[:6]]
    preview.render_comparison(views, rig.mesh.triangles, args.out / "frames.png", **style)
    preview.write_video(frames, rig.mesh.triangles, args.out / "animation.mp4", fps=fps, label="AU-driven", **style)
    print(f"wrote {args.out}/frames.png and animation.mp4")


if __name__ == "__main__":
    main()
