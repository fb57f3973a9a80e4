"""Kato's hyper-expression: a captured take replayed at 3 g.

A Live Link Face take (written by the example) plays on the built-in face twice in a Newton world whose head
is at rest: once under the gravity the face was captured in (1 g, which its rest shape already balances) and
once at 3 g (``SolverFace(gravity=...)``: a roller coaster's pull, a heavier planet), where the cheeks and lips
sag by the extra 2 g. Writes ``out/newton_hyper/face.usda`` with the 3 g skin's point cache and ``hyper.mp4``.

    python examples/newton_hyper.py [--out out/newton_hyper] [--nodes 600] [--g 3]
"""

from __future__ import annotations

import numpy as np
from newton_common import arguments, face_stage, finish, live_link_take, play_take

DT, FPS, EARTH = 2.0e-3, 30.0, np.array([0.0, -9.81, 0.0])


def at_rest(t: float):
    """The head's pose and twist: still, upright."""
    return np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.zeros(3)


def main(argv=None) -> None:
    args = arguments(
        argv, __doc__, "newton_hyper", lambda p: p.add_argument("--g", type=float, default=3.0, help="gravity, in g")
    )
    stage_path, rig = face_stage(args.out, args.nodes, args.material)
    take = live_link_take(args.out / "take.csv")
    captured, _ = play_take(stage_path, rig, take, at_rest, dt=DT, fps=FPS)
    hyper, _ = play_take(stage_path, rig, take, at_rest, dt=DT, fps=FPS, gravity=args.g * EARTH)
    sag = np.stack(hyper.frames) - np.stack(captured.frames)
    drop = -sag[..., 1].min(axis=1)
    print(f"at {args.g:g} g the skin hangs up to {1e3 * drop.max():.3f} mm lower than in the captured take")
    finish(hyper, stage_path, args.out, "hyper", FPS, labels=lambda i: f"{args.g:g} g  sag {1e3 * drop[i]:.3f} mm")


if __name__ == "__main__":
    main()
