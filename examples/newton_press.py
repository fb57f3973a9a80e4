"""A sphere pressed into the cheek of the built-in face and released, in a Newton world.

The face's skull is a kinematic Newton body at rest; a kinematic sphere (3 cm radius) comes down the cheek's
normal, presses 3 mm into the skin, holds, and leaves. Newton's CollisionPipeline finds the soft contacts,
``SolverFace`` turns them into forces on the skin nodes within the tissue's Newmark step. Writes the rig stage
``out/newton_press/face.usda`` with the skin's point cache and ``press.mp4``.

    python examples/newton_press.py [--out out/newton_press] [--nodes 600]
"""

from __future__ import annotations

import newton
import numpy as np
import warp as wp
from newton_common import arguments, face_stage, finish, head_world, set_body

from warpface.newton import SkinRecorder, SolverFace, add_face

DT, FPS, SECONDS = 2.0e-3, 30.0, 1.2
RADIUS, DEPTH = 0.03, 0.003


def depth_at(t: float) -> float:
    """How far the sphere's apex is below the rest skin [m]: 5 mm off, in by 0.3 s, held, out by 0.8 s."""
    return -0.005 + (DEPTH + 0.005) * (np.clip((t - 0.1) / 0.2, 0, 1) - np.clip((t - 0.6) / 0.2, 0, 1))


def main(argv=None) -> None:
    args = arguments(argv, __doc__, "newton_press")
    stage_path, rig = face_stage(args.out, args.nodes, args.material)

    builder, head = head_world(newton.ModelBuilder)
    ibug = rig.mesh.points[rig.landmarks]
    cheek = int(np.argmin(np.linalg.norm(rig.mesh.points - 0.5 * (ibug[2] + ibug[31]), axis=1)))
    normal = rig.mesh.vertex_normals(device="cpu")[cheek]
    sphere = builder.add_body(xform=wp.transform((0.0, 0.0, 1.0), wp.quat_identity()), is_kinematic=True)
    builder.add_shape_sphere(sphere, radius=RADIUS)
    face = add_face(builder, stage_path, head_body=head, contact_radius=2.0e-4)
    model = builder.finalize(device="cpu")
    solver = SolverFace(model, face)
    pipeline = newton.CollisionPipeline(model, soft_contact_gap=0.004)
    contacts = pipeline.contacts()
    state_in, state_out, control = model.state(), model.state(), model.control()
    recorder = SkinRecorder(solver)

    def centre(t):
        return rig.mesh.points[cheek] + normal * (RADIUS - depth_at(t))

    set_body(state_in, sphere, centre(0.0), (0, 0, 0))
    steps, every = int(round(SECONDS / DT)), int(round(1.0 / (FPS * DT)))
    labels, deepest = [], 0.0
    for k in range(steps):
        t0, t1 = k * DT, (k + 1) * DT
        set_body(state_out, head, (0, 0, 0), (0, 0, 0))
        set_body(state_out, sphere, centre(t1), (centre(t1) - centre(t0)) / DT)
        pipeline.collide(state_in, contacts)
        solver.step(state_in, state_out, control, contacts, DT)
        state_in, state_out = state_out, state_in
        if (k + 1) % every == 0:
            recorder.record((k + 1) // every, state_in)
            press = -(recorder.frames[-1][cheek] - rig.mesh.points[cheek]) @ normal
            deepest = max(deepest, press)
            labels.append(f"t {t1:.2f} s  sphere {1e3 * depth_at(t1):+.1f} mm  skin {1e3 * press:+.2f} mm")
    print(f"deepest indentation of the cheek vertex: {1e3 * deepest:.2f} mm (sphere {1e3 * DEPTH:.1f} mm in)")
    print(f"clamped contact steps: {solver.clamped_steps}")
    finish(recorder, stage_path, args.out, "press", FPS, labels=lambda i: labels[i])


if __name__ == "__main__":
    main()
