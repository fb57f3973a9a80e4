"""Scripted, time-sampled animation authored in Python: facial action units drive the built-in rig.

The driver is a real recording when ``../shared/data`` is present — OpenFace 2.x action-unit
intensities (AUplayer, recorded for the AMHUSE dataset, Boccignone et al., ICMI 2017) at the
recording's own frame rate — and otherwise a scripted sequence of AU pulses. Each FACS action unit
maps to the muscles that produce it (SPEC §5); intensities 0–5 scale the muscles' contractions,
given in inter-ocular distances (the built-in rig's presets use the same unit). The contractions
become time samples on the rig's muscle prims, the stage is baked to a ``.usdc`` point cache, and
a video and a contact sheet are rendered from the baked stage.

    python examples/scripted_animation.py [--recording 10_3_au.txt] [--out out/scripted] [--device cpu]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import warp as wp

from warpface import preview, usd
from warpface.assets import default_rig, rig_scale
from warpface.data import shared_data_path

AU_MUSCLES = {
    # action unit: {muscle: contraction at intensity 5, in inter-ocular distances (sphincters: K)}
    "AU01": {"frontalis_inner_L": 0.16, "frontalis_inner_R": 0.16},
    "AU02": {"frontalis_outer_L": 0.14, "frontalis_outer_R": 0.14},
    "AU04": {"corrugator_L": 0.09, "corrugator_R": 0.09, "procerus": 0.06},
    "AU06": {"orbicularis_oculi_L": 0.22, "orbicularis_oculi_R": 0.22},
    "AU09": {"levator_labii_alaeque_nasi_L": 0.11, "levator_labii_alaeque_nasi_R": 0.11},
    "AU10": {"levator_labii_superioris_L": 0.06, "levator_labii_superioris_R": 0.06},
    "AU12": {"zygomaticus_major_L": 0.22, "zygomaticus_major_R": 0.22},
    "AU15": {"depressor_anguli_oris_L": 0.06, "depressor_anguli_oris_R": 0.06},
    "AU17": {"mentalis": 0.05},
    "AU20": {"risorius_L": 0.06, "risorius_R": 0.06},
}


def read_openface(path: Path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Timestamps [s] (F,) and AU intensities {AUxx: (F,)} of successfully tracked frames of an OpenFace CSV."""
    table = np.genfromtxt(path, delimiter=",", names=True, dtype=float, autostrip=True)
    ok = table["success"] > 0.5
    intensities = {name[:-2]: table[name][ok] for name in table.dtype.names if name.endswith("_r")}
    return table["timestamp"][ok], intensities


def scripted_aus(fps: float = 30.0, seconds: float = 6.0) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """A scripted performance: brows up, a frown, a sneer, then a smile, as smooth AU pulses."""
    times = np.arange(int(seconds * fps) + 1) / fps
    pulse = lambda centre: 5.0 * np.exp(-0.5 * ((times - centre) / 0.35) ** 2)
    aus = {au: np.zeros_like(times) for au in AU_MUSCLES}
    aus["AU01"] = aus["AU02"] = pulse(1.0)
    aus["AU04"] = pulse(2.4)
    aus["AU09"] = aus["AU10"] = pulse(3.7)
    aus["AU06"] = aus["AU12"] = pulse(5.0)
    return times, aus


def contractions_from_aus(rig, intensities: dict[str, np.ndarray], frames: int) -> np.ndarray:
    """Per-frame contractions (F, M) in the rig's muscle order: the sum of each AU's muscle pattern."""
    scale = rig_scale(rig)
    index = {m.name: i for i, m in enumerate(rig.muscles)}
    linear = {m.name: type(m).__name__ == "LinearMuscle" for m in rig.muscles}
    out = np.zeros((frames, len(rig.muscles)))
    for au, pattern in AU_MUSCLES.items():
        if au not in intensities:
            continue
        level = np.clip(intensities[au], 0.0, 5.0) / 5.0
        for muscle, value in pattern.items():
            out[:, index[muscle]] += level * value * (scale if linear[muscle] else 1.0)
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--recording", default="10_3_au.txt", help="AUplayer OpenFace file in ../shared/data")
    parser.add_argument("--out", type=Path, default=Path("out/scripted"), help="output folder")
    parser.add_argument("--device", default=None, help="Warp device")
    args = parser.parse_args(argv)
    wp.config.log_level = wp.LOG_WARNING
    args.out.mkdir(parents=True, exist_ok=True)

    recording = shared_data_path("auplayer_openface_au", args.recording)
    if recording is not None:
        times, aus = read_openface(recording)
        source = f"OpenFace recording {recording.name} ({len(times)} frames)"
    else:
        times, aus = scripted_aus()
        source = "scripted AU pulses (../shared/data not present)"
    fps = float(round(1.0 / np.median(np.diff(times)), 3))
    rig = default_rig()
    contractions = contractions_from_aus(rig, aus, len(times))

    stage_path = args.out / "face.usda"
    stage = usd.write_rig(stage_path, rig, fps=fps)
    time_codes = (times - times[0]) * fps  # the recording's own clock, at its native rate
    usd.write_animation(stage, time_codes, contractions=contractions, fps=fps)
    usd.export_layer_atomically(stage.GetRootLayer(), stage_path)
    cache = usd.bake(stage, device=args.device)
    print(f"driver: {source}, {fps:g} frames/s")
    print(f"wrote {stage_path} (contractions as time samples) and {cache} (baked points)")

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
