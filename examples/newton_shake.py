"""The built-in face's head shaken by a prescribed rigid motion while a Live Link take plays: the tissue jiggles.

The skull is a kinematic Newton body: a 3 Hz head shake (yaw ±12°) with a small nod and a bob; a Live Link Face
take (smile, raised brows, open jaw, a blink; written by the example) drives the muscles through warpface's
default ARKit table. ``SolverFace`` adds the inertial forces of the head's motion to the tissue's Newmark step.
Writes ``out/newton_shake/face.usda`` with the skin's point cache (head frame: the jiggle without the shake) and
``shake.mp4``.

    python examples/newton_shake.py [--out out/newton_shake] [--nodes 600]
"""

from __future__ import annotations

import numpy as np
import warp as wp
from newton_common import arguments, face_stage, finish, live_link_take, play_take, quat_about

DT, FPS = 2.0e-3, 30.0
SHAKE_HZ, YAW, NOD, BOB = 3.0, np.radians(12.0), np.radians(4.0), 0.01


def head_pose(t: float):
    """Pose and twist of the shaken head at time ``t`` [s] (yaw about y, nod about x, bob along y)."""
    w = 2.0 * np.pi * SHAKE_HZ
    ramp = min(t / 0.3, 1.0)  # the shake starts within 0.3 s
    yaw, nod = ramp * YAW * np.sin(w * t), ramp * NOD * np.sin(2.0 * w * t)
    yaw_rate, nod_rate = ramp * YAW * w * np.cos(w * t), ramp * NOD * 2.0 * w * np.cos(2.0 * w * t)
    q_yaw, q_nod = quat_about((0.0, 1.0, 0.0), yaw), quat_about((1.0, 0.0, 0.0), nod)
    rotation = np.asarray(wp.mul(wp.quat(*q_yaw), wp.quat(*q_nod)), dtype=np.float64)
    omega = np.array([0.0, yaw_rate, 0.0]) + np.asarray(wp.quat_rotate(wp.quat(*q_yaw), wp.vec3(nod_rate, 0, 0)))
    position = np.array([0.0, BOB * ramp * np.sin(w * t), 0.0])
    velocity = np.array([0.0, BOB * ramp * w * np.cos(w * t), 0.0])
    return position, rotation, velocity, omega


def main(argv=None) -> None:
    args = arguments(argv, __doc__, "newton_shake")
    stage_path, rig = face_stage(args.out, args.nodes, args.material)
    take = live_link_take(args.out / "take.csv")
    recorder, _ = play_take(stage_path, rig, take, head_pose, dt=DT, fps=FPS)
    riding, _ = play_take(stage_path, rig, take, head_pose, dt=DT, fps=FPS, inertia=False)  # no jiggle
    jiggle = np.linalg.norm(np.stack(recorder.frames) - np.stack(riding.frames), axis=2).max(axis=1)
    print(f"jiggle (skin with minus without the head's inertial forces): up to {1e3 * jiggle.max():.2f} mm")
    finish(
        recorder, stage_path, args.out, "shake", FPS, labels=lambda i: f"frame {i + 1}  jiggle {1e3 * jiggle[i]:.2f} mm"
    )


if __name__ == "__main__":
    main()
